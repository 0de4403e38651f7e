"""All-or-nothing output folders, one registration per output folder, and the input record.

A case's outputs (mesh, result, report, figures) are written into a hidden temporary folder
beside the target (``.<name>.tmp-<random>``, same file system) and then moved into place:

* where the system can exchange two folders in one step (Linux ``renameat2`` with
  ``RENAME_EXCHANGE``, on the usual local file systems), the temporary folder and the previous
  output are exchanged, and the previous output, now under the hidden name, is deleted: at
  every instant the target is a complete output folder (the previous one or the new one);
* elsewhere, the previous output folder is renamed to ``.<name>.old-<random>``, the temporary
  folder to the target, and the old folder is deleted. A kill between the two renames leaves
  no target but the previous output under its hidden name: the next run (:func:`clean_stale`)
  moves it back before anything else, so a crash never costs the previous output.

Stale hidden folders of killed runs are removed by :func:`clean_stale`. A registration holds
:func:`output_lock` (``.<name>.register.lock`` beside the target) from before it reads the case
until its output is in place: a second registration into the same folder is refused (one line,
exit 2) instead of deleting the first one's temporary folder, and a folder that cannot be
written (read-only, no permission) is reported before any work.

``inputs.json`` in each output folder records the case's input files (:func:`input_fingerprint`)
as they were when the registration started; ``batch`` compares it with the case folder
(:func:`inputs_changed`) to register a case again when its inputs changed.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import glob
import hashlib
import logging
import os
import shutil
import tempfile
import tomllib
from collections.abc import Iterable, Iterator
from contextvars import ContextVar
from pathlib import Path
from typing import Any

import numpy as np

from ..calibration.autoscoper import (
    AutoscoperVolume,
    distortion_warnings,
    write_autoscoper_trial,
)
from ..calibration.views import PerspectiveView
from ..io.atomic import atomic_write_json, current_umask, exchange_paths, remove_orphaned_parts
from ..io.jsonfile import read_json
from ..io.lock import LockFile
from ..io.meshes import write_mesh
from ..io.names import file_name_word
from ..io.transforms import (
    rigid_pose,
    write_itk_tfm,
    write_kinematics_csv,
    write_markups_json,
    write_tra,
)
from ._lock import RegisterLock, permitted

__all__: list[str] = []

log = logging.getLogger(__name__)

#: Files whose presence marks a complete case output folder.
REQUIRED_OUTPUTS = ("registered.ply", "result.json", "report.html")
#: The folder of a multi-bone case's per-bone outputs (``out/bones/<name>/``, docs/bones.md);
#: such an output has no top-level ``registered.ply``.
BONES_DIR = "bones"
#: The input record of an output folder (:func:`input_fingerprint`).
INPUTS_FILE = "inputs.json"
INPUTS_FORMAT = "biplanar-reg/inputs@1"
#: Files up to this size (bytes) are hashed (SHA-256) in the input record ...
HASH_FILE_LIMIT = 64 * 2**20
#: ... until this many bytes have been hashed for one case; larger files and the rest are
#: recorded by size and modification time only.
HASH_CASE_LIMIT = 256 * 2**20
#: ``errno`` values that mean the output cannot be written (reported as one line, exit 2).
UNWRITABLE = frozenset(
    {errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)}
)

#: ``(out, record)``: the input record to write into the output folder ``out`` (run_case_dir).
_INPUTS: ContextVar[tuple[Path, dict[str, Any]] | None] = ContextVar("inputs", default=None)
#: The permit file of the batch running this case (:class:`._lock.RunPermit`), or None.
_PERMIT: ContextVar[str | None] = ContextVar("permit", default=None)


def uncertainty_summary(sd_mm: np.ndarray | None) -> dict[str, float] | None:
    """``result.json["uncertainty"]``: median, 95th percentile and max of the per-vertex
    standard deviation (mm; ``RegistrationResult.vertex_sd_mm``), or None without one."""
    if sd_mm is None or len(sd_mm) == 0:
        return None
    sd = np.asarray(sd_mm, float)
    return {
        "median_mm": float(np.median(sd)),
        "p95_mm": float(np.percentile(sd, 95)),
        "max_mm": float(np.max(sd)),
        "statistic": "per-vertex posterior sd, RMS over the three axes (pose, weights and "
        "model truncation; view poses taken as known)",
    }


def mesh_properties(sd_mm: np.ndarray | None) -> dict[str, np.ndarray]:
    """The vertex properties of ``registered.ply``: ``sd_mm`` when there is one."""
    return {} if sd_mm is None else {"sd_mm": np.asarray(sd_mm, float)}


def is_complete(out: Path, report: bool = True) -> bool:
    """True when ``out`` is a complete case output folder (``report=False``: without
    ``report.html``, as ``--no-report`` writes it)."""
    need = REQUIRED_OUTPUTS if report else tuple(f for f in REQUIRED_OUTPUTS if f != "report.html")
    if (out / BONES_DIR).is_dir():  # a multi-bone case: the meshes are in bones/<name>/
        need = tuple(f for f in need if f != "registered.ply")
    return out.is_dir() and all((out / f).is_file() for f in need)


def _check_output_target(out: Path) -> None:
    """Refuse to replace a folder that is not ours (non-empty and without ``result.json``)."""
    if out.exists():
        if not out.is_dir():
            raise ValueError(f"--out {out}: exists and is not a folder")
        if any(out.iterdir()) and not (out / "result.json").is_file():
            raise ValueError(
                f"--out {out}: exists, is not empty and is not a biplanar-reg output folder "
                "(no result.json); choose a new or empty folder"
            )


def unwritable(exc: OSError, out: Path, what: str, inside: Iterable[Path] = ()) -> OSError:
    """``exc`` as the one-line error of an output folder that cannot be written, or ``exc``
    itself when it is about something else.

    A full disk or a read-only file system (``ENOSPC``, ``EDQUOT``, ``EROFS``) always is;
    a refused permission (``EACCES``, ``EPERM``) when it names no file or a file in ``out`` or
    in one of the folders ``inside`` (not an input file the report could not read). The error
    keeps its ``errno`` and names ``out`` as its file; ``what`` says what became of the output
    (``str``: ``[Errno 28] No space left on device (...): '/data/out'``; the command line
    prints ``error: /data/out: No space left on device (...)``).
    """
    if exc.errno not in UNWRITABLE:
        return exc
    if exc.errno in (errno.EACCES, errno.EPERM) and exc.filename is not None:
        where = Path(os.fsdecode(exc.filename))
        if not any(where == p or where.is_relative_to(p) for p in (out, *inside)):
            return exc
    strerror = exc.strerror or os.strerror(exc.errno)
    return OSError(exc.errno, f"{strerror} ({what})", str(out))


@contextlib.contextmanager
def holding(lock: LockFile, out: Path, folder: Path, what: str) -> Iterator[None]:
    """Hold ``lock`` (on the output folder ``out``) for the block, creating ``folder`` (where
    its lock file goes) first: this is also the check, before any work, that the output can be
    written; an ``OSError`` then is one line naming ``out`` and ``what`` (:func:`unwritable`)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        lock.acquire()
    except OSError as exc:
        raise unwritable(exc, out, what, [out.parent]) from None
    try:
        yield
    finally:
        lock.release()


