"""The Mitsuba scenes shipped with the package, and ``polarbssrdf scenes``, which lists them.

``scenes/*.xml`` of a checkout is installed as ``polarbssrdf/scenes/`` (with
the face mesh that ``lightstage.xml`` loads, under ``assets/``), so the
scenes are there after ``pip install .`` too; ``polarbssrdf scenes`` prints
where, and ``polarbssrdf scenes --path NAME`` one scene's file, for
``polarbssrdf render "$(polarbssrdf scenes --path sphere)" out/``.
"""

from __future__ import annotations

import re
from pathlib import Path

from polarbssrdf.errors import CommandError

_PACKAGE = Path(__file__).resolve().parents[1]


def scene_directory() -> Path:
    """The directory of the shipped scenes: ``polarbssrdf/scenes`` when installed, the
    checkout's ``scenes/`` in an editable install."""
    for candidate in (_PACKAGE / "scenes", _PACKAGE.parent / "scenes"):
        if any(candidate.glob("*.xml")):
            return candidate
    raise FileNotFoundError(f"no scenes next to the package in {_PACKAGE}: the installation "
                            "is incomplete (reinstall polarbssrdf)")


def scene_summary(path: Path) -> str:
    """The first sentence of a scene file's leading XML comment (what the scene is)."""
    text = Path(path).read_text(encoding="utf-8")
    match = re.search(r"<!--(.*?)-->", text, re.DOTALL)
    if not match:
        return ""
    words = " ".join(match.group(1).split())
    sentence = re.match(r"(.+?\.)(\s|$)", words)
    return sentence.group(1) if sentence else words


def shipped_scenes() -> dict[str, Path]:
    """``name -> path`` of every shipped scene (``sphere`` for ``sphere.xml``), sorted."""
    return {path.stem: path for path in sorted(scene_directory().glob("*.xml"))}


def register(subparsers) -> None:
    """Add ``scenes`` to the ``polarbssrdf`` argument parser."""
    parser = subparsers.add_parser(
        "scenes", help="list the Mitsuba scenes shipped with polarbssrdf and where they are",
        description="List the scene files installed with the package (name, path, what it "
                    "is). With --path NAME, print only that scene's path, e.g. "
                    "polarbssrdf render \"$(polarbssrdf scenes --path sphere)\" out/")
    parser.add_argument("--path", metavar="NAME", default=None,
                        help="print the path of the scene NAME (e.g. sphere, lightstage)")
    parser.set_defaults(run=run_scenes)


def run_scenes(args) -> int:
    """Execute ``polarbssrdf scenes``; returns the exit status 0."""
    scenes = shipped_scenes()
    if args.path is not None:
        name = args.path[:-4] if args.path.endswith(".xml") else args.path
        if name not in scenes:
            raise CommandError(f"no shipped scene {args.path!r}; the scenes are: "
                               f"{', '.join(scenes)}")
        print(scenes[name])
        return 0
    width = max(map(len, scenes))
    print(f"scenes in {scene_directory()}:")
    for name, path in scenes.items():
        print(f"  {name:<{width}}  {scene_summary(path)}")
    return 0
