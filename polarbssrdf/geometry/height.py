"""Normals of a displaced surface from a height map (supplement eq. 25, Riviere et al. 2020)."""

from __future__ import annotations

import numpy as np

from polarbssrdf._arrays import constant_like, neighbour_index, take


def _shifted(height, axis, step):
    """``height`` shifted by one texel along ``axis`` (edge texels repeated)."""
    return take(height, neighbour_index(height.shape[:2], axis, step))


def height_gradient(height):
    """``(dH/du, dH/dv)`` per texel by central differences, in height units per unit ``u``/``v``.

    ``u`` runs along columns and ``v`` along rows (texture convention of
    :mod:`polarbssrdf.geometry`); one texel is ``1 / T`` in ``u`` and ``v``.
    One-sided differences at the borders.
    """
    rows, cols = height.shape[0], height.shape[1]
    dH_du = (_shifted(height, 1, +1) - _shifted(height, 1, -1)) * (0.5 * cols)
    dH_dv = (_shifted(height, 0, +1) - _shifted(height, 0, -1)) * (0.5 * rows)
    # the border differences span one texel, not two
    border_u = np.ones((rows, cols), np.float32)
    border_u[:, [0, -1]] = 2.0
    border_v = np.ones((rows, cols), np.float32)
    border_v[[0, -1], :] = 2.0
    return dH_du * constant_like(height, border_u), dH_dv * constant_like(height, border_v)


def normals_from_height(height, atlas):
    """Unit normals of the surface displaced by ``height`` along the mesh normal; eq. 25.

    ``n ~ (dp/du + dH/du n0) x (dp/dv + dH/dv n0)``, the cross-product form of
    eq. 25 with ``s_u t_u = dp/du`` and ``s_v t_v = dp/dv`` from the atlas.
    (The supplement's matrix form of eq. 25 scales ``dH/du`` by ``s_u`` where
    the cross product gives ``s_v``; the two agree only for square texels, and
    the cross product is the derivative of the displaced surface.)

    Parameters
    ----------
    height : (T, T) array (NumPy, or Dr.Jit TensorXf for autodiff)
        Displacement along the mesh normal, mm.
    atlas : TexelAtlas
        Surface frame per texel.

    Returns
    -------
    (T, T, 3) NumPy array, or a tuple of three (T, T) tensors for Dr.Jit input.
    """
    dH_du, dH_dv = height_gradient(height)
    n0, a, b = atlas.normal, atlas.dp_du, atlas.dp_dv
    # Mitsuba's v runs against the OBJ's (see polarbssrdf.geometry), which turns
    # dp/du x dp/dv inward: orient by the undisplaced surface.
    orientation = np.where(np.sum(np.cross(a, b) * n0, axis=-1) < 0, -1.0, 1.0)
    if isinstance(height, np.ndarray):
        du = a + dH_du[..., None] * n0
        dv = b + dH_dv[..., None] * n0
        n = np.cross(du, dv) * orientation[..., None]
        n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-30)
        return np.where(atlas.valid[..., None], n, n0)
    import drjit as dr

    Tensor = type(height)

    def component(array, k):
        return constant_like(height, array[..., k])

    du = [component(a, k) + dH_du * component(n0, k) for k in range(3)]
    dv = [component(b, k) + dH_dv * component(n0, k) for k in range(3)]
    sign = Tensor(orientation.astype(np.float32))
    n = [du[1] * dv[2] - du[2] * dv[1], du[2] * dv[0] - du[0] * dv[2], du[0] * dv[1] - du[1] * dv[0]]
    length = dr.sqrt(dr.maximum(n[0] * n[0] + n[1] * n[1] + n[2] * n[2], 1e-30))
    return tuple(c * sign / length for c in n)
