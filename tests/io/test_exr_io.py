"""EXR and atomic-write I/O: round trips, atomicity, refusal to overwrite, clear errors."""

import json
import os

import numpy as np
import OpenEXR
import pytest

import polarbssrdf.io.atomic as atomic
import polarbssrdf.io.exr as exr
from polarbssrdf.io import atomic_write_bytes, atomic_write_text, read_exr, write_exr


def _leftover_temporaries(directory):
    return [name for name in os.listdir(directory) if name.endswith(atomic.TEMP_SUFFIX)]


@pytest.fixture
def channels(rng):
    """Three 5 x 7 float32 channels with awkward values (negative, tiny, huge, denormal)."""
    a = rng.normal(size=(5, 7)).astype(np.float32)
    b = (rng.random((5, 7)) * 1e30).astype(np.float32)
    c = rng.normal(size=(5, 7)).astype(np.float32) * np.float32(1e-38)
    c[0, 0] = np.float32(1.4e-45)  # smallest denormal
    return {"S0": a, "I0": b, "S0.R": c}


def test_round_trip_is_bit_exact_with_names_order_and_metadata(tmp_path, channels):
    metadata = {"scene": "sphere.xml", "spp": 4, "eta": 1.4, "flags": [True, None],
                "nested": {"a": [1, 2.5, "x"]}}
    path = write_exr(tmp_path / "image.exr", channels, metadata)
    assert path == tmp_path / "image.exr"
    read, meta = read_exr(path)
    assert list(read) == ["S0", "I0", "S0.R"]  # write order, not the file's sorted order
    for name, values in channels.items():
        assert read[name].dtype == np.float32 and read[name].shape == (5, 7)
        assert np.array_equal(read[name].view(np.uint32), values.view(np.uint32)), name
    assert meta == metadata


def test_inputs_are_converted_to_contiguous_float32(tmp_path, rng):
    wide = rng.normal(size=(4, 6))  # float64
    strided = rng.normal(size=(6, 4)).astype(np.float32).T  # not C-contiguous
    integers = np.arange(24).reshape(4, 6)
    write_exr(tmp_path / "a.exr", {"W": wide, "T": strided, "N": integers},
              {"scale": np.float32(0.5), "shape": np.array([4, 6])})
    read, meta = read_exr(tmp_path / "a.exr")
    assert np.array_equal(read["W"], wide.astype(np.float32))
    assert np.array_equal(read["T"], strided)
    assert np.array_equal(read["N"], integers.astype(np.float32))
    assert meta == {"scale": 0.5, "shape": [4, 6]}


def test_no_temporary_files_are_left(tmp_path, channels):
    write_exr(tmp_path / "a.exr", channels)
    write_exr(tmp_path / "a.exr", channels, overwrite=True)
    with pytest.raises(FileExistsError):
        write_exr(tmp_path / "a.exr", channels)
    assert sorted(os.listdir(tmp_path)) == ["a.exr"]


def test_failure_mid_write_leaves_previous_file_intact(tmp_path, channels, monkeypatch):
    path = write_exr(tmp_path / "a.exr", channels, {"run": 1})
    before = path.read_bytes()

    def broken_writer(temporary, header, arrays):
        temporary.write_bytes(b"v/1\x01 half an image")
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(exr, "_write_exr_file", broken_writer)
    new = {name: values + 1 for name, values in channels.items()}
    with pytest.raises(OSError, match="simulated"):
        write_exr(path, new, {"run": 2}, overwrite=True)
    assert path.read_bytes() == before
    assert read_exr(path)[1] == {"run": 1}
    assert _leftover_temporaries(tmp_path) == []


def test_refuses_to_overwrite_unless_asked(tmp_path, channels):
    path = write_exr(tmp_path / "a.exr", channels, {"run": 1})
    with pytest.raises(FileExistsError, match="a.exr.*overwrite=True"):
        write_exr(path, channels, {"run": 2})
    assert read_exr(path)[1] == {"run": 1}
    write_exr(path, {"S0": channels["S0"] * 2}, {"run": 2}, overwrite=True)
    read, meta = read_exr(path)
    assert meta == {"run": 2} and list(read) == ["S0"]
    assert np.array_equal(read["S0"], channels["S0"] * 2)


