"""Patches of the texture and what one optimizer step needs of them, prepared once.

The texture is tiled into square patches (edge a multiple of the observation
store's block size); each epoch visits every patch once in a seeded random
order (:func:`patch_order`), so a resumed run repeats the same order. A
:class:`PreparedPatch` holds the patch's texel-views as Dr.Jit arrays, its
window (the patch plus a :data:`~polarbssrdf.inverse.polarimetric.regularizers.HALO`-texel
halo) and the window's atlas, normalized for :func:`normals_from_height`.
Preparing a patch costs a read from the store; :class:`PatchCache` keeps
prepared patches up to a budget of texel-views so epochs after the first
read nothing from disk when the observations fit in memory.
"""

from __future__ import annotations

import collections
import dataclasses

import drjit as dr
import numpy as np

from polarbssrdf._arrays import to_jit
from polarbssrdf.geometry.atlas import TexelAtlas
from polarbssrdf.geometry.height import height_frame
from polarbssrdf.inverse.polarimetric.model import ViewGeometry, jit_types
from polarbssrdf.inverse.polarimetric.regularizers import HALO, window_stencils


@dataclasses.dataclass(frozen=True)
class Patch:
    """A ``rows x cols`` block of texels at ``(row0, col0)``."""

    row0: int
    col0: int
    rows: int
    cols: int


