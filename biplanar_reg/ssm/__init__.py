"""Shape models: the SSM itself, templates, populations and model building.

See ``docs/ssm.md``; the package exports the names listed in ``docs/api.md``.
"""

from .._lazy import lazy_dir, lazy_getattr
from .model import ShapeModel

#: Everything but the model itself is imported on first use: a registration needs only
#: :class:`ShapeModel`, and model building pulls in scipy's sparse solvers and graph routines.
_LAZY = {
    **dict.fromkeys(
        ("affine_fractions", "build_ssm", "explained_fractions", "procrustes_align"), ".build"
    ),
    "BuiltModel": ".from_files",
    "build_model_from_files": ".from_files",
    "Correspondence": ".correspond",
    "correspond_meshes": ".correspond",
    "densify": ".dense",
    "augment_model": ".gaussian_process",
    "ModelFit": ".fit",
    "fit_model": ".fit",
    **dict.fromkeys(("BoxCage", "box_cage", "harmonic_coordinates"), ".harmonic"),
    "mirror_mesh": ".mirror",
    "mirror_model": ".mirror",
    **dict.fromkeys(("FAMILIES", "Population", "synthesise_population"), ".population"),
    **dict.fromkeys(
        (
            "ModelQuality",
            "compactness",
            "generalisation",
            "model_quality",
            "plot_quality",
            "recommended_modes",
            "specificity",
        ),
        ".quality",
    ),
    "read_statismo": ".statismo",
    "write_statismo": ".statismo",
    "BoneSurface": ".template",
    "bone_surface": ".template",
}

__getattr__ = lazy_getattr(__name__, _LAZY)
__dir__ = lazy_dir(__name__, _LAZY)


__all__ = [
    "FAMILIES",
    "BoneSurface",
    "BoxCage",
    "BuiltModel",
    "Correspondence",
    "ModelFit",
    "ModelQuality",
    "Population",
    "ShapeModel",
    "affine_fractions",
    "augment_model",
    "bone_surface",
    "box_cage",
    "build_model_from_files",
    "build_ssm",
    "correspond_meshes",
    "compactness",
    "densify",
    "explained_fractions",
    "fit_model",
    "generalisation",
    "harmonic_coordinates",
    "mirror_mesh",
    "mirror_model",
    "model_quality",
    "plot_quality",
    "procrustes_align",
    "read_statismo",
    "recommended_modes",
    "specificity",
    "synthesise_population",
    "write_statismo",
]
