"""CT volume to a template bone surface: segment, marching cubes in mm, smooth, decimate.

Pipeline (:func:`bone_surface`):

1. **Segment** (:func:`segment_bone`): voxels above a threshold; default 300 HU for CT in
   Hounsfield units (between cancellous and cortical bone) and Otsu's threshold for raw
   intensities (e.g. the masked TIFF crops shipped in ``sample_cases``). Keep the largest
   6-connected component, fill its enclosed holes in 3-D and, by default, also per slice (the
   medullary cavity of a long bone cut by the CT field of view is open at the cut, so 3-D filling
   alone leaves a tunnel).
2. **Marching cubes** (scikit-image) on the intensities clamped to the segmentation (values
   inside the mask are raised to at least the threshold, those outside lowered below it), so the
   surface is the mask's boundary but keeps sub-voxel placement from the partial-volume
   intensities. The volume is padded by one background voxel so a bone cut by the field of view
   is capped flat: the surface is always closed. Vertices go through the volume's affine (mm).
3. **Smoothing**: windowed-sinc (Taubin-type, VTK) low-pass filter, which does not shrink the
   surface (measured volume change well under 1 %, see docs/ssm.md).
4. **Decimation**: VTK quadric decimation with volume preservation to ``target_vertices``, in
   stages of at most halving, each checked for closedness.
5. **Checks**: closed, consistently oriented (outward) and one component; faces are flipped if
   the enclosed volume comes out negative (a left-handed affine).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi

from ..io.meshes import to_polydata
from ..io.volumes import Volume
from .surface import count_components, is_closed_manifold, signed_volume

__all__ = ["BoneSurface", "bone_surface"]

log = logging.getLogger(__name__)

#: Default bone threshold for volumes in Hounsfield units.
HU_BONE_THRESHOLD = 300.0


@dataclass(frozen=True)
class BoneSurface:
    """A closed bone surface extracted from a CT volume.

    Attributes
    ----------
    vertices : (N, 3) array
        mm, in the volume's frame (patient LPS for DICOM, the scaled voxel grid otherwise).
    faces : (F, 3) int array
        Outward-oriented triangles.
    threshold : float
        The segmentation threshold used, in the volume's units.
    volume_mm3 : float
        Enclosed volume of the final surface, mm^3.
    segmented_mm3 : float
        Volume of the filled segmentation (voxel count x voxel volume), mm^3.
    decimated : bool
        Whether decimation to ``target_vertices`` was applied.
    """

    vertices: np.ndarray
    faces: np.ndarray
    threshold: float
    volume_mm3: float
    segmented_mm3: float
    decimated: bool


def _default_threshold(volume: Volume) -> float:
    """The documented default: 300 HU for HU volumes, else Otsu's threshold of all voxels."""
    if volume.units == "HU":
        return HU_BONE_THRESHOLD
    from skimage.filters import threshold_otsu

    return float(threshold_otsu(np.asarray(volume.data, dtype=np.float32)))


def segment_bone(
    volume: Volume, threshold: float | None = None, fill_slices: bool = True
) -> tuple[np.ndarray, float]:
    """Binary bone mask: threshold, largest connected component, hole filling.

    Parameters
    ----------
    volume : Volume
        The CT volume.
    threshold : float, optional
        In the volume's units; default :func:`_default_threshold`.
    fill_slices : bool
        Also fill holes slice by slice (along the volume's slice axis).

    Returns
    -------
    mask : (K, J, I) bool array
    threshold : float

    Raises
    ------
    ValueError
        Nothing is above the threshold (an empty segmentation), naming the volume.
    """
    data = np.asarray(volume.data)
    thr = _default_threshold(volume) if threshold is None else float(threshold)
    if not np.isfinite(thr):
        raise ValueError(f"threshold: must be finite, got {threshold!r}")
    mask = data > thr
    if not mask.any():
        raise ValueError(
            f"{volume.source}: empty segmentation, no voxel above the threshold {thr:g} "
            f"(voxel range {float(data.min()):g} .. {float(data.max()):g} {volume.units})"
        )
    labels, n = ndi.label(mask)
    if n > 1:
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        mask = labels == int(np.argmax(sizes))
    mask = ndi.binary_fill_holes(mask)
    if fill_slices:
        mask = np.stack([ndi.binary_fill_holes(s) for s in mask])
    return mask, thr


def _poly_faces(poly) -> np.ndarray:
    return np.asarray(poly.faces).reshape(-1, 4)[:, 1:].astype(np.int64)


