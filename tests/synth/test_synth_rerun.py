"""`polarbssrdf synth` run again: --overwrite starts over, --resume continues, interrupts, seeds."""

import json
import os

import numpy as np
import pytest

from polarbssrdf.cli import main
from polarbssrdf.io import CaptureWriter, load_capture
from polarbssrdf.synth.synthesize import SEED_LIMIT, image_seed

TINY = ["--object", "sphere", "--frames", "1", "--resolution", "32", "--texture", "32", "--quiet"]


def synth(directory, *arguments):
    return main(["synth", str(directory), *TINY, *arguments])


def assert_same_capture(first, second):
    """Bit-identical manifests, images, truth maps and truth.json."""
    a, b = load_capture(first), load_capture(second)
    assert (json.loads((first / "capture.json").read_text())
            == json.loads((second / "capture.json").read_text()))
    assert (json.loads((first / "truth" / "truth.json").read_text())
            == json.loads((second / "truth" / "truth.json").read_text()))
    for frame, record in a.manifest.records():
        ours, theirs = a.images(frame, record.camera, record.light), b.images(
            frame, record.camera, record.light)
        assert ours.keys() == theirs.keys()
        for name in ours:
            np.testing.assert_array_equal(ours[name], theirs[name], err_msg=f"{record.path} {name}")
    for frame in a.manifest.frames:
        ours, theirs = a.truth_maps(frame.index), b.truth_maps(frame.index)
        assert ours.keys() == theirs.keys()
        for name in ours:
            np.testing.assert_array_equal(ours[name], theirs[name], err_msg=f"truth {name}")


def test_overwrite_with_other_settings_renders_everything_anew(tmp_path):
    old, fresh = tmp_path / "old", tmp_path / "fresh"
    assert synth(old, "--views", "3", "--spp", "2", "--seed", "1") == 0
    (old / "notes.txt").write_text("mine")
    new_settings = ["--views", "2", "--spp", "3", "--seed", "7"]
    assert synth(old, *new_settings, "--overwrite") == 0
    assert synth(fresh, *new_settings) == 0
    assert_same_capture(old, fresh)
    # the old run's third camera is not part of the new capture; its files stay, unreferenced
    manifest = (old / "capture.json").read_text()
    assert "cam02" not in manifest
    assert (old / "images" / "f0000" / "cam02_light02.exr").is_file()
    assert (old / "notes.txt").read_text() == "mine"
    assert len([n for n in os.listdir(old) if n.startswith("capture.superseded-")]) == 1
    # the preview shows the new images
    assert (old / "preview.png").read_bytes() == (fresh / "preview.png").read_bytes()


def interrupted(directory, *arguments):
    """Whether ``synth`` was stopped by Ctrl-C: the command line may report it as status 130."""
    try:
        status = synth(directory, *arguments)
    except KeyboardInterrupt:
        return True
    return status == 130


class Interrupt:
    """Make ``CaptureWriter.add_image`` raise KeyboardInterrupt once ``after`` images exist."""

    def __init__(self, monkeypatch, after):
        self.written = 0
        original = CaptureWriter.add_image

        def add_image(writer, *args, **kwargs):
            if self.written == after:
                raise KeyboardInterrupt
            self.written += 1
            return original(writer, *args, **kwargs)

        monkeypatch.setattr(CaptureWriter, "add_image", add_image)


def test_an_interrupted_overwrite_resumes_to_a_fresh_capture(tmp_path, monkeypatch):
    directory, fresh = tmp_path / "capture", tmp_path / "fresh"
    settings = ["--views", "2", "--spp", "2", "--seed", "3"]
    assert synth(fresh, *settings) == 0
    assert synth(directory, "--views", "2", "--spp", "1", "--seed", "4") == 0  # an earlier capture
    with monkeypatch.context() as patch:
        Interrupt(patch, after=1)
        assert interrupted(directory, *settings, "--overwrite")
    names = {str(p.relative_to(directory)) for p in directory.rglob("*") if p.is_file()}
    # no capture.json until the end, no temporary files left, and the old run's second image
    # (same name as the new run's) is gone rather than mistaken for a finished image
    assert "capture.json" not in names and "capture.plan.json" in names
    assert not [n for n in names if n.endswith(".tmp")]
    assert "images/f0000/cam00_light00.exr" in names
    assert "images/f0000/cam01_light01.exr" not in names
    assert synth(directory, *settings, "--resume") == 0
    assert_same_capture(directory, fresh)
    assert (directory / "preview.png").read_bytes() == (fresh / "preview.png").read_bytes()


def test_resume_with_other_settings_names_them(tmp_path, monkeypatch, capsys):
    directory = tmp_path / "capture"
    with monkeypatch.context() as patch:
        Interrupt(patch, after=1)
        assert interrupted(directory, "--views", "2", "--spp", "2")
    assert synth(directory, "--views", "2", "--spp", "3", "--seed", "5", "--resume") == 2
    error = capsys.readouterr().err
    assert "--spp: 2 (first run) vs 3 (now)" in error
    assert "--seed: 0 (first run) vs 5 (now)" in error
    assert "--overwrite" in error and "original settings" in error
    assert "or --resume" not in error  # --resume was given


def test_large_seeds_render(tmp_path):
    assert synth(tmp_path / "capture", "--views", "1", "--spp", "1", "--raw",
                 "--seed", "4000000000") == 0
    load_capture(tmp_path / "capture")


@pytest.mark.parametrize("seed", [0, 429, 430, 4_000_000_000, SEED_LIMIT - 1])
def test_image_seeds_are_distinct_32_bit_values(seed):
    seeds = [image_seed(seed, frame, camera, band)
             for frame in range(4) for camera in range(16) for band in range(6)]
    assert len(set(seeds)) == len(seeds)
    assert all(0 <= s < 2**32 for s in seeds)


@pytest.mark.parametrize("seed", ["-1", str(SEED_LIMIT), "1.5"])
def test_seed_out_of_range_is_refused(tmp_path, capsys, seed):
    with pytest.raises(SystemExit) as exit_info:
        synth(tmp_path / "x", "--seed", seed)
    assert exit_info.value.code == 2
    assert "2**64" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_spectral_variants_are_refused_with_the_reason(tmp_path, capsys):
    assert synth(tmp_path / "x", "--variant", "llvm_ad_spectral_polarized") == 2
    error = capsys.readouterr().err
    reason, _, choices = error.partition("use one of:")
    assert "mono polarized" in reason and "per band" in reason
    assert "llvm_ad_mono_polarized" in choices and "spectral" not in choices


def test_help_documents_every_option(capsys):
    with pytest.raises(SystemExit):
        main(["synth", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "must be empty" not in text
    assert "--overwrite (start over)" in text and "--resume (continue)" in text
    assert "docs/synth.md" in text and "polarbssrdf.synth.truth" not in text
    for default in ("(default: face)", "(default: 8)", "(default: 512)", "(default: 16)",
                    "(default: 0)", "(default: llvm_ad_mono_polarized)"):
        assert default in text
    assert "[0, 2**64)" in text
