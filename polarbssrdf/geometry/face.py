"""The embedded face: the MediaPipe canonical face mesh and its forehead and cheek regions.

The supplement reports skin parameters per region (Table 2: forehead and
cheek); the regions here are ellipses in UV space placed on landmarks of the
canonical mesh, so they follow the mesh on any face that shares its UV layout.
"""

from __future__ import annotations

import pathlib

from polarbssrdf.geometry.atlas import texel_uv_grid
from polarbssrdf.geometry.mesh import load_mesh, subdivide

FACE_MESH_PATH = pathlib.Path(__file__).parent / "assets" / "canonical_face_model.obj"
CENTIMETRES_TO_MM = 10.0

# Region -> (landmark indices whose mean UV is the centre, semi-axes in UV (u, v)).
# 151: forehead centre, 108/337: forehead either side; 50/205 and 280/425: cheeks.
FACE_REGIONS = {
    "forehead": ((151, 108, 337), (0.12, 0.05)),
    "cheek_right": ((50, 205), (0.055, 0.05)),
    "cheek_left": ((280, 425), (0.055, 0.05)),
}


def face_mesh(subdivisions=1):
    """The canonical face in millimetres, subdivided ``subdivisions`` times (4x triangles each)."""
    mesh = load_mesh(FACE_MESH_PATH, scale_to_mm=CENTIMETRES_TO_MM)
    return subdivide(mesh, subdivisions) if subdivisions else mesh


def face_region_masks(resolution, mesh=None):
    """Boolean (T, T) masks of the forehead and the two cheeks, in the package's texture convention.

    Parameters
    ----------
    resolution : int
        Map size ``T``.
    mesh : SurfaceMesh, optional
        A mesh with the canonical face's first 468 vertices (landmarks);
        defaults to :func:`face_mesh` without subdivision.
    """
    mesh = mesh if mesh is not None else face_mesh(0)
    uv_mitsuba = texel_uv_grid(resolution)
    u, v_obj = uv_mitsuba[..., 0], 1.0 - uv_mitsuba[..., 1]
    masks = {}
    for name, (landmarks, (a, b)) in FACE_REGIONS.items():
        centre = mesh.uvs[list(landmarks)].mean(axis=0)
        masks[name] = ((u - centre[0]) / a) ** 2 + ((v_obj - centre[1]) / b) ** 2 <= 1.0
    masks["cheeks"] = masks["cheek_right"] | masks["cheek_left"]
    return masks
