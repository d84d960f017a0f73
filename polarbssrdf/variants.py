"""Choosing the Mitsuba variant a command or stage runs in, with the package's plugins registered.

A Mitsuba variant is process-wide state, and every stage that casts rays, builds
a texel atlas or renders needs one of a certain kind: the inverse stages a JIT
autodiff polarized variant (``llvm_ad_*`` or ``cuda_ad_*``), held-out
re-renders a JIT mono polarized one (bands are rendered one at a time). This
module is the one place that activates variants, so that the plugins
(:func:`polarbssrdf.register_plugins`) are always registered in the variant
that ends up active, and a variant that cannot be used is refused with one
line naming the usable ones.
"""

from __future__ import annotations

import mitsuba as mi

from polarbssrdf.errors import CommandError
from polarbssrdf.registration import register_plugins

DEFAULT_VARIANT = "llvm_ad_mono_polarized"
"""The variant of the stages and re-renders on a CPU (``cuda_ad_mono_polarized`` on a GPU)."""

JIT_PREFIXES = ("llvm_", "cuda_")


def autodiff_polarized_variants(available) -> list[str]:
    """The variants the stages run in: JIT (LLVM or CUDA), autodiff, polarized."""
    return [v for v in available
            if v.startswith(JIT_PREFIXES) and "_ad_" in v and v.endswith("polarized")]


def jit_mono_polarized_variants(available) -> list[str]:
    """The variants held-out views are re-rendered in: JIT, mono, polarized."""
    return [v for v in available if v.startswith(JIT_PREFIXES) and v.endswith("mono_polarized")]


def check_variant(variant: str, available) -> None:
    """Raise :class:`CommandError` unless ``variant`` is an available JIT AD polarized variant."""
    usable = autodiff_polarized_variants(available)
    if variant in usable:
        return
    choices = ", ".join(usable) or "none in this Mitsuba build"
    if variant not in available:
        reason = f"Mitsuba variant {variant!r} is not available in this build"
    elif not variant.endswith("polarized"):
        reason = f"variant {variant!r} is not polarized: the stages fit Stokes observations"
    else:
        reason = (f"variant {variant!r} is not a JIT autodiff variant: the stages need "
                  "Dr.Jit's autodiff (llvm_ad_* or cuda_ad_*)")
    raise CommandError(f"{reason}; use one of: {choices}")


def select_variant(variant: str) -> None:
    """Activate ``variant`` and register the package's plugins in it."""
    try:
        mi.set_variant(variant)
    except (ImportError, RuntimeError) as error:  # e.g. a CUDA variant without a GPU
        raise CommandError(f"cannot activate Mitsuba variant '{variant}': {error}") from None
    register_plugins()


def ensure_jit_variant(variant: str | None = None) -> None:
    """Make a JIT variant active: ``variant`` if given, else the active one if it is JIT, else
    :data:`DEFAULT_VARIANT` (ray casting, texel atlases and re-renders need one)."""
    active = mi.variant()
    wanted = variant or (active if active and active.startswith(JIT_PREFIXES)
                         else DEFAULT_VARIANT)
    if wanted != active:
        select_variant(wanted)
    else:
        register_plugins()


def ensure_mono_polarized_variant(variant: str) -> None:
    """Activate ``variant`` for per-band re-renders; a :class:`ValueError` unless it is an
    available mono polarized variant."""
    if not variant.endswith("mono_polarized"):
        raise ValueError(f"held-out views are rendered per band in a mono polarized variant, "
                         f"not {variant!r} (e.g. {DEFAULT_VARIANT})")
    if mi.variant() != variant:
        if variant not in mi.variants():
            raise ValueError(f"Mitsuba variant {variant!r} is not available in this build")
        select_variant(variant)
    else:
        register_plugins()
