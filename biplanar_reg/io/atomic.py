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
the previous file or the new one, never a half-written one. An ``OSError`` of the write (a full
disk: ``ENOSPC``) names the target when the system did not name a file.

While the block runs, the writer holds an exclusive ``flock`` on its temporary file. A process
killed mid-write (SIGKILL, power cut) leaves the temporary file behind; its lock is gone with the
process, which is how :func:`remove_orphaned_parts` tells such an orphan from a live write.

:func:`exchange_paths` swaps two folders in one step where the system can (Linux
``renameat2(RENAME_EXCHANGE)``), for output folders replaced as a whole.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import json
import os
import re
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from .lock import try_flock

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
    try:
        fd, name = tempfile.mkstemp(
            prefix=f".{path.name}.", suffix=f".part{_temp_suffix(path)}", dir=path.parent
        )
    except OSError as exc:
        raise _naming(exc, path) from None
    if os.name != "nt":  # held until the end: a live write, not an orphan (module docstring)
        try_flock(fd)
    else:  # pragma: no cover - Windows: an open file could not be replaced
        os.close(fd)
        fd = -1
    tmp = Path(name)
    try:
        try:
            yield tmp
            _fsync_path(tmp)
            os.chmod(tmp, new_file_mode(path))
            os.replace(tmp, path)
            _fsync_dir(path.parent)
        except OSError as exc:
            raise _naming(exc, path) from None
    finally:
        with contextlib.suppress(FileNotFoundError):  # gone after a successful replace
            tmp.unlink()
        if fd >= 0:
            os.close(fd)


def _naming(exc: OSError, path: Path) -> OSError:
    """``exc`` with the target ``path`` as its file name when the system named none (a full disk
    reported by ``write`` or ``fsync``); else ``exc`` itself."""
    if exc.filename is not None or exc.errno is None:
        return exc
    return type(exc)(exc.errno, exc.strerror or os.strerror(exc.errno), str(path))


#: The temporary files of :func:`atomic_path`: ``.<name>.<8 random characters>.part<suffix>``.
PART_NAME = re.compile(r"^\..+\.[a-z0-9_]{8}\.part(\.[^./]+){0,2}$")
#: Age (seconds) after which a temporary file counts as orphaned on a file system without
#: ``flock``, where a live write cannot be told from a dead one.
ORPHAN_AGE_WITHOUT_LOCKS = 3600.0


def _orphaned(path: Path) -> bool:
    """True when the temporary file ``path`` belongs to no live writer (see the module doc)."""
    try:
        fd = os.open(path, os.O_RDWR | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return False
    try:
        state = try_flock(fd)  # "held": nobody holds it, its writer is gone (ours ends with fd)
        if state != "unsupported":  # a file system without flock: fall back on the age
            return state == "held"
        return time.time() - os.fstat(fd).st_mtime > ORPHAN_AGE_WITHOUT_LOCKS
    finally:
        os.close(fd)


def remove_orphaned_parts(folder: str | os.PathLike[str]) -> list[Path]:
    """Delete the temporary files that killed writers left in ``folder`` (not its subfolders).

    Only files named as :func:`atomic_path` names them, and only those no live writer holds
    (its ``flock``; on a file system without ``flock``, those older than
    :data:`ORPHAN_AGE_WITHOUT_LOCKS`). Never raises; returns the files deleted.
    """
    removed: list[Path] = []
    try:
        names = [e.name for e in os.scandir(folder) if e.is_file(follow_symlinks=False)]
    except OSError:
        return removed
    for name in names:
        path = Path(folder) / name
        if PART_NAME.match(name) and _orphaned(path):
            with contextlib.suppress(OSError):
                path.unlink()
                removed.append(path)
    return removed


_RENAME_EXCHANGE = 2  # <linux/fs.h>
_AT_FDCWD = -100


def exchange_paths(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """Swap the two existing paths ``a`` and ``b`` in one atomic step; False where the system
    cannot (not Linux, an old C library or kernel, a file system without the operation), and
    nothing changed then.

    Linux ``renameat2(..., RENAME_EXCHANGE)``: at no instant is either name missing.

    Raises
    ------
    OSError
        The exchange is supported but failed (e.g. a missing path, no permission).
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        func = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    func.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    func.restype = ctypes.c_int
    if func(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), os.fsdecode(a), None, os.fsdecode(b))


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
