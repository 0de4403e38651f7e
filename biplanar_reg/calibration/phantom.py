"""Calibration of one X-ray view from an image of a bead phantom.

Pipeline (:func:`calibrate_phantom`):

1. :func:`detect_beads`: beads are small dark (or bright) blobs; a morphological top-hat
   removes the background, an Otsu threshold finds the blobs, and each centre is the
   intensity-weighted centroid of its top-hat signal (sub-pixel; unbiased for symmetric
   blobs, anti-aliased edges included).
2. Matching: the user gives >= 4 seed correspondences (bead label -> approximate pixel); each
   seed snaps to the nearest detected blob. An initial camera comes from the DLT (>= 6 seeds)
   or, with 4-5 seeds, from PnP with a focal-length sweep (principal point at the image
   centre). Every bead is then projected and matched to its mutual-nearest blob within a gate;
   the camera is re-estimated with all matches until the matching stops changing.
3. :func:`calibrate_from_beads`: DLT, RQ decomposition, then Levenberg-Marquardt refinement of
   ``fx, fy, cx, cy`` (skew fixed at 0 unless asked), the pose and, optionally, 2/4/5/8 OpenCV
   distortion coefficients, minimising pixel reprojection error.

Units: bead coordinates in mm in the phantom's (= world) frame; pixels 0-based, origin at the
centre of the top-left pixel. Note that a sphere's X-ray shadow is centred slightly off the
projection of its centre under strong obliquity (second order in bead radius over distance);
this is not corrected.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage
from scipy.optimize import least_squares
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from .._validate import as_array
from ..errors import CalibrationFormatError
from ._textio import is_numeric_line, parse_numbers, read_lines
from .native_json import read_json
from .pinhole import project_camera_points
from .projection_matrix import decompose_projection, dlt_projection
from .views import PerspectiveView

__all__ = ["PhantomCalibration", "calibrate_phantom"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PhantomCalibration:
    """Result of a phantom calibration.

    Attributes
    ----------
    view : PerspectiveView
        The calibrated view.
    bead_index : (M,) int array
        Indices (into the bead table) of the beads used.
    labels : list of str
        Their labels.
    detected_uv : (M, 2) array
        Their detected centres, pixels.
    residuals_px : (M,) array
        Per-bead reprojection error (distance between detected and projected centre), pixels.
    rms_px : float
        Root-mean-square of ``residuals_px``.
    n_detected : int
        Number of blobs detected in the image.
    """

    view: PerspectiveView
    bead_index: np.ndarray
    labels: list[str]
    detected_uv: np.ndarray
    residuals_px: np.ndarray
    rms_px: float
    n_detected: int

    def report(self) -> dict[str, object]:
        """A JSON-ready per-bead report (pixels)."""
        return {
            "rms_px": self.rms_px,
            "n_detected": self.n_detected,
            "n_used": len(self.bead_index),
            "beads": [
                {"label": lab, "uv": uv.tolist(), "residual_px": float(r)}
                for lab, uv, r in zip(self.labels, self.detected_uv, self.residuals_px, strict=True)
            ],
        }


# -- input files --------------------------------------------------------------------------------
def read_beads_csv(path: Path | str) -> tuple[list[str], np.ndarray]:
    """Read bead coordinates: rows ``x,y,z`` or ``label,x,y,z`` (mm), optional header line.

    Labels default to the 1-based row number among the data rows (``"1"``, ``"2"``, ...).
    """
    path = Path(path)
    lines = read_lines(path)
    if lines and not is_numeric_line(lines[0][1].split(",", 1)[-1]):
        lines = lines[1:]  # header
    if len(lines) < 4:
        raise CalibrationFormatError(f"{path}: need at least 4 beads, found {len(lines)} row(s)")
    labels, xyz = [], []
    for i, (ln, text) in enumerate(lines):
        fields = [f.strip() for f in text.split(",")]
        if len(fields) == 4:
            label, coords = fields[0], ",".join(fields[1:])
        elif len(fields) == 3:
            label, coords = str(i + 1), text
        else:
            raise CalibrationFormatError(
                f"{path}: line {ln}: expected 'x,y,z' or 'label,x,y,z', got {text!r}"
            )
        labels.append(label)
        xyz.append(parse_numbers(path, ln, coords, 3, "bead x,y,z"))
    dup = {lab for lab in labels if labels.count(lab) > 1}
    if dup:
        raise CalibrationFormatError(f"{path}: duplicate bead label(s) {sorted(dup)[:5]}")
    return labels, np.array(xyz)


def read_seeds_json(path: Path | str, labels: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Read seed correspondences ``{"<bead label>": [u, v], ...}`` (optionally under "seeds").

    Returns the bead indices (K,) and their approximate pixels (K, 2).
    """
    path = Path(path)
    data = read_json(path)
    if isinstance(data, dict) and isinstance(data.get("seeds"), dict):
        data = data["seeds"]
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected an object {{bead label: [u, v]}}")
    index = {lab: i for i, lab in enumerate(labels)}
    idx, uv = [], []
    for key, val in data.items():
        if str(key) not in index:
            raise ValueError(f"{path}: key {key!r}: no bead with this label in the bead file")
        try:
            uv.append(as_array(f"{path}: key {key!r}", val, (2,)))
        except ValueError as exc:
            raise ValueError(str(exc)) from None
        idx.append(index[str(key)])
    if len(idx) < 4:
        raise ValueError(f"{path}: need at least 4 seed correspondences, got {len(idx)}")
    return np.array(idx), np.array(uv)


