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
    """Unit normals of the surface displaced by ``height`` along the shading normal; eq. 25.

    Built in the shading frame of each texel: with ``n0`` the interpolated
    (shading) normal and ``P = I - n0 n0^T`` the projection onto its plane,

        ``n ~ (P dp/du + dH/du n0) x (P dp/dv + dH/dv n0)``,

    oriented like ``n0``. At ``H = 0`` this is ``n0`` itself (the atlas'
    :attr:`~polarbssrdf.geometry.TexelAtlas.normal`, what the renderer shades
    with), not the triangle's flat normal ``dp/du x dp/dv``, which differs from
    it by degrees on a coarse mesh. ``P dp/du`` and ``P dp/dv`` play the roles
    of ``s_u t_u`` and ``s_v t_v`` of eq. 25. (The supplement's matrix form of
    eq. 25 scales ``dH/du`` by ``s_u`` where the cross product gives ``s_v``;
    the two agree only for square texels, and the cross product is the
    derivative of the displaced surface, so the cross-product form is used.)
    The term ``H dn0/du`` of the exact derivative (curvature times height) is
    neglected, as in eq. 25.

    Parameters
    ----------
    height : (T, T) array (NumPy, or Dr.Jit TensorXf for autodiff)
        Displacement along the shading normal, mm.
    atlas : TexelAtlas
        Surface frame per texel.

    Returns
    -------
    (T, T, 3) NumPy array, or a tuple of three (T, T) tensors for Dr.Jit input.
    Texels off the mesh get ``atlas.normal`` (NumPy path).
    """
    dH_du, dH_dv = height_gradient(height)
    n0 = atlas.normal.astype(np.float64)
    n0 /= np.maximum(np.linalg.norm(n0, axis=-1, keepdims=True), 1e-30)
    # tangents projected onto the shading normal's plane: P dp/du x P dp/dv is parallel to n0
    a = atlas.dp_du - np.sum(atlas.dp_du * n0, axis=-1, keepdims=True) * n0
    b = atlas.dp_dv - np.sum(atlas.dp_dv * n0, axis=-1, keepdims=True) * n0
    # Mitsuba's v runs against the OBJ's (see polarbssrdf.geometry), which turns
    # dp/du x dp/dv inward: orient by the undisplaced surface. (The projection
    # keeps det(dp/du, dp/dv, n0), so the sign is the unprojected one.)
    orientation = np.where(np.sum(np.cross(a, b) * n0, axis=-1) < 0, -1.0, 1.0)
    if isinstance(height, np.ndarray):
        du = a + dH_du[..., None] * n0
        dv = b + dH_dv[..., None] * n0
        n = np.cross(du, dv) * orientation[..., None]
        n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-30)
        return np.where(atlas.valid[..., None], n, atlas.normal)
    import drjit as dr

    Tensor = type(height)

    def component(array, k):
        return constant_like(height, array[..., k])

    du = [component(a, k) + dH_du * component(n0, k) for k in range(3)]
    dv = [component(b, k) + dH_dv * component(n0, k) for k in range(3)]
    sign = constant_like(height, orientation)
    n = [du[1] * dv[2] - du[2] * dv[1], du[2] * dv[0] - du[0] * dv[2], du[0] * dv[1] - du[1] * dv[0]]
    length = dr.sqrt(dr.maximum(n[0] * n[0] + n[1] * n[1] + n[2] * n[2], 1e-30))
    return tuple(c * sign / length for c in n)
