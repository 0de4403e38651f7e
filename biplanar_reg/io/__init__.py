"""File input/output: meshes and point clouds, CT volumes, atomic writes, strict JSON, pose
and landmark exports (Autoscoper ``.tra``, ITK ``.tfm``, Slicer ``.mrk.json``, kinematics CSV).

See ``docs/ssm.md`` (meshes, volumes) and ``README.md``; the package exports the names listed
in ``docs/api.md``.
"""

from .._lazy import lazy_dir, lazy_getattr
from .atomic import atomic_path, atomic_write_bytes, atomic_write_json, atomic_write_text
from .jsonfile import read_json
from .meshes import read_mesh, write_mesh
from .transforms import (
    ANGLE_SEQUENCE,
    read_itk_tfm,
    read_kinematics_csv,
    read_markups_json,
    read_tra,
    relative_pose,
    rigid_pose,
    write_itk_tfm,
    write_kinematics_csv,
    write_markups_json,
    write_tra,
)

#: CT volumes, imported on first use (a registration reads none).
_LAZY = dict.fromkeys(("Volume", "read_dicom_series", "read_volume"), ".volumes")
__getattr__ = lazy_getattr(__name__, _LAZY)
__dir__ = lazy_dir(__name__, _LAZY)

__all__ = [
    "ANGLE_SEQUENCE",
    "Volume",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "read_dicom_series",
    "read_itk_tfm",
    "read_json",
    "read_kinematics_csv",
    "read_markups_json",
    "read_mesh",
    "read_tra",
    "read_volume",
    "relative_pose",
    "rigid_pose",
    "write_itk_tfm",
    "write_kinematics_csv",
    "write_markups_json",
    "write_mesh",
    "write_tra",
]
