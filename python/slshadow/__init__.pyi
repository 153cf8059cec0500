"""Type stubs of the slshadow package (python/slshadow/__init__.py)."""

import os
from typing import Any

import numpy as np

import open3d  # type: ignore[import]

from ._slshadow import (
    CameraModel as CameraModel,
    calibrate_camera as calibrate_camera,
    Comparison as Comparison,
    Device as Device,
    Error as Error,
    ImageSet as ImageSet,
    PatternSpec as PatternSpec,
    PointCloud as PointCloud,
    ProjectorMap as ProjectorMap,
    Reconstruction as Reconstruction,
    Reference as Reference,
    Rig as Rig,
    Scan as Scan,
    Scene as Scene,
    __version__ as __version__,
    compare as compare,
    decode as decode,
    read_ply as read_ply,
    reconstruct as reconstruct,
    shadow as shadow,
    simulate as simulate,
    write_image_set as write_image_set,
)

def read_table(path: str | os.PathLike[str]) -> dict[str, np.ndarray[Any, Any]]: ...
def sweep(
    study: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    shard: str = "0/1",
    verbose: bool = False,
    progress: Any = None,
) -> dict[str, Any]: ...
def to_open3d(cloud: PointCloud | Reconstruction) -> open3d.geometry.PointCloud: ...

__all__ = [
    "CameraModel",
    "calibrate_camera",
    "Comparison",
    "Device",
    "Error",
    "ImageSet",
    "PatternSpec",
    "PointCloud",
    "ProjectorMap",
    "Reconstruction",
    "Reference",
    "Rig",
    "Scan",
    "Scene",
    "compare",
    "decode",
    "read_ply",
    "read_table",
    "reconstruct",
    "shadow",
    "simulate",
    "sweep",
    "to_open3d",
    "write_image_set",
]
