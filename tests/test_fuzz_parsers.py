"""Property-based fuzzing of every input parser (issue 18): only documented exceptions escape.

Each parser gets inputs derived from a valid file (edited bytes, tokens, lines, keys and values)
or built from scratch, and must either accept them or raise a ``ValueError`` (the documented
bad-input type, exit 2 at the command line; :mod:`biplanar_reg.errors`) whose message names the
file; any other exception fails the test. The parsers: the calibration formats (MayaCam 2.0,
MayaCam 1.0, DLT, native JSON, DICOM from pydicom-built datasets), the annotation file,
``case.toml`` (through :func:`load_case` on a case folder), the mesh readers (PLY, STL, OBJ),
SSM ``.npz`` files and the X-ray image loaders.

Seeded (``derandomize=True``, no example database), about 4,000 examples in all (~15 s).
Every crash the fuzzer found is fixed and kept as an explicit ``@example``: a JSON calibration
``"projection": [0, 0]`` (``TypeError``), a MayaCam 1.0 width of 1e40 (``TypeError``), a DLT
coefficient of 1e308 (``OverflowError``), a DICOM ``ImagerPixelSpacing`` of one value
(``TypeError``), an empty TIFF page (a message without the file), a TIFF header that kept
tifffile's series analysis busy for minutes, ``units = []`` in ``case.toml`` (``TypeError``);
plus the issue's own defects (corrupt ``.npz``, unknown DICOM VR, symlink loop, deep JSON, ...).
"""

from __future__ import annotations

import io
import json
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import tifffile
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from pydicom.dataset import FileDataset, FileMetaDataset
from pydicom.uid import ExplicitVRLittleEndian

from biplanar_reg.annotation import AnnotationError, load_annotations, load_image
from biplanar_reg.calibration import (
    OrthographicView,
    PerspectiveView,
    SlotScanningView,
    load_calibration,
    save_calibration,
)
from biplanar_reg.cases import load_case
from biplanar_reg.io import read_mesh, write_mesh
from biplanar_reg.simulate import write_synthetic_case
from biplanar_reg.ssm import ShapeModel

#: Fuzzed numbers overflow in the parsers' casts: those warnings are the inputs', not news.
pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")

W, H = 64, 48
#: What a fuzzed DICOM file holds about its patient: must never reach a message.
SECRETS = ("Secret^Patient", "Secret", "ID-12345")


#: ``BIPLANAR_FUZZ_SCALE=20 pytest tests/test_fuzz_parsers.py``: 20 times the examples, with a
#: random seed (a longer search for new crashes; the suite runs the seeded default, 1).
SCALE = int(os.environ.get("BIPLANAR_FUZZ_SCALE", "1"))


def fuzz(n: int) -> settings:
    """Seeded settings: ``n`` examples, no deadline (the machine is shared), no database."""
    return settings(
        max_examples=n * SCALE,
        derandomize=SCALE == 1,
        deadline=None,
        database=None,
        suppress_health_check=[
            HealthCheck.too_slow,
            HealthCheck.data_too_large,
            HealthCheck.function_scoped_fixture,  # caplog: it only collects, never resets
        ],
    )


def refused(call: Callable[..., Any], *args: Any, names: str, **kwargs: Any) -> None:
    """Run a parser on fuzzed input: it may return or raise a ``ValueError`` naming ``names``
    (a file), on one line unless it is an ``AnnotationError`` (which lists every problem);
    no patient data in it. Anything else escapes and fails the test."""
    try:
        call(*args, **kwargs)
    except ValueError as exc:
        text = str(exc)
        assert names in text, text
        assert isinstance(exc, AnnotationError) or "\n" not in text, text
        assert not any(s in text for s in SECRETS), text


# -- edits of bytes, lines and tokens --------------------------------------------------------

#: ``(kind, position, payload)``; positions are taken modulo the input's length.
byte_edits = st.lists(
    st.one_of(
        st.tuples(st.just("set"), st.integers(0, 2**20), st.binary(min_size=1, max_size=4)),
        st.tuples(st.just("insert"), st.integers(0, 2**20), st.binary(min_size=1, max_size=8)),
        st.tuples(st.just("delete"), st.integers(0, 2**20), st.integers(1, 64)),
        st.tuples(st.just("cut"), st.integers(0, 2**20), st.just(0)),
    ),
    min_size=1,
    max_size=4,
)


