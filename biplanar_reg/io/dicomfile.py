"""Reading DICOM files with pydicom: every parser failure as one ``ValueError``, and quiet.

pydicom parses element values lazily and raises whatever its value converters raise on
damaged bytes (``NotImplementedError`` for an unknown VR, ``BytesLengthException``,
``struct.error``, ``OSError`` from a seek to a negative offset, ...). :func:`read_dicom` reads
every element at once, so that these surface here and become a ``ValueError`` naming the file
and the tag. Its messages and the warnings pydicom emits on damaged files may quote raw element
bytes (a patient's name among them): :func:`quiet_pydicom` keeps pydicom's warnings and log
records away from the application's log, and :func:`dicom_problem` describes an exception by
its type and tag only.

A file pydicom reads but whose pixels it cannot decode says what is missing:
:func:`decoder_problem` names the transfer syntax and the packages that decode it (pydicom's
own list of its decoder plugins' requirements), :func:`pixel_data_problem` checks a file
before anything is decoded (the decoder, and that there is pixel data at all).
"""

from __future__ import annotations

import logging
import os
import re
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__: list[str] = []

_TAG = re.compile(r"\(([0-9A-Fa-f]{4}),\s*([0-9A-Fa-f]{4})\)")
#: pydicom's message when no installed plugin can decode a transfer syntax (pydicom 3).
_NO_DECODER = re.compile(r"Unable to decompress '([^']+)' pixel data because all plugins")
#: pydicom's message when every installed plugin failed on the pixel data (pydicom 3).
_ALL_FAILED = re.compile(r"Unable to decode as exceptions were raised by all available plugins")
#: pydicom's message for a dataset without pixel data, and for a missing element.
_NO_PIXELS = re.compile(r"has no 'Pixel Data'")
_NO_ATTRIBUTE = re.compile(r"object has no attribute '([A-Za-z][A-Za-z0-9]*)'")
#: The one-line description of a file without pixel data.
NO_PIXEL_DATA = "no pixel data (no PixelData element: the file holds no image)"
#: The pixel data elements of a DICOM image.
_PIXEL_TAGS = ("PixelData", "FloatPixelData", "DoubleFloatPixelData")
#: Exception types whose message is about structure only (never element values).
_SAFE_MESSAGES = (NotImplementedError,)


class DicomReadError(ValueError):
    """A DICOM file pydicom cannot read; ``reason`` is the message without the file name."""

    def __init__(self, path: Path, reason: str):
        self.path, self.reason = path, reason
        super().__init__(f"{path}: {reason}")


def dicom_problem(exc: BaseException) -> str:
    """A one-line description of a pydicom failure that never quotes an element's value.

    The type of the exception, the tag it names (pydicom adds "in tag (gggg,eeee)") and, for
    the types whose messages hold no values (an unknown VR), the message itself. Pixel data
    that no installed decoder reads says which decoder is needed and how to install it
    (``"needs a JPEG-LS Lossless Image Compression decoder: pip install pylibjpeg
    pylibjpeg-libjpeg"``), a missing element names it (``"no Rows element"``,
    :data:`NO_PIXEL_DATA`): names from pydicom's dictionaries, never element values.
    """
    raw = str(exc)
    text = " ".join(raw.split())
    name = type(exc).__name__
    missing = _NO_DECODER.search(text)
    if isinstance(exc, RuntimeError) and missing:
        return _install_hint(missing.group(1), raw.splitlines()[1:])
    if isinstance(exc, RuntimeError) and _ALL_FAILED.search(text):
        tried = [ln.split(":", 1)[0].strip() for ln in raw.splitlines()[1:] if ":" in ln]
        return (
            f"pixel data that the installed decoders ({', '.join(tried) or 'none'}) could not "
            "read: damaged, or a variant they do not support"
        )
    if isinstance(exc, AttributeError):
        if _NO_PIXELS.search(text):
            return NO_PIXEL_DATA
        element = _NO_ATTRIBUTE.search(text)
        if element:
            return f"no {element.group(1)} element"
    if isinstance(exc, _SAFE_MESSAGES) and len(text) <= 200:
        return f"{name}: {text}"
    tags = _TAG.findall(text)
    return f"{name}, tag ({tags[-1][0]},{tags[-1][1]})" if tags else name


def _install_hint(syntax: str, requirements: list[str]) -> str:
    """``needs a <syntax> decoder: pip install <packages>`` from pydicom's lines
    ``"<plugin> - requires <pkg>>=<v> and <pkg>>=<v>"`` (the pylibjpeg plugin preferred: pure
    pip wheels; numpy is always there)."""
    plugins = {}
    for line in requirements:
        plugin, _, needs = line.strip().partition(" - requires ")
        if needs:
            names = [re.split(r"[<>=!~ ]", p.strip(), maxsplit=1)[0] for p in needs.split(" and ")]
            plugins[plugin.strip()] = [n for n in names if n and n != "numpy"]
    chosen = plugins.get("pylibjpeg") or next(iter(plugins.values()), None)
    hint = f": pip install {' '.join(chosen)}" if chosen else ""
    return f"needs a {syntax} decoder{hint}"


