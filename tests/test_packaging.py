"""Packaging: every sub-package and data folder is installed (a wheel is built and read), the
scenes ship with the package, and the plugins register per variant."""

import pathlib
import shutil
import subprocess
import sys
import tomllib
import zipfile

import mitsuba as mi
import pytest

import polarbssrdf
from helpers import run_cli

ROOT = pathlib.Path(__file__).resolve().parents[1]
SOURCES = ("polarbssrdf", "plugins", "scenes", "pyproject.toml", "README.md", "LICENSE")
"""What a wheel is built from (tests, benchmarks and docs are not installed)."""


def test_every_subpackage_is_listed_in_pyproject():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    on_disk = {"polarbssrdf." + ".".join(p.parent.relative_to(ROOT / "polarbssrdf").parts)
               for p in (ROOT / "polarbssrdf").rglob("__init__.py")}
    on_disk = {name.rstrip(".") for name in on_disk} | {"polarbssrdf.plugins"}
    assert on_disk <= listed, f"not installed: {sorted(on_disk - listed)}"


def test_every_data_folder_is_a_listed_package():
    """A folder of data files that is not listed makes setuptools warn 'Package would be
    ignored' (and, with other settings, leave the files out)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    roots = {"polarbssrdf": ROOT / "polarbssrdf", "polarbssrdf.scenes": ROOT / "scenes"}
    folders = set()
    for package, base in roots.items():
        for path in base.rglob("*"):
            if path.is_file() and "__pycache__" not in path.parts:
                parts = path.parent.relative_to(base).parts
                folders.add(".".join((package, *parts)))
    assert folders <= set(config["packages"]), sorted(folders - set(config["packages"]))
    for package in folders:
        if package in config["package-data"]:
            assert config["package-data"][package], package


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """``(wheel path, build output)`` of the package built from a copy of its sources."""
    root = tmp_path_factory.mktemp("wheel")
    source = root / "source"
    source.mkdir()
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, source / name,
                            ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy2(ROOT / name, source / name)
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                            "--no-build-isolation", "--no-index", "-w", str(root / "dist"),
                            str(source)], capture_output=True, text=True, timeout=300)
    assert built.returncode == 0, built.stdout + built.stderr
    (path,) = (root / "dist").glob("polarbssrdf-*.whl")
    return path, built.stdout + built.stderr


def test_the_build_warns_of_no_ignored_package(wheel):
    _, output = wheel
    assert "would be ignored" not in output and "absent from the `packages`" not in output


def test_the_wheel_holds_the_scenes_and_the_data(wheel, tmp_path):
    path, _ = wheel
    with zipfile.ZipFile(path) as archive:
        names = set(archive.namelist())
        archive.extractall(tmp_path)
    for scene in (ROOT / "scenes").glob("*.xml"):
        assert f"polarbssrdf/scenes/{scene.name}" in names
    for data in ("geometry/assets/canonical_face_model.obj",
                 "geometry/assets/canonical_face_model.NOTICE.txt",
                 "skin/data/hemoglobin_molar_extinction_prahl.csv",
                 "spectral/data/default_bands.json", "plugins/pbssrdf.py"):
        assert f"polarbssrdf/{data}" in names, data
    # the light stage's mesh travels with it (a copy of the vendored one, not a link)
    mesh = tmp_path / "polarbssrdf" / "scenes" / "assets" / "canonical_face_model.obj"
    assert not mesh.is_symlink()
    assert mesh.read_bytes() == (ROOT / "polarbssrdf/geometry/assets/canonical_face_model.obj"
                                 ).read_bytes()
    mi.set_variant("llvm_ad_mono_polarized")
    scene = mi.load_file(str(tmp_path / "polarbssrdf" / "scenes" / "lightstage.xml"),
                         resolution=8, spp=1)
    assert len(scene.shapes()) >= 1 and len(scene.sensors()) >= 1


def test_polarbssrdf_scenes_lists_the_shipped_scenes():
    status, stdout, stderr = run_cli("scenes")
    assert status == 0, stderr
    for scene in (ROOT / "scenes").glob("*.xml"):
        assert f"  {scene.stem}  " in stdout
    status, stdout, _ = run_cli("scenes", "--path", "sphere")
    assert status == 0 and pathlib.Path(stdout.strip()).read_bytes() == (
        ROOT / "scenes" / "sphere.xml").read_bytes()
    status, _, stderr = run_cli("scenes", "--path", "face")
    assert status == 2 and "lightstage, sphere" in stderr and stderr.count("\n") == 1


def test_plugins_are_registered_again_after_a_variant_change():
    for variant in ["llvm_ad_mono_polarized", "scalar_rgb", "llvm_ad_spectral_polarized"]:
        mi.set_variant(variant)
        bsdf = mi.load_dict({"type": "pbssrdf"})
        emitter = mi.load_dict({"type": "ppoint"})
        assert isinstance(bsdf, mi.BSDF) and isinstance(emitter, mi.Emitter)
    assert polarbssrdf.register_plugins() is True