def apply_bytes(data: bytes, edits: list[tuple[str, int, Any]], keep: int = 0) -> bytes:
    """``data`` with ``edits`` applied after its first ``keep`` bytes."""
    out = bytearray(data)
    for kind, pos, payload in edits:
        span = max(len(out) - keep, 1)
        i = keep + pos % span
        if kind == "set":
            out[i : i + len(payload)] = payload
        elif kind == "insert":
            out[i:i] = payload
        elif kind == "delete":
            del out[i : i + payload]
        else:
            del out[i:]
    return bytes(out)


#: Tokens that have broken number and key parsers somewhere.
TOKENS = [
    "nan", "inf", "-inf", "Infinity", "1e400", "-1e400", "1e-400", "-0", "0", "-1", "1.5",
    "abc", "", ",", ";", "1,2", "1 2 3", "9" * 40, "0x10", "1_000", "+5", "\uff11", "\u0661",
    "\x00", "image size", "camera matrix", "rotation", "translation", "undistortion", "{", "[",
    "]", '"', "true", "null", "1e308", "4294967296", "-2147483649", "65536", "\ufeff",
]  # fmt: skip
token_edits = st.lists(
    st.one_of(
        st.tuples(
            st.just("token"), st.integers(0, 999), st.integers(0, 9), st.sampled_from(TOKENS)
        ),
        st.tuples(st.just("text"), st.integers(0, 999), st.integers(0, 9), st.text(max_size=12)),
        st.tuples(st.just("drop"), st.integers(0, 999), st.just(0), st.just("")),
        st.tuples(st.just("dup"), st.integers(0, 999), st.just(0), st.just("")),
        st.tuples(st.just("line"), st.integers(0, 999), st.just(0), st.sampled_from(TOKENS)),
    ),
    min_size=1,
    max_size=5,
)


def apply_tokens(text: str, edits: list[tuple[str, int, int, str]], sep: str = ",") -> str:
    """``text`` with line and token ``edits`` (tokens split on ``sep``)."""
    lines = text.splitlines()
    for kind, i, j, value in edits:
        if not lines:
            lines = [value]
            continue
        i %= len(lines)
        if kind in ("token", "text"):
            parts = lines[i].split(sep)
            parts[j % len(parts)] = value
            lines[i] = sep.join(parts)
        elif kind == "drop":
            del lines[i]
        elif kind == "dup":
            lines.insert(i, lines[i])
        else:
            lines.insert(i, value)
    return "\n".join(lines) + "\n"


#: Any JSON value, small (NaN and infinities included).
json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.floats()
    | st.integers()
    | st.integers(-(2**70), 2**70)
    | st.text(max_size=6),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=4), inner, max_size=4)
    ),
    max_leaves=8,
)


# -- reference inputs ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


def _view() -> PerspectiveView:
    c, s = np.cos(0.3), np.sin(0.3)
    R = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
    K = np.array([[900.0, 0.0, 31.5], [0.0, 900.0, 23.5], [0.0, 0.0, 1.0]])
    return PerspectiveView(K=K, R=R, t=np.array([1.0, -2.0, 900.0]), image_size=(W, H), name="c")


def _reference_text(work: Path, fmt: str, view=None) -> str:
    path = work / f"ref_{fmt}.txt"
    save_calibration(view or _view(), path, fmt)
    return path.read_text()


# -- calibration text formats ----------------------------------------------------------------


def _load_both_ways(path: Path, fmt: str) -> None:
    size = (W, H) if fmt == "dlt" else None
    refused(load_calibration, path, fmt, image_size=size, names=str(path))
    refused(load_calibration, path, image_size=size, names=str(path))


@pytest.mark.parametrize(("fmt", "n"), [("mayacam2", 300), ("mayacam1", 200), ("dlt", 200)])
def test_calibration_text_formats(work, fmt, n):
    ref = _reference_text(work, fmt)
    path = work / f"calib_{fmt}.txt"

    @fuzz(n)
    @given(edits=token_edits)
    @example(edits=[("dup", 0, 0, ""), ("token", 161, 1, "9" * 40), ("drop", 0, 0, "")])
    # found (MayaCam 1.0): a width of 1e40 pixels, TypeError in the image size check
    @example(edits=[("drop", 1, 0, ""), ("line", 1, 0, "1e308")])
    # found (DLT): a coefficient of 1e308, OverflowError (scale**3) in decompose_projection
    def run(edits):
        path.write_text(apply_tokens(ref, edits), encoding="utf-8")
        _load_both_ways(path, fmt)

    run()