# -- detection ----------------------------------------------------------------------------------
def detect_beads(
    image: np.ndarray,
    *,
    dark: bool = True,
    max_radius_px: float = 15.0,
    min_area_px: int = 4,
) -> np.ndarray:
    """Detect bead centres with sub-pixel accuracy.

    Parameters
    ----------
    image : (H, W) array
        Grey-level image (any numeric type; colour images are averaged).
    dark : bool
        Beads darker than the background (the usual radiograph polarity).
    max_radius_px : float
        Largest bead radius in pixels; sets the top-hat size. Bigger blobs are dropped.
    min_area_px : int
        Smallest blob area kept, pixels.

    Returns
    -------
    (N, 2) array
        Bead centres ``(u, v)``, pixels, sorted by row then column.
    """
    img = np.asarray(image, dtype=float)
    if img.ndim == 3:
        img = img.mean(axis=2)
    if img.ndim != 2 or min(img.shape) < 8:
        raise ValueError(f"image: expected a 2D grey image, got shape {np.shape(image)}")
    if not np.all(np.isfinite(img)):
        raise ValueError("image: contains NaN or infinite values")
    if dark:
        img = -img
    size = int(2 * np.ceil(max_radius_px) + 3)
    signal = img - ndimage.grey_opening(img, size=(size, size))  # white top-hat: blobs only
    if signal.max() <= 0:
        return np.zeros((0, 2))
    from skimage.filters import threshold_otsu

    thr = max(threshold_otsu(signal), 0.05 * signal.max())
    lab, n = ndimage.label(signal > thr)
    if n == 0:
        return np.zeros((0, 2))
    areas = ndimage.sum_labels(np.ones_like(signal), lab, index=np.arange(1, n + 1))
    max_area = np.pi * (max_radius_px + 1) ** 2
    ok = (areas >= min_area_px) & (areas <= max_area)
    if np.any(ok):  # overlapping beads merge into one bigger blob with a biased centre: drop
        ok &= areas <= 1.6 * np.median(areas[ok])
    keep = np.flatnonzero(ok) + 1
    # weight = top-hat signal on each blob grown by 2 px (to include anti-aliased rims)
    grown = ndimage.grey_dilation(lab, size=(5, 5))
    grown[lab > 0] = lab[lab > 0]
    rows, cols = np.indices(signal.shape, dtype=float)
    w = ndimage.sum_labels(signal, grown, index=keep)
    cu = ndimage.sum_labels(signal * cols, grown, index=keep) / w
    cv = ndimage.sum_labels(signal * rows, grown, index=keep) / w
    out = np.column_stack([cu, cv])
    return out[np.lexsort((out[:, 0], out[:, 1]))]


