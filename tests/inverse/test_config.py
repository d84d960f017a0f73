"""A run's config file: every value has its JSON type, and a wrong one is named (issue 21, item 1).

``bool("false")`` is ``True`` in Python, so before this check ``{"coaxial": "false"}`` turned
the coaxial ablation on and exited 0. The errors name the file, the key and the type found.
"""

from __future__ import annotations

import dataclasses
import json

import pytest

from helpers import run_cli
from polarbssrdf.inverse.config import load_static_config
from polarbssrdf.inverse.polarimetric.config import StaticConfig

BOOLEAN_KEYS = [f.name for f in dataclasses.fields(StaticConfig) if f.type == "bool"]


def _config_file(tmp_path, data):
    path = tmp_path / "config.json"
    path.write_text(json.dumps(data))
    return path


def _refused(tmp_path, data, *expected):
    path = _config_file(tmp_path, data)
    with pytest.raises(ValueError) as caught:
        load_static_config(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: config: "), message
    assert "\n" not in message
    for text in expected:
        assert text in message, message
    return message


def test_the_flags_are_the_documented_ones():
    # a new flag is checked without a change here; these are the ones the issue names
    assert {"coaxial", "polarimetric", "estimate_noise", "separate_lobes",
            "glossy_amplitudes"} <= set(BOOLEAN_KEYS)


@pytest.mark.parametrize("key", BOOLEAN_KEYS)
@pytest.mark.parametrize("value, kind", [("false", 'a string ("false")'),
                                         ("true", 'a string ("true")'),
                                         (0, "an integer (0)"), (1, "an integer (1)"),
                                         (None, "null")])
def test_a_flag_must_be_a_json_boolean(tmp_path, key, value, kind):
    _refused(tmp_path, {key: value}, f"config: {key} must be true or false", kind)


@pytest.mark.parametrize("key", BOOLEAN_KEYS)
def test_json_booleans_are_read_as_such(tmp_path, key):
    default = getattr(StaticConfig(), key)
    config = load_static_config(_config_file(tmp_path, {key: not default}))
    assert getattr(config, key) is (not default)
    assert config.to_json()[key] is (not default)  # result.json records a boolean


@pytest.mark.parametrize("data, key, kind", [
    ({"iterations": 150.0}, "iterations", "a number (150.0)"),
    ({"iterations": "150"}, "iterations", 'a string ("150")'),
    ({"iterations": True}, "iterations", "a boolean (true)"),
    ({"patch_size": 64.0}, "patch_size", "a number (64.0)"),
    ({"seed": "7"}, "seed", 'a string ("7")'),
    ({"min_cosine": "0.3"}, "min_cosine", 'a string ("0.3")'),
    ({"photometric_noise": False}, "photometric_noise", "a boolean (false)"),
    ({"weights": {"psi": "0.002"}}, "weights.psi", 'a string ("0.002")'),
    ({"initial": {"eta": True}}, "initial.eta", "a boolean (true)"),
    ({"optimizer": 1}, "optimizer", "an integer (1)"),
    ({"bounds": {"eta": [True, 1.5]}}, "bounds.eta", "[True, 1.5]"),
    ({"weights": "heavy"}, "weights", 'a string ("heavy")'),
])
def test_numbers_strings_and_objects_of_the_static_stage(tmp_path, data, key, kind):
    _refused(tmp_path, data, f"config: {key} ", kind)


@pytest.mark.parametrize("dynamic, key, kind", [
    ({"iterations": 30.0}, "dynamic.iterations", "a number (30.0)"),
    ({"iterations": "30"}, "dynamic.iterations", 'a string ("30")'),
    ({"iterations": True}, "dynamic.iterations", "a boolean (true)"),
    ({"weights": {"sss": "1"}}, "dynamic.weights.sss", 'a string ("1")'),
    ({"weights": {"sss": False}}, "dynamic.weights.sss", "a boolean (false)"),
    ({"weights": [1, 2]}, "dynamic.weights", "an array"),
])
def test_the_dynamic_object(tmp_path, dynamic, key, kind):
    _refused(tmp_path, {"dynamic": dynamic}, f"config: {key} ", kind)


@pytest.mark.parametrize("bio, key, kind", [
    ({"free_melanin": "false"}, "free_melanin", 'a string ("false")'),
    ({"free_melanin": 1}, "free_melanin", "an integer (1)"),
    ({"iterations": True}, "iterations", "a boolean (true)"),
    ({"iterations": 12.0}, "iterations", "a number (12.0)"),
    ({"rounds": "3"}, "rounds", 'a string ("3")'),
    ({"spectral": 3}, "spectral", "an integer (3)"),
    ({"tolerance": True}, "tolerance", "a boolean (true)"),
    ({"thickness_mm": "0.25"}, "thickness_mm", 'a string ("0.25")'),
    ({"eta": None}, "eta", "null"),
    ({"albedo_noise": "0.05"}, "albedo_noise", 'a string ("0.05")'),
    ({"nuisance_std": {"eta": "fast"}}, "nuisance_std.eta", 'a string ("fast")'),
    ({"bounds": {"C_m": ["0", "0.5"]}}, "bounds.C_m", 'a string ("0")'),
    ({"prior_std": "300"}, "prior_std", 'a string ("300")'),
    ({"prior_std": {"C_m": True}}, "prior_std.C_m", "a boolean (true)"),
])
def test_the_bio_object(tmp_path, bio, key, kind):
    _refused(tmp_path, {"bio": bio}, f"config: bio: {key} ", kind)


def test_free_melanin_as_a_json_boolean():
    from polarbssrdf.inverse.biophysical.config import bio_config

    assert bio_config({"free_melanin": True})[1] is True
    assert bio_config({"free_melanin": False})[1] is False
    assert bio_config({})[1] is False


def test_reconstruct_refuses_a_string_flag_before_any_work(sphere_capture_dir, tmp_path):
    """The issue's case on the command line: one line naming the file, key and type; no OUTDIR."""
    from polarbssrdf.errors import EXIT_USER_ERROR

    config = _config_file(tmp_path, {"coaxial": "false"})
    outdir = tmp_path / "out"
    status, _, stderr = run_cli("reconstruct", sphere_capture_dir, outdir, "--config", config,
                                "--quiet")
    assert status == EXIT_USER_ERROR
    assert stderr == (f"polarbssrdf reconstruct: error: {config}: config: coaxial must be true "
                      'or false (a JSON boolean), got a string ("false")\n')
    assert not outdir.exists()


def test_an_unknown_bio_key_says_config_once(tmp_path):
    """Issue 32, item 14: the message read "config: bio: config: unknown bio key(s)"."""
    from polarbssrdf.inverse.config import load_static_config

    path = tmp_path / "config.json"
    path.write_text(json.dumps({"bio": {"foo": 1}}))
    with pytest.raises(ValueError) as error:
        load_static_config(path)
    assert "config: bio: unknown bio key(s) ['foo']" in str(error.value)
    assert str(error.value).count("config:") == 1
