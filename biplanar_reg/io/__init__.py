"""File input/output: meshes and point clouds, CT volumes, atomic writes."""

from .atomic import atomic_path
from .meshes import MESH_SUFFIXES, check_manifold, read_mesh, write_mesh
from .volumes import Volume, read_dicom_series, read_volume

__all__ = [
    "MESH_SUFFIXES",
    "Volume",
    "atomic_path",
    "check_manifold",
    "read_dicom_series",
    "read_mesh",
    "read_volume",
    "write_mesh",
]
