"""Rigid alignment of a ground-truth surface onto a registered one ("ground truth up to pose").

When a case's ground truth is known only up to pose (``[ground_truth] up_to_pose = true``, e.g.
a CT of the same subject in the CT's own frame), the error metrics are computed after the
ground truth is moved rigidly onto the registered surface. The alignment is deterministic:

1. initial pose: Kabsch fit of corresponding vertices when both meshes have the same vertex
   count and order (a template and its registration), else the centroid and principal axes
   (the sign ambiguity of the axes resolved by the lowest mean distance of the 4 proper
   rotations);
2. point-to-point ICP (Kabsch per iteration, no scaling, no reflection) of seeded area-uniform
   samples of the ground truth to the nearest of dense seeded samples of the registered
   surface (scipy k-d tree; 20,000 samples, i.e. well under 0.5 mm apart on a bone).

Lengths are mm, the frame is the registered surface's (world frame of the calibrations).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..pose import Pose

__all__ = ["RigidAlignment", "align_rigid"]

#: Ground-truth points moved by the ICP, and target points they are matched to.
ICP_SAMPLES = 5000
ICP_TARGET_SAMPLES = 20000
#: At most this many ICP iterations; stop earlier when the cost changes by less than 1e-8 mm^2.
ICP_ITERATIONS = 60


@dataclass(frozen=True)
class RigidAlignment:
    """``aligned = pose.apply(vertices)`` (ground truth -> registered surface, mm) and how it
    was obtained."""

    pose: Pose
    init: str  # "vertex correspondence" or "principal axes"
    icp_cost_mm2: float  # final ICP cost: mean squared closest-point distance of the samples

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Move points (K, 3) of the ground truth onto the registered surface."""
        return self.pose.apply(points)


def _principal_axes_init(src: np.ndarray, dst_vertices: np.ndarray, dst_faces: np.ndarray) -> Pose:
    from .metrics import _Surface

    target = _Surface(dst_vertices, dst_faces)  # prepared once for the 4 candidates
    ca, cb = src.mean(axis=0), dst_vertices.mean(axis=0)
    ea = np.linalg.svd(src - ca, full_matrices=False)[2]
    eb = np.linalg.svd(dst_vertices - cb, full_matrices=False)[2]
    best = (np.inf, Pose(np.eye(3), cb - ca))
    for s0, s1 in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
        S = np.diag([s0, s1, s0 * s1 * np.linalg.det(ea) * np.linalg.det(eb)])
        R = eb.T @ S @ ea
        pose = Pose(R, cb - R @ ca)
        cost = float(np.mean(target.distance(pose.apply(src))))
        if cost < best[0]:
            best = (cost, pose)
    return best[1]


def align_rigid(
    vertices: np.ndarray,
    faces: np.ndarray,
    target_vertices: np.ndarray,
    target_faces: np.ndarray,
    *,
    seed: int = 0,
) -> RigidAlignment:
    """Rigidly align a surface (the ground truth) onto a target (the registered surface).

    Parameters
    ----------
    vertices, faces : arrays
        The surface to move (mm, any frame).
    target_vertices, target_faces : arrays
        The fixed surface (mm, world frame).
    seed : int
        Seed of the surface samples used by the ICP.

    Returns
    -------
    RigidAlignment
    """
    from scipy.spatial import cKDTree

    from .metrics import sample_surface

    V = np.asarray(vertices, float)
    T = np.asarray(target_vertices, float)
    if len(V) == len(T):
        pose = Pose.fit_rigid(V, T)
        init = "vertex correspondence"
    else:
        pose = _principal_axes_init(V, T, np.asarray(target_faces))
        init = "principal axes"
    pts = sample_surface(V, faces, ICP_SAMPLES, seed)
    tree = cKDTree(sample_surface(T, target_faces, ICP_TARGET_SAMPLES, seed + 1))
    cost = np.inf
    for _ in range(ICP_ITERATIONS):
        d, idx = tree.query(pose.apply(pts))
        new_cost = float(np.mean(d**2))
        if cost - new_cost < 1e-8:
            cost = min(cost, new_cost)
            break
        cost = new_cost
        pose = Pose.fit_rigid(pts, tree.data[idx])
    return RigidAlignment(pose, init, cost)
