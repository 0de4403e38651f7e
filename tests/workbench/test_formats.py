"""The workbench on the image formats of docs/annotation.md: the synthetic case's 8-bit PNG
radiographs rewritten as a 16-bit TIFF and a 12-bit MONOCHROME1 DICOM with a window. The
views' windows, ranges and polarity, the tiles (bone dark on every format), and the livewire
and edge quality (the same trace as on the PNG) through the API."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import tifffile
from _http import page_client
from starlette.testclient import TestClient

from biplanar_reg.workbench import Workbench, create_app
from tests.dicom_files import new_dataset

TOKEN = "test-token-0123456789"


def _dicom(path: Path, pixels: np.ndarray) -> None:
    ds = new_dataset(path)
    ds.Modality = "DX"
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME1"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 12, 11, 0
    ds.Rows, ds.Columns = pixels.shape
    ds.WindowCenter, ds.WindowWidth = 2048, 4096
    ds.PixelData = pixels.astype(np.uint16).tobytes()
    ds.save_as(path, enforce_file_format=True)


def _tile(client: TestClient, view: str) -> np.ndarray:
    r = client.get(f"/api/views/{view}/tiles/0/0/0.png")
    assert r.status_code == 200
    return cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_UNCHANGED)


def test_png_tiff16_and_monochrome1_dicom(synthetic_case):
    case = synthetic_case
    png = {v: cv2.imread(str(case / "xray" / f"{v}.png"), cv2.IMREAD_GRAYSCALE) for v in
           ("cam1", "cam2")}  # fmt: skip
    # reference: the PNG case (tiles and livewire) before the images are replaced
    with Workbench(case) as wb:
        c = page_client(create_app(wb, TOKEN), TOKEN)
        contour = np.asarray(c.get("/api/annotations").json()["views"]["cam1"]["contours"][0]["uv"])
        anchors = contour[np.linspace(0, len(contour) - 1, 5).round().astype(int)].tolist()
        ref_path = {v: np.asarray(c.post(f"/api/views/{v}/livewire", json={"anchors": anchors})
                                  .json()["uv"]) for v in ("cam1", "cam2")}  # fmt: skip
        ref_tile = {v: _tile(c, v) for v in ("cam1", "cam2")}
    tifffile.imwrite(case / "xray" / "cam1.tif", png["cam1"].astype(np.uint16) * 250 + 3)
    _dicom(case / "xray" / "cam2.dcm", 4095 - png["cam2"].astype(np.uint16) * 16)
    toml = (case / "case.toml").read_text()
    toml = re.sub(r"xray/cam1\.png", "xray/cam1.tif", toml)
    (case / "case.toml").write_text(re.sub(r"xray/cam2\.png", "xray/cam2.dcm", toml))

    with Workbench(case) as wb:
        c = page_client(create_app(wb, TOKEN), TOKEN)
        info = {v["name"]: v for v in c.get("/api/case").json()["views"]}
        assert info["cam1"]["file_format"] == "tiff" and not info["cam1"]["inverted"]
        assert info["cam1"]["range"] == [float(png["cam1"].min()) * 250 + 3,
                                         float(png["cam1"].max()) * 250 + 3]  # fmt: skip
        assert info["cam2"]["file_format"] == "dicom" and info["cam2"]["inverted"]
        # the DICOM window, linear rule: c - 0.5 -+ (w - 1) / 2
        assert info["cam2"]["window"] == [0.0, 4095.0]
        for view in ("cam1", "cam2"):
            tile = _tile(c, view).astype(float)
            # the same picture as the PNG's tile, bone dark (up to the window's scaling)
            corr = np.corrcoef(tile.ravel(), ref_tile[view].astype(float).ravel())[0, 1]
            assert corr > 0.99, (view, corr)
            # a narrower window (raw units) brightens/darkens as asked
            lo, hi = info[view]["range"]
            r = c.get(f"/api/views/{view}/tiles/0/0/0.png", params={"lo": lo, "hi": (lo + hi) / 2})
            narrow = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_UNCHANGED)
            assert (narrow.astype(float).mean() > tile.mean()) != info[view]["inverted"]
            # livewire and quality work on the display image: the same trace as on the PNG
            path = np.asarray(
                c.post(f"/api/views/{view}/livewire", json={"anchors": anchors}).json()["uv"]
            )
            d = np.min(np.linalg.norm(path[:, None] - ref_path[view][None], axis=2), axis=1)
            assert np.median(d) < 0.3, (view, np.median(d))
            q = c.get(f"/api/views/{view}/quality").json()["contours"]
            assert q and all(x["verdict"] == "ok" for x in q)
