"""Type helpers that keep the optics functions generic over Dr.Jit backends.

Every function in :mod:`polarbssrdf.optics` works on Python floats, on
``drjit.scalar`` arrays and on JIT arrays (``drjit.llvm.ad``,
``drjit.cuda.ad``); Mueller matrices are built in a matrix type given by the
caller (e.g. ``mi.Spectrum`` inside a polarized Mitsuba variant) or, when
none is given, in the ``Matrix4f`` of the backend of the inputs.
"""

from __future__ import annotations

import sys

import drjit as dr


def _backend_module(value):
    tp = type(value)
    if tp in (float, int, bool):
        return dr.scalar
    if dr.is_array_v(tp):
        module = sys.modules.get(tp.__module__)
        if module is not None and hasattr(module, "Matrix4f"):
            return module
        # Mitsuba's own aliases (mi.Float, mi.Color1f, ...) live in `mitsuba`;
        # find the Dr.Jit backend through the leaf type instead.
        leaf = dr.leaf_t(tp) if hasattr(dr, "leaf_t") else None
        if leaf is not None and leaf is not tp:
            return _backend_module(leaf(0))
        backend = dr.backend_v(tp)
        is_ad = dr.is_diff_v(tp)
        if backend == dr.JitBackend.LLVM:
            return dr.llvm.ad if is_ad else dr.llvm
        if backend == dr.JitBackend.CUDA:
            return dr.cuda.ad if is_ad else dr.cuda
    return dr.scalar


def matrix_type_for(*values):
    """Return the Dr.Jit ``Matrix4f`` type matching the backend of ``values``."""
    for value in values:
        if dr.is_array_v(type(value)):
            return _backend_module(value).Matrix4f
    return dr.scalar.Matrix4f


def array3_type_for(*values):
    """Return the Dr.Jit ``Array3f`` type matching the backend of ``values``."""
    for value in values:
        if dr.is_array_v(type(value)):
            return _backend_module(value).Array3f
    return dr.scalar.Array3f