def decoder_problem(syntax: object) -> str | None:
    """What decoding pixel data of transfer syntax ``syntax`` (a UID) needs, or None when an
    installed decoder handles it.

    E.g. ``"needs a JPEG-LS Lossless Image Compression decoder: pip install pylibjpeg
    pylibjpeg-libjpeg"`` (the packages are those pydicom's plugins list as missing).
    """
    from pydicom.pixels import get_decoder
    from pydicom.uid import UID

    uid = UID(str(syntax))
    try:
        decoder = get_decoder(uid)
    except (NotImplementedError, ValueError):
        return f"no decoder for the pixel data's transfer syntax {uid} ({uid.name})"
    if decoder.is_available:
        return None
    return _install_hint(uid.name, list(decoder.missing_dependencies))


def looks_like_dicom(path: str | os.PathLike) -> bool:
    """A ``.dcm``/``.dicom`` file, or one with the ``DICM`` preamble."""
    path = Path(path)
    if path.suffix.lower() in (".dcm", ".dicom"):
        return True
    try:
        with path.open("rb") as fh:
            return fh.read(132)[128:132] == b"DICM"
    except OSError:
        return False


def pixel_data_problem(path: str | os.PathLike) -> str | None:
    """Whether a DICOM image's pixels can be decoded here, without decoding them.

    Returns None for a file whose pixel data an installed decoder reads (and for a file that
    is not DICOM or that pydicom cannot parse: the readers report those); otherwise one line:
    :data:`NO_PIXEL_DATA`, or what :func:`decoder_problem` says is needed. Large element values
    are skipped, not read, so this costs about one pass over the file's element headers.
    """
    path = Path(path)
    if not looks_like_dicom(path):
        return None  # before importing pydicom (0.2 CPU s): most images are not DICOM
    import pydicom

    with quiet_pydicom():
        try:
            ds = pydicom.dcmread(path, defer_size=4096)
        except Exception:  # noqa: BLE001 - damaged files are the readers' to describe
            return None
    if not any(tag in ds for tag in _PIXEL_TAGS):
        return NO_PIXEL_DATA
    meta = getattr(ds, "file_meta", None)
    syntax = None if meta is None else meta.get("TransferSyntaxUID")
    return None if syntax is None else decoder_problem(syntax)


@contextmanager
def quiet_pydicom() -> Iterator[None]:
    """Silence pydicom's warnings and its logger (they may quote raw element bytes)."""
    logger = logging.getLogger("pydicom")
    disabled = logger.disabled
    logger.disabled = True
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        logger.disabled = disabled


def _convert_all(ds: Any) -> None:
    """Convert every element of ``ds`` (and of its sequences' items) from its raw bytes."""
    for tag in list(ds.keys()):
        element = ds[tag]  # the conversion of a raw element happens on access
        if element.VR == "SQ":
            for item in element.value:
                _convert_all(item)


def read_dicom(
    path: str | os.PathLike, *, stop_before_pixels: bool = False, force: bool = False
) -> Any:
    """Read a DICOM file with every element parsed; any failure is a ``ValueError``.

    Parameters
    ----------
    path : path-like
        The file.
    stop_before_pixels : bool
        Do not read the pixel data (geometry readers).
    force : bool
        Read a file without the ``DICM`` preamble (pydicom's ``force``).

    Returns
    -------
    pydicom.Dataset
        Every element already converted (a damaged one has failed here, not later).

    Raises
    ------
    DicomReadError
        (a ``ValueError``) ``<path>: not a DICOM file (...)`` or
        ``<path>: malformed DICOM (<type>, tag (g,e))``.
    """
    import pydicom
    from pydicom.errors import InvalidDicomError

    path = Path(path)
    with quiet_pydicom():
        try:
            ds = pydicom.dcmread(path, stop_before_pixels=stop_before_pixels, force=force)
            _convert_all(ds)
            if getattr(ds, "file_meta", None) is not None:
                _convert_all(ds.file_meta)
        except InvalidDicomError:
            reason = "not a DICOM file (no 'DICM' preamble and no file meta header)"
            raise DicomReadError(path, reason) from None
        except Exception as exc:  # noqa: BLE001 - pydicom raises anything on damaged bytes
            raise DicomReadError(path, f"malformed DICOM ({dicom_problem(exc)})") from None
    return ds
