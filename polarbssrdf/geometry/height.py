"""Normals of a displaced surface from a height map (supplement eq. 25, Riviere et al. 2020)."""

from __future__ import annotations

import dataclasses
import functools

import drjit as dr
import numpy as np

from polarbssrdf._arrays import constant_like, neighbour_index, take, to_jit


@dataclasses.dataclass(frozen=True)
class HeightFrame:
    """What eq. 25 needs of an atlas besides ``H``, computed once (see :func:`height_frame`).

    Attributes
    ----------
    normal : (T, T, 3) float64
        Unit shading normal ``n0``.
    tangent_u, tangent_v : (T, T, 3) float64
        ``P dp/du`` and ``P dp/dv``: the surface tangents projected on ``n0``'s plane.
    orientation : (T, T) float64
        +-1 orienting ``tangent_u x tangent_v`` like ``n0``.
    valid : (T, T) bool
    fallback : (T, T, 3)
        The atlas normal, returned off the mesh (NumPy path).
    shape : (rows, cols)
    """

    normal: np.ndarray
    tangent_u: np.ndarray
    tangent_v: np.ndarray
    orientation: np.ndarray
    valid: np.ndarray
    fallback: np.ndarray
    shape: tuple

    def on_device(self, tensor_type):
        """The frame's constants as ``tensor_type`` maps, for Dr.Jit heights (:class:`DeviceHeightFrame`)."""

        def as_map(values):
            return to_jit(tensor_type, values, np.float32)

        def maps(values):
            return tuple(as_map(values[..., k]) for k in range(3))

        index_type = dr.uint32_array_t(dr.array_t(tensor_type))
        shifts = {(axis, step): to_jit(index_type, chart_neighbour_index(self.valid, axis, step),
                                       np.uint32)
                  for axis in (0, 1) for step in (-1, 1)}
        return DeviceHeightFrame(
            normal=maps(self.normal), tangent_u=maps(self.tangent_u),
            tangent_v=maps(self.tangent_v),
            orientation=as_map(self.orientation),
            border_u=as_map(one_sided_factor(self.valid, 1)),
            border_v=as_map(one_sided_factor(self.valid, 0)), shifts=shifts, shape=self.shape)


@dataclasses.dataclass(frozen=True)
class DeviceHeightFrame:
    """A :class:`HeightFrame` as Dr.Jit tensors (components as tuples of (T, T) maps)."""

    normal: tuple
    tangent_u: tuple
    tangent_v: tuple
    orientation: object
    border_u: object
    border_v: object
    shifts: dict
    shape: tuple


def height_frame(atlas):
    """The per-texel constants of eq. 25 of ``atlas`` (:class:`HeightFrame`)."""
    n0 = atlas.normal.astype(np.float64)
    n0 /= np.maximum(np.linalg.norm(n0, axis=-1, keepdims=True), 1e-30)
    # tangents projected onto the shading normal's plane: P dp/du x P dp/dv is parallel to n0
    a = atlas.dp_du - np.sum(atlas.dp_du * n0, axis=-1, keepdims=True) * n0
    b = atlas.dp_dv - np.sum(atlas.dp_dv * n0, axis=-1, keepdims=True) * n0
    # Mitsuba's v runs against the OBJ's (see polarbssrdf.geometry), which turns
    # dp/du x dp/dv inward: orient by the undisplaced surface. (The projection
    # keeps det(dp/du, dp/dv, n0), so the sign is the unprojected one.)
    orientation = np.where(np.sum(np.cross(a, b) * n0, axis=-1) < 0, -1.0, 1.0)
    return HeightFrame(n0, a, b, orientation, np.asarray(atlas.valid, bool), atlas.normal,
                       tuple(atlas.valid.shape))


def chart_neighbour_index(valid, axis, step):
    """Flat index of each texel's neighbour ``step`` (+-1) along ``axis``, or of the texel
    itself where that neighbour is off the map or off the charts (``valid`` False).

    A texel beyond a chart's edge carries no surface of that chart (the surface goes on in
    another chart, or ends), so a difference across the edge is one-sided, as at the map's
    border: its height never enters.
    """
    valid = np.asarray(valid, bool)
    return _chart_stencil(valid.shape, valid.tobytes())[0][axis, step]


def one_sided_factor(valid, axis):
    """(rows, cols) float32: 2 where a central difference along ``axis`` lost one of its two
    neighbours (:func:`chart_neighbour_index`), so that it spans one texel, not two; else 1."""
    valid = np.asarray(valid, bool)
    return _chart_stencil(valid.shape, valid.tobytes())[1][axis]


@functools.lru_cache(maxsize=16)
def _chart_stencil(shape, valid_bytes):
    """Neighbour indices and one-sided factors of a mask, kept: a fit's every step asks for
    its windows' (the arrays are shared, read-only)."""
    valid = np.frombuffer(valid_bytes, bool).reshape(shape)
    own = np.arange(valid.size)
    indices, factors = {}, {}
    for axis in (0, 1):
        for step in (-1, 1):
            neighbour = neighbour_index(shape, axis, step)
            indices[axis, step] = np.where(valid.ravel()[neighbour], neighbour, own)
            indices[axis, step].flags.writeable = False
        missing = sum((indices[axis, step] == own).astype(int) for step in (-1, 1))
        factors[axis] = np.where(missing.reshape(shape) == 1, 2.0, 1.0).astype(np.float32)
        factors[axis].flags.writeable = False
    return indices, factors