def render_bead_image(
    uv: np.ndarray,
    radius_px: float,
    image_size: tuple[int, int],
    *,
    supersample: int = 8,
    background: float = 1.0,
    contrast: float = 0.6,
) -> np.ndarray:
    """Render dark anti-aliased discs on a bright background (a synthetic phantom image).

    Parameters
    ----------
    uv : (N, 2) array
        Disc centres, pixels.
    radius_px : float
        Disc radius, pixels.
    image_size : (W, H)
        Image size, pixels.
    supersample : int
        Sub-samples per pixel side for the coverage (anti-aliasing).
    background, contrast : float
        Background level, and how much a fully covered pixel is darkened.

    Returns
    -------
    (H, W) float array
    """
    uv = as_array("uv", uv, (None, 2))
    W, H = image_size
    cover = np.zeros((H, W))
    offs = (np.arange(supersample) + 0.5) / supersample - 0.5
    for u, v in uv:
        c0, c1 = max(int(np.floor(u - radius_px)) - 1, 0), min(int(np.ceil(u + radius_px)) + 2, W)
        r0, r1 = max(int(np.floor(v - radius_px)) - 1, 0), min(int(np.ceil(v + radius_px)) + 2, H)
        if c0 >= c1 or r0 >= r1:
            continue
        sx = (np.arange(c0, c1)[:, None] + offs[None, :]).ravel()
        sy = (np.arange(r0, r1)[:, None] + offs[None, :]).ravel()
        inside = (sx[None, :] - u) ** 2 + (sy[:, None] - v) ** 2 <= radius_px**2
        frac = inside.reshape(r1 - r0, supersample, c1 - c0, supersample).mean(axis=(1, 3))
        cover[r0:r1, c0:c1] += frac
    return background - contrast * np.minimum(cover, 1.0)


# -- estimation ---------------------------------------------------------------------------------
_N_DIST = (0, 2, 4, 5, 8)


def calibrate_from_beads(
    xyz: np.ndarray,
    uv: np.ndarray,
    *,
    image_size: tuple[int, int] | None = None,
    n_distortion: int = 0,
    fix_skew: bool = True,
    initial: PerspectiveView | None = None,
    name: str = "",
) -> tuple[PerspectiveView, np.ndarray]:
    """Calibrate a pinhole view from matched beads: DLT, then Levenberg-Marquardt.

    Parameters
    ----------
    xyz : (N, 3) array
        Bead centres, mm, world frame (N >= 6 and not coplanar, unless ``initial`` is given).
    uv : (N, 2) array
        Their detected pixels.
    image_size : (W, H), optional
        Stored on the view.
    n_distortion : int
        Number of OpenCV distortion coefficients to estimate: 0, 2 (k1, k2), 4 (+ p1, p2),
        5 (+ k3) or 8 (+ k4, k5, k6).
    fix_skew : bool
        Keep ``K[0, 1] = 0`` (square pixel grid axes; true of X-ray detectors).
    initial : PerspectiveView, optional
        Starting camera instead of the DLT.

    Returns
    -------
    view : PerspectiveView
    residuals : (N,) array
        Per-bead reprojection error, pixels.
    """
    xyz = as_array("xyz", xyz, (None, 3))
    uv = as_array("uv", uv, (len(xyz), 2))
    if n_distortion not in _N_DIST:
        raise ValueError(f"n_distortion: expected one of {_N_DIST}, got {n_distortion}")
    if initial is None:
        K, R, t = decompose_projection(dlt_projection(xyz, uv))
    else:
        K, R, t = initial.K, initial.R, initial.t
    n_par = 6 + 4 + (0 if fix_skew else 1) + n_distortion
    if 2 * len(xyz) < n_par:
        raise ValueError(f"xyz: {len(xyz)} beads cannot determine {n_par} parameters")

    def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        Rm = Rotation.from_rotvec(p[0:3]).as_matrix()
        fx, fy, cx, cy = p[6:10]
        skew = 0.0 if fix_skew else p[10]
        Km = np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        d = None
        if n_distortion:
            d = np.zeros(8)
            d[:n_distortion] = p[n_par - n_distortion :]
        return Km, Rm, p[3:6], d

    def residual(p: np.ndarray) -> np.ndarray:
        Km, Rm, tm, d = unpack(p)
        Xc = xyz @ Rm.T + tm
        if np.any(Xc[:, 2] <= 0):
            return np.full(2 * len(xyz), 1e6)
        return (project_camera_points(Xc, Km, d) - uv).ravel()

    p0 = np.concatenate(
        [
            Rotation.from_matrix(R).as_rotvec(),
            t,
            [K[0, 0], K[1, 1], K[0, 2], K[1, 2]],
            [] if fix_skew else [K[0, 1]],
            np.zeros(n_distortion),
        ]
    )
    sol = least_squares(
        residual,
        p0,
        method="lm",
        x_scale="jac",
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
        max_nfev=200 * n_par,
    )
    Km, Rm, tm, d = unpack(sol.x)
    view = PerspectiveView(K=Km, R=Rm, t=tm, distortion=d, image_size=image_size, name=name)
    res = np.linalg.norm(view.project(xyz) - uv, axis=1)
    return view, res


