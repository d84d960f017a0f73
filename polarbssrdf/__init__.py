"""polarbssrdf: polarimetric BSSRDF acquisition of faces with Mitsuba 3.

Importing the package registers the Mitsuba plugins ``pbssrdf`` (BSDF) and
``ppoint`` (polarized point light) for the active Mitsuba variant, and again
each time :func:`mitsuba.set_variant` changes it. :func:`register_plugins`
does the same on demand.
"""

from polarbssrdf._llvm import LibLLVMError, configure_libllvm, one_line_if_uncaught

try:
    configure_libllvm()  # before Mitsuba imports Dr.Jit
except LibLLVMError as _error:
    one_line_if_uncaught(_error)
    raise

from polarbssrdf.registration import register_plugins  # noqa: E402

__version__ = "0.1.0"
__all__ = ["register_plugins", "__version__"]

register_plugins(install_variant_callback=True)
