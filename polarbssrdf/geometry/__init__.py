"""Meshes with UVs, the texel atlas, and normals from displacement (supplement sec. 4.1).

Texture convention (used by every map in the package): a map is an array of
``T x T`` texels, row 0 at the top, and texel ``(row i, column j)`` covers
Mitsuba's surface parameterization ``uv = ((j + 0.5) / T, (i + 0.5) / T)``.
Mitsuba's own OBJ loader flips ``v`` (``uv_mitsuba = (u, 1 - v_obj)``), and
:func:`polarbssrdf.geometry.mesh.to_mitsuba` does the same, so a map written
as an image and loaded by Mitsuba's ``bitmap`` texture lands on the surface
exactly where the atlas says.
"""

from polarbssrdf.geometry.atlas import TexelAtlas, texel_atlas, texel_uv_grid
from polarbssrdf.geometry.height import normals_from_height
from polarbssrdf.geometry.face import face_mesh, face_region_masks
from polarbssrdf.geometry.mesh import (
    SurfaceMesh,
    displace,
    load_mesh,
    sample_map_at_vertices,
    subdivide,
    to_mitsuba,
    uv_sphere,
)

__all__ = [
    "SurfaceMesh", "load_mesh", "subdivide", "to_mitsuba", "uv_sphere",
    "TexelAtlas", "texel_atlas", "texel_uv_grid", "normals_from_height",
    "face_mesh", "face_region_masks", "displace", "sample_map_at_vertices",
]
