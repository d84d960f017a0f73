"""Registration of the package's Mitsuba plugins with the active variant.

A Python plugin class subclasses the ``mi.BSDF`` / ``mi.Emitter`` of the
variant that is active when its class statement runs, so the plugin modules
build their classes in a function of the variant and are registered anew
whenever the variant changes.
"""

from __future__ import annotations

import mitsuba as mi

_callback_installed = False


def _register_for_current_variant() -> None:
    from polarbssrdf.plugins import pbssrdf, pexitance, ppoint

    mi.register_bsdf("pbssrdf", lambda props: pbssrdf.make_class()(props))
    mi.register_emitter("ppoint", lambda props: ppoint.make_class()(props))
    mi.register_emitter("pexitance", lambda props: pexitance.make_class()(props))


def _on_variant_change(old_variant, new_variant) -> None:
    if new_variant is not None:
        _register_for_current_variant()


def register_plugins(install_variant_callback: bool = False) -> bool:
    """Register ``pbssrdf``, ``ppoint`` and ``pexitance`` for the active Mitsuba variant.

    Parameters
    ----------
    install_variant_callback:
        Also re-register automatically after every later
        :func:`mitsuba.set_variant` call.

    Returns
    -------
    bool
        ``True`` if a variant was active and the plugins were registered;
        ``False`` if no variant is set yet (they will be registered when one
        is set, provided the callback is installed).
    """
    global _callback_installed
    if install_variant_callback and not _callback_installed:
        mi.detail.add_variant_callback(_on_variant_change)
        _callback_installed = True
    if mi.variant() is None:
        return False
    _register_for_current_variant()
    return True
