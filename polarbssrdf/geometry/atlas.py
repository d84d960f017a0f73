"""Texel atlas: what surface point, frame and footprint each texel of a map covers."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from polarbssrdf._arrays import to_jit


def texel_uv_grid(resolution):
    """Mitsuba ``uv`` of the texel centres of a ``resolution x resolution`` map, (T, T, 2).

    Row ``i`` and column ``j`` map to ``((j + 0.5) / T, (i + 0.5) / T)`` (see
    :mod:`polarbssrdf.geometry` for the convention).
    """
    if int(resolution) != resolution or resolution < 1:
        raise ValueError(f"texture resolution must be a positive integer, got {resolution!r}")
    centres = (np.arange(resolution) + 0.5) / resolution
    u, v = np.meshgrid(centres, centres)
    return np.stack([u, v], axis=-1)


@dataclasses.dataclass(frozen=True)
class TexelAtlas:
    """Per-texel surface data of a ``T x T`` map; arrays are (T, T, ...) float32.

    Attributes
    ----------
    valid : (T, T) bool
        The texel centre lies on the mesh.
    position : (T, T, 3)
        Surface point, mm.
    normal : (T, T, 3)
        Unit shading normal.
    dp_du, dp_dv : (T, T, 3)
        Position derivatives with respect to Mitsuba's ``u`` and ``v`` (mm per
        unit of texture coordinate); their lengths divided by ``T`` are the
        texel's extent in mm (:attr:`texel_size_mm`).
    """

    valid: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    dp_du: np.ndarray
    dp_dv: np.ndarray

    @property
    def resolution(self):
        return self.valid.shape[0]

    @functools.cached_property
    def texel_size_mm(self):
        """(T, T, 2) extent of each texel along ``u`` and ``v``, mm (0 where invalid).

        Computed once per atlas (the blur's geometry cache recognises the array).
        """
        sizes = np.stack([np.linalg.norm(self.dp_du, axis=-1),
                          np.linalg.norm(self.dp_dv, axis=-1)], axis=-1) / self.resolution
        return np.where(self.valid[..., None], sizes, 0.0)

    @property
    def tangent_frame(self):
        """Orthonormal ``(t_u, t_v, n)`` per texel: ``t_u`` along ``dp/du`` projected on the tangent plane."""
        n = self.normal
        t_u = self.dp_du - np.sum(self.dp_du * n, axis=-1, keepdims=True) * n
        t_u /= np.maximum(np.linalg.norm(t_u, axis=-1, keepdims=True), 1e-30)
        t_v = np.cross(n, t_u)
        return t_u, t_v, n


def texel_atlas(mitsuba_mesh, resolution):
    """Evaluate the mesh's parameterization at every texel centre.

    Parameters
    ----------
    mitsuba_mesh : mitsuba.Mesh
        A mesh with texture coordinates (see
        :func:`polarbssrdf.geometry.mesh.to_mitsuba`); the active variant must
        be a JIT variant.
    resolution : int
        Map size ``T``.
    """
    import drjit as dr
    import mitsuba as mi

    if not mitsuba_mesh.has_vertex_texcoords():
        raise ValueError("texel_atlas: the mesh has no texture coordinates")
    uv = texel_uv_grid(resolution).reshape(-1, 2)
    si = mitsuba_mesh.eval_parameterization(mi.Point2f(to_jit(mi.Float, uv[:, 0], np.float32),
                                                       to_jit(mi.Float, uv[:, 1], np.float32)))
    valid = np.array(si.is_valid())

    def grid(vector):
        values = np.array(vector, dtype=np.float32).T.reshape(resolution, resolution, -1)
        return np.where(valid.reshape(resolution, resolution, 1), values, 0.0).astype(np.float32)

    dr.eval(si.p, si.sh_frame.n, si.dp_du, si.dp_dv)
    return TexelAtlas(valid=valid.reshape(resolution, resolution), position=grid(si.p),
                      normal=grid(si.sh_frame.n), dp_du=grid(si.dp_du), dp_dv=grid(si.dp_dv))