def _shifted(height, axis, step, shifts=None, valid=None):
    """``height`` at each texel's neighbour along ``axis`` (:func:`chart_neighbour_index`)."""
    if shifts is not None:
        Array = type(height.array)
        return type(height)(dr.gather(Array, height.array, shifts[(axis, step)]), height.shape)
    return take(height, chart_neighbour_index(valid, axis, step))


def height_gradient(height, frame=None, valid=None):
    """``(dH/du, dH/dv)`` per texel by central differences, in height units per unit ``u``/``v``.

    ``u`` runs along columns and ``v`` along rows (texture convention of
    :mod:`polarbssrdf.geometry`); one texel is ``1 / T`` in ``u`` and ``v``.
    One-sided differences at the map's borders and at the charts' edges: ``valid``
    (rows, cols) bool marks the texels on the charts (all, when not given), whose
    neighbours alone enter a texel's differences. ``frame``: a :class:`DeviceHeightFrame`
    whose shift indices and border factors to reuse (Dr.Jit heights; its own ``valid``).
    """
    rows, cols = height.shape[0], height.shape[1]
    shifts = None if frame is None else frame.shifts
    if frame is None:
        valid = np.ones((rows, cols), bool) if valid is None else np.asarray(valid, bool)
    dH_du = ((_shifted(height, 1, +1, shifts, valid) - _shifted(height, 1, -1, shifts, valid))
             * (0.5 * cols))
    dH_dv = ((_shifted(height, 0, +1, shifts, valid) - _shifted(height, 0, -1, shifts, valid))
             * (0.5 * rows))
    if frame is not None:
        return dH_du * frame.border_u, dH_dv * frame.border_v
    return (dH_du * constant_like(height, one_sided_factor(valid, 1)),
            dH_dv * constant_like(height, one_sided_factor(valid, 0)))


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
    atlas : TexelAtlas, HeightFrame or DeviceHeightFrame
        Surface frame per texel; an optimizer evaluating eq. 25 at every step
        passes the frame of :func:`height_frame` (on the device for Dr.Jit
        heights) so its constants are computed once.

    Returns
    -------
    (T, T, 3) NumPy array, or a tuple of three (T, T) tensors for Dr.Jit input.
    Texels off the mesh get ``atlas.normal`` (NumPy path).
    """
    if isinstance(atlas, DeviceHeightFrame):
        return _device_normals(height, atlas)
    frame = atlas if isinstance(atlas, HeightFrame) else height_frame(atlas)
    if not isinstance(height, np.ndarray):
        return _device_normals(height, frame.on_device(type(height)))
    dH_du, dH_dv = height_gradient(height, valid=frame.valid)
    n0 = frame.normal
    du = frame.tangent_u + dH_du[..., None] * n0
    dv = frame.tangent_v + dH_dv[..., None] * n0
    n = np.cross(du, dv) * frame.orientation[..., None]
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-30)
    return np.where(frame.valid[..., None], n, frame.fallback)


def normals_from_slopes(dH_du, dH_dv, normal, tangent_u, tangent_v, orientation):
    """Eq. 25 from the height's slopes: ``n ~ (t_u + dH/du n0) x (t_v + dH/dv n0)``, unit length.

    Elementwise on Dr.Jit arrays (components as sequences of three): per
    texel, or per texel-view with the frame gathered to it. ``normal``,
    ``tangent_u``, ``tangent_v`` and ``orientation`` are the fields of
    :class:`HeightFrame`. Returns a tuple of three components.
    """
    du = [tangent_u[k] + dH_du * normal[k] for k in range(3)]
    dv = [tangent_v[k] + dH_dv * normal[k] for k in range(3)]
    n = [du[1] * dv[2] - du[2] * dv[1], du[2] * dv[0] - du[0] * dv[2], du[0] * dv[1] - du[1] * dv[0]]
    length = dr.sqrt(dr.maximum(n[0] * n[0] + n[1] * n[1] + n[2] * n[2], 1e-30))
    return tuple(c * orientation / length for c in n)


def height_gradient_adjoint(gradient_u, gradient_v, valid=None):
    """Adjoint of :func:`height_gradient` (NumPy): the gradient with respect to ``H`` of a
    function whose gradients with respect to ``dH/du`` and ``dH/dv`` are given.

    Parameters
    ----------
    gradient_u, gradient_v : (rows, cols) arrays
    valid : (rows, cols) bool, optional
        The texels on the charts, as given to :func:`height_gradient` (all when not given).

    Returns
    -------
    (rows, cols) array
    """
    rows, cols = gradient_u.shape
    valid = np.ones((rows, cols), bool) if valid is None else np.asarray(valid, bool)
    out = np.zeros(rows * cols, np.result_type(gradient_u, gradient_v))
    for axis, gradient, per_unit in ((1, gradient_u, 0.5 * cols), (0, gradient_v, 0.5 * rows)):
        weighted = (gradient * per_unit * one_sided_factor(valid, axis)).ravel()
        for step, sign in ((1, 1.0), (-1, -1.0)):
            out += sign * np.bincount(chart_neighbour_index(valid, axis, step), weights=weighted,
                                      minlength=rows * cols)
    return out.reshape(rows, cols)


def _device_normals(height, frame):
    dH_du, dH_dv = height_gradient(height, frame)
    return normals_from_slopes(dH_du, dH_dv, frame.normal, frame.tangent_u, frame.tangent_v,
                               frame.orientation)
