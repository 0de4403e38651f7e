"""Shape models: the SSM itself, templates, populations and model building.

See ``docs/ssm.md``; the package exports the names listed in ``docs/api.md``.
"""

from .build import affine_fractions, build_ssm, explained_fractions, procrustes_align
from .correspond import Correspondence, correspond_meshes
from .dense import densify
from .fit import ModelFit, fit_model
from .harmonic import BoxCage, box_cage, harmonic_coordinates
from .mirror import mirror_mesh, mirror_model
from .model import ShapeModel
from .population import FAMILIES, Population, synthesise_population
from .quality import (
    ModelQuality,
    compactness,
    generalisation,
    model_quality,
    plot_quality,
    recommended_modes,
    specificity,
)
from .statismo import read_statismo, write_statismo
from .template import BoneSurface, bone_surface

__all__ = [
    "FAMILIES",
    "BoneSurface",
    "BoxCage",
    "Correspondence",
    "ModelFit",
    "ModelQuality",
    "Population",
    "ShapeModel",
    "affine_fractions",
    "bone_surface",
    "box_cage",
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
