"""Packaging: every sub-package is installed, and the plugins register per variant."""

import pathlib
import tomllib

import mitsuba as mi

import polarbssrdf

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_every_subpackage_is_listed_in_pyproject():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    on_disk = {"polarbssrdf." + ".".join(p.parent.relative_to(ROOT / "polarbssrdf").parts)
               for p in (ROOT / "polarbssrdf").rglob("__init__.py")}
    on_disk = {name.rstrip(".") for name in on_disk} | {"polarbssrdf.plugins"}
    assert on_disk <= listed, f"not installed: {sorted(on_disk - listed)}"


def test_plugins_are_registered_again_after_a_variant_change():
    for variant in ["llvm_ad_mono_polarized", "scalar_rgb", "llvm_ad_spectral_polarized"]:
        mi.set_variant(variant)
        bsdf = mi.load_dict({"type": "pbssrdf"})
        emitter = mi.load_dict({"type": "ppoint"})
        assert isinstance(bsdf, mi.BSDF) and isinstance(emitter, mi.Emitter)
    assert polarbssrdf.register_plugins() is True
