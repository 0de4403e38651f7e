"""Correspondence for model building: one template's topology fitted to meshes of any topology.

For every subject mesh (any vertex count, pose, frame; left or right):

1. **Pre-alignment** (similarity, then affine). Both surfaces are sampled uniformly by area.
   The template's principal axes are mapped onto the subject's; the axes' sign ambiguity (4
   proper sign patterns) and, for near-cylindrical bones, the roll about the long axis (12
   steps of 30 deg) give 48 candidate starts. Each is refined on a subsample (4 similarity-ICP
   then 8 affine-ICP steps) and scored by the symmetric mean squared surface distance; scoring
   after the affine steps matters: a member stretched or twisted relative to the template can
   make a wrong similarity fit look better than the right one. The 3 best are refined on more
   points and the lowest cost wins.
   With ``auto_mirror`` the mirrored subject is tried as well and the better fit kept (its
   vertices are then returned in the mirrored frame, so all shapes share one handedness).
2. **Non-rigid registration** of the aligned template to the subject's surface samples:
   optimal-step non-rigid ICP (Amberg et al. 2007, ``trimesh.registration.nricp_amberg``) with
   a decreasing stiffness schedule. Coordinates are scaled so that the template's RMS radius is
   :data:`REFERENCE_SIZE` during the fit, which makes the stiffness schedule size-independent.
3. **Residuals**: ``residual_mean`` is the mean distance of the corresponded vertices to the
   subject's surface (exact point-to-triangle distance); ``residual_max`` is the symmetric
   Hausdorff distance between the corresponded mesh and the subject surface (the subject's
   surface samples to the corresponded mesh as well), so an unreached part of the subject
   shows up. A subject is ``converged`` when ``residual_mean <= MEAN_TOLERANCE * d`` and
   ``residual_max <= MAX_TOLERANCE * d``, with ``d`` the diagonal of the subject's bounding box.
4. **Groupwise** (optional): the Procrustes mean of the corresponded shapes, with the template's
   faces, becomes the template and step 1-3 are repeated ``groupwise`` times.

Units: mm throughout (any consistent length unit works; the size checks assume mm).
The corresponded shapes are then modelled by :func:`.build.build_ssm` (GPA + PCA).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .._validate import as_array
from ..io.meshes import check_manifold
from ..pose import Pose
from .build import procrustes_align
from .mirror import mirror_mesh

__all__ = [
    "Correspondence",
    "SubjectFit",
    "check_subjects",
    "correspond_meshes",
    "correspond_subject",
    "prealign",
    "surface_distance",
]

#: Template RMS radius during the non-rigid fit (the stiffness schedule was tuned at this size).
REFERENCE_SIZE = 25.0
#: Non-rigid ICP schedule (stiffness, landmark weight, normal weight, iterations) at that size.
NRICP_STEPS = (
    (0.05, 0.0, 0.0, 10),
    (0.02, 0.0, 0.0, 10),
    (0.007, 0.0, 0.0, 10),
    (0.002, 0.0, 0.0, 10),
)
#: Non-rigid ICP ignores template-vertex matches farther than this fraction of REFERENCE_SIZE.
DISTANCE_THRESHOLD = 0.2
#: Convergence: mean residual and Hausdorff distance as fractions of the bounding-box diagonal.
MEAN_TOLERANCE = 0.005
MAX_TOLERANCE = 0.025
#: Bone-sized: the largest bounding-box side must lie in this range (mm).
EXTENT_RANGE = (5.0, 1000.0)
#: Largest allowed ratio between two subjects' largest bounding-box sides.
MAX_EXTENT_RATIO = 3.0

_ROLLS = np.deg2rad(np.arange(0, 360, 30))
_SIGNS = (
    np.eye(3),
    np.diag([-1.0, -1.0, 1.0]),
    np.diag([-1.0, 1.0, -1.0]),
    np.diag([1.0, -1.0, -1.0]),
)


@dataclass(frozen=True)
class SubjectFit:
    """One subject's correspondence.

    Attributes
    ----------
    vertices : (N, 3) array
        The template's vertices placed on the subject, mm, in the subject's frame (its mirrored
        frame if ``mirrored``).
    residual_mean, residual_max : float
        Mean distance of the vertices to the subject surface, and the symmetric Hausdorff
        distance, mm (see the module docstring).
    converged : bool
        Both residuals within tolerance.
    mirrored : bool
        The subject was mirrored (across x of its frame) to match the template's handedness.
    """

    vertices: np.ndarray
    residual_mean: float
    residual_max: float
    converged: bool
    mirrored: bool


@dataclass(frozen=True)
class Correspondence:
    """A population in the template's topology.

    Attributes
    ----------
    shapes : (S, N, 3) array
        Corresponded vertices of each subject, mm (each in its own, possibly mirrored, frame).
    faces : (F, 3) int array
        The template's faces, shared by every shape.
    template : (N, 3) array
        The last template used (the input template, or the last groupwise mean), mm.
    fits : list of SubjectFit
    """

    shapes: np.ndarray
    faces: np.ndarray
    template: np.ndarray
    fits: list[SubjectFit]

    @property
    def converged(self) -> np.ndarray:
        """(S,) bool."""
        return np.array([f.converged for f in self.fits], dtype=bool)


# -- checks --------------------------------------------------------------------------------------


def extent(vertices: np.ndarray) -> float:
    """Largest side of the axis-aligned bounding box, mm."""
    return float(np.ptp(vertices, axis=0).max())


def check_subjects(
    meshes: Sequence[tuple[np.ndarray, np.ndarray | None]], names: Sequence[str]
) -> list[str]:
    """Check meshes for correspondence; ``ValueError`` naming the file, else warnings.

    Errors: a point set (no faces), a non-manifold or inconsistently oriented mesh, a largest
    bounding-box side outside :data:`EXTENT_RANGE` mm, or two meshes whose extents differ by
    more than :data:`MAX_EXTENT_RATIO` (the one farthest from the median, in log scale, is
    named). Warnings: open meshes (boundary edges), which are fitted but whose holes the
    residual cannot judge.
    """
    warnings: list[str] = []
    extents = []
    for (v, f), name in zip(meshes, names, strict=True):
        if f is None or len(f) == 0:
            raise ValueError(f"{name}: a point set; correspondence needs a triangle mesh")
        check_manifold(f, name=name)
        e = extent(v)
        if not EXTENT_RANGE[0] <= e <= EXTENT_RANGE[1]:
            raise ValueError(
                f"{name}: largest extent {e:.4g} mm is not bone-sized "
                f"({EXTENT_RANGE[0]:g}..{EXTENT_RANGE[1]:g} mm; wrong units?)"
            )
        extents.append(e)
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        if np.any(counts == 1):
            warnings.append(f"{name}: open mesh ({int(np.sum(counts == 1))} boundary edges)")
    ext = np.array(extents)
    if ext.max() > MAX_EXTENT_RATIO * ext.min():
        worst = int(np.argmax(np.abs(np.log(ext / np.median(ext)))))
        raise ValueError(
            f"{names[worst]}: extent {ext[worst]:.4g} mm, but the meshes range "
            f"{ext.min():.4g}..{ext.max():.4g} mm (more than {MAX_EXTENT_RATIO:g}x apart; "
            "mixed units or a different bone?)"
        )
    return warnings


# -- geometry helpers ----------------------------------------------------------------------------


def sample_surface(
    vertices: np.ndarray, faces: np.ndarray, count: int, seed: int = 0
) -> np.ndarray:
    """``count`` points uniformly by area on a triangle mesh (K, 3), deterministic."""
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(faces), size=count, p=area / area.sum())
    u, w = rng.random((2, count))
    flip = u + w > 1
    u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
    t = tri[idx]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + w[:, None] * (t[:, 2] - t[:, 0])


def surface_distance(points: object, vertices: object, faces: object) -> np.ndarray:
    """Exact distance of each point (K, 3) to a triangle mesh's surface (K,), mm."""
    import pyvista as pv

    from ..io.meshes import to_polydata

    pts = as_array("points", points, (None, 3))
    mesh = to_polydata(np.asarray(vertices, float), np.asarray(faces, np.int64))
    assert isinstance(mesh, pv.PolyData)
    _, closest = mesh.find_closest_cell(pts, return_closest_point=True)
    return np.linalg.norm(np.asarray(closest).reshape(-1, 3) - pts, axis=1)


