"""The surface a height map describes, as a mesh fine enough to carry it (issue 33, item 1).

A displacement map ``H`` (mm, one value per texel) moves the base surface along its
shading normal ``n0``; the normal of the moved surface is eq. 25 of ``H``
(:func:`~polarbssrdf.geometry.height.normals_from_height`). Moving the base mesh's own
vertices (:func:`~polarbssrdf.geometry.mesh.displace`) carries only what its vertex
spacing resolves: on the embedded face (``face_mesh(1)``, 1,833 vertices, about 4 mm
apart) with synth's default field (8 mm correlation, 0.1 mm) at 256^2 texels, the
rendered normals' deviation from the base's was 0.59 of the truth's (regression slope),
0.26 deg off the truth's normals where those deviate 0.72 deg from the base's: the
capture recorded a smoother face than its truth maps said (measured 2026-12-05,
bench/RESULTS.md).

:func:`displaced_mesh` subdivides the base until its edges are no longer than half a
texel (:func:`subdivisions_for_texels`), keeping the base's smooth shading normals
(:func:`~polarbssrdf.geometry.mesh.subdivide` with ``keep_shading``), moves every vertex
by ``H`` at its UV, and gives it the normal eq. 25 gives the surface there. Why eq. 25's
normal and not the area-weighted normal of the moved triangles: the finer mesh's
triangles lie in the base's flat triangles, whose facets (degrees on the face) the base's
smooth shading hides, and the area-weighted normal of a vertex averages its ring of
triangles, a low-pass over about two texels (slope 0.90 at 115,233 vertices). The
normal a height map defines is eq. 25 of it; to first order in ``H`` that is the
normal of the moved smooth surface (its second-order error, ``H`` times the
curvature, is 0.002 rad for 0.1 mm on a 50 mm radius). Why half a texel: the normals
are looked up at the vertices and interpolated linearly between them, which flattens
detail near the texel scale; on a 3 mm field at 128^2 texels (1.8 mm) the rendered
deviation's slope on the truth's was 0.90 with edges of one texel, 0.95 with half a
texel, 0.97 with a quarter (4x the vertices per step; 2026-12-05).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from polarbssrdf.geometry.height import normals_from_height
from polarbssrdf.geometry.mesh import SurfaceMesh, sample_map_at_vertices, subdivide

MAX_SUBDIVISIONS = 4
"""At most this many midpoint subdivisions (256x the triangles): the embedded face at
level 1 has 3,600 triangles, so a render mesh has at most about 0.9 million."""

VERTICES_PER_TEXEL = 2
"""Edges of the render mesh are at most a texel divided by this (module docstring)."""


def median_edge_mm(mesh):
    """Median edge length of a mesh (mm)."""
    corners = mesh.vertices[mesh.faces]
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=-1)
    return float(np.median(edges))


def subdivisions_for_texels(mesh, atlas, maximum=MAX_SUBDIVISIONS, per_texel=VERTICES_PER_TEXEL):
    """The number of midpoint subdivisions after which the median edge of ``mesh`` is no
    longer than ``1 / per_texel`` of the median texel extent of ``atlas`` (mm), at most
    ``maximum``."""
    sizes = np.asarray(atlas.texel_size_mm)[np.asarray(atlas.valid, bool)]
    if sizes.size == 0:
        return 0
    texel = float(np.median(sizes))
    ratio = median_edge_mm(mesh) * per_texel / max(texel, 1e-9)
    return int(min(maximum, max(0, np.ceil(np.log2(max(ratio, 1.0))))))


def subdivided_for_texels(base, atlas, levels=None):
    """``base`` subdivided :func:`subdivisions_for_texels` times (or ``levels``), its smooth
    shading normals kept: the mesh :func:`displaced_mesh` moves. Depends on the atlas's
    resolution only, so a sequence computes it once (seconds for the face at 256^2)."""
    levels = subdivisions_for_texels(base, atlas) if levels is None else int(levels)
    return subdivide(base, levels, keep_shading=True)


def filled_off_chart(values, valid):
    """``values`` (T, T, ...) with every texel off the charts set to its nearest valid
    texel's value, so that bilinear lookups at a chart's edge see no off-chart texel."""
    valid = np.asarray(valid, bool)
    values = np.asarray(values, np.float64)
    if valid.all() or not valid.any():
        return values
    _, (rows, cols) = ndimage.distance_transform_edt(~valid, return_indices=True)
    return values[rows, cols]


def displaced_mesh(base, height_mm, atlas, fine=None):
    """The base mesh moved by a height map, fine enough to carry it (module docstring).

    Parameters
    ----------
    base : SurfaceMesh
        The undisplaced mesh (its shading normals define ``n0``).
    height_mm : (T, T) array
        Displacement along ``n0``, mm.
    atlas : TexelAtlas
        The base mesh's atlas at the map's resolution.
    fine : SurfaceMesh, optional
        :func:`subdivided_for_texels` of ``base`` and ``atlas``, when the caller keeps it
        (a sequence of frames); computed when not given.

    Returns
    -------
    SurfaceMesh
        With ``normals`` set to eq. 25's normals at its vertices.
    """
    height = np.asarray(height_mm, np.float64)
    if height.shape != atlas.valid.shape:
        raise ValueError(f"the height map is {height.shape}, the atlas {atlas.valid.shape}")
    valid = np.asarray(atlas.valid, bool)
    if not np.isfinite(height[valid]).all():
        raise ValueError("the height map has NaN or infinite values on the mesh")
    fine = subdivided_for_texels(base, atlas) if fine is None else fine
    height = filled_off_chart(np.where(valid, height, 0.0), valid)
    shading = fine.vertex_normals()
    offsets = sample_map_at_vertices(fine, height)
    # the normal's change eq. 25 gives, looked up at the vertices and added to n0 there
    change = filled_off_chart(normals_from_height(height * valid, atlas) - atlas.normal, valid)
    change = np.stack([sample_map_at_vertices(fine, change[..., k]) for k in range(3)], axis=1)
    normals = shading + change
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return SurfaceMesh(fine.vertices + offsets[:, None] * shading, fine.faces, fine.uvs,
                       name=base.name, normals=normals)
