"""Texture-space observations (polarbssrdf.inverse.observations.build) on tiny synthetic captures."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.ndimage import binary_dilation, map_coordinates

import mitsuba as mi

from polarbssrdf.inverse.observations import build as obs
from polarbssrdf.inverse.observations.build import (
    ObservationError,
    ObservationStore,
    build_observations,
    load_or_build_observations,
    rig_in_object_space,
)
from polarbssrdf.io import load_capture

T = 32


@pytest.fixture(scope="module")
def atlas(sphere_capture):
    from polarbssrdf.geometry.atlas import texel_atlas
    from polarbssrdf.geometry.mesh import to_mitsuba

    mi.set_variant("llvm_ad_mono_polarized")
    return texel_atlas(to_mitsuba(sphere_capture.load_mesh()), T)


@pytest.fixture(scope="module")
def everything(sphere_store):
    return sphere_store.read_rows(0, len(sphere_store))


def _rig(store, capture, view):
    record = store.views[view]
    return capture.manifest.camera(record["camera"]), capture.manifest.light(record["light"])


# --------------------------------------------------------------------------- (a) geometry, samples
def test_every_view_contributes_and_reprojects_inside(sphere_store, sphere_capture, atlas,
                                                      everything):
    assert [v["camera"] for v in sphere_store.views] == ["cam00", "cam01", "cam02", "cam03"]
    position = atlas.position.reshape(-1, 3).astype(np.float64)
    for view in range(len(sphere_store.views)):
        rows = everything.view == view
        assert rows.sum() > 100
        camera, _ = _rig(sphere_store, sphere_capture, view)
        uv = camera.project(position[everything.texel[rows]])  # identity pose: world = object
        assert np.all(uv >= 1.0) and np.all(uv[:, 0] <= camera.width - 2)
        assert np.all(uv[:, 1] <= camera.height - 2)


def test_texels_facing_away_are_not_observed(sphere_store, sphere_capture, atlas, everything):
    position = atlas.position.reshape(-1, 3).astype(np.float64)
    normal = atlas.normal.reshape(-1, 3).astype(np.float64)
    valid = atlas.valid.ravel()
    for view in range(len(sphere_store.views)):
        camera, _ = _rig(sphere_store, sphere_capture, view)
        facing = np.sum(normal * (camera.center - position), axis=1) > 0
        observed = np.zeros(T * T, bool)
        observed[everything.texel[everything.view == view]] = True
        assert not np.any(observed & ~facing)
        assert not np.any(observed & ~valid)


def test_analyser_samples_are_bilinear_interpolations_of_the_image(sphere_store, sphere_capture,
                                                                   atlas, everything):
    from polarbssrdf.io.exr import read_exr

    position = atlas.position.reshape(-1, 3).astype(np.float64)
    rng = np.random.default_rng(3)
    for view in range(len(sphere_store.views)):
        camera, light = _rig(sphere_store, sphere_capture, view)
        channels, _ = read_exr(sphere_capture.image_path(0, camera.name, light.name))
        rows = rng.choice(np.flatnonzero(everything.view == view), 5, replace=False)
        u, v = camera.project(position[everything.texel[rows]]).T
        for b, band in enumerate(sphere_store.bands):
            for a, angle in enumerate((0, 45, 90, 135)):
                expected = map_coordinates(channels[f"{band}.I{angle}"].astype(np.float64),
                                           [v, u], order=1)
                np.testing.assert_allclose(everything.analyser[rows, b, a], expected,
                                           rtol=1e-5, atol=1e-9)


def test_analyser_samples_are_consistent_stokes(everything):
    I0, I45, I90, I135 = np.moveaxis(everything.analyser.astype(np.float64), -1, 0)
    assert np.all(np.isfinite(everything.analyser)) and np.all(I0 + I90 > 0)
    np.testing.assert_allclose(I0 + I90, I45 + I135, rtol=1e-4, atol=1e-7)


def test_directions_agree_with_the_rig(sphere_store, sphere_capture, atlas, everything):
    from polarbssrdf.plugins.ppoint import polarization_direction

    position = atlas.position.reshape(-1, 3).astype(np.float64)
    for view in range(len(sphere_store.views)):
        rows = everything.view == view
        camera, light = _rig(sphere_store, sphere_capture, view)
        p = position[everything.texel[rows]]
        to_camera, to_light = camera.center - p, light.position - p
        distance = np.linalg.norm(to_light, axis=1)
        np.testing.assert_allclose(everything.to_camera[rows],
                                   to_camera / np.linalg.norm(to_camera, axis=1)[:, None],
                                   atol=2e-6)
        np.testing.assert_allclose(everything.to_light[rows], to_light / distance[:, None],
                                   atol=2e-6)
        np.testing.assert_allclose(everything.light_distance_mm[rows], distance, rtol=1e-6)
        np.testing.assert_array_equal(everything.light_intensity[rows], np.float32(light.intensity))
        # ppoint's own field direction (Dr.Jit) for the light travelling light -> texel
        axis = light.polarization_axis / np.linalg.norm(light.polarization_axis)
        absorption = np.cross(light.polarizer_normal, axis)
        forward = -everything.to_light[rows].astype(np.float32).T
        field = polarization_direction(mi.Vector3f(forward), mi.Vector3f(axis),
                                       mi.Vector3f(absorption / np.linalg.norm(absorption)))
        np.testing.assert_allclose(everything.light_field[rows], np.array(field).T, atol=1e-5)
        # the image's Stokes x axis is perpendicular to image up and points right
        basis = everything.camera_basis[rows].astype(np.float64)
        assert np.abs(basis @ camera.down).max() < 1e-6
        assert np.all(basis @ camera.right > 0.95)
    for name in ("to_camera", "to_light", "light_field", "camera_basis"):
        np.testing.assert_allclose(np.linalg.norm(getattr(everything, name), axis=1), 1, atol=1e-6)
    assert np.abs(np.sum(everything.light_field * everything.to_light, axis=1)).max() < 1e-6
    assert np.abs(np.sum(everything.camera_basis * everything.to_camera, axis=1)).max() < 1e-6


def test_projection_model_of_the_light_field():
    forward = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    field = obs.polarization_field(forward, np.array([1.0, 0.0, 0.0]))
    np.testing.assert_allclose(field, [[1, 0, 0], [0.8, 0, -0.6]], atol=1e-12)


# --------------------------------------------------------------------------- (b) windows, counts
def test_windows_give_each_texel_view_once(sphere_store, everything):
    parts = [sphere_store.read_window(*window) for window in sphere_store.windows(16)]
    assert sum(len(p) for p in parts) == len(sphere_store) == len(everything)
    pairs = np.concatenate([p.texel.astype(np.int64) * 100 + p.view for p in parts])
    assert len(np.unique(pairs)) == len(pairs)
    expected = everything.texel.astype(np.int64) * 100 + everything.view
    np.testing.assert_array_equal(np.sort(pairs), np.sort(expected))
    counts = sphere_store.texel_view_counts()
    assert counts.shape == (T, T) and counts.dtype == np.int32 and counts.sum() == len(sphere_store)
    np.testing.assert_array_equal(counts.ravel(), np.bincount(everything.texel, minlength=T * T))


def test_window_is_clipped_to_its_texels(sphere_store, everything):
    window = sphere_store.read_window(8, 16, 12, 100)  # 8..19 x 16..31 after clipping
    rows, cols = everything.texel // T, everything.texel % T
    expected = (rows >= 8) & (rows < 20) & (cols >= 16)
    assert len(window) == expected.sum() > 0
    np.testing.assert_array_equal(np.sort(window.texel), np.sort(everything.texel[expected]))
    with pytest.raises(ValueError, match="multiple of the block size"):
        sphere_store.read_window(3, 0, 8, 8)


def test_store_layout_is_chunked_zarr(sphere_store):
    import zarr

    group = zarr.open_group(str(sphere_store.path), mode="r")
    assert group.metadata.zarr_format == 3
    assert group["analyser"].shape == (len(sphere_store), 6, 4)
    assert group["block_offsets"].shape == (16 + 1,)
    offsets = sphere_store.block_offsets
    assert offsets[0] == 0 and np.all(np.diff(offsets) >= 0)
    assert group.attrs["format_version"] == obs.FORMAT_VERSION


# --------------------------------------------------------------------------- (c) reuse, rebuild
def test_reuse_and_rebuild(sphere_capture, tmp_path, monkeypatch, capsys):
    path = tmp_path / "store.zarr"
    calls = []
    project = obs.project_to_image
    monkeypatch.setattr(obs, "project_to_image", lambda *a: (calls.append(1), project(*a))[1])
    first = load_or_build_observations(sphere_capture, 0, 16, path, block_size=8)
    assert calls and "building" in capsys.readouterr().out
    calls.clear()
    again = load_or_build_observations(sphere_capture, 0, 16, path, block_size=8)
    assert not calls and "reusing" in capsys.readouterr().out
    assert again.fingerprint == first.fingerprint and len(again) == len(first)
    smaller = load_or_build_observations(sphere_capture, 0, 8, path, block_size=8, progress=False)
    assert calls and smaller.texture_size == 8
    calls.clear()
    held_out = load_or_build_observations(sphere_capture, 0, 8, path, block_size=8,
                                          exclude_cameras=("cam01",), progress=False)
    assert calls and [v["camera"] for v in held_out.views] == ["cam00", "cam02", "cam03"]
    leftovers = sorted(p.name for p in tmp_path.iterdir())
    assert leftovers == ["store.zarr"]


def test_interrupted_build_keeps_the_old_store(sphere_capture, tmp_path, monkeypatch):
    path = tmp_path / "store.zarr"
    old = build_observations(sphere_capture, 0, 8, path, block_size=8, progress=False)

    def crash(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(obs, "_merge_strips", crash)
    with pytest.raises(KeyboardInterrupt):
        build_observations(sphere_capture, 0, 16, path, block_size=8, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["store.zarr"]
    assert ObservationStore.open(path).fingerprint == old.fingerprint


# --------------------------------------------------------------------------- (d) raw
def test_raw_capture_is_demosaicked_and_agrees_with_analyser(sphere_raw_capture_dir, everything,
                                                             tmp_path):
    raw = build_observations(sphere_raw_capture_dir, 0, T, tmp_path / "raw.zarr", block_size=8,
                             progress=False)
    observed = raw.read_rows(0, len(raw))
    assert np.all(np.isfinite(observed.analyser)) and len(observed) > 0
    assert raw.attrs["units"]["analyser"].startswith("W/(sr mm^2)")
    # same rig and seed: match texel-views and compare radiance as it is, no fitted scale: the
    # samples went through the records' radiance_per_dn and black_level_dn
    key_raw = observed.texel.astype(np.int64) * 100 + observed.view
    key_ref = everything.texel.astype(np.int64) * 100 + everything.view
    common, i_raw, i_ref = np.intersect1d(key_raw, key_ref, return_indices=True)
    # demosaicking reaches one pixel further from the mesh's outline: the raw store keeps a
    # subset, and only texel-views that close to a mixed pixel are missing from it
    assert len(common) == len(observed)
    missing = np.setdiff1d(np.arange(len(everything)), i_ref)
    capture = load_capture(raw.attrs["capture"], check_images=False)
    surface, manifest = obs._Surface(capture.load_mesh(), T), capture.manifest
    for view in range(4):
        camera = manifest.camera(raw.views[view]["camera"])
        light = manifest.light(raw.views[view]["light"])
        mixed = obs.mixed_pixels(surface, camera, np.eye(4), 0.1, light.position)
        near_outline = binary_dilation(mixed, np.ones((3, 3), bool)).astype(np.float32)
        rows = missing[everything.view[missing] == view]
        uv = camera.project(surface.position[np.searchsorted(surface.texel,
                                                             everything.texel[rows])])
        assert np.all(obs.bilinear_samples([near_outline], uv[:, 0], uv[:, 1]) > 0)
    errors, ratios = [], []
    for view in range(4):
        rows = observed.view[i_raw] == view
        for band in range(len(raw.bands)):
            a = observed.analyser[i_raw][rows, band].astype(np.float64)
            b = everything.analyser[i_ref][rows, band].astype(np.float64)
            ratios.append(np.mean(a) / np.mean(b))
            errors.append(np.mean(np.abs(a - b)) / np.mean(b))
    print("raw / analyser mean ratios", np.round(ratios, 4))
    print("raw vs analyser relative errors", np.round(errors, 4))
    assert np.abs(np.array(ratios) - 1).max() < 0.02, ratios  # noise and demosaicking only
    assert max(errors) < 0.06, errors


def test_raw_capture_without_calibration_is_refused(sphere_raw_capture_dir, tmp_path):
    """An old-style raw capture (no radiance_per_dn) loads, but has no radiance to observe."""
    import json
    import shutil

    from polarbssrdf.io import load_capture

    old = tmp_path / "old_raw"
    shutil.copytree(sphere_raw_capture_dir, old)
    document = json.loads((old / "capture.json").read_text())
    for frame in document["frames"]:
        for image in frame["images"]:
            for name in ("radiance_per_dn", "black_level_dn", "saturation_dn"):
                image.pop(name)
    (old / "capture.json").write_text(json.dumps(document))
    capture = load_capture(old)
    assert all(record.kind == "raw" and not record.calibrated
               for _, record in capture.manifest.records())
    with pytest.raises(ObservationError, match="lacks radiance_per_dn"):
        build_observations(capture, 0, 8, tmp_path / "old.zarr", block_size=8, progress=False)
    assert not (tmp_path / "old.zarr").exists()


# --------------------------------------------------------------------------- (e) posed frame
def test_pose_transform_of_the_rig(sphere_capture, pose_helpers):
    random_rotation, _ = pose_helpers
    camera, light = sphere_capture.manifest.cameras[0], sphere_capture.manifest.lights[0]
    rotation = random_rotation(1)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation, [10.0, -20.0, 5.0]
    rig = rig_in_object_space(pose, camera, light)
    np.testing.assert_allclose(rotation @ rig["camera_centre"] + pose[:3, 3], camera.center,
                               atol=1e-9)
    np.testing.assert_allclose(rotation @ rig["light_position"] + pose[:3, 3], light.position,
                               atol=1e-9)
    np.testing.assert_allclose(rotation @ rig["camera_down"], camera.down, atol=1e-12)


def test_posed_frame_gives_the_same_object_space_observations(sphere_capture_dir, everything,
                                                              tmp_path, pose_helpers):
    random_rotation, posed_copy = pose_helpers
    posed_dir = posed_copy(sphere_capture_dir, tmp_path / "posed", random_rotation(5),
                           [30.0, -12.0, 7.5])
    posed = build_observations(posed_dir, 0, T, tmp_path / "posed.zarr", block_size=8,
                               progress=False)
    moved = posed.read_rows(0, len(posed))
    np.testing.assert_array_equal(moved.texel, everything.texel)
    np.testing.assert_array_equal(moved.view, everything.view)
    for name in ("to_camera", "to_light", "light_field", "camera_basis"):
        np.testing.assert_allclose(getattr(moved, name), getattr(everything, name), atol=1e-5)
    np.testing.assert_allclose(moved.light_distance_mm, everything.light_distance_mm, rtol=1e-6)
    np.testing.assert_allclose(moved.analyser, everything.analyser, rtol=1e-4, atol=1e-8)


# --------------------------------------------------------------------------- (f) bad input
def _with_manifest(capture, **changes):
    from polarbssrdf.io.capture import Capture

    return Capture(capture.directory, dataclasses.replace(capture.manifest, **changes), None)


def _turned_around(camera):
    """The camera rotated 180 degrees about its image-down axis, around its own centre."""
    from polarbssrdf.io.manifest import Camera

    R = np.diag([-1.0, 1.0, -1.0]) @ camera.R
    return Camera(camera.name, camera.K, camera.dist, R, -R @ camera.center, camera.image_size,
                  camera.sensor)


def test_bad_inputs_raise_clear_errors(sphere_capture, tmp_path):
    from polarbssrdf.io.manifest import Frame

    out = tmp_path / "store.zarr"
    with pytest.raises(ObservationError, match="no frame 3"):
        build_observations(sphere_capture, 3, T, out, progress=False)
    with pytest.raises(ValueError, match="texture_size must be a positive integer"):
        build_observations(sphere_capture, 0, 0, out, progress=False)
    with pytest.raises(ObservationError, match="has no mesh"):
        build_observations(_with_manifest(sphere_capture, mesh=None), 0, T, out, progress=False)
    empty = Frame(1, 1.0, np.eye(4), ())
    no_images = _with_manifest(sphere_capture, frames=sphere_capture.manifest.frames + (empty,))
    with pytest.raises(ObservationError, match="no polarization images"):
        build_observations(no_images, 1, T, out, progress=False)
    with pytest.raises(ObservationError, match="unknown cameras"):
        build_observations(sphere_capture, 0, T, out, exclude_cameras=("cam9",), progress=False)
    away = tuple(_turned_around(c) for c in sphere_capture.manifest.cameras)
    with pytest.raises(ObservationError, match="no texel-view at all"):
        build_observations(_with_manifest(sphere_capture, cameras=away), 0, 8, out,
                           progress=False)
    assert not any(tmp_path.iterdir())


def test_camera_looking_away_is_warned_about_and_skipped(sphere_capture, tmp_path, capsys):
    cameras = list(sphere_capture.manifest.cameras)
    cameras[1] = _turned_around(cameras[1])
    capture = _with_manifest(sphere_capture, cameras=tuple(cameras))
    store = build_observations(capture, 0, 8, tmp_path / "s.zarr", block_size=8, progress=False)
    assert capsys.readouterr().err == ("polarbssrdf: warning: camera 'cam01' (light 'light01') "
                                       "sees no texel of frame 0: every facing texel projects "
                                       "outside the image; skipping it\n")
    assert [v["camera"] for v in store.views] == ["cam00", "cam02", "cam03"]
    assert store.attrs["skipped_views"][0]["camera"] == "cam01"
    assert set(np.unique(store.read_rows(0, len(store)).view)) == {0, 1, 2}


def test_nan_pixels_drop_only_their_texel_views(sphere_capture_dir, sphere_store, everything,
                                                tmp_path):
    import shutil

    from polarbssrdf.io.exr import read_exr, write_exr

    copy = tmp_path / "nan_capture"
    shutil.copytree(sphere_capture_dir, copy)
    image = copy / "images/f0000/cam00_light00.exr"
    channels, _ = read_exr(image)
    channels["GA.I45"][30:34, 30:34] = np.nan
    write_exr(image, channels, overwrite=True, allow_nonfinite=True)
    store = build_observations(copy, 0, T, tmp_path / "nan.zarr", block_size=8, progress=False)
    dropped = store.attrs["statistics"][0]["nonfinite"]
    assert dropped > 0
    assert len(store) == len(everything) - dropped
    assert all(s["nonfinite"] == 0 for s in store.attrs["statistics"][1:])


# --------------------------------------------------------------------------- (g) mixed pixels
def _pixel_corner_hits_sphere(camera, centre, radius, columns, rows):
    """Whether rays through pixel corners ``(columns, rows)`` hit the analytic sphere.

    Independent of the store's ray casting: the pinhole ray ``R^T K^-1 (u, v, 1)``
    (no distortion) against the sphere the tessellated mesh is inscribed in.
    """
    pixels = np.stack([columns, rows, np.ones_like(columns)], axis=-1).astype(np.float64)
    directions = pixels @ np.linalg.inv(camera.K).T @ camera.R
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    offset = camera.center - centre
    along = directions @ offset
    return along * along - (offset @ offset - radius * radius) >= 0


def test_no_texel_view_samples_a_pixel_past_the_outline(sphere_store, sphere_capture, atlas,
                                                        everything):
    vertices = np.asarray(sphere_capture.load_mesh().vertices, np.float64)
    centre = vertices.mean(axis=0)
    radius = float(np.linalg.norm(vertices - centre, axis=1).max())
    position = atlas.position.reshape(-1, 3).astype(np.float64)
    normal = atlas.normal.reshape(-1, 3).astype(np.float64)
    # the 3 x 3 corners of the bilinear stencil's 2 x 2 pixels
    corner = np.arange(3) - 0.5
    for view in range(4):
        camera, light = _rig(sphere_store, sphere_capture, view)
        rows = everything.view == view
        uv = camera.project(position[everything.texel[rows]])
        columns = np.floor(uv[:, 0])[:, None, None] + corner[None, None, :]
        image_rows = np.floor(uv[:, 1])[:, None, None] + corner[None, :, None]
        columns, image_rows = np.broadcast_arrays(columns, image_rows)
        assert np.all(_pixel_corner_hits_sphere(camera, centre, radius, columns, image_rows))
        # and only those are dropped: every facing texel deep inside the outline is kept
        facing = ((np.einsum("ij,ij->i", normal, obs._unit(camera.center - position)) > 0.1)
                  & (np.einsum("ij,ij->i", normal, obs._unit(light.position - position)) > 0.1)
                  & atlas.valid.ravel())
        uv_all = camera.project(position[facing])
        deep = np.ones(len(uv_all), bool)
        for du in (-3.5, 0.0, 3.5):
            for dv in (-3.5, 0.0, 3.5):
                deep &= _pixel_corner_hits_sphere(camera, centre, radius, uv_all[:, 0] + du,
                                                  uv_all[:, 1] + dv)
        inside = ((uv_all >= 1.0).all(axis=1) & (uv_all[:, 0] <= camera.width - 2)
                  & (uv_all[:, 1] <= camera.height - 2))
        expected = np.flatnonzero(facing)[deep & inside]
        assert len(expected) > 100
        assert np.isin(expected, everything.texel[rows]).all()
        assert sphere_store.attrs["statistics"][view]["mixed"] > 0


class _Scene:
    """What :func:`mixed_pixels` reads of a surface: a Mitsuba scene, its shadow rays."""

    epsilon_mm = 0.01
    occluded = obs._Surface.occluded

    def __init__(self, *rectangles):
        mi.set_variant("llvm_ad_mono_polarized")
        shapes = {f"r{i}": {"type": "rectangle",
                            "to_world": mi.ScalarTransform4f().translate(centre).scale(size)}
                  for i, (centre, size) in enumerate(rectangles)}
        self.scene = mi.load_dict({"type": "scene", **shapes})


def _pinhole(K=((100.0, 0.0, 31.5), (0.0, 100.0, 31.5), (0.0, 0.0, 1.0)), R=np.eye(3)):
    from polarbssrdf.io.manifest import Camera

    return Camera("cam", np.array(K), np.zeros(5), R, np.zeros(3), (64, 64))


def test_mixed_pixels_are_the_outline_and_the_occluding_contour():
    camera = _pinhole()
    # a wall at 100 mm filling the view, and a card at 50 mm whose right edge (x = 0.1 mm)
    # projects to u = 31.7, inside pixel 32 (31.5 .. 32.5)
    wall = ((0.0, 0.0, 100.0), (500.0, 500.0, 1.0))
    card = ((-49.9, 0.0, 50.0), (50.0, 500.0, 1.0))
    mixed = obs.mixed_pixels(_Scene(wall, card), camera, np.eye(4), 0.1)
    assert np.array_equal(np.flatnonzero(mixed.any(axis=0)), [32]) and mixed[:, 32].all()
    # without the wall the card's outline: pixel 32 and everything right of it see past it
    mixed = obs.mixed_pixels(_Scene(card), camera, np.eye(4), 0.1)
    assert np.array_equal(np.flatnonzero(mixed.all(axis=0)), np.arange(32, 64))
    assert not mixed[:, :32].any()


def test_a_shadow_edge_across_a_pixel_mixes_it():
    camera = _pinhole()
    wall = ((0.0, 0.0, 100.0), (500.0, 500.0, 1.0))
    # the card's edge (x = -4.9 mm at 50 mm) projects to u = 21.7 (pixel 22); a light at
    # x = -20 mm casts its shadow on the wall up to x = 10.2 mm, u = 41.7 (pixel 42)
    card = ((-54.9, 0.0, 50.0), (50.0, 500.0, 1.0))
    scene = _Scene(wall, card)
    unlit = obs.mixed_pixels(scene, camera, np.eye(4), 0.1)
    assert np.array_equal(np.flatnonzero(unlit.any(axis=0)), [22])
    lit = obs.mixed_pixels(scene, camera, np.eye(4), 0.1, light_position=[-20.0, 0.0, 0.0])
    assert np.array_equal(np.flatnonzero(lit.any(axis=0)), [22, 42]) and lit[:, 42].all()
    # a light beside the camera on the other side puts the card's shadow behind the card
    lit = obs.mixed_pixels(scene, camera, np.eye(4), 0.1, light_position=[20.0, 0.0, 0.0])
    assert np.array_equal(np.flatnonzero(lit.any(axis=0)), [22])


def test_a_steep_surface_is_not_a_contour():
    # a plane at 100 mm turned 70 deg away from the camera: cos 0.34 at the image centre, 0.19
    # at its far side (kept by min_cosine 0.1), where its depth changes by 2.5 mm across a pixel
    turned = mi.ScalarTransform4f().translate([0.0, 0.0, 100.0]).rotate([0, 1, 0], 70.0)
    surface = _Scene()
    surface.scene = mi.load_dict({"type": "scene", "plane": {
        "type": "rectangle", "to_world": turned @ mi.ScalarTransform4f().scale(400.0)}})
    narrow = ((200.0, 0.0, 31.5), (0.0, 200.0, 31.5), (0.0, 0.0, 1.0))
    assert not obs.mixed_pixels(surface, _pinhole(narrow), np.eye(4), 0.1).any()
    # a pose moves the pixels' rays into object space: 20 mm further, still no contour; turned
    # further away, the plane's horizon enters the image and the pixels past it are mixed
    pose = np.eye(4)
    pose[:3, 3] = [0.0, 0.0, -20.0]
    assert not obs.mixed_pixels(surface, _pinhole(narrow), pose, 0.1).any()
    pose[:3, :3] = np.array(mi.ScalarTransform4f().rotate([0, 1, 0], 15.0).matrix)[:3, :3]
    assert obs.mixed_pixels(surface, _pinhole(narrow), pose, 0.1).any()
