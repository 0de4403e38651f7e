"""Reading DICOM files with pydicom: every parser failure as one ``ValueError``, and quiet.

pydicom parses element values lazily and raises whatever its value converters raise on
damaged bytes (``NotImplementedError`` for an unknown VR, ``BytesLengthException``,
``struct.error``, ``OSError`` from a seek to a negative offset, ...). :func:`read_dicom` reads
every element at once, so that these surface here and become a ``ValueError`` naming the file
and the tag. Its messages and the warnings pydicom emits on damaged files may quote raw element
bytes (a patient's name among them): :func:`quiet_pydicom` keeps pydicom's warnings and log
records away from the application's log, and :func:`dicom_problem` describes an exception by
its type and tag only.
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
    the types whose messages hold no values (an unknown VR), the message itself.
    """
    text = " ".join(str(exc).split())
    name = type(exc).__name__
    if isinstance(exc, _SAFE_MESSAGES) and len(text) <= 200:
        return f"{name}: {text}"
    tags = _TAG.findall(text)
    return f"{name}, tag ({tags[-1][0]},{tags[-1][1]})" if tags else name


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