def _decimate_closed(poly, target: int):  # pyvista.PolyData -> pyvista.PolyData
    """Quadric decimation (volume-preserving) to about ``target`` vertices, in stages.

    One big quadric-decimation step occasionally leaves a non-manifold edge on flat caps
    (measured on the wrist radius at 1,000 and 2,000 vertices); at most halving the vertex count
    per stage, and checking closedness after each, avoided it in every case tried. A stage that
    still breaks the surface is retried with a gentler step; if that also fails the last closed
    mesh is kept (with a warning), so the result is always closed.
    """
    while poly.n_points > 1.02 * target:
        for keep in (0.5, 0.8):
            goal = max(target, keep * poly.n_points)
            # A closed genus-g surface has F = 2V + 4g - 4 triangles: aim at 2 * goal faces.
            candidate = poly.decimate(1.0 - 2.0 * goal / poly.n_cells, volume_preservation=True)
            if is_closed_manifold(_poly_faces(candidate)):
                poly = candidate
                break
        else:
            log.warning(
                "decimation would break the surface's closedness; stopping at %d vertices "
                "(target %d)",
                poly.n_points,
                target,
            )
            break
    return poly


def bone_surface(
    volume: Volume,
    threshold: float | None = None,
    target_vertices: int | None = 4000,
    smooth_iterations: int = 20,
    pass_band: float = 0.1,
    fill_slices: bool = True,
) -> BoneSurface:
    """Extract a closed, outward-oriented bone surface in mm from a CT volume.

    Parameters
    ----------
    volume : Volume
        The CT volume (its affine maps voxels to mm).
    threshold : float, optional
        Segmentation threshold in the volume's units; default :func:`_default_threshold`.
    target_vertices : int or None
        Decimate to about this many vertices (``None``: keep the marching-cubes resolution).
    smooth_iterations : int
        Windowed-sinc smoothing iterations (0 disables smoothing).
    pass_band : float
        Smoothing pass band in (0, 2); smaller is smoother.
    fill_slices : bool
        See :func:`segment_bone`.
    """
    from skimage import measure

    if target_vertices is not None and int(target_vertices) < 100:
        raise ValueError(f"target_vertices: must be at least 100, got {target_vertices}")
    if smooth_iterations < 0:
        raise ValueError(f"smooth_iterations: must be >= 0, got {smooth_iterations}")
    if not 0.0 < pass_band < 2.0:
        raise ValueError(f"pass_band: must be in (0, 2), got {pass_band}")
    mask, thr = segment_bone(volume, threshold, fill_slices=fill_slices)

    data = np.asarray(volume.data, dtype=np.float64)
    # Clamp so the iso-surface at thr is exactly the mask's boundary; the 1e-3 margins keep the
    # partial-volume interpolation of genuine boundary voxels and push forced ones just across.
    eps = 1e-3 * max(1.0, abs(thr))
    field = np.where(mask, np.maximum(data, thr + eps), np.minimum(data, thr - eps))
    field = np.pad(field, 1, constant_values=min(float(data.min()), thr) - 1.0)
    verts, faces, _, _ = measure.marching_cubes(field, thr, allow_degenerate=False)
    ijk = verts[:, ::-1] - 1.0  # (k, j, i) of the padded grid -> (i, j, k) of the volume
    vertices = volume.to_mm(ijk)
    faces = faces.astype(np.int64)

    poly = to_polydata(vertices, faces)
    if smooth_iterations:
        poly = poly.smooth_taubin(n_iter=int(smooth_iterations), pass_band=float(pass_band))
    decimated = False
    if target_vertices is not None and poly.n_points > int(target_vertices):
        poly = _decimate_closed(poly, int(target_vertices))
        decimated = True
    vertices = np.asarray(poly.points, dtype=float)
    faces = _poly_faces(poly)
    used = np.unique(faces)
    if len(used) != len(vertices):  # drop unreferenced points, keeping their order
        remap = np.full(len(vertices), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        vertices, faces = vertices[used], remap[faces]

    vol = signed_volume(vertices, faces)
    if vol < 0:
        faces = faces[:, ::-1].copy()
        vol = -vol
    if not is_closed_manifold(faces):
        raise RuntimeError(f"{volume.source}: the extracted surface is not closed (a bug)")
    n_comp = count_components(len(vertices), faces)
    if n_comp != 1:
        raise RuntimeError(f"{volume.source}: the surface has {n_comp} components (a bug)")
    voxel_volume = float(abs(np.linalg.det(volume.affine[:3, :3])))
    return BoneSurface(
        vertices=vertices,
        faces=faces,
        threshold=thr,
        volume_mm3=vol,
        segmented_mm3=float(mask.sum()) * voxel_volume,
        decimated=decimated,
    )