def test_nonfinite_values_are_rejected_naming_the_channel(tmp_path, channels):
    bad = dict(channels)
    bad["I90"] = np.ones((5, 7), np.float32)
    bad["I90"][2, 3] = np.nan
    with pytest.raises(ValueError, match=r"channel 'I90'.*1 NaN.*row 2, column 3.*allow_nonfinite"):
        write_exr(tmp_path / "a.exr", bad)
    bad["I90"][0, 1] = np.inf
    with pytest.raises(ValueError, match=r"channel 'I90'.*1 NaN and 1 infinite"):
        write_exr(tmp_path / "a.exr", bad)
    with pytest.raises(ValueError, match=r"channel 'S1'.*outside the float32 range"):
        write_exr(tmp_path / "a.exr", {"S1": np.full((2, 2), 1e300)})
    assert not (tmp_path / "a.exr").exists()
    write_exr(tmp_path / "a.exr", bad, allow_nonfinite=True)
    read, _ = read_exr(tmp_path / "a.exr")
    assert np.isnan(read["I90"][2, 3]) and np.isinf(read["I90"][0, 1])


@pytest.mark.parametrize("shape", [(5,), (5, 7, 3), ()])
def test_channels_must_be_two_dimensional(tmp_path, shape):
    with pytest.raises(ValueError, match=r"channel 'S2' has shape .*2-D H x W"):
        write_exr(tmp_path / "a.exr", {"S2": np.zeros(shape, np.float32)})


def test_mismatched_shapes_name_both_channels(tmp_path):
    with pytest.raises(ValueError, match=r"channel 'S1' has shape \(4, 5\) but channel 'S0' "
                                         r"has shape \(5, 4\)"):
        write_exr(tmp_path / "a.exr", {"S0": np.zeros((5, 4)), "S1": np.zeros((4, 5))})


def test_other_bad_channel_inputs(tmp_path):
    with pytest.raises(ValueError, match="at least one channel"):
        write_exr(tmp_path / "a.exr", {})
    with pytest.raises(ValueError, match="non-empty strings"):
        write_exr(tmp_path / "a.exr", {"": np.zeros((2, 2))})
    with pytest.raises(TypeError, match="channel 'S0' has dtype"):
        write_exr(tmp_path / "a.exr", {"S0": np.array([["a", "b"]])})
    with pytest.raises(ValueError, match="channel 'S0' is empty"):
        write_exr(tmp_path / "a.exr", {"S0": np.zeros((0, 3))})
    with pytest.raises(ValueError, match="metadata cannot be stored as JSON"):
        write_exr(tmp_path / "a.exr", {"S0": np.zeros((2, 2))}, {"x": object()})
    with pytest.raises(ValueError, match="metadata cannot be stored as JSON"):
        write_exr(tmp_path / "a.exr", {"S0": np.zeros((2, 2))}, {"x": float("nan")})
    with pytest.raises(FileNotFoundError, match="directory .*missing.* does not exist"):
        write_exr(tmp_path / "missing" / "a.exr", {"S0": np.zeros((2, 2))})
    assert os.listdir(tmp_path) == []


