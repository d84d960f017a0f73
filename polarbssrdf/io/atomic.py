"""Atomic file writes: write a temporary file beside the target, then rename.

A reader never sees a half-written file: the data go to a hidden temporary
file in the target's directory (same file system, so the final rename is
atomic), are flushed to disk, and only then take the target's name. If
anything fails on the way, the temporary file is removed and an existing
target is left untouched.

By default an existing target is never replaced (a run must not overwrite
its inputs or earlier results); pass ``overwrite=True`` to replace it.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable
from pathlib import Path

from polarbssrdf.errors import option

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text", "temporary_path_for"]

TEMP_SUFFIX = ".tmp"
"""Suffix of the temporary files; they also start with a dot (hidden)."""


def temporary_path_for(path: str | os.PathLike) -> Path:
    """A fresh, hidden temporary path in the same directory as ``path``.

    Parameters
    ----------
    path:
        The final destination.

    Returns
    -------
    pathlib.Path
        ``<dir>/.<name>.<random hex>.tmp``; the file does not exist yet.
    """
    path = Path(path)
    return path.with_name(f".{path.name}.{uuid.uuid4().hex[:12]}{TEMP_SUFFIX}")


def _check_destination(path: Path, overwrite: bool) -> None:
    """Fail early, with the path in the message, if ``path`` cannot be written."""
    parent = path.parent
    if not parent.is_dir():
        raise FileNotFoundError(f"cannot write '{path}': directory '{parent}' does not exist")
    if path.is_dir():
        raise IsADirectoryError(f"cannot write '{path}': it is a directory")
    if path.exists() and not overwrite:
        raise FileExistsError(f"'{path}' already exists; refusing to overwrite it "
                              f"(pass {option('overwrite', True)} to replace it)")


def _fsync_file(path: Path) -> None:
    """Flush the contents of the file at ``path`` to stable storage."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_directory(directory: Path) -> None:
    """Flush a directory entry change (the rename) to disk; best effort."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _publish(temporary: Path, path: Path, overwrite: bool) -> None:
    """Give the finished ``temporary`` file the name ``path``.

    With ``overwrite=False`` a hard link creates the name only if it does not
    exist (no race with another writer); file systems without hard links
    fall back to an existence check followed by a rename.
    """
    if overwrite:
        os.replace(temporary, path)
        return
    try:
        os.link(temporary, path)
    except FileExistsError:
        raise FileExistsError(f"'{path}' already exists; refusing to overwrite it "
                              f"(pass {option('overwrite', True)} to replace it)") from None
    except OSError:
        if path.exists():
            raise FileExistsError(f"'{path}' already exists; refusing to overwrite it "
                                  f"(pass {option('overwrite', True)} to replace it)") from None
        os.replace(temporary, path)
        return
    os.unlink(temporary)


def atomic_write(path: str | os.PathLike, write: Callable[[Path], None], *,
                 overwrite: bool = False) -> Path:
    """Write a file atomically through a caller-supplied writer.

    Parameters
    ----------
    path:
        Destination file. Its directory must exist.
    write:
        Called once with the temporary path (an empty file that already
        exists, created with the usual permissions); it must write the
        complete contents there, by path. If it raises, the temporary file
        is removed, ``path`` is left as it was, and the error propagates.
    overwrite:
        Replace ``path`` if it exists. Otherwise an existing ``path`` raises
        :class:`FileExistsError` naming it, before ``write`` is called.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    _check_destination(path, overwrite)
    temporary = temporary_path_for(path)
    # O_EXCL: never reuse somebody else's file; mode 0o666 is filtered by the umask.
    os.close(os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    try:
        write(temporary)
        _fsync_file(temporary)
        _publish(temporary, path, overwrite)
    except BaseException:
        try:
            os.unlink(temporary)
        except FileNotFoundError:
            pass
        raise
    _fsync_directory(path.parent)
    return path


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, overwrite: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically (temporary file + rename).

    Parameters
    ----------
    path:
        Destination file; its directory must exist.
    data:
        The complete file contents (``bytes``, ``bytearray`` or ``memoryview``).
    overwrite:
        Replace an existing ``path``; otherwise raise :class:`FileExistsError`.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise TypeError(f"atomic_write_bytes: data for '{path}' must be bytes, "
                        f"not {type(data).__name__}")

    def write(temporary: Path) -> None:
        with open(temporary, "wb") as stream:
            stream.write(data)

    return atomic_write(path, write, overwrite=overwrite)


def atomic_write_text(path: str | os.PathLike, text: str, *, encoding: str = "utf-8",
                      overwrite: bool = False) -> Path:
    """Write the string ``text`` to ``path`` atomically (temporary file + rename).

    Parameters
    ----------
    path:
        Destination file; its directory must exist.
    text:
        The complete file contents.
    encoding:
        Text encoding (default UTF-8). Newlines are written as given.
    overwrite:
        Replace an existing ``path``; otherwise raise :class:`FileExistsError`.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    if not isinstance(text, str):
        raise TypeError(f"atomic_write_text: text for '{path}' must be str, "
                        f"not {type(text).__name__}")
    return atomic_write_bytes(path, text.encode(encoding), overwrite=overwrite)