def _principal_axes(points: np.ndarray) -> np.ndarray:
    """Columns: principal axes, largest variance first, right-handed."""
    _, vecs = np.linalg.eigh(np.cov((points - points.mean(0)).T))
    vecs = vecs[:, ::-1].copy()
    if np.linalg.det(vecs) < 0:
        vecs[:, 2] *= -1
    return vecs


@dataclass(frozen=True)
class _Clouds:
    """Surface samples for ICP: a sparse source is moved onto the dense target (``tree``);
    the symmetric cost uses the dense source for the reverse direction, so that neither
    direction is limited by the sparse sampling's spacing."""

    src: np.ndarray  # (k, 3) sparse template samples, moved by ICP
    src_dense: np.ndarray  # (K, 3)
    dst: np.ndarray  # (K', 3) dense target samples
    dst_sparse: np.ndarray  # (k', 3)
    tree: cKDTree  # over dst

    def cost(self, affine: np.ndarray) -> float:
        """Symmetric mean squared surface distance after ``affine`` (4, 3), mm^2."""
        forward = self.tree.query(_apply(self.src, affine))[0]
        reverse = cKDTree(_apply(self.src_dense, affine)).query(self.dst_sparse)[0]
        return float(np.mean(forward**2) + np.mean(reverse**2))