def test_read_errors_name_the_problem(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing.exr' does not exist"):
        read_exr(tmp_path / "nothing.exr")
    (tmp_path / "text.exr").write_text("not an image")
    with pytest.raises(ValueError, match="text.exr' is not an OpenEXR file"):
        read_exr(tmp_path / "text.exr")
    (tmp_path / "truncated.exr").write_bytes(b"v/1\x01" + b"\x00" * 10)
    with pytest.raises(ValueError, match="truncated.exr' is not a readable OpenEXR file"):
        read_exr(tmp_path / "truncated.exr")
    with pytest.raises(IsADirectoryError):
        read_exr(tmp_path)


def test_foreign_exr_and_newer_schema(tmp_path):
    pixels = np.arange(6, dtype=np.float32).reshape(2, 3)
    OpenEXR.File({}, {"Z": pixels}).write(str(tmp_path / "foreign.exr"))
    read, meta = read_exr(tmp_path / "foreign.exr")
    assert meta == {} and np.array_equal(read["Z"], pixels)

    newer = json.dumps({"schema_version": exr.EXR_METADATA_SCHEMA_VERSION + 1, "metadata": {}})
    OpenEXR.File({exr.METADATA_ATTRIBUTE: newer}, {"Z": pixels}).write(str(tmp_path / "new.exr"))
    with pytest.raises(ValueError, match="schema version .* newer"):
        read_exr(tmp_path / "new.exr")


def test_atomic_text_and_bytes(tmp_path, monkeypatch):
    path = atomic_write_text(tmp_path / "a.json", '{"x": 1}\n')
    assert path.read_text() == '{"x": 1}\n'
    with pytest.raises(FileExistsError, match="a.json.*overwrite=True"):
        atomic_write_text(path, "other")
    atomic_write_bytes(path, b"\x00\x01", overwrite=True)
    assert path.read_bytes() == b"\x00\x01"
    with pytest.raises(TypeError, match="must be bytes"):
        atomic_write_bytes(tmp_path / "b.bin", "text")
    with pytest.raises(TypeError, match="must be str"):
        atomic_write_text(tmp_path / "b.txt", b"bytes")
    with pytest.raises(IsADirectoryError):
        atomic_write_text(tmp_path, "x", overwrite=True)

    # File systems without hard links: the no-overwrite check still holds.
    def no_links(source, destination):
        raise PermissionError("hard links not supported (simulated)")

    monkeypatch.setattr(atomic.os, "link", no_links)
    with pytest.raises(FileExistsError):
        atomic_write_text(path, "other")
    atomic_write_text(tmp_path / "c.txt", "fresh")
    assert (tmp_path / "c.txt").read_text() == "fresh"
    assert path.read_bytes() == b"\x00\x01"
    assert _leftover_temporaries(tmp_path) == []


def test_atomic_write_failure_keeps_old_contents(tmp_path):
    path = atomic_write_text(tmp_path / "a.txt", "old")

    def failing(temporary):
        temporary.write_text("partial")
        raise RuntimeError("writer failed (simulated)")

    with pytest.raises(RuntimeError, match="simulated"):
        atomic.atomic_write(path, failing, overwrite=True)
    assert path.read_text() == "old"
    assert _leftover_temporaries(tmp_path) == []


def test_written_files_have_normal_permissions(tmp_path, channels):
    umask = os.umask(0o022)
    os.umask(umask)
    path = write_exr(tmp_path / "a.exr", channels)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask


@pytest.mark.parametrize("damage", ["truncated", "zeroed", "header only"])
def test_a_damaged_exr_is_named_in_one_message_and_nothing_else_is_printed(tmp_path, capfd,
                                                                           damage):
    """OpenEXR raised "Invalid part index '0': file has 0 parts" and named the file only in
    its own stderr lines (issue 21, item 8)."""
    rng = np.random.default_rng(0)
    path = write_exr(tmp_path / "good.exr", {"A": rng.random((64, 64)), "B": rng.random((64, 64))})
    data = path.read_bytes()
    broken = tmp_path / "broken.exr"
    if damage == "truncated":
        broken.write_bytes(data[:len(data) // 2])
    elif damage == "zeroed":
        broken.write_bytes(data[:400] + bytes(400) + data[800:])
    else:
        broken.write_bytes(data[:8])
    capfd.readouterr()
    with pytest.raises(ValueError) as caught:
        read_exr(broken)
    message = str(caught.value)
    assert message.startswith(f"'{broken}' is not a readable OpenEXR file (truncated or "
                              "damaged: ")
    assert "\n" not in message and "part index" not in message
    assert capfd.readouterr() == ("", "")
    read_exr(path)  # the descriptors are back: a good file still reads, silently
    assert capfd.readouterr() == ("", "")
