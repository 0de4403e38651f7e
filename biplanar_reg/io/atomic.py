"""The one atomic file writer of the package.

Every file the package writes goes through :func:`atomic_path` (or the helpers built on it):

1. a temporary file is created beside the target (same folder, hence the same file system,
   so the final rename is atomic), named ``.<name>.<random>.part<suffix>``;
2. the content is written to it and ``fsync``-ed;
3. it gets the mode a plain ``open(path, "w")`` would give: the existing target's mode when the
   target exists, else ``0o666 & ~umask`` (``tempfile.mkstemp`` alone would leave ``0o600``);
4. ``os.replace`` moves it onto the target and the folder is ``fsync``-ed (where the platform
   allows opening a folder), so the rename itself survives a power cut.

On any exception the temporary file is removed and the target is left as it was: a reader sees
the previous file or the new one, never a half-written one.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text", "atomic_write_json"]

#: Compression suffixes kept together with the one before them (``.csv.gz``), so a library that
#: picks its format from the file name still sees it in the temporary name.
_COMPRESSION_SUFFIXES = (".gz", ".bz2", ".xz", ".zst")


def current_umask() -> int:
    """The process's file-mode creation mask, read without changing it where possible.

    Linux reports it in ``/proc/self/status``; elsewhere it is read by setting and restoring it
    (``os.umask`` has no read-only form), which is racy only against threads creating files in
    the same instant.
    """
    with contextlib.suppress(OSError, ValueError):
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def new_file_mode(path: str | os.PathLike[str]) -> int:
    """Permission bits ``open(path, "w")`` would leave on ``path``.

    The existing file's bits when ``path`` exists (rewriting a file does not change its mode),
    else ``0o666 & ~umask``.
    """
    try:
        return os.stat(path).st_mode & 0o777
    except FileNotFoundError:
        return 0o666 & ~current_umask()


def _temp_suffix(path: Path) -> str:
    """The target's suffix (two for ``name.csv.gz``), kept at the end of the temporary name."""
    suffixes = path.suffixes
    if len(suffixes) >= 2 and suffixes[-1].lower() in _COMPRESSION_SUFFIXES:
        return "".join(suffixes[-2:])
    return path.suffix


def _fsync_path(path: Path) -> None:
    """Flush a written file's data to the disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(folder: Path) -> None:
    """Flush a folder's entries (the rename) to the disk where folders can be opened (POSIX)."""
    flags = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0)
    try:
        fd = os.open(folder, flags)
    except OSError:  # Windows cannot open a folder; its rename is flushed by the file system
        return
    try:
        with contextlib.suppress(OSError):  # some file systems refuse fsync on a folder
            os.fsync(fd)
    finally:
        os.close(fd)


def _check_folder(path: Path, make_parents: bool) -> None:
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    elif not path.parent.is_dir():
        raise ValueError(f"{path}: the folder {path.parent} does not exist")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], *, make_parents: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it onto ``path`` only if the block succeeds.

    For libraries that write to a file name themselves (numpy, PyVista, pydicom, trimesh). The
    temporary name keeps the target's suffix, because several writers (VTK, trimesh) choose the
    format from it. See the module docstring for the mode, ``fsync`` and failure guarantees.

    Parameters
    ----------
    path : path-like
        The target file.
    make_parents : bool
        Create missing parent folders (default: a missing folder raises ``ValueError``).

    Yields
    ------
    Path
        An existing, empty temporary file in the target's folder; the block writes it (or
        replaces it with a file of the same name).
    """
    path = Path(path)
    _check_folder(path, make_parents)
    fd, name = tempfile.mkstemp(
        prefix=f".{path.name}.", suffix=f".part{_temp_suffix(path)}", dir=path.parent
    )
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        _fsync_path(tmp)
        os.chmod(tmp, new_file_mode(path))
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    finally:
        with contextlib.suppress(FileNotFoundError):  # gone after a successful replace
            tmp.unlink()


def atomic_write_bytes(
    path: str | os.PathLike[str], data: bytes, *, make_parents: bool = True
) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`); returns ``path``.

    Missing parent folders are created unless ``make_parents`` is false.
    """
    path = Path(path)
    with atomic_path(path, make_parents=make_parents) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
    return path


def atomic_write_text(
    path: str | os.PathLike[str], text: str, *, make_parents: bool = True
) -> Path:
    """Write ``text`` as UTF-8 with ``\\n`` line ends, atomically; returns ``path``."""
    return atomic_write_bytes(path, text.encode("utf-8"), make_parents=make_parents)


def atomic_write_json(path: str | os.PathLike[str], obj: Any, *, make_parents: bool = True) -> Path:
    """Serialise ``obj`` as indented JSON (NaN and infinities refused) and write it atomically.

    Raises
    ------
    ValueError
        ``obj`` holds NaN or an infinity (strict JSON has neither); nothing is written.
    TypeError
        ``obj`` holds a value JSON cannot represent; nothing is written.
    """
    text = json.dumps(obj, indent=2, allow_nan=False) + "\n"
    return atomic_write_text(path, text, make_parents=make_parents)