def output_lock(out: str | os.PathLike) -> contextlib.AbstractContextManager[None]:
    """Hold the registration lock of the output folder ``out`` for the block.

    Creates ``out``'s missing parent folders and the lock file ``.<name>.register.lock`` beside
    ``out`` (:class:`._lock.RegisterLock`; deleted at the end): this is also the check, before
    any work, that the folder can be written.

    Raises
    ------
    LockedError
        Another live registration holds ``out`` (a ``ValueError``: exit 2).
    OSError
        ``out`` cannot be written (read-only file system, no permission, full disk): the error
        names ``out`` (:func:`unwritable`).
    """
    out = Path(out)
    what = "the output folder cannot be written; nothing was done"
    return holding(RegisterLock(out), out, out.parent, what)


def _remove(path: Path) -> None:
    if path.is_symlink() or not path.is_dir():
        with contextlib.suppress(OSError):
            path.unlink()
    else:
        shutil.rmtree(path, ignore_errors=True)


def clean_stale(out: Path) -> list[Path]:
    """Tidy what killed runs left beside ``out``; return the hidden folders removed.

    When ``out`` is missing and a previous output waits under its hidden old name (a run killed
    between the two renames of the swap), it is moved back to ``out`` first (with a warning).
    Then the hidden temporary and old folders are removed. Call it while holding
    :func:`output_lock` (a live run's temporary folder looks the same).
    """
    removed: list[Path] = []
    if not out.parent.is_dir():
        return removed
    name = glob.escape(out.name)
    olds = sorted(out.parent.glob(f".{name}.old-*"))
    if olds and not out.exists() and not out.is_symlink():
        keep = next((p for p in olds if p.is_dir() and any(p.iterdir())), None)
        if keep is not None:
            os.replace(keep, out)
            olds.remove(keep)
            log.warning("%s: restored the previous output (a run was killed replacing it)", out)
    for p in [*sorted(out.parent.glob(f".{name}.tmp-*")), *olds]:
        _remove(p)
        removed.append(p)
    return removed


