"""Element-wise math that dispatches to NumPy for ``ndarray`` inputs, else to Dr.Jit.

The optics formulas are written once against this small namespace, so they
run on Dr.Jit arrays (with autodiff, inside Mitsuba kernels) and on NumPy
images and texel arrays alike.
"""

from __future__ import annotations

import drjit as dr
import numpy as np

pi = np.pi
inv_pi = 1.0 / np.pi


def _numpy(*args):
    return any(isinstance(a, (np.ndarray, np.generic)) for a in args)


def select(mask, a, b):
    return np.where(mask, a, b) if _numpy(mask, a, b) else dr.select(mask, a, b)


def maximum(a, b):
    return np.maximum(a, b) if _numpy(a, b) else dr.maximum(a, b)


def clip(x, low, high):
    return np.clip(x, low, high) if _numpy(x) else dr.clip(x, low, high)


def square(x):
    return np.square(x) if _numpy(x) else dr.square(x)


def sqrt(x):
    return np.sqrt(x) if _numpy(x) else dr.sqrt(x)


def safe_sqrt(x):
    """``sqrt(max(x, 0))``."""
    return np.sqrt(np.maximum(x, 0.0)) if _numpy(x) else dr.safe_sqrt(x)


def sin(x):
    return np.sin(x) if _numpy(x) else dr.sin(x)


def cos(x):
    return np.cos(x) if _numpy(x) else dr.cos(x)


def sincos(x):
    return (np.sin(x), np.cos(x)) if _numpy(x) else dr.sincos(x)


def atan(x):
    return np.arctan(x) if _numpy(x) else dr.atan(x)


def atan2(y, x):
    return np.arctan2(y, x) if _numpy(y, x) else dr.atan2(y, x)
