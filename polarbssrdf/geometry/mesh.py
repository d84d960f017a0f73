"""Triangle meshes with texture coordinates: loading, validation, subdivision, Mitsuba export."""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np

from polarbssrdf._arrays import to_jit


@dataclasses.dataclass(frozen=True)
class SurfaceMesh:
    """A triangle mesh with one texture coordinate per vertex.

    Attributes
    ----------
    vertices : (V, 3) float64
        Positions in millimetres.
    faces : (F, 3) int64
        Vertex indices, counter-clockwise seen from outside.
    uvs : (V, 2) float64
        Texture coordinates in the OBJ convention (``v`` up), in [0, 1].
    name : str
        A label for messages.
    normals : (V, 3) float64, optional
        Unit shading normals; None (the default): the area-weighted normals of the
        faces (:meth:`vertex_normals`).
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    name: str = "mesh"
    normals: np.ndarray | None = None

    def __post_init__(self):
        validate_mesh(self)

    def vertex_normals(self):
        """Unit vertex normals: :attr:`normals` if the mesh has them, else area-weighted."""
        if self.normals is not None:
            return np.asarray(self.normals, np.float64)
        corners = self.vertices[self.faces]
        face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals = np.zeros_like(self.vertices)
        for k in range(3):
            np.add.at(normals, self.faces[:, k], face_normals)
        return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)


def validate_mesh(mesh, min_area_mm2=1e-12, min_uv_area=1e-14):
    """Raise ``ValueError`` naming the problem if ``mesh`` is unusable for texel maps.

    Checks: shapes, finite values, face indices in range, UVs in [0, 1],
    no triangle with (near) zero area in 3-D or in UV space.
    """
    v, f, uv = mesh.vertices, mesh.faces, mesh.uvs
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
        raise ValueError(f"{mesh.name}: vertices must be an (N, 3) array, got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise ValueError(f"{mesh.name}: faces must be an (M, 3) array of triangles, got {f.shape}")
    if uv is None or uv.shape != (len(v), 2):
        raise ValueError(f"{mesh.name}: needs one UV per vertex, got "
                         f"{None if uv is None else uv.shape} for {len(v)} vertices")
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(uv))):
        raise ValueError(f"{mesh.name}: vertices or UVs contain NaN or infinite values")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"{mesh.name}: face indices must lie in [0, {len(v) - 1}]")
    if uv.min() < 0 or uv.max() > 1:
        raise ValueError(f"{mesh.name}: UVs must lie in [0, 1], found [{uv.min():g}, {uv.max():g}]")
    corners = v[f]
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0],
                                         corners[:, 2] - corners[:, 0]), axis=1)
    if np.any(area <= min_area_mm2):
        raise ValueError(f"{mesh.name}: {int(np.sum(area <= min_area_mm2))} degenerate "
                         f"triangle(s), e.g. face {int(np.argmin(area))}")
    t = uv[f]
    uv_area = 0.5 * np.abs((t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1])
                           - (t[:, 2, 0] - t[:, 0, 0]) * (t[:, 1, 1] - t[:, 0, 1]))
    if np.any(uv_area <= min_uv_area):
        raise ValueError(f"{mesh.name}: {int(np.sum(uv_area <= min_uv_area))} triangle(s) with "
                         f"zero UV area, e.g. face {int(np.argmin(uv_area))}")


def load_mesh(path, scale_to_mm=1.0):
    """Load a triangle mesh with UVs (OBJ, PLY, ... through trimesh), scaled to mm.

    Parameters
    ----------
    path : str or Path
        Mesh file. Vertex order and UVs are kept as stored.
    scale_to_mm : float
        Factor from the file's length unit to millimetres (10 for centimetres).
    """
    import trimesh

    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file not found: {path}")
    try:
        loaded = trimesh.load(path, process=False, maintain_order=True, force="mesh")
    except Exception as error:  # trimesh raises many types for malformed files
        raise ValueError(f"{path}: cannot read mesh ({error})") from error
    if len(loaded.faces) == 0 or len(loaded.vertices) == 0:
        # trimesh reads an empty or garbage file as an empty mesh, without an error
        raise ValueError(f"{path}: could not be read as a mesh (no triangles in it: an empty "
                         f"file, or not in the {path.suffix.lstrip('.').upper() or 'mesh'} "
                         "format)")
    uv = getattr(loaded.visual, "uv", None)
    if uv is None:
        raise ValueError(f"{path}: the mesh has no texture coordinates")
    return SurfaceMesh(np.asarray(loaded.vertices, dtype=np.float64) * scale_to_mm,
                       np.asarray(loaded.faces, dtype=np.int64),
                       np.asarray(uv, dtype=np.float64), name=path.name)


def subdivide(mesh, levels=1, keep_shading=False):
    """Loop-free midpoint subdivision: each triangle into four, ``levels`` times.

    Positions and UVs are interpolated linearly, so the surface and its
    parameterization are unchanged; only the texel-to-vertex density grows.
    With ``keep_shading`` the shading normals are interpolated too (and
    normalized), so the finer mesh shades like the coarse one (whose flat
    triangles would otherwise show as facets); without it the finer mesh's
    normals are its own area-weighted ones.
    """
    import trimesh.remesh

    vertices, faces, uvs = mesh.vertices, mesh.faces, mesh.uvs
    normals = mesh.vertex_normals() if keep_shading else None
    for _ in range(levels):
        carried = {"uv": uvs} if normals is None else {"uv": uvs, "normal": normals}
        vertices, faces, attributes = trimesh.remesh.subdivide(
            vertices, faces, vertex_attributes=carried)
        uvs = attributes["uv"]
        if normals is not None:
            normals = attributes["normal"]
            normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    return SurfaceMesh(vertices, faces, uvs, name=mesh.name, normals=normals)


def uv_sphere(radius_mm=50.0, rings=48, segments=96, name="uv_sphere"):
    """A UV sphere centred at the origin: ``u`` follows longitude, ``v`` latitude (v = 1 at +y).

    The seam column is duplicated so UVs stay continuous; the poles are cut
    by a small cap (``v`` in [1e-3, 1 - 1e-3]) to avoid zero-area UV triangles.
    """
    v = np.linspace(1e-3, 1 - 1e-3, rings + 1)
    u = np.linspace(0.0, 1.0, segments + 1)
    U, V = np.meshgrid(u, v)
    polar = (1.0 - V) * np.pi            # 0 at +y
    azimuth = U * 2 * np.pi
    positions = radius_mm * np.stack([np.sin(polar) * np.sin(azimuth), np.cos(polar),
                                      np.sin(polar) * np.cos(azimuth)], axis=-1)
    index = np.arange((rings + 1) * (segments + 1)).reshape(rings + 1, segments + 1)
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, :-1].ravel(), index[1:, 1:].ravel()
    # rows go from -y (v small) to +y; keep the outward, counter-clockwise winding
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    return SurfaceMesh(positions.reshape(-1, 3), faces,
                       np.stack([U.ravel(), V.ravel()], 1), name=name)


def to_mitsuba(mesh, bsdf=None, emitter=None, with_normals=True):
    """A ``mitsuba.Mesh`` for the active variant, with Mitsuba's UV convention ``(u, 1 - v)``.

    Parameters
    ----------
    bsdf : mitsuba.BSDF, optional
        Material to attach.
    emitter : mitsuba.Emitter, optional
        Area emitter to attach (e.g. ``pexitance``).
    with_normals : bool
        Store area-weighted vertex normals (smooth shading).
    """
    import mitsuba as mi

    props = mi.Properties()
    if bsdf is not None:
        props["bsdf"] = bsdf
    if emitter is not None:
        props["emitter"] = emitter
    result = mi.Mesh(mesh.name, len(mesh.vertices), len(mesh.faces), props,
                     has_vertex_normals=with_normals, has_vertex_texcoords=True)
    params = mi.traverse(result)
    params["vertex_positions"] = to_jit(mi.Float, np.ravel(mesh.vertices), np.float32)
    params["faces"] = to_jit(mi.UInt32, np.ravel(mesh.faces), np.uint32)
    flipped = np.stack([mesh.uvs[:, 0], 1.0 - mesh.uvs[:, 1]], axis=1)
    params["vertex_texcoords"] = to_jit(mi.Float, flipped.ravel(), np.float32)
    if with_normals:
        params["vertex_normals"] = to_jit(mi.Float, mesh.vertex_normals().ravel(), np.float32)
    params.update()
    return result


def sample_map_at_vertices(mesh, values):
    """Bilinear lookup of a (T, T) map at each vertex's UV (package texture convention)."""
    from scipy.ndimage import map_coordinates

    values = np.asarray(values, dtype=np.float64)
    rows, cols = values.shape
    column = mesh.uvs[:, 0] * cols - 0.5
    row = (1.0 - mesh.uvs[:, 1]) * rows - 0.5   # Mitsuba v = 1 - v_obj, rows follow Mitsuba v
    return map_coordinates(values, [row, column], order=1, mode="nearest")


def displace(mesh, height_mm):
    """The mesh with each vertex moved along its normal by the height map (mm) at its UV.

    This is the geometry whose normals :func:`polarbssrdf.geometry.normals_from_height`
    approximates per texel (eq. 25).
    """
    offsets = sample_map_at_vertices(mesh, height_mm)
    return SurfaceMesh(mesh.vertices + offsets[:, None] * mesh.vertex_normals(), mesh.faces,
                       mesh.uvs, name=mesh.name)