def _pnp_sweep(xyz: np.ndarray, uv: np.ndarray, image_size: tuple[int, int]) -> PerspectiveView:
    """A camera from 4-5 correspondences: PnP over a sweep of focal lengths, then LM.

    The principal point is fixed at the image centre and pixels are square; the focal length
    with the smallest reprojection error seeds a 7-parameter refinement (f, pose).
    """
    W, H = image_size
    c = np.array([(W - 1) / 2, (H - 1) / 2])
    best = None
    for f in np.geomspace(0.3, 30.0, 60) * max(W, H):
        K = np.array([[f, 0, c[0]], [0, f, c[1]], [0, 0, 1.0]])
        ok, rvec, tvec = cv2.solvePnP(xyz, uv, K, None, flags=cv2.SOLVEPNP_SQPNP)
        if not ok:
            continue
        proj, _ = cv2.projectPoints(xyz, rvec, tvec, K, None)
        err = float(np.sum((proj.reshape(-1, 2) - uv) ** 2))
        if best is None or err < best[0]:
            best = (err, f, rvec.ravel(), tvec.ravel())
    if best is None:
        raise ValueError("seeds: could not find an initial camera from the seed correspondences")
    _, f0, r0, t0 = best

    def residual(p: np.ndarray) -> np.ndarray:
        K = np.array([[p[0], 0, c[0]], [0, p[0], c[1]], [0, 0, 1.0]])
        Xc = xyz @ Rotation.from_rotvec(p[1:4]).as_matrix().T + p[4:7]
        if np.any(Xc[:, 2] <= 0):
            return np.full(2 * len(xyz), 1e6)
        return (project_camera_points(Xc, K, None) - uv).ravel()

    sol = least_squares(residual, np.concatenate([[f0], r0, t0]), x_scale="jac")
    p = sol.x
    K = np.array([[p[0], 0, c[0]], [0, p[0], c[1]], [0, 0, 1.0]])
    return PerspectiveView(
        K=K, R=Rotation.from_rotvec(p[1:4]).as_matrix(), t=p[4:7], image_size=image_size
    )