def _apply(points: np.ndarray, affine: np.ndarray) -> np.ndarray:
    return points @ affine[:3] + affine[3]


def _as_affine(s: float, rot: np.ndarray, t: np.ndarray) -> np.ndarray:
    return np.vstack([s * rot.T, t])


def _similarity_icp(c: _Clouds, start: np.ndarray, iters: int) -> np.ndarray:
    """Similarity ICP of the sparse source onto the target from ``start`` (4, 3)."""
    a = start
    for _ in range(iters):
        _, j = c.tree.query(_apply(c.src, a))
        fit = Pose.fit_similarity(c.src, c.dst[j])
        a = _as_affine(fit.scale, fit.pose.R, fit.pose.t)
    return a


def _affine_icp(c: _Clouds, start: np.ndarray, iters: int) -> np.ndarray:
    """Affine ICP of the sparse source onto the target from ``start`` (4, 3)."""
    homog = np.c_[c.src, np.ones(len(c.src))]
    a = start
    for _ in range(iters):
        a = np.linalg.lstsq(homog, c.dst[c.tree.query(homog @ a)[1]], rcond=None)[0]
    return a


def _starts(src: np.ndarray, dst: np.ndarray) -> list[np.ndarray]:
    """The 48 principal-axis starts (4 proper sign patterns x 12 rolls), as (4, 3) maps."""
    u_s, u_t = _principal_axes(src), _principal_axes(dst)
    c_s, c_t = src.mean(0), dst.mean(0)
    scale = np.sqrt(np.sum(np.var(dst, axis=0)) / np.sum(np.var(src, axis=0)))
    out = []
    for sign in _SIGNS:
        for roll in _ROLLS:
            c, s_ = np.cos(roll), np.sin(roll)
            about_long = np.array([[1, 0, 0], [0, c, -s_], [0, s_, c]])
            rot = u_t @ about_long @ sign @ u_s.T
            out.append(_as_affine(scale, rot, c_t - scale * c_s @ rot.T))
    return out


def prealign(
    template_points: object,
    target_points: object,
    subsample: int = 300,
    keep: int = 3,
    seed: int = 0,
) -> tuple[np.ndarray, float]:
    """Affine map taking template surface points onto target surface points.

    Parameters
    ----------
    template_points, target_points : (K, 3) arrays
        Area-uniform surface samples, mm, in their own frames.
    subsample : int
        Template points moved while the 48 candidate starts are scored (each: 4 similarity
        then 8 affine ICP steps, see the module docstring); the ``keep`` best are refined
        on 4x as many points (20 similarity + 20 affine steps) and the lowest cost wins.
    keep : int
        Candidates refined.
    seed : int
        Subsampling seed.

    Returns
    -------
    affine : (4, 3) array
        ``np.c_[x, 1] @ affine`` maps template points (rows) into the target frame.
    cost : float
        Symmetric mean squared surface distance of the result, mm^2.
    """
    src = as_array("template_points", template_points, (None, 3))
    dst = as_array("target_points", target_points, (None, 3))
    rng = np.random.default_rng(seed)

    def pick(x: np.ndarray, n: int) -> np.ndarray:
        return x[rng.choice(len(x), min(n, len(x)), replace=False)]

    tree = cKDTree(dst)
    dense_src = pick(src, 4 * subsample)
    coarse = _Clouds(pick(src, subsample), dense_src, dst, pick(dst, subsample), tree)
    scored = []
    for start in _starts(src, dst):
        a = _affine_icp(coarse, _similarity_icp(coarse, start, 4), 8)
        scored.append((coarse.cost(a), a))
    scored.sort(key=lambda ca: ca[0])
    fine = _Clouds(dense_src, src, dst, pick(dst, 4 * subsample), tree)
    best = None
    for _, a in scored[:keep]:
        a = _affine_icp(fine, a, 20)
        cost = fine.cost(a)
        if best is None or cost < best[1]:
            best = (a, cost)
    assert best is not None
    return best


# -- one subject ---------------------------------------------------------------------------------


