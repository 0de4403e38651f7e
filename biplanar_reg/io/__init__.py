"""File input/output: meshes and point clouds, CT volumes, atomic writes, strict JSON.

See ``docs/ssm.md`` (meshes, volumes) and ``README.md``; the package exports the names listed
in ``docs/api.md``.
"""

from .atomic import atomic_path, atomic_write_bytes, atomic_write_json, atomic_write_text
from .jsonfile import read_json
from .meshes import read_mesh, write_mesh
from .volumes import Volume, read_dicom_series, read_volume

__all__ = [
    "Volume",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "read_dicom_series",
    "read_json",
    "read_mesh",
    "read_volume",
    "write_mesh",
]
