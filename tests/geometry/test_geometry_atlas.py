"""The texel atlas and the texture convention, checked by ray tracing and by barycentrics."""

import numpy as np
import pytest

import mitsuba as mi
from polarbssrdf.geometry import face_mesh, texel_atlas, texel_uv_grid, to_mitsuba, uv_sphere


@pytest.fixture(autouse=True)
def variant():
    mi.set_variant("llvm_ad_mono_polarized")


def barycentric_positions(mesh, uv_obj):
    """Surface points at OBJ-convention UVs by brute-force point-in-triangle search."""
    t = mesh.uvs[mesh.faces]                       # (F, 3, 2)
    p = uv_obj[:, None, :]                         # (N, 1, 2)
    v0, v1 = t[None, :, 1] - t[None, :, 0], t[None, :, 2] - t[None, :, 0]
    w = p - t[None, :, 0]
    det = v0[..., 0] * v1[..., 1] - v0[..., 1] * v1[..., 0]
    b1 = (w[..., 0] * v1[..., 1] - w[..., 1] * v1[..., 0]) / det
    b2 = (v0[..., 0] * w[..., 1] - v0[..., 1] * w[..., 0]) / det
    inside = (b1 >= -1e-9) & (b2 >= -1e-9) & (b1 + b2 <= 1 + 1e-9)
    face = np.argmax(inside, axis=1)
    found = inside.any(axis=1)
    rows = np.arange(len(uv_obj))
    corners = mesh.vertices[mesh.faces[face]]
    points = (corners[:, 0] * (1 - b1[rows, face] - b2[rows, face])[:, None]
              + corners[:, 1] * b1[rows, face][:, None] + corners[:, 2] * b2[rows, face][:, None])
    return found, points


def test_atlas_positions_match_barycentric_interpolation():
    mesh = face_mesh(0)
    atlas = texel_atlas(to_mitsuba(mesh), 64)
    uv = texel_uv_grid(64).reshape(-1, 2)
    found, points = barycentric_positions(mesh, np.stack([uv[:, 0], 1 - uv[:, 1]], 1))
    np.testing.assert_array_equal(atlas.valid.ravel(), found)
    np.testing.assert_allclose(atlas.position.reshape(-1, 3)[found], points[found], atol=2e-3)


def test_texel_sizes_on_a_uv_sphere_are_analytic():
    radius = 50.0
    rings = 256
    atlas = texel_atlas(to_mitsuba(uv_sphere(radius, rings=rings, segments=2 * rings)), 64)
    uv = texel_uv_grid(64)
    polar = uv[..., 1] * np.pi   # Mitsuba v = 1 - v_obj; v_obj = 1 at +y
    size = atlas.texel_size_mm
    ok = atlas.valid & (np.sin(polar) > 0.3)
    # dp/du is constant per triangle, so it belongs to a latitude up to one ring
    # away from the texel centre: relative error <= cot(polar) * pi / rings
    tolerance = np.abs(np.cos(polar[ok]) / np.sin(polar[ok])) * np.pi / rings + 2e-3
    expected = 2 * np.pi * radius * np.sin(polar[ok]) / 64
    assert np.all(np.abs(size[..., 0][ok] / expected - 1) <= tolerance)
    np.testing.assert_allclose(size[..., 1][ok], np.pi * radius * (1 - 2e-3) / 64, rtol=3e-3)
    t_u, t_v, n = atlas.tangent_frame
    np.testing.assert_allclose(np.sum(t_u * n, -1)[ok], 0, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(np.cross(t_u, t_v), axis=-1)[ok], 1, atol=1e-5)


def test_a_map_baked_through_the_atlas_renders_in_place():
    """Bake f(p) into a map, load it as a Mitsuba bitmap, read it back at ray hits."""
    mesh = face_mesh(1)
    mitsuba_mesh = to_mitsuba(mesh)
    resolution = 256
    atlas = texel_atlas(mitsuba_mesh, resolution)

    def f(p):
        return 0.5 + 0.004 * p[..., 0] + 0.002 * p[..., 1]

    baked = np.where(atlas.valid, f(atlas.position), 0.0).astype(np.float32)
    texture = mi.load_dict({"type": "bitmap", "data": mi.TensorXf(baked[..., None]), "raw": True,
                            "filter_type": "bilinear"})
    scene = mi.load_dict({"type": "scene", "face": mitsuba_mesh})
    rng = np.random.default_rng(0)
    n = 4000
    origins = np.stack([rng.uniform(-50, 50, n), rng.uniform(-60, 60, n), np.full(n, 500.0)])
    rays = mi.Ray3f(mi.Point3f(origins.astype(np.float32)), mi.Vector3f(0, 0, -1))
    si = scene.ray_intersect(rays)
    hit = np.array(si.is_valid())
    assert hit.mean() > 0.8
    value = np.array(texture.eval_1(si))
    expected = f(np.array(si.p).T)
    # away from the UV border, bilinear lookup of the baked map reproduces f
    uv = np.array(si.uv).T
    inner = hit & np.all((uv > 0.05) & (uv < 0.95), axis=1)
    np.testing.assert_allclose(value[inner], expected[inner], atol=0.01)
    # a v-flip would put the forehead's values on the chin: far larger errors
    assert np.abs(value[inner] - expected[inner]).mean() < 2e-3
