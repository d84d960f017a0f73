"""Content fingerprints of a capture's files, and a capture's identity.

A file's fingerprint is a hash of its bytes (:func:`file_digest`), never its
size and modification time: ``cp -p``, ``rsync -a`` or a re-export of an
uncompressed EXR replace an image by another of the same size and time.
BLAKE2b (128-bit digests) is in the standard library and hashes about
580 MB/s on one core of the development machine (SHA-256: 620 MB/s there,
with the CPU's SHA instructions; neither is the bottleneck next to reading
and demosaicking the images); a file is hashed once per process unless it
changes (:func:`file_digest` keys its memo on the file's inode and change
time, which every write updates).

A capture's identity (:func:`capture_identity`) is what was measured: the
manifest's cameras, lights, bands, units, mesh and frames (not its free-form
``metadata``, ``synthetic`` flag or ``truth`` reference: a copy of a
synthetic capture without its truth is still that capture), the mesh's
bytes and the bytes of one frame's images. ``result.json`` records it, so
``evaluate --truth`` and ``report --capture`` can refuse another capture
(:func:`identity_differences` says what differs).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from polarbssrdf.io.capture import MANIFEST_NAME

__all__ = ["DIGEST_NAME", "capture_identity", "file_digest", "identity_differences",
           "manifest_digest"]

DIGEST_NAME = "blake2b-128"
"""The hash of :func:`file_digest` and of the identity, as recorded next to the digests."""

_CHUNK_BYTES = 1 << 22
_NOT_MEASURED = ("metadata", "synthetic", "truth")
"""``capture.json`` keys outside a capture's identity (see the module docstring)."""

_MEMO: dict = {}


def _hasher():
    return hashlib.blake2b(digest_size=16)


def file_digest(path) -> str:
    """Hex BLAKE2b-128 of the bytes of ``path``.

    Memoized per process on ``(device, inode, size, mtime, ctime)``: the change
    time moves on every write and cannot be set by ``cp -p`` or ``touch``, so a
    rewritten file is hashed again.
    """
    path = Path(path)
    stat = os.stat(path)
    key = (os.fspath(path.resolve()), stat.st_dev, stat.st_ino, stat.st_size,
           stat.st_mtime_ns, stat.st_ctime_ns)
    digest = _MEMO.get(key)
    if digest is None:
        hasher = _hasher()
        with open(path, "rb") as stream:
            for chunk in iter(lambda: stream.read(_CHUNK_BYTES), b""):
                hasher.update(chunk)
        digest = hasher.hexdigest()
        if len(_MEMO) > 4096:  # a long sequence in one process: keep the memo bounded
            _MEMO.clear()
        _MEMO[key] = digest
    return digest


def manifest_digest(document: dict) -> str:
    """Hex BLAKE2b-128 of the measured part of a decoded ``capture.json`` (canonical JSON:
    sorted keys, no whitespace, so reformatting the file keeps it)."""
    measured = {key: value for key, value in document.items() if key not in _NOT_MEASURED}
    text = json.dumps(measured, sort_keys=True, separators=(",", ":"))
    hasher = _hasher()
    hasher.update(text.encode("utf-8"))
    return hasher.hexdigest()


def capture_identity(capture, frame: int) -> dict:
    """The identity of ``capture`` (a :class:`~polarbssrdf.io.capture.Capture`) from frame
    ``frame``'s images.

    Returns ``{"digest", "hash", "capture_json", "mesh", "frame", "images"}``: the
    combined digest, :data:`DIGEST_NAME`, the digest of ``capture.json``'s measured part
    (:func:`manifest_digest`), the mesh file's (or None), and ``{path: digest}`` of the
    frame's images.
    """
    directory = Path(capture.directory)
    document = json.loads((directory / MANIFEST_NAME).read_text(encoding="utf-8"))
    mesh = None if capture.mesh_path is None else file_digest(capture.mesh_path)
    images = {record.path: file_digest(directory / record.path)
              for record in capture.manifest.frame(int(frame)).images}
    parts = {"capture_json": manifest_digest(document), "mesh": mesh, "frame": int(frame),
             "images": images}
    hasher = _hasher()
    hasher.update(json.dumps(parts, sort_keys=True).encode("utf-8"))
    return {"digest": hasher.hexdigest(), "hash": DIGEST_NAME, **parts}


def identity_differences(recorded: dict, found: dict) -> list[str]:
    """What differs between two :func:`capture_identity` results, as short phrases."""
    if recorded.get("digest") == found.get("digest"):
        return []
    differences = []
    if recorded.get("capture_json") != found.get("capture_json"):
        differences.append("capture.json differs (cameras, lights, bands, units, mesh or "
                           "frames)")
    if recorded.get("mesh") != found.get("mesh"):
        differences.append("the mesh file differs")
    old, new = recorded.get("images") or {}, found.get("images") or {}
    changed = sorted(path for path in old if path in new and old[path] != new[path])
    absent = sorted(set(old) ^ set(new))
    frame = recorded.get("frame")
    if changed:
        differences.append(f"{len(changed)} of {len(old)} images of frame {frame} have other "
                           f"contents (e.g. {changed[0]})")
    if absent:
        differences.append(f"frame {frame} lists other images (e.g. {absent[0]})")
    return differences or ["the identity digests differ"]
