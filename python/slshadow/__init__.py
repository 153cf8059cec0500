"""slshadow: structured-light scanning and its digital shadow, from Python.

The project's C++ libraries with numpy in and out (docs/python.md): Rig, PatternSpec, ImageSet,
simulate, decode, reconstruct, compare. Units: mm, rad, px; pixel (0, 0) is the centre of the
top-left pixel (OpenCV). Bad input raises slshadow.Error with the command line's one-line message.
"""

from ._slshadow import (  # noqa: F401
    CameraModel,
    Comparison,
    Device,
    Error,
    ImageSet,
    PatternSpec,
    PointCloud,
    ProjectorMap,
    Reconstruction,
    Reference,
    Rig,
    Scan,
    Scene,
    __version__,
    compare,
    decode,
    read_ply,
    reconstruct,
    shadow,
    simulate,
    write_image_set,
)


def to_open3d(cloud):
    """An open3d.geometry.PointCloud of a PointCloud or Reconstruction (points, normals and
    colours copied; colours scaled to [0, 1])."""
    import numpy as np
    import open3d as o3d

    if isinstance(cloud, Reconstruction):
        cloud = cloud.cloud
    out = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(cloud.points)))
    if cloud.normals is not None:
        out.normals = o3d.utility.Vector3dVector(np.array(cloud.normals, dtype=np.float64))
    if cloud.colors is not None:
        out.colors = o3d.utility.Vector3dVector(np.asarray(cloud.colors, dtype=np.float64) / 255.0)
    return out


__all__ = [
    "CameraModel",
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
    "reconstruct",
    "shadow",
    "simulate",
    "to_open3d",
    "write_image_set",
]