@fuzz(300)
@given(
    base=st.sampled_from(["perspective", "orthographic", "slot_scanning"]),
    changes=st.dictionaries(
        st.sampled_from(
            [
                "image_size",
                "K",
                "R",
                "t",
                "distortion",
                "projection",
                "name",
                "fu",
                "cu",
                "cv",
                "row_pitch",
                "format",
                "colour",
            ]
        ),  # fmt: skip
        json_values | st.lists(st.floats() | st.integers(), min_size=2, max_size=3),
        max_size=3,
    ),
    drop=st.lists(st.sampled_from(["K", "R", "t", "image_size", "fu"]), max_size=2),
)
@example(base="perspective", changes={"image_size": [float("inf"), 512]}, drop=[])
@example(base="perspective", changes={"projection": [0.0, 0.0]}, drop=[])  # found: TypeError
def test_calibration_json(work, base, changes, drop):
    views = {
        "perspective": _view(),
        "orthographic": OrthographicView(
            K=np.array([[3.0, 0.0, 31.5], [0.0, 3.0, 23.5], [0.0, 0.0, 1.0]]),
            R=np.eye(3),
            t=np.zeros(3),
            image_size=(W, H),
        ),
        "slot_scanning": SlotScanningView(
            fu=900.0,
            cu=31.5,
            cv=23.5,
            row_pitch=0.5,
            R=np.eye(3),
            t=[0, 0, 900.0],
            image_size=(W, H),
        ),
    }
    doc = json.loads(_reference_text(work, "json", views[base]))
    doc.update(changes)
    for key in drop:
        doc.pop(key, None)
    path = work / "calib.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    _load_both_ways(path, "json")


# -- DICOM -----------------------------------------------------------------------------------


def _dicom_bytes(image: bool, **values: Any) -> bytes:
    """A DICOM file built with pydicom: X-ray geometry tags, or a small MONOCHROME2 image."""
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.12.1"
    meta.MediaStorageSOPInstanceUID = "1.2.3.4"
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = FileDataset("x.dcm", {}, file_meta=meta, preamble=b"\0" * 128)
    ds.PatientName = "Secret^Patient"
    ds.PatientID = "ID-12345"
    ds.Modality = "XA"
    tags: dict[str, Any] = {
        "Rows": H,
        "Columns": W,
        "DistanceSourceToDetector": 1200.0,
        "DistanceSourceToPatient": 800.0,
        "ImagerPixelSpacing": [0.2, 0.2],
        "PositionerPrimaryAngle": 10.0,
        "PositionerSecondaryAngle": -5.0,
        "PatientOrientation": ["L", "F"],
    }
    if image:
        pixels = (np.arange(W * H, dtype=np.uint16) % 4096).reshape(H, W)
        tags.update(
            SamplesPerPixel=1,
            PhotometricInterpretation="MONOCHROME2",
            BitsAllocated=16,
            BitsStored=12,
            HighBit=11,
            PixelRepresentation=0,
            WindowCenter=2048,
            WindowWidth=4096,
            PixelData=pixels.tobytes(),
        )
    tags.update(values)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for key, value in tags.items():
            if value is not None:
                setattr(ds, key, value)
        buf = io.BytesIO()
        ds.save_as(buf, enforce_file_format=True)
    return buf.getvalue()


#: Values for the geometry and image tags of a pydicom-built dataset (strings go in as such).
dicom_values = st.dictionaries(
    st.sampled_from(
        [
            "Rows",
            "Columns",
            "DistanceSourceToDetector",
            "DistanceSourceToPatient",
            "ImagerPixelSpacing",
            "PositionerPrimaryAngle",
            "PatientOrientation",
            "NumberOfFrames",
            "BitsAllocated",
            "PhotometricInterpretation",
            "WindowWidth",
            "PixelSpacing",
        ]
    ),  # fmt: skip
    st.one_of(
        st.integers(0, 65535),
        st.sampled_from(["nan", "inf", "-1e400", "abc", "", "1\\2", "0", "-5", "1e9", "RF"]),
        st.lists(st.sampled_from(["0.2", "0", "-1", "nan", "L", "HF"]), min_size=1, max_size=3),
    ),
    max_size=3,
)