def texture_patches(texture_size, patch_size, block_size):
    """The tiling of a ``T x T`` texture into patches (row-major)."""
    edge = max(block_size, (min(patch_size, texture_size) // block_size) * block_size)
    return [Patch(r, c, min(edge, texture_size - r), min(edge, texture_size - c))
            for r in range(0, texture_size, edge) for c in range(0, texture_size, edge)]


def patch_order(patches, epoch, seed, min_steps):
    """Seeded random order of one epoch's patch visits (at least ``min_steps`` of them)."""
    rng = np.random.default_rng([seed, epoch])
    repeats = max(1, -(-min_steps // len(patches)))
    return [patches[i] for _ in range(repeats) for i in rng.permutation(len(patches))]


def window_atlas(atlas, rows, cols):
    """The atlas of a window, with ``dp/du`` and ``dp/dv`` per unit of the window's own ``u``, ``v``.

    :func:`polarbssrdf.geometry.normals_from_height` differentiates ``H`` per
    unit of texture coordinate of the array it is given; scaling the tangents
    by the window's share of the texture keeps the normals those of the full
    texture (both factors of the cross product scale alike).
    """
    T = atlas.resolution
    return TexelAtlas(valid=atlas.valid[rows, cols], position=atlas.position[rows, cols],
                      normal=atlas.normal[rows, cols],
                      dp_du=atlas.dp_du[rows, cols] * ((cols.stop - cols.start) / T),
                      dp_dv=atlas.dp_dv[rows, cols] * ((rows.stop - rows.start) / T))


@dataclasses.dataclass
class PreparedPatch:
    """One patch ready for optimizer steps (see the module docstring).

    Attributes
    ----------
    patch : Patch
    window_rows, window_cols : slice
        The window (patch plus halo, clipped to the texture) in the texture.
    window_index : (n_window,) int64
        Flat texture index of every window texel (row-major).
    window_index_jit : UInt32
        The same, as a Dr.Jit array.
    window_valid : (rows, cols) bool
    window_valid_jit : Float
        The same, flat, as 0/1.
    atlas : TexelAtlas
        The window's atlas (see :func:`window_atlas`).
    height_frame : DeviceHeightFrame
        Eq. 25's constants of that atlas on the device (normals from ``H`` at every step).
    stencils : WindowStencils
    texel : UInt32
        Window index of each texel-view's texel (texel-views are ordered by it).
    texel_numpy : (N,) int64
        The same, in NumPy.
    view_start, view_count : UInt32
        Per window texel: its first texel-view and how many it has.
    camera_numpy : (N,) int64
        Each texel-view's camera: the index of the first of the store's views taken with it
        (the posterior's clusters of view-specific error).
    geometry : ViewGeometry
    observed : list of tuple of 4 Float
        ``(I0, I45, I90, I135)`` per band.
    image_scale : float
        Mean observed ``I_sss`` over the patch's texel-views (loss normalization).
    """

    patch: Patch
    window_rows: slice
    window_cols: slice
    window_index: np.ndarray
    window_index_jit: object
    window_valid: np.ndarray
    window_valid_jit: object
    atlas: TexelAtlas
    height_frame: object
    stencils: object
    texel: object
    texel_numpy: np.ndarray
    view_start: object
    view_count: object
    camera_numpy: np.ndarray
    geometry: ViewGeometry
    observed: list
    image_scale: float

    def __len__(self):
        return len(self.texel_numpy)

    def texel_sums(self, values):
        """Per window texel, the sums of per texel-view ``values`` over its texel-views.

        ``values``: sequence of Float of length N; returns a tuple of Float of
        the window's length. Each texel adds its own texel-views in order, so
        the sums do not depend on how Dr.Jit shares the kernel between
        threads (a scatter-add's do).
        """
        values = tuple(values)
        Float = type(values[0])
        UInt32 = type(self.view_start)
        n_window = len(self.window_index)

        def more(k, sums):
            return k < self.view_count

        def add(k, sums):
            index = self.view_start + k
            return k + 1, tuple(total + dr.gather(Float, v, index) for total, v in zip(sums, values))

        _, sums = dr.while_loop(state=(dr.zeros(UInt32, n_window),
                                       tuple(dr.zeros(Float, n_window) for _ in values)),
                                cond=more, body=add)
        return sums


def prepare_patch(store, atlas, patch):
    """Read a patch's texel-views from ``store`` and prepare them (:class:`PreparedPatch`)."""
    Float, _, UInt32, TensorXf = jit_types()
    T = atlas.resolution
    rows = slice(max(patch.row0 - HALO, 0), min(patch.row0 + patch.rows + HALO, T))
    cols = slice(max(patch.col0 - HALO, 0), min(patch.col0 + patch.cols + HALO, T))
    i, j = np.meshgrid(np.arange(rows.start, rows.stop), np.arange(cols.start, cols.stop),
                       indexing="ij")
    window_index = (i * T + j).ravel()
    valid = atlas.valid[rows, cols]
    patch_rows = slice(patch.row0 - rows.start, patch.row0 - rows.start + patch.rows)
    patch_cols = slice(patch.col0 - cols.start, patch.col0 - cols.start + patch.cols)
    views = store.read_window(patch.row0, patch.col0, patch.rows, patch.cols)
    local_atlas = window_atlas(atlas, rows, cols)
    texel_row, texel_col = np.divmod(np.asarray(views.texel, np.int64), T)
    local = (texel_row - rows.start) * (cols.stop - cols.start) + (texel_col - cols.start)
    order = np.argsort(local, kind="stable")
    views, local = views.take(order), local[order]
    view_count = np.bincount(local, minlength=len(window_index))
    view_index = np.asarray(views.view, np.int64)
    camera_names = [view["camera"] for view in store.views]
    # a store that names no cameras (one made in memory) counts each view as its own camera
    camera = (np.array([camera_names.index(name) for name in camera_names], np.int64)[view_index]
              if camera_names else view_index)
    view_start = np.concatenate([[0], np.cumsum(view_count)[:-1]])
    analyser = np.asarray(views.analyser, np.float32)
    observed = [tuple(to_jit(Float, analyser[:, band, k]) for k in range(4))
                for band in range(analyser.shape[1])]
    scale = float(np.mean(2.0 * analyser[:, :, 2])) if len(analyser) else 1.0
    return PreparedPatch(
        patch=patch, window_rows=rows, window_cols=cols, window_index=window_index,
        window_valid=valid, atlas=local_atlas,
        height_frame=height_frame(local_atlas).on_device(TensorXf),
        stencils=window_stencils(valid, patch_rows, patch_cols),
        texel=to_jit(UInt32, local, np.uint32), texel_numpy=local,
        view_start=to_jit(UInt32, view_start, np.uint32),
        view_count=to_jit(UInt32, view_count, np.uint32),
        camera_numpy=camera,
        window_index_jit=to_jit(UInt32, window_index, np.uint32),
        window_valid_jit=to_jit(Float, valid.ravel(), np.float32),
        geometry=ViewGeometry.from_texel_views(views), observed=observed,
        image_scale=max(scale, 1e-30))


class PatchCache:
    """Prepared patches, least recently used dropped beyond ``budget`` texel-views."""

    def __init__(self, store, atlas, budget=8_000_000):
        self.store, self.atlas, self.budget = store, atlas, int(budget)
        self._patches = collections.OrderedDict()
        self._size = 0

    def get(self, patch):
        if patch in self._patches:
            self._patches.move_to_end(patch)
            return self._patches[patch]
        prepared = prepare_patch(self.store, self.atlas, patch)
        self._patches[patch] = prepared
        self._size += len(prepared)
        while self._size > self.budget and len(self._patches) > 1:
            _, dropped = self._patches.popitem(last=False)
            self._size -= len(dropped)
        return prepared
