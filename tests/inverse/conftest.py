"""Shared fixtures of the inverse-rendering tests: tiny synthetic captures, made once per session.

The sphere at 64 x 64 pixels, 4 views, texture 32 and 4 spp renders in a few
seconds; every capture is written under ``tmp_path_factory`` and never
modified by a test (tests that need a changed capture copy it).
"""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest

import mitsuba as mi

TINY = dict(object="sphere", views=4, resolution=64, texture=32, spp=4, seed=7)
"""Settings of the tiny synthetic captures (shared by the analyser and raw ones)."""


def _synthesize(directory, **overrides):
    from polarbssrdf.synth.synthesize import SynthesisSettings, synthesize

    mi.set_variant("llvm_ad_mono_polarized")
    synthesize(directory, SynthesisSettings(**{**TINY, **overrides}), progress=False)
    return directory


@pytest.fixture(scope="session")
def sphere_capture_dir(tmp_path_factory):
    """Directory of a tiny synthetic sphere capture, analyser images, frame 0, identity pose."""
    return _synthesize(tmp_path_factory.mktemp("sphere_analyser") / "capture")


@pytest.fixture(scope="session")
def sphere_raw_capture_dir(tmp_path_factory):
    """The same capture (same seed) recorded as noisy IMX250MZR raw mosaics."""
    return _synthesize(tmp_path_factory.mktemp("sphere_raw") / "capture", raw=True)


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