def tidy_output(out: Path) -> None:
    """:func:`clean_stale` of ``out`` unless a registration holds it (then nothing)."""
    with contextlib.suppress(ValueError, OSError), output_lock(out):
        clean_stale(out)


def _swap(tmp: Path, out: Path) -> None:
    """Put the finished folder ``tmp`` in place of ``out`` (see the module docstring); the
    previous output, if any, is left under ``tmp``'s name or deleted."""
    if not out.exists() and not out.is_symlink():
        os.replace(tmp, out)
    elif not exchange_paths(tmp, out):  # no atomic exchange here: two renames
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
        os.replace(out, old)  # an empty directory target is replaced atomically
        os.replace(tmp, out)
        _remove(old)


@contextlib.contextmanager
def atomic_output_dir(out: str | os.PathLike) -> Iterator[Path]:
    """Yield a fresh temporary folder; on success it replaces ``out`` (see the module doc).

    On an exception the temporary folder is deleted and ``out`` is left as it was. In a batch
    case on a Dask cluster, the folder is moved into place only while the batch's permit exists
    (:class:`._lock.RunPermit`); with an input record pending for ``out`` (:func:`run_case_dir`
    of :mod:`.run`), ``inputs.json`` is written into it.

    Raises
    ------
    OSError
        The folder cannot be written (full disk, read-only): one line naming ``out``
        (:func:`unwritable`); the previous output is kept.
    """
    out = Path(out)
    kept = "the output was not written; the previous output is kept"
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        _check_output_target(out)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    except OSError as exc:
        raise unwritable(exc, out, kept, [out.parent]) from None
    try:
        try:
            yield tmp
            record = _INPUTS.get()
            if record is not None and record[0] == out:
                atomic_write_json(tmp / INPUTS_FILE, record[1])
            os.chmod(tmp, 0o755 & ~current_umask())
            permit = _PERMIT.get()
            with permitted(permit) if _permits(permit, out) else contextlib.nullcontext():
                _swap(tmp, out)
        except OSError as exc:
            raise unwritable(exc, out, kept, [tmp]) from None
    finally:
        if tmp.exists() or tmp.is_symlink():
            _remove(tmp)


def _permits(permit: str | None, out: Path) -> bool:
    """Whether the batch permit ``permit`` governs writing ``out`` (a case folder of its
    output folder; not the per-bone folders inside a case's temporary folder)."""
    return permit is not None and Path(permit).parent == out.parent


@contextlib.contextmanager
def batch_permit(permit: str | None) -> Iterator[None]:
    """Within the block, output folders beside ``permit`` are moved into place only while the
    batch's permit file ``permit`` exists (None: no condition)."""
    token = _PERMIT.set(permit)
    try:
        yield
    finally:
        _PERMIT.reset(token)


@contextlib.contextmanager
def recording_inputs(out: Path, record: dict[str, Any]) -> Iterator[None]:
    """Within the block, the output folder ``out`` gets ``inputs.json`` = ``record``."""
    token = _INPUTS.set((Path(out), record))
    try:
        yield
    finally:
        _INPUTS.reset(token)


# -- the input record (inputs.json) ----------------------------------------------------------
def _looks_like_output(folder: Path) -> bool:
    """A biplanar-reg output folder inside the case folder (``out/`` of ``register``)."""
    return (folder / "result.json").is_file() and (
        (folder / "registered.ply").is_file() or (folder / BONES_DIR).is_dir()
    )


def _toml_strings(node: Any) -> Iterator[str]:
    if isinstance(node, str):
        yield node
    elif isinstance(node, dict):
        for v in node.values():
            yield from _toml_strings(v)
    elif isinstance(node, list):
        for v in node:
            yield from _toml_strings(v)


