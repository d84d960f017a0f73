"""Shared fixtures of the inverse-rendering tests: tiny synthetic captures, made once per session.

The sphere at 64 x 64 pixels, 4 views, texture 32 and 4 spp renders in a few
seconds; every capture is written under ``tmp_path_factory`` and never
modified by a test (tests that need a changed capture copy it). Each shared
capture's files are hashed when it is made and again at the end of the
session: a test that wrote into one fails there, naming the files.

Which module uses which capture (a synthesis costs 10-20 s on the shared
2-core machine, so modules share them rather than make their own):

- ``sphere_capture_dir`` (analyser images, 64^2 px, T = 32): observations, run
  inputs, config, ``reconstruct`` command, ``evaluate``;
- ``sphere_raw_capture_dir`` (the same, raw mosaics): observations, run inputs,
  ``evaluate``'s raw held-out re-render;
- ``two_frame_sphere_dir`` (48^2 px, T = 16, 2 spp, 2 frames): stage plan,
  result files protected.
"""

from __future__ import annotations

import dataclasses
import hashlib
import shutil

import numpy as np
import pytest

import mitsuba as mi

TINY = dict(object="sphere", views=4, resolution=64, texture=32, spp=4, seed=7)
"""Settings of the tiny synthetic captures (shared by the analyser and raw ones)."""


TWO_FRAMES = dict(object="sphere", views=4, resolution=48, texture=16, spp=2, frames=2)
"""Settings of the two-frame sphere (stage plan, protected result files): T = 16 keeps their
many 1-2 epoch fits cheap."""


def _synthesize(directory, settings=TINY, bands=None):
    from polarbssrdf.synth.synthesize import SynthesisSettings, synthesize

    mi.set_variant("llvm_ad_mono_polarized")
    synthesize(directory, SynthesisSettings(**settings), bands=bands, progress=False)
    return directory


def tree_hashes(directory):
    """Relative path -> sha256 of every file under ``directory``."""
    return {str(path.relative_to(directory)): hashlib.sha256(path.read_bytes()).hexdigest()
            for path in sorted(directory.rglob("*")) if path.is_file()}


@pytest.fixture(scope="session")
def _shared_captures():
    """Registry of the session's shared captures; at the end, each must be as it was made."""
    made = {}
    yield made
    changed = {}
    for directory, before in made.items():
        after = tree_hashes(directory)
        diff = sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))
        if diff:
            changed[str(directory)] = diff
    assert not changed, f"a test modified a shared capture (copy it instead): {changed}"


def _shared(made, directory, settings, bands=None):
    _synthesize(directory, settings, bands)
    made[directory] = tree_hashes(directory)
    return directory


@pytest.fixture(scope="session")
def sphere_capture_dir(tmp_path_factory, _shared_captures):
    """Directory of a tiny synthetic sphere capture, analyser images, frame 0, identity pose."""
    return _shared(_shared_captures, tmp_path_factory.mktemp("sphere_analyser") / "capture",
                   TINY)


@pytest.fixture(scope="session")
def sphere_raw_capture_dir(tmp_path_factory, _shared_captures):
    """The same capture (same seed) recorded as noisy IMX250MZR raw mosaics."""
    return _shared(_shared_captures, tmp_path_factory.mktemp("sphere_raw") / "capture",
                   {**TINY, "raw": True})


@pytest.fixture(scope="session")
def two_frame_sphere_dir(tmp_path_factory, _shared_captures):
    """A two-frame sphere, 48 x 48 px, T = 16, 2 spp (analyser images)."""
    return _shared(_shared_captures, tmp_path_factory.mktemp("two_frames") / "capture",
                   TWO_FRAMES)


@pytest.fixture(scope="session")
def sphere_capture(sphere_capture_dir):
    from polarbssrdf.io import load_capture

    return load_capture(sphere_capture_dir, check_images=False)


@pytest.fixture(scope="session")
def sphere_store(sphere_capture, tmp_path_factory):
    """Observations of the analyser capture: T = 32 in 8 x 8 blocks (16 blocks)."""
    from polarbssrdf.inverse.observations.build import build_observations

    mi.set_variant("llvm_ad_mono_polarized")
    path = tmp_path_factory.mktemp("sphere_store") / "observations.zarr"
    return build_observations(sphere_capture, 0, 32, path, block_size=8, progress=False)


def random_rotation(seed: int) -> np.ndarray:
    """A reproducible 3 x 3 rotation (QR of a Gaussian matrix, determinant +1)."""
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))[None, :]
    return q if np.linalg.det(q) > 0 else -q


def posed_copy(source_dir, target_dir, rotation, translation_mm):
    """A copy of a single-frame capture whose frame has ``pose = [rotation | translation]``.

    Cameras and lights move with the object (``X_new = rotation X_old + translation``),
    so every image stays valid and object-space observations must not change.
    Ground truth is dropped (it is not needed and would reference the old files).
    """
    from polarbssrdf.io import load_capture
    from polarbssrdf.io.capture import dumps_json
    from polarbssrdf.io.manifest import Camera, Frame, Light

    source = load_capture(source_dir, check_images=False)
    manifest = source.manifest
    rotation = np.asarray(rotation, dtype=np.float64)
    translation = np.asarray(translation_mm, dtype=np.float64)
    cameras = []
    for camera in manifest.cameras:
        R = camera.R @ rotation.T
        cameras.append(Camera(camera.name, camera.K, camera.dist, R, camera.t - R @ translation,
                              camera.image_size, camera.sensor))
    lights = [Light(light.name, rotation @ light.position + translation, light.intensity,
                    rotation @ light.polarization_axis,
                    None if light.polarizer_normal is None else rotation @ light.polarizer_normal)
              for light in manifest.lights]
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation, translation
    frames = [Frame(frame.index, frame.time_s, pose @ frame.pose, frame.images)
              for frame in manifest.frames]
    posed = dataclasses.replace(manifest, cameras=tuple(cameras), lights=tuple(lights),
                                frames=tuple(frames), truth=None)
    target_dir.mkdir(parents=True)
    shutil.copytree(source_dir / "images", target_dir / "images")
    shutil.copy2(source_dir / manifest.mesh, target_dir / manifest.mesh)
    (target_dir / "capture.json").write_text(dumps_json(posed.to_json()), encoding="utf-8")
    return target_dir


@pytest.fixture(scope="session")
def pose_helpers():
    """``(random_rotation, posed_copy)`` for tests (test directories are not packages)."""
    return random_rotation, posed_copy