def without_patient_data(caplog, call: Callable[..., Any], *args: Any, names: str) -> None:
    """:func:`refused`, and no patient data in a warning or a log record either (pydicom's
    warnings about damaged elements quote their raw bytes)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with caplog.at_level("DEBUG"):
            refused(call, *args, names=names)
    shown = caplog.text + " ".join(str(w.message) for w in caught)
    assert not any(s in shown for s in SECRETS), shown
    caplog.clear()


def _dicom_case(image: bool, values: dict, edits: list) -> bytes:
    try:
        data = _dicom_bytes(image, **values)
    except Exception:  # pydicom will not write these values: fuzz the valid file instead
        data = _dicom_bytes(image)
    return apply_bytes(data, edits, keep=132) if edits else data


#: Where the VR of ``Rows`` is in the built geometry file, after the 132-byte preamble.
ROWS_VR = _dicom_bytes(False).index(b"\x28\x00\x10\x00US") + 4 - 132


@fuzz(300)
@given(values=dicom_values, edits=st.one_of(st.just([]), byte_edits))
@example(values={}, edits=[("set", ROWS_VR, b"ZZ")])  # unknown VR: NotImplementedError
def test_calibration_dicom(work, caplog, values, edits):
    path = work / "xa.dcm"
    path.write_bytes(_dicom_case(False, values, edits))
    without_patient_data(caplog, load_calibration, path, "dicom", names=str(path))


@fuzz(200)
@given(values=dicom_values, edits=st.one_of(st.just([]), byte_edits))
@example(values={"ImagerPixelSpacing": 1}, edits=[])  # found: TypeError (len of a DSfloat)
def test_image_dicom(work, caplog, values, edits):
    path = work / "image.dcm"
    path.write_bytes(_dicom_case(True, values, edits))
    without_patient_data(caplog, load_image, path, names=str(path))


@pytest.mark.parametrize(("suffix", "n"), [(".png", 150), (".tif", 150)])
def test_image_raster_and_tiff(work, suffix, n):
    ref = work / f"ref{suffix}"
    img = (np.arange(W * H) % 251).astype(np.uint8).reshape(H, W)
    if suffix == ".tif":
        tifffile.imwrite(ref, img.astype(np.uint16), compression="zlib")
    else:
        cv2.imwrite(str(ref), img)
    data = ref.read_bytes()
    path = work / f"image{suffix}"

    @fuzz(n)
    @given(edits=byte_edits)
    @example(edits=[("insert", 15, b"\x00")])  # found (TIFF): an empty page, a message without
    # the file name ("zero-size array to reduction operation minimum")
    @example(edits=[("insert", 1968, b"v\x82_Gs\xf2\xd8@"), ("insert", 1968, b"\x00")])
    # found (TIFF): a page 1979711552 pixels wide and 0 high; tifffile's series analysis ran
    # for minutes (the loader now reads pages, not series)
    def run(edits):
        path.write_bytes(apply_bytes(data, edits))
        refused(load_image, path, names=str(path))

    run()


# -- annotation file -------------------------------------------------------------------------

LANDMARKS = ["a", "b", "c", "d"]
coordinate = st.one_of(st.floats(-10, 80), st.floats(), st.integers(-(2**64), 2**64), json_values)
uv = st.one_of(
    st.lists(coordinate, min_size=2, max_size=2), st.lists(coordinate, max_size=3), json_values
)
landmark = st.one_of(
    st.fixed_dictionaries({"uv": uv}, optional={"sigma_px": coordinate, "sigma": coordinate}),
    json_values,
)
contour = st.one_of(
    st.fixed_dictionaries(
        {"uv": st.lists(uv, max_size=6)},
        optional={"closed": st.one_of(st.booleans(), json_values), "colour": json_values},
    ),
    json_values,
)
view = st.one_of(
    st.fixed_dictionaries(
        {},
        optional={
            "landmarks": st.dictionaries(
                st.sampled_from(LANDMARKS) | st.text(max_size=3), landmark, max_size=4
            )
            | json_values,
            "contours": st.lists(contour, max_size=3) | json_values,
        },
    ),
    json_values,
)
annotation_docs = st.one_of(
    st.fixed_dictionaries(
        {
            "format": st.just("biplanar-reg/annotations@1") | json_values,
            "views": st.dictionaries(st.sampled_from(["cam1", "cam2", "x"]), view, max_size=3)
            | json_values,
        }
    ),
    json_values,
)


def _load_annotation_file(path: Path) -> None:
    refused(
        load_annotations,
        path,
        known_views=["cam1", "cam2"],
        known_landmarks=LANDMARKS,
        image_sizes={"cam1": (W, H)},
        names=str(path),
    )


@fuzz(400)
@given(doc=annotation_docs)
@example(doc={"format": "biplanar-reg/annotations@1", "views": {"cam1": {"contours": [
    {"uv": [[10.0, 10.0]] * 4}]}}})  # fmt: skip
@example(doc={"views": {"cam1": {"landmarks": {"a": {"uv": [float("nan"), 1.0]}}}}})
def test_annotation_documents(work, doc):
    path = work / "annotations.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    _load_annotation_file(path)


@fuzz(200)
@given(edits=token_edits, depth=st.sampled_from([0, 0, 0, 50, 5000, 100_000]))
@example(edits=[("line", 0, 0, "")], depth=100_000)  # RecursionError in the JSON parser
def test_annotation_text(work, edits, depth):
    doc = {
        "format": "biplanar-reg/annotations@1",
        "views": {
            "cam1": {
                "landmarks": {"a": {"uv": [10.5, 20.0], "sigma_px": 1.0}},
                "contours": [{"uv": [[1, 2], [3, 4], [5, 7]], "closed": False}],
            }
        },
    }
    text = apply_tokens(json.dumps(doc, indent=1), edits)
    if depth:
        text = text.replace("[10.5", "[" * depth + "10.5" + "]" * (depth - 1), 1)
    path = work / "annotations_text.json"
    path.write_text(text, encoding="utf-8")
    _load_annotation_file(path)


# -- case.toml -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def case_dir(work) -> Path:
    case = write_synthetic_case(work / "case", 0, image_size=(64, 64), silhouettes=False)
    (case / "calib" / "loop.txt").symlink_to("loop.txt")
    return case


#: Values a ``case.toml`` key may be given: other files of the case, paths that leave it or
#: loop, numbers at and beyond every bound, wrong types. (No template mesh: building a model
#: from it takes a second.)
TOML_VALUES = [
    '"model/bone_ssm.npz"', '"model/landmarks.json"', '"calib/cam1.txt"', '"calib/cam2.json"',
    '"xray/cam1.png"', '"annotations.json"', '"gt/truth.json"', '"calib/loop.txt"',
    '"../../etc/passwd"', '"/dev/null"', '"missing.txt"', '""', '"calib"', '"a\\u0000b"',
    '"mayacam1"', '"dlt"', '"dicom"', '"json"', '"known"', '"unknown"', '"m"', '"cm"',
    "9223372036854775807", "-9223372036854775808", "0", "-1", "1", "2", "3", "1001", "100001",
    "1.5", "0.0", "1e308", "inf", "-inf", "nan", "true", "false", "[]", "[1, 2]", "{}",
    '{a = 1}', '"x"', '"biplanar-reg/case@1"', '"biplanar-reg/case@2"', "1979-05-27",
]  # fmt: skip
TOML_KEYS = [
    "format", "id", "units", "ssm", "landmarks", "name", "calibration", "calibration_format",
    "dlt_column", "image", "image_frame", "file", "poses", "silhouettes", "mesh", "up_to_pose",
    "silhouette_points", "max_iterations", "gate_px", "landmark_weight", "population_size",
    "silhouete_points", "calibraton", "colour",
]  # fmt: skip
toml_edits = st.lists(
    st.one_of(
        st.tuples(st.just("value"), st.integers(0, 99), st.sampled_from(TOML_VALUES)),
        st.tuples(
            st.just("add"),
            st.integers(0, 99),
            st.tuples(st.sampled_from(TOML_KEYS), st.sampled_from(TOML_VALUES)).map(
                lambda kv: f"{kv[0]} = {kv[1]}"
            ),
        ),
        st.tuples(st.just("drop"), st.integers(0, 99), st.just("")),
        st.tuples(st.just("dup"), st.integers(0, 99), st.just("")),
        st.tuples(
            st.just("line"),
            st.integers(0, 99),
            st.sampled_from(
                [
                    "[model]",
                    "[[views]]",
                    "[registration]",
                    "[registration.expert]",
                    "[x]",
                    "[[model]]",
                    "=",
                ]
            ),
        ),
    ),
    min_size=1,
    max_size=5,
)


def apply_toml(text: str, edits: list[tuple[str, int, str]]) -> str:
    lines = text.splitlines()
    for kind, i, value in edits:
        i %= max(len(lines), 1)
        if kind == "value" and lines and " = " in lines[i]:
            lines[i] = lines[i].split(" = ")[0] + " = " + value
        elif kind in ("add", "line"):
            lines.insert(i, value)
        elif kind == "drop" and lines:
            del lines[i]
        elif kind == "dup" and lines:
            lines.insert(i, lines[i])
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def case_toml(case_dir) -> str:
    return (case_dir / "case.toml").read_text()


@fuzz(250)
@given(edits=toml_edits)
@example(edits=[("value", 10, '"calib/loop.txt"')])  # a symlink loop (RuntimeError)
@example(edits=[("add", 24, "[registration.expert]\nsilhouette_points = 9223372036854775807")])
@example(edits=[("value", 30, "[]")])  # found: units = [] (TypeError: unhashable type)
def test_case_toml(case_dir, case_toml, edits):
    (case_dir / "case.toml").write_text(apply_toml(case_toml, edits), encoding="utf-8")
    refused(load_case, case_dir, names="case.toml")


# -- meshes ----------------------------------------------------------------------------------


def _octahedron() -> tuple[np.ndarray, np.ndarray]:
    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    F = np.array(
        [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    )
    return V * 10.0, F


ASCII_PLY = (
    "ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\n"
    "property float z\nelement face 8\nproperty list uchar int vertex_indices\nend_header\n"
    + "".join(" ".join(f"{x:g}" for x in v) + "\n" for v in _octahedron()[0])
    + "".join("3 " + " ".join(str(i) for i in f) + "\n" for f in _octahedron()[1])
)


@pytest.mark.parametrize(("suffix", "n"), [(".ply", 200), (".stl", 150), (".obj", 150)])
def test_mesh_bytes(work, suffix, n):
    ref = work / f"ref{suffix}"
    write_mesh(ref, *_octahedron())
    data = ref.read_bytes()
    path = work / f"mesh{suffix}"

    @fuzz(n)
    @given(edits=byte_edits)
    def run(edits):
        path.write_bytes(apply_bytes(data, edits))
        refused(read_mesh, path, names=str(path))

    run()


@pytest.mark.parametrize(
    ("suffix", "text"), [(".ply", ASCII_PLY), (".obj", None)], ids=["ply", "obj"]
)
def test_mesh_text(work, suffix, text):
    if text is None:
        write_mesh(work / f"ref_text{suffix}", *_octahedron())
        text = (work / f"ref_text{suffix}").read_text()
    path = work / f"mesh_text{suffix}"

    @fuzz(150)
    @given(edits=token_edits)
    def run(edits):
        path.write_text(apply_tokens(text, edits, sep=" "), encoding="utf-8")
        refused(read_mesh, path, names=str(path))

    run()


# -- SSM .npz --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def model_npz(work) -> bytes:
    V, F = _octahedron()
    modes = np.stack([np.roll(V, 1, axis=1), V * 0.1])
    model = ShapeModel(V, modes, faces=F, variances=[2.0, 1.0], landmarks={"tip": 4})
    model.save(work / "ref.npz")
    return (work / "ref.npz").read_bytes()


@fuzz(400)
@given(edits=byte_edits)
@example(edits=[("cut", 400, 0)])  # truncated: zipfile.BadZipFile
@example(edits=[("set", 120, b"\xff\xff\xff\xff")])  # damaged deflate stream: zlib.error
def test_ssm_npz_bytes(work, model_npz, edits):
    path = work / "model.npz"
    path.write_bytes(apply_bytes(model_npz, edits))
    refused(ShapeModel.load, path, names=str(path))


arrays = st.one_of(
    st.builds(np.zeros, st.lists(st.integers(0, 4), max_size=4).map(tuple)),
    st.builds(np.array, st.lists(st.floats(), max_size=6)),
    st.builds(np.array, st.lists(st.integers(-(2**63), 2**63 - 1), max_size=6)),
    st.builds(np.array, st.text(max_size=20)),
    st.builds(np.array, json_values.map(json.dumps)),
)


@fuzz(200)
@given(
    members=st.dictionaries(
        st.sampled_from(["mean", "modes", "faces", "variances", "landmarks_json", "format", "x"]),
        arrays,
        max_size=4,
    ),
    keep=st.booleans(),
)
def test_ssm_npz_members(work, members, keep):
    V, F = _octahedron()
    base = {"mean": V, "modes": np.zeros((1, 6, 3)), "faces": F} if keep else {}
    path = work / "members.npz"
    with open(path, "wb") as fh:
        np.savez(fh, **{**base, **members})
    refused(ShapeModel.load, path, names=str(path))
