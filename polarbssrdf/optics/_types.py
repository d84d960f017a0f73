"""Type helpers that keep the optics functions generic over Dr.Jit backends and precisions.

Every function in :mod:`polarbssrdf.optics` works on Python floats, on
``drjit.scalar`` arrays and on JIT arrays (``drjit.llvm.ad``,
``drjit.cuda.ad``), in single or double precision; Mueller matrices are
built in a matrix type given by the caller (e.g. ``mi.Spectrum`` inside a
polarized Mitsuba variant) or, when none is given, in the ``Matrix4f`` (or
``Matrix4f64``) of the backend of the inputs.
"""

from __future__ import annotations

import drjit as dr


def _first_array_type(values):
    for value in values:
        if dr.is_array_v(type(value)):
            return type(value)
    return None


def _module_and_double(values):
    """(Dr.Jit backend module, double precision?) of the first Dr.Jit array in ``values``."""
    tp = _first_array_type(values)
    if tp is None:
        return dr.scalar, True  # Python floats are doubles
    double = dr.type_v(tp) == dr.VarType.Float64
    backend, differentiable = dr.backend_v(tp), dr.is_diff_v(tp)
    if backend == dr.JitBackend.LLVM:
        return (dr.llvm.ad if differentiable else dr.llvm), double
    if backend == dr.JitBackend.CUDA:
        return (dr.cuda.ad if differentiable else dr.cuda), double
    return dr.scalar, double


def matrix_type_for(*values):
    """The Dr.Jit 4x4 matrix type matching the backend and precision of ``values``."""
    module, double = _module_and_double(values)
    return module.Matrix4f64 if double else module.Matrix4f


def array3_type_for(*values):
    """The Dr.Jit 3-vector type matching the backend and precision of ``values``."""
    module, double = _module_and_double(values)
    return module.Array3f64 if double else module.Array3f