def _match(
    view: PerspectiveView, xyz: np.ndarray, detections: np.ndarray, gate_px: float
) -> tuple[np.ndarray, np.ndarray]:
    """Mutual-nearest matches of projected beads to detections within a gate.

    Returns bead indices (M,) and detection indices (M,).
    """
    Xc = view.to_camera(xyz)
    front = np.flatnonzero(Xc[:, 2] > 0)
    proj = view.project(xyz[front])
    tree_d, tree_p = cKDTree(detections), cKDTree(proj)
    dist, j = tree_d.query(proj)
    # the gate also shrinks to half the spacing of the projected beads (ambiguity guard)
    if len(proj) > 1:
        nn, _ = tree_p.query(proj, k=2)
        gate = np.minimum(gate_px, 0.5 * nn[:, 1])
    else:
        gate = np.full(len(proj), gate_px)
    _, back = tree_p.query(detections[j])
    ok = (dist <= gate) & (back == np.arange(len(proj)))
    return front[ok], j[ok]


def _snap_seeds(
    det: np.ndarray,
    seed_index: np.ndarray,
    seed_uv: np.ndarray,
    labels: list[str],
    snap_px: float,
) -> np.ndarray:
    """Snap each seed (K, 2) pixels to its nearest detected bead (N, 2) pixels.

    Returns the detection index (K,) of each seed. Raises ``ValueError`` naming the beads
    (up to 5 labels) whose seed has no detection within ``snap_px`` pixels, or when two seeds
    snap to the same detection.
    """
    dist, j = cKDTree(det).query(seed_uv)
    far = np.flatnonzero(dist > snap_px)
    if far.size:
        bad = [labels[seed_index[k]] for k in far[:5]]
        raise ValueError(f"seeds: no detected bead within {snap_px} px of seed(s) {bad}")
    if len(set(j.tolist())) < len(j):
        raise ValueError("seeds: two seeds snap to the same detected bead")
    return j


@dataclass(frozen=True, eq=False)
class _BeadMatch:
    """A camera and the beads matched under it.

    ``bead_idx`` (M,) indexes the bead table, ``det_idx`` (M,) the detections, pairwise;
    ``residuals_px`` (M,) are the reprojection errors of the final fit, pixels (None before).
    """

    view: PerspectiveView
    bead_idx: np.ndarray
    det_idx: np.ndarray
    residuals_px: np.ndarray | None = None


def _rematch_until_stable(
    start: _BeadMatch,
    xyz: np.ndarray,
    det: np.ndarray,
    gate_px: float,
    image_size: tuple[int, int],
) -> _BeadMatch:
    """Match every bead under the current camera and refit, until the matching stops changing.

    At most 20 rounds; each round matches with :func:`_match` (gate ``gate_px`` pixels) and
    refits the camera (no distortion) from its previous estimate. Raises ``ValueError`` when
    fewer than 6 beads match.
    """
    view, bead_idx, det_idx = start.view, start.bead_idx, start.det_idx
    for _ in range(20):
        new_b, new_d = _match(view, xyz, det, gate_px)
        if len(new_b) < 6:
            raise ValueError(f"matching: only {len(new_b)} beads matched; check the seeds")
        same = len(new_b) == len(bead_idx) and np.array_equal(np.sort(new_b), np.sort(bead_idx))
        bead_idx, det_idx = new_b, new_d
        view, _ = calibrate_from_beads(
            xyz[bead_idx], det[det_idx], image_size=image_size, initial=view
        )
        if same:
            break
    return _BeadMatch(view, bead_idx, det_idx)


def _final_fit(
    match: _BeadMatch,
    xyz: np.ndarray,
    det: np.ndarray,
    image_size: tuple[int, int],
    *,
    n_distortion: int,
    fix_skew: bool,
    outlier_factor: float,
    name: str,
) -> _BeadMatch:
    """Fit the full camera model to the matched beads, drop outliers once and refit.

    Beads whose residual exceeds ``outlier_factor`` times the median residual are dropped
    unless fewer than 6 would remain. Returns the final match with its residuals, sorted by
    bead index.
    """
    view, bead_idx, det_idx = match.view, match.bead_idx, match.det_idx
    for _ in range(2):  # final fit; then drop outliers (> ~3 sigma, sigma from the median)
        view, res = calibrate_from_beads(
            xyz[bead_idx],
            det[det_idx],
            image_size=image_size,
            n_distortion=n_distortion,
            fix_skew=fix_skew,
            initial=view,
            name=name,
        )
        inl = res <= outlier_factor * np.median(res)
        if np.all(inl) or inl.sum() < 6:
            break
        log.info("dropping %d outlier bead(s)", int((~inl).sum()))
        bead_idx, det_idx = bead_idx[inl], det_idx[inl]
    order = np.argsort(bead_idx)
    return _BeadMatch(view, bead_idx[order], det_idx[order], res[order])


