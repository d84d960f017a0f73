"""The mesh synth renders carries the displacement map it records as truth (issue 33, item 1)."""

import numpy as np
import pytest

import mitsuba as mi

from polarbssrdf.geometry import displace, face_mesh, normals_from_height, texel_atlas, to_mitsuba, uv_sphere
from polarbssrdf.geometry.displaced import (displaced_mesh, median_edge_mm, subdivided_for_texels,
                                           subdivisions_for_texels)
from polarbssrdf.synth.truth import TruthSettings, truth_maps

T = 128


def angle_deg(a, b):
    """Angle between unit vectors, exact for small angles (arccos of float32 dots is not)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def tangential(normal, n0):
    return normal - n0 * np.sum(normal * n0, axis=-1)[..., None]


def deviation_slope(rendered, truth, n0, valid):
    """Regression slope of the rendered normals' tangential deviation from ``n0`` on the truth's."""
    dr_, dt = tangential(rendered, n0)[valid], tangential(truth, n0)[valid]
    return float(np.sum(dr_ * dt) / np.sum(dt * dt))


@pytest.fixture(scope="module")
def face():
    """The face's base mesh and atlas, and a displacement map synth draws at a seed of its own
    with a correlation length (3 mm) shorter than the default's."""
    mi.set_variant("llvm_ad_mono_polarized")
    base = face_mesh(1)
    atlas = texel_atlas(to_mitsuba(base), T)
    settings = TruthSettings(correlation_mm=3.0)
    height = truth_maps(atlas, settings, np.random.default_rng(41))["displacement"].astype(np.float64)
    return base, atlas, height


def test_subdivisions_bring_the_edges_to_a_texel(face):
    base, atlas, _ = face
    levels = subdivisions_for_texels(base, atlas)
    texel = float(np.median(atlas.texel_size_mm[atlas.valid]))
    # edges of at most half a texel, and not needlessly shorter
    assert median_edge_mm(base) / 2 ** levels <= texel / 2 < median_edge_mm(base) / 2 ** (levels - 1)
    sphere = uv_sphere(60.0, rings=96, segments=192)
    assert subdivisions_for_texels(sphere, texel_atlas(to_mitsuba(sphere), 32)) == 0  # edges of 2-4 mm
    assert subdivisions_for_texels(base, texel_atlas(to_mitsuba(base), 32)) < levels
    assert subdivisions_for_texels(base, atlas, maximum=1) == 1


def test_zero_height_keeps_the_smooth_base_without_facets(face):
    """Subdivided flat triangles shaded by their own normals would show the base's facets
    (degrees on the face); the render mesh keeps the base's smooth shading."""
    base, atlas, height = face
    flat = displaced_mesh(base, np.zeros_like(height), atlas)
    rendered = texel_atlas(to_mitsuba(flat), T)
    valid = atlas.valid & rendered.valid
    # the carried normals are renormalized at each level's midpoints, where Mitsuba
    # interpolates the coarse ones directly: a second-order difference, largest where the
    # base's normals turn fast; far below the facets (> 0.5 deg) and the relief (0.7 deg)
    off = angle_deg(rendered.normal, atlas.normal)[valid]
    assert np.median(off) < 0.01 and np.percentile(off, 99) < 0.1
    assert np.abs(rendered.position - atlas.position)[valid].max() < 1e-3  # mm
    faceted = texel_atlas(to_mitsuba(face_mesh(1 + subdivisions_for_texels(base, atlas))), T)
    assert np.median(angle_deg(faceted.normal, atlas.normal)[valid & faceted.valid]) > 0.5


def test_the_rendered_surface_carries_the_map(face):
    """The rendered normals follow eq. 25 of the map and its points move by the map; moving
    only the base's vertices (the old synth) rendered a smoother face than its truth."""
    base, atlas, height = face
    truth = normals_from_height(height * atlas.valid, atlas)
    fine = subdivided_for_texels(base, atlas)
    rendered = texel_atlas(to_mitsuba(displaced_mesh(base, height, atlas, fine)), T)
    coarse = texel_atlas(to_mitsuba(displace(base, height)), T)
    valid = atlas.valid & rendered.valid & coarse.valid
    spread = angle_deg(truth, atlas.normal)[valid].mean()
    assert deviation_slope(rendered.normal, truth, atlas.normal, valid) > 0.9
    assert angle_deg(rendered.normal, truth)[valid].mean() < 0.1 * spread
    moved = np.sum((rendered.position - atlas.position) * atlas.normal, axis=-1)[valid]
    assert np.sum(moved * height[valid]) / np.sum(height[valid] ** 2) > 0.97
    # the test sees the defect it replaces
    assert deviation_slope(coarse.normal, truth, atlas.normal, valid) < 0.8


def test_bad_height_maps_are_refused(face):
    base, atlas, height = face
    with pytest.raises(ValueError, match="atlas"):
        displaced_mesh(base, height[:-1], atlas)
    broken = height.copy()
    broken[atlas.valid.nonzero()[0][0], atlas.valid.nonzero()[1][0]] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        displaced_mesh(base, broken, atlas)


def test_a_posed_mesh_turns_its_normals_with_it(face):
    from polarbssrdf.inverse.evaluation.rerender import posed_mesh

    base, atlas, height = face
    mesh = displaced_mesh(base, height, atlas, subdivided_for_texels(base, atlas, levels=1))
    angle = np.radians(30.0)
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
    pose[:3, 3] = [5.0, -2.0, 1.0]
    posed = posed_mesh(mesh, pose)
    np.testing.assert_allclose(posed.normals, mesh.normals @ pose[:3, :3].T, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(posed.normals, axis=1), 1.0, atol=1e-12)
