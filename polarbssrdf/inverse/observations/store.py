"""On-disk layout of texture-space observations: :class:`TexelViews` and :class:`ObservationStore`.

The store is a zarr (v3) group. Why zarr: the observations of a 2K texture
seen by hundreds of views do not fit in memory, and the optimizer reads them
one texel patch at a time. Zarr gives exactly that: N-dimensional arrays cut
into independently compressed chunks, partial reads of any row range, a plain
directory of files that needs no server, and a well-kept, specified format
(v3) that the scientific Python world (xarray, dask, napari) reads directly.

Layout (``FORMAT_VERSION`` 1)::

    <store>/
      zarr.json                 group attributes: format_version, texture_size,
                                block_size, bands, views, frame, fingerprint, ...
      texel, view, to_camera, to_light, light_distance_mm, light_intensity,
      light_field, camera_basis, analyser
                                one array per :class:`TexelViews` field, N rows,
                                chunked along rows
      block_offsets             int64 (n_blocks + 1,): rows of block b are
                                block_offsets[b]:block_offsets[b + 1]
      texel_view_counts         int32 (T, T): texel-views stored per texel

Rows are sorted by texel block (``block_size x block_size`` texels, blocks
in row-major order over the texture), then by texel, then by view, so a
window of whole blocks is a few contiguous row ranges.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

__all__ = ["FIELDS", "FORMAT_VERSION", "ObservationStore", "TexelViews", "block_of_texel"]

FORMAT_VERSION = 2  # 2: raw samples in radiance (recorded calibration)
"""Version of the store layout; part of the fingerprint, so a new layout forces a rebuild."""

ROWS_PER_CHUNK = 65536
"""Rows per zarr chunk: about 1-6 MB uncompressed per array, a good unit for zstd and for reads."""

FIELDS = ("texel", "view", "to_camera", "to_light", "light_distance_mm", "light_intensity",
          "light_field", "camera_basis", "analyser")
"""Names of the :class:`TexelViews` arrays, in storage order."""

FIELD_DTYPES = {"texel": np.int32, "view": np.int16}
"""Non-float32 fields; every other field is float32."""


@dataclasses.dataclass(frozen=True)
class TexelViews:
    """Visible texel-views of a set of texels.

    All arrays have N rows and are float32 unless said; directions are in
    OBJECT space (the atlas frame: ``world = pose @ object``) and unit length.

    Attributes
    ----------
    texel : (N,) int32
        Flat texel index ``row * T + col`` in the full texture.
    view : (N,) int16
        Index into :attr:`ObservationStore.views`.
    to_camera : (N, 3)
        Texel -> camera centre.
    to_light : (N, 3)
        Texel -> light position.
    light_distance_mm : (N,)
        Texel to light, mm.
    light_intensity : (N,)
        The light's radiant intensity, W/sr (= S0 per sr leaving the polarizer).
    light_field : (N, 3)
        Unit electric-field direction of the light arriving at the texel
        (perpendicular to ``to_light``), ``ppoint``'s model: projection, or
        dichroic when the light has a ``polarizer_normal``.
    camera_basis : (N, 3)
        Unit Stokes x axis of the image for this ray:
        ``normalize(cross(-to_camera, camera_up))``, ``camera_up = -camera.down``
        (Mitsuba's ``stokes`` frame: x = image right, y = image up).
    analyser : (N, n_bands, 4)
        ``I0, I45, I90, I135`` sampled bilinearly at the projected texel centre.
    """

    texel: np.ndarray
    view: np.ndarray
    to_camera: np.ndarray
    to_light: np.ndarray
    light_distance_mm: np.ndarray
    light_intensity: np.ndarray
    light_field: np.ndarray
    camera_basis: np.ndarray
    analyser: np.ndarray

    def __len__(self):
        return len(self.texel)

    def as_dict(self) -> dict[str, np.ndarray]:
        """Field name -> array (storage order of :data:`FIELDS`)."""
        return {name: getattr(self, name) for name in FIELDS}

    def take(self, rows) -> TexelViews:
        """The texel-views at ``rows`` (an index array or boolean mask)."""
        return TexelViews(**{name: values[rows] for name, values in self.as_dict().items()})

    @classmethod
    def concatenate(cls, parts, n_bands: int) -> TexelViews:
        """One :class:`TexelViews` of ``parts`` in order; empty (with ``n_bands``) if none."""
        parts = list(parts)
        if not parts:
            return cls.empty(n_bands)
        return cls(**{name: np.concatenate([getattr(p, name) for p in parts]) for name in FIELDS})

    @classmethod
    def empty(cls, n_bands: int) -> TexelViews:
        """No texel-views, with the right dtypes and trailing shapes."""
        return cls(**{name: np.zeros((0, *field_shape(name, n_bands)), field_dtype(name))
                      for name in FIELDS})


def field_dtype(name: str):
    """NumPy dtype of a :class:`TexelViews` field."""
    return FIELD_DTYPES.get(name, np.float32)


def field_shape(name: str, n_bands: int) -> tuple[int, ...]:
    """Trailing shape (after the row axis) of a :class:`TexelViews` field."""
    if name == "analyser":
        return (n_bands, 4)
    if name in ("to_camera", "to_light", "light_field", "camera_basis"):
        return (3,)
    return ()


def block_of_texel(texel, texture_size: int, block_size: int) -> np.ndarray:
    """Row-major block index of flat texel indices (``row * T + col``)."""
    texel = np.asarray(texel, dtype=np.int64)
    blocks_per_row = -(-texture_size // block_size)
    row, col = texel // texture_size, texel % texture_size
    return (row // block_size) * blocks_per_row + col // block_size


class ChunkedAppender:
    """Append rows to a zarr array of known final length, writing whole chunks only.

    Writing chunk-aligned row ranges lets zarr compress each chunk once
    instead of reading back and rewriting partly filled chunks.
    """

    def __init__(self, array):
        self.array = array
        self.rows_per_chunk = array.chunks[0]
        self.written = 0
        self.pending: list[np.ndarray] = []
        self.pending_rows = 0

    def append(self, values: np.ndarray) -> None:
        """Queue ``values`` (rows of the array) and write every full chunk."""
        if len(values) == 0:
            return
        self.pending.append(values)
        self.pending_rows += len(values)
        if self.pending_rows >= self.rows_per_chunk:
            self._write(flush=False)

    def close(self) -> None:
        """Write what is left; the array must then be exactly full."""
        self._write(flush=True)
        if self.written != self.array.shape[0]:
            raise RuntimeError(f"internal error: wrote {self.written} rows into an array of "
                               f"{self.array.shape[0]}")

    def _write(self, flush: bool) -> None:
        if not self.pending:
            return
        values = np.concatenate(self.pending) if len(self.pending) > 1 else self.pending[0]
        full = len(values) if flush else (len(values) // self.rows_per_chunk) * self.rows_per_chunk
        if full:
            self.array[self.written:self.written + full] = values[:full]
            self.written += full
        rest = values[full:].copy()  # a view would keep the whole concatenation alive
        self.pending = [rest] if len(rest) else []
        self.pending_rows = len(rest)


def compressor():
    """Blosc zstd with bit shuffling: about 0.75 of the raw size for these float32 rows
    (0.87 with zarr's default plain zstd) and faster to write."""
    # zarr (0.3 s to import) is imported where a store is opened or written: the command
    # line reaches this module for its constants, and must start fast
    from zarr.codecs import BloscCodec

    return BloscCodec(cname="zstd", clevel=3, shuffle="bitshuffle")


def create_field_arrays(group, n_rows: int, n_bands: int, rows_per_chunk: int = ROWS_PER_CHUNK):
    """Create one zarr array per :class:`TexelViews` field in ``group``; returns name -> array."""
    chunk_rows = max(1, min(rows_per_chunk, n_rows))
    arrays = {}
    for name in FIELDS:
        trailing = field_shape(name, n_bands)
        arrays[name] = group.create_array(name, shape=(n_rows, *trailing),
                                          chunks=(chunk_rows, *trailing), dtype=field_dtype(name),
                                          fill_value=0, compressors=compressor())
    return arrays


class ObservationStore:
    """Read side of an on-disk observation store (a zarr v3 group); see the module docstring.

    Open one with :meth:`open`; build one with
    :func:`polarbssrdf.inverse.observations.build.build_observations`.

    Attributes
    ----------
    path : pathlib.Path
    texture_size : int
        ``T`` of the texel atlas.
    block_size : int
        Texels per block side.
    bands : tuple of str
        Band names, the order of ``TexelViews.analyser``'s second axis.
    views : list of dict
        One per stored view: ``{"camera": name, "light": name, "image": relative path}``.
    frame : int
        The capture's frame index.
    fingerprint : str
        Hash of everything the store was built from (see
        :func:`~polarbssrdf.inverse.observations.build.observation_fingerprint`).
    attrs : dict
        All group attributes (also build statistics and skipped views).
    """

    def __init__(self, path, group):
        self.path = Path(path)
        self._group = group
        attrs = dict(group.attrs)
        version = attrs.get("format_version")
        if version != FORMAT_VERSION:
            raise ValueError(f"'{path}' is an observation store of format version {version!r}; "
                             f"this code reads version {FORMAT_VERSION}: rebuild it")
        self.attrs = attrs
        self.texture_size = int(attrs["texture_size"])
        self.block_size = int(attrs["block_size"])
        self.bands = tuple(attrs["bands"])
        self.views = [dict(view) for view in attrs["views"]]
        self.frame = int(attrs["frame"])
        self.fingerprint = str(attrs["fingerprint"])
        self.block_offsets = np.asarray(group["block_offsets"][:], dtype=np.int64)
        self._arrays = {name: group[name] for name in FIELDS}

    @classmethod
    def open(cls, path) -> ObservationStore:
        """Open the store at ``path`` read-only.

        ``FileNotFoundError`` if there is no zarr group, ``ValueError`` if it is
        not an observation store or has another format version.
        """
        import zarr  # deferred, see compressor()

        path = Path(path)
        if not (path / "zarr.json").is_file():
            raise FileNotFoundError(f"'{path}' is not an observation store (no zarr.json)")
        group = zarr.open_group(os.fspath(path), mode="r")
        if group.attrs.get("kind") != "polarbssrdf.observations":
            raise ValueError(f"'{path}' is a zarr group but not a polarbssrdf observation store")
        return cls(path, group)

    def __repr__(self):
        return (f"ObservationStore('{self.path}', T={self.texture_size}, "
                f"{len(self.views)} views, {len(self)} texel-views)")

    def __len__(self):
        return int(self.block_offsets[-1])

    @property
    def blocks_per_row(self) -> int:
        return -(-self.texture_size // self.block_size)

    @property
    def n_bands(self) -> int:
        return len(self.bands)

    def read_rows(self, start: int, stop: int) -> TexelViews:
        """Texel-views of rows ``start:stop`` of the store (storage order)."""
        return TexelViews(**{name: np.asarray(self._arrays[name][start:stop])
                             for name in FIELDS})

    def read_window(self, row0, col0, rows, cols) -> TexelViews:
        """Texel-views of all texels in a window of the texture.

        Parameters
        ----------
        row0, col0 : int
            Top-left texel of the window; multiples of :attr:`block_size`.
        rows, cols : int
            Window size in texels; the window is clipped to the texture.

        Returns
        -------
        TexelViews
            Sorted by block (row-major over the window's blocks), then texel,
            then view.
        """
        T, bs = self.texture_size, self.block_size
        for name, value in (("row0", row0), ("col0", col0)):
            if int(value) != value or value < 0 or value % bs:
                raise ValueError(f"{name} must be a non-negative multiple of the block size "
                                 f"{bs}, got {value!r}")
        if rows < 1 or cols < 1:
            raise ValueError(f"the window must be at least 1 x 1 texels, got {rows} x {cols}")
        row1, col1 = min(T, row0 + rows), min(T, col0 + cols)
        if row0 >= T or col0 >= T:
            return TexelViews.empty(self.n_bands)
        block_cols = range(col0 // bs, -(-col1 // bs))
        parts = []
        for block_row in range(row0 // bs, -(-row1 // bs)):
            first = block_row * self.blocks_per_row + block_cols.start
            last = block_row * self.blocks_per_row + block_cols.stop
            start, stop = int(self.block_offsets[first]), int(self.block_offsets[last])
            if stop > start:
                parts.append(self.read_rows(start, stop))
        views = TexelViews.concatenate(parts, self.n_bands)
        # whole blocks were read: drop the texels of partly covered blocks outside the window
        texel_row, texel_col = views.texel // T, views.texel % T
        inside = (texel_row >= row0) & (texel_row < row1) & (texel_col >= col0) & (texel_col < col1)
        return views if inside.all() else views.take(inside)

    def windows(self, size: int):
        """``(row0, col0, rows, cols)`` of every ``size x size`` window covering the texture.

        ``size`` must be a multiple of :attr:`block_size`.
        """
        if size < 1 or size % self.block_size:
            raise ValueError(f"window size must be a positive multiple of the block size "
                             f"{self.block_size}, got {size}")
        T = self.texture_size
        return [(r, c, min(size, T - r), min(size, T - c))
                for r in range(0, T, size) for c in range(0, T, size)]

    def texel_view_counts(self) -> np.ndarray:
        """(T, T) int32: texel-views stored per texel (written at build time)."""
        return np.asarray(self._group["texel_view_counts"][:], dtype=np.int32)