def _outside_files(case_dir: Path) -> dict[str, Path]:
    """Files outside the case folder that its ``case.toml`` names (``--allow-outside``), by
    absolute path."""
    try:
        doc = tomllib.loads((case_dir / "case.toml").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    found = {}
    for text in _toml_strings(doc):
        if not text or len(text) > 4096 or "\0" in text:
            continue
        try:
            path = (case_dir / text).resolve()
            if path.is_file() and not path.is_relative_to(case_dir):
                found[str(path)] = path
        except (OSError, ValueError, RuntimeError):
            continue
    return found


def input_files(
    case_dir: str | os.PathLike, exclude: Iterable[Path] = (), tidy: bool = False
) -> dict[str, Path]:
    """The files of a case's input record: every file under the case folder (relative POSIX
    path -> path), without hidden files and folders (names starting with ``.``), the folders
    ``exclude`` and output folders of ``register`` (``result.json`` with ``registered.ply``
    or ``bones/``); plus the files outside the folder that ``case.toml`` names (absolute path).

    ``tidy``: also delete the temporary files of killed writers in each folder walked
    (:func:`biplanar_reg.io.atomic.remove_orphaned_parts`).
    """
    root = Path(case_dir).resolve()
    skip = {Path(p).resolve() for p in exclude}
    files: dict[str, Path] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        here = Path(dirpath)
        if tidy:
            remove_orphaned_parts(here)
        dirnames[:] = sorted(
            d
            for d in dirnames
            if not d.startswith(".") and here / d not in skip and not _looks_like_output(here / d)
        )
        for name in sorted(filenames):
            path = here / name
            if not name.startswith(".") and path.is_file():
                files[path.relative_to(root).as_posix()] = path
    files.update(_outside_files(root))
    return files


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def input_fingerprint(
    case_dir: str | os.PathLike, exclude: Iterable[Path] = (), tidy: bool = False
) -> dict[str, Any]:
    """The input record of a case (``inputs.json``): per file of :func:`input_files` its size,
    modification time (ns) and SHA-256 (None beyond :data:`HASH_FILE_LIMIT` or once
    :data:`HASH_CASE_LIMIT` bytes were hashed, or unreadable). A file that vanishes meanwhile
    is left out."""
    files: dict[str, dict[str, Any]] = {}
    budget = HASH_CASE_LIMIT
    for key, path in input_files(case_dir, exclude, tidy).items():
        try:
            st = path.stat()
        except OSError:
            continue
        digest = None
        if st.st_size <= min(HASH_FILE_LIMIT, budget):
            with contextlib.suppress(OSError):  # unreadable: size and time only
                digest = _sha256(path)
                budget -= st.st_size
        files[key] = {"size": st.st_size, "mtime_ns": st.st_mtime_ns, "sha256": digest}
    return {
        "format": INPUTS_FORMAT,
        "case_dir": str(Path(case_dir).resolve()),
        "method": "every file of the case folder except hidden ones and output folders, and "
        "the files outside it that case.toml names: size, modification time and SHA-256 "
        f"(files up to {HASH_FILE_LIMIT >> 20} MB, {HASH_CASE_LIMIT >> 20} MB per case)",
        "files": files,
    }


def _same_file(info: Any, path: Path) -> bool:
    """Whether ``path`` still is the file the record ``info`` describes: same size, and the
    same modification time or (when the record has one) the same SHA-256."""
    if not isinstance(info, dict):
        return False
    try:
        st = path.stat()
        if st.st_size != info.get("size"):
            return False
        if st.st_mtime_ns == info.get("mtime_ns"):
            return True
        digest = info.get("sha256")
        return isinstance(digest, str) and _sha256(path) == digest
    except OSError:
        return False


def inputs_changed(case_dir: str | os.PathLike, out: Path) -> list[str] | None:
    """How the case's inputs differ from the record in its output folder ``out``.

    Returns
    -------
    list of str or None
        None when ``out`` has no readable record (written by an older version); ``[]`` when
        nothing changed; else one entry per difference (``"annotations.json changed"``,
        ``"notes.txt added"``, ``"gt/bone.ply removed"``), sorted.
    """
    try:
        record = read_json(out / INPUTS_FILE)
    except ValueError:
        return None
    if not isinstance(record, dict) or not isinstance(record.get("files"), dict):
        return None
    old = record["files"]
    now = input_files(case_dir, exclude=[out])
    changes = [f"{k} removed" for k in old if k not in now]
    changes += [f"{k} added" for k in now if k not in old]
    changes += [f"{k} changed" for k, p in now.items() if k in old and not _same_file(old[k], p)]
    return sorted(changes)


# -- exports for Autoscoper and 3D Slicer (docs/exports.md) -------------------------------------
def _trial_name(case: Any) -> str:
    """The case id as the Autoscoper trial's file-name word (the id may hold any characters;
    the trial file ``<word>.cfg`` is not hidden)."""
    return file_name_word(case.id.lstrip("."), "case")


def _autoscoper_volume(bone: str) -> AutoscoperVolume:
    return AutoscoperVolume(
        f"volumes/{bone}.tif",
        comment="the bone's density volume (CT partial volume) in the model frame: not made by "
        "biplanar-reg; put it here (see docs/exports.md)",
    )


def write_exports(tmp: Path, out: Path, case: Any, res: Any) -> list[str]:
    """Write the pose, transform, landmark, kinematics, mesh and Autoscoper exports of a result.

    Parameters
    ----------
    tmp : Path
        The temporary output folder being filled (:func:`atomic_output_dir`).
    out : Path
        The final output folder (relative paths of the Autoscoper ``.cfg`` are computed from it).
    case : Case
        The case (its views, landmarks, ``mesh_formats`` and ``bone``).
    res : RegistrationResult
        ``rotation``, ``translation`` (model -> world, mm) and ``vertices`` (world, mm).

    Returns
    -------
    list of str
        The files written, relative to the output folder (``result.json["exports"]``).
    """
    pose = rigid_pose(res.rotation, res.translation)
    return write_pose_exports(tmp, out, case, pose[None], res.vertices)


def write_pose_exports(
    tmp: Path, out: Path, case: Any, poses: np.ndarray, vertices: np.ndarray
) -> list[str]:
    """The exports of :func:`write_exports` from poses per frame (a multi-frame case too).

    Parameters
    ----------
    tmp, out, case
        As for :func:`write_exports`.
    poses : (F, 4, 4) array
        Model -> world rigid transforms per frame, mm (NaN rows: untracked frames).
    vertices : (N, 3) array
        The registered bone in frame 0, world frame, mm (landmark markups and extra mesh
        formats; ``registered.tfm`` holds frame 0's pose too).

    Returns
    -------
    list of str
        The files written, relative to the output folder.
    """
    files = [
        write_tra(tmp / "registered.tra", poses),
        write_itk_tfm(tmp / "registered.tfm", poses[0]),
    ]
    files.append(write_kinematics_csv(tmp / "kinematics.csv", {case.bone: poses}))
    if case.landmarks:
        names = list(case.landmarks)
        idx = [case.landmarks[n] for n in names]
        files.append(write_markups_json(tmp / "landmarks.mrk.json", names, vertices[idx]))
    for fmt in case.mesh_formats:
        path = tmp / f"registered.{fmt}"
        write_mesh(path, vertices, case.model.faces)
        files.append(path)
    files += autoscoper_exports(tmp, out, case, {case.bone: poses})
    return [p.relative_to(tmp).as_posix() for p in files]


def _radiograph_dirs(case: Any) -> list[Path | None]:
    """Each view's radiograph folder for ``CameraRootDir``: the folder of its image when that is
    a TIFF and no other view's image shares the folder (Autoscoper reads every TIFF frame of
    the folder), else None (``radiographs/<view>/``, for the user's TIFF sequence)."""
    parents = [cv.image_path.parent if cv.image_path is not None else None for cv in case.views]
    out = []
    for cv, parent in zip(case.views, parents, strict=True):
        tiff = cv.image_path is not None and cv.image_path.suffix.lower() in (".tif", ".tiff")
        out.append(parent if tiff and parents.count(parent) == 1 else None)
    return out


def export_warnings(case: Any, files: list) -> list[str]:
    """Warnings about the exported ``files`` (paths relative to the output folder): an
    Autoscoper trial leaves out the views' lens distortion
    (:func:`~biplanar_reg.calibration.autoscoper.distortion_warnings`)."""
    if not any(Path(f).parts[:1] == ("autoscoper",) for f in files):
        return []
    return distortion_warnings([cv.view for cv in case.views], _trial_name(case))


def autoscoper_exports(tmp: Path, out: Path, case: Any, poses: dict[str, np.ndarray]) -> list[Path]:
    """``autoscoper/``: the trial ``.cfg`` (one volume per bone), MayaCam 2.0 per view, and
    ``Tracking/<id>_<bone>.tra`` per bone (``poses``: bone name -> (F, 4, 4) model -> world).

    Only for cases whose views are all pinhole cameras with an image size (what Autoscoper and
    MayaCam 2.0 hold); otherwise nothing is written here.
    """
    views = []
    for cv in case.views:
        v = cv.view
        if not isinstance(v, PerspectiveView):
            return []
        if v.image_size is None and cv.image_file_size is not None:
            v = dataclasses.replace(v, image_size=tuple(cv.image_file_size))
        if v.image_size is None:
            return []
        views.append(v)
    folder = tmp / "autoscoper"
    dirs = _radiograph_dirs(case)
    files = write_autoscoper_trial(
        folder,
        _trial_name(case),
        views,
        dirs,
        [_autoscoper_volume(bone) for bone in poses],
        final_folder=out / "autoscoper",
    )
    for bone, P in poses.items():
        files.append(write_tra(folder / "Tracking" / f"{_trial_name(case)}_{bone}.tra", P))
    return files