def _nonrigid(template: np.ndarray, faces: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Non-rigid ICP of an aligned template (N, 3) onto target points (K, 3), mm."""
    import trimesh

    centre = template.mean(0)
    size = np.sqrt(np.mean(np.sum((template - centre) ** 2, axis=1)))
    k = REFERENCE_SIZE / size
    src = trimesh.Trimesh((template - centre) * k, faces, process=False)
    out = trimesh.registration.nricp_amberg(
        src,
        (target - centre) * k,
        steps=[list(s) for s in NRICP_STEPS],
        distance_threshold=DISTANCE_THRESHOLD * REFERENCE_SIZE,
        use_faces=False,  # the face-based closest point needs rtree; samples are dense enough
    )
    return np.asarray(out) / k + centre


def correspond_subject(
    template: object,
    faces: object,
    subject: object,
    subject_faces: object,
    auto_mirror: bool = False,
    samples: int = 20000,
    seed: int = 0,
) -> SubjectFit:
    """Place the template's vertices on one subject's surface (see the module docstring).

    Parameters
    ----------
    template : (N, 3) array, faces : (F, 3) int array
        Template mesh, mm, any frame.
    subject : (M, 3) array, subject_faces : (G, 3) int array
        Subject mesh, mm, any frame and topology.
    auto_mirror : bool
        Also try the subject mirrored across x and keep the better pre-alignment.
    samples : int
        Surface samples of the subject (and of the template for the pre-alignment).
    seed : int
        Sampling seed.

    Returns
    -------
    SubjectFit
    """
    tv = as_array("template", template, (None, 3))
    tf = as_array("faces", faces, (None, 3), dtype=int)
    sv = as_array("subject", subject, (None, 3))
    sf = as_array("subject_faces", subject_faces, (None, 3), dtype=int)
    n_samples = max(int(samples), 2 * len(tv))
    tmpl_pts = sample_surface(tv, tf, n_samples, seed=seed)
    options = [(False, sv, sf)]
    if auto_mirror:
        mv, mf = mirror_mesh(sv, sf, "x")
        options.append((True, mv, mf))
    best = None
    for mirrored, v, f in options:
        pts = sample_surface(v, f, n_samples, seed=seed + 1)
        fit, cost = prealign(tmpl_pts, pts, seed=seed)
        if best is None or cost < best[0]:
            best = (cost, fit, mirrored, v, f, pts)
    _, affine, mirrored, v, f, pts = best
    aligned = np.c_[tv, np.ones(len(tv))] @ affine
    placed = _nonrigid(aligned, tf, pts)
    to_subject = surface_distance(placed, v, f)
    to_template = surface_distance(pts[:: max(1, len(pts) // 5000)], placed, tf)
    diag = float(np.linalg.norm(np.ptp(v, axis=0)))
    r_mean = float(to_subject.mean())
    r_max = float(max(to_subject.max(), to_template.max()))
    return SubjectFit(
        vertices=placed,
        residual_mean=r_mean,
        residual_max=r_max,
        converged=bool(r_mean <= MEAN_TOLERANCE * diag and r_max <= MAX_TOLERANCE * diag),
        mirrored=bool(mirrored),
    )


# -- a population --------------------------------------------------------------------------------


def correspond_meshes(
    template: object,
    faces: object,
    subjects: Sequence[tuple[np.ndarray, np.ndarray]],
    groupwise: int = 0,
    auto_mirror: bool = False,
    samples: int = 20000,
    progress: Callable[[int, int, SubjectFit], None] | None = None,
) -> Correspondence:
    """Correspondence of a population of meshes in the template's topology.

    Parameters
    ----------
    template : (N, 3) array, faces : (F, 3) int array
        Template mesh (typically one of the subjects), mm.
    subjects : sequence of (vertices, faces)
        Subject meshes, mm, any topology and frame.
    groupwise : int
        Extra passes with the Procrustes mean of the previous pass as template (0: none).
    auto_mirror : bool
        Per subject, also try its mirror image (see :func:`correspond_subject`).
    samples : int
        Surface samples per subject.
    progress : callable, optional
        Called as ``progress(pass_index, subject_index, fit)`` after each subject.

    Returns
    -------
    Correspondence
    """
    tv = as_array("template", template, (None, 3))
    tf = as_array("faces", faces, (None, 3), dtype=int)
    if len(subjects) < 1:
        raise ValueError("subjects: need at least one subject mesh")
    fits: list[SubjectFit] = []
    for pass_index in range(int(groupwise) + 1):
        if pass_index:
            tv = procrustes_align(np.stack([f.vertices for f in fits]), scaling=True).mean(0)
        fits = []
        for i, (v, f) in enumerate(subjects):
            fit = correspond_subject(tv, tf, v, f, auto_mirror=auto_mirror, samples=samples)
            fits.append(fit)
            if progress is not None:
                progress(pass_index, i, fit)
    return Correspondence(
        shapes=np.stack([f.vertices for f in fits]), faces=tf, template=tv, fits=fits
    )