def calibrate_phantom(
    image: np.ndarray,
    xyz: np.ndarray,
    seed_index: np.ndarray,
    seed_uv: np.ndarray,
    *,
    labels: list[str] | None = None,
    dark: bool = True,
    max_radius_px: float = 15.0,
    snap_px: float = 15.0,
    gate_px: float = 10.0,
    n_distortion: int = 0,
    fix_skew: bool = True,
    outlier_factor: float = 4.5,
    name: str = "",
) -> PhantomCalibration:
    """Detect, match and calibrate (see the module docstring).

    Parameters
    ----------
    image : (H, W) array
        The phantom radiograph.
    xyz : (N, 3) array
        Bead centres, mm.
    seed_index, seed_uv : (K,) int array, (K, 2) array
        K >= 4 seed correspondences: bead indices and approximate pixels.
    labels : list of str, optional
        Bead labels for the report (default: 1-based numbers).
    dark, max_radius_px : bool, float
        Passed to :func:`detect_beads`.
    snap_px : float
        A seed snaps to the nearest detected bead within this distance, pixels.
    gate_px : float
        Largest distance between a projected bead and its matched detection, pixels.
    n_distortion, fix_skew : int, bool
        Passed to :func:`calibrate_from_beads`.
    outlier_factor : float
        After the fit, beads whose residual exceeds this multiple of the median residual
        (4.5 is about 3 sigma) are dropped and the view is refitted once.
    name : str
        The view's name.
    """
    xyz = as_array("xyz", xyz, (None, 3))
    seed_index = np.asarray(seed_index, dtype=int)
    seed_uv = as_array("seed_uv", seed_uv, (len(seed_index), 2))
    if len(seed_index) < 4:
        raise ValueError(f"seed_index: need at least 4 seeds, got {len(seed_index)}")
    if np.any((seed_index < 0) | (seed_index >= len(xyz))):
        raise ValueError("seed_index: index out of range of the bead table")
    labels = labels or [str(i + 1) for i in range(len(xyz))]
    H, W = np.shape(image)[:2]
    det = detect_beads(image, dark=dark, max_radius_px=max_radius_px)
    log.info("detected %d blobs", len(det))
    if len(det) < 4:
        raise ValueError(f"image: only {len(det)} bead(s) detected; need at least 4")
    j = _snap_seeds(det, seed_index, seed_uv, labels, snap_px)
    # the DLT needs 6 correspondences; with 4-5 seeds, PnP with a focal-length sweep
    if len(seed_index) >= 6:
        view, _ = calibrate_from_beads(xyz[seed_index], det[j], image_size=(W, H))
    else:
        view = _pnp_sweep(xyz[seed_index], det[j], (W, H))
    match = _rematch_until_stable(_BeadMatch(view, seed_index, j), xyz, det, gate_px, (W, H))
    match = _final_fit(
        match,
        xyz,
        det,
        (W, H),
        n_distortion=n_distortion,
        fix_skew=fix_skew,
        outlier_factor=outlier_factor,
        name=name,
    )
    return PhantomCalibration(
        view=match.view,
        bead_index=match.bead_idx,
        labels=[labels[i] for i in match.bead_idx],
        detected_uv=det[match.det_idx],
        residuals_px=match.residuals_px,
        rms_px=float(np.sqrt(np.mean(match.residuals_px**2))),
        n_detected=len(det),
    )
