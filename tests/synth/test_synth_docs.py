"""docs/synth.md documents every truth setting, and its example settings file works."""

import dataclasses
import json
import re
from pathlib import Path

from polarbssrdf.cli import main
from polarbssrdf.io import load_capture
from polarbssrdf.synth.truth import BIOPHYSICAL, DEFAULT_REFLECTANCE, TruthSettings, load_settings

DOC = Path(__file__).resolve().parents[2] / "docs" / "synth.md"


def test_every_truth_setting_is_documented_with_its_default():
    text = DOC.read_text()
    defaults = TruthSettings()
    for field in dataclasses.fields(TruthSettings):
        assert f"| `{field.name}` |" in text, field.name
    for name, value in DEFAULT_REFLECTANCE.items():
        assert f"| `{name}` |" in text and json.dumps(list(value)) in text, name
    for name in BIOPHYSICAL:
        assert f"| `{name}` | {defaults.biophysical_std[name]} |" in text, name
    assert f"| {defaults.correlation_mm} |" in text and f"| {defaults.hemoglobin_swing} |" in text


def test_the_example_settings_file_runs(tmp_path):
    example = re.search(r"```json\n(.*?)```", DOC.read_text(), re.S).group(1)
    params = tmp_path / "params.json"
    params.write_text(example)
    settings = load_settings(params)
    assert settings.skin == ("cheek", "IV") and settings.reflectance["alpha_s"][0] == 0.35
    assert settings.biophysical_std["C_m"] == 0.006 and settings.biophysical_std["C_h_in"] == 0.008
    assert settings.biophysical_maps()["C_h_in"] == (0.035, 0.008, 0.0, 1.0)
    assert settings.features[0]["map"] == "C_m" and settings.features[0]["count"] == 25
    assert main(["synth", str(tmp_path / "cap"), "--object", "sphere", "--views", "1",
                 "--resolution", "32", "--texture", "32", "--spp", "1", "--quiet",
                 "--params", str(params)]) == 0
    recorded = load_capture(tmp_path / "cap").manifest.metadata["truth_settings"]
    assert recorded["skin"] == ["cheek", "IV"] and recorded["correlation_mm"] == 12.0
    assert recorded["features"][0]["name"] == "freckles"
