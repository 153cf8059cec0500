"""Type stubs of the slshadow extension module (python/*.cc). Units: mm, rad, px."""

import os
from typing import Any, Callable, Optional, Sequence, Union, overload

import numpy as np
import numpy.typing as npt

__version__: str

_PathLike = Union[str, os.PathLike[str]]
_Progress = Optional[Callable[[str, int, int], Any]]
_ImageStack = Union[npt.NDArray[np.uint8], npt.NDArray[np.uint16], Sequence[npt.NDArray[Any]]]

class Error(ValueError):
    """Bad input: the command line's one-line message (file, field, value)."""

class CameraModel:
    """Pinhole + Brown-Conrady distortion (OpenCV's k1, k2, p1, p2, k3)."""

    def __init__(
        self,
        width: int,
        height: int,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        k1: float = 0.0,
        k2: float = 0.0,
        p1: float = 0.0,
        p2: float = 0.0,
        k3: float = 0.0,
    ) -> None: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def params(self) -> npt.NDArray[np.float64]: ...
    @property
    def K(self) -> npt.NDArray[np.float64]: ...
    @property
    def dist_coeffs(self) -> npt.NDArray[np.float64]: ...
    def project(
        self, points_in_cam: npt.ArrayLike
    ) -> tuple[npt.NDArray[np.float64], Any]: ...
    def unproject(self, pixels: npt.ArrayLike) -> tuple[npt.NDArray[np.float64], Any]: ...

class Device:
    """A camera or the projector of a rig, with its pose."""

    @property
    def name(self) -> str: ...
    @property
    def model(self) -> CameraModel: ...
    @property
    def cam_from_rig(self) -> npt.NDArray[np.float64]: ...
    @property
    def center_in_rig(self) -> npt.NDArray[np.float64]: ...
    @property
    def axis_in_rig(self) -> npt.NDArray[np.float64]: ...
    def project(
        self, points_in_rig: npt.ArrayLike
    ) -> tuple[npt.NDArray[np.float64], Any]: ...
    def unproject(self, pixels: npt.ArrayLike) -> tuple[npt.NDArray[np.float64], Any]: ...

class Rig:
    """Cameras and at most one projector (docs/formats.md "Rig YAML")."""

    @staticmethod
    def load(path: _PathLike) -> Rig: ...
    @staticmethod
    def from_dict(tree: dict[str, Any]) -> Rig: ...
    def save(self, path: _PathLike) -> None: ...
    def describe(self) -> str: ...
    def to_dict(self) -> dict[str, Any]: ...
    @property
    def name(self) -> str: ...
    @property
    def working_distance_mm(self) -> float: ...
    @property
    def cameras(self) -> list[Device]: ...
    @property
    def projector(self) -> Optional[Device]: ...
    @property
    def camera_names(self) -> list[str]: ...
    def camera(self, name: str) -> Device: ...
    def device(self, name: str) -> Device: ...

class PointCloud:
    """Points (mm), optional normals, colours and scalar fields; read-only array views."""

    def __init__(
        self,
        points: npt.ArrayLike,
        normals: Optional[npt.ArrayLike] = None,
        colors: Optional[npt.ArrayLike] = None,
        scalars: Optional[dict[str, npt.ArrayLike]] = None,
    ) -> None: ...
    def __len__(self) -> int: ...
    @property
    def points(self) -> npt.NDArray[np.float64]: ...
    @property
    def normals(self) -> Optional[npt.NDArray[np.float32]]: ...
    @property
    def colors(self) -> Optional[npt.NDArray[np.uint8]]: ...
    @property
    def scalar_names(self) -> list[str]: ...
    def scalar(self, name: str) -> npt.NDArray[np.float32]: ...
    def write_ply(self, path: _PathLike, binary: bool = True) -> None: ...

def read_ply(path: _PathLike) -> PointCloud: ...

class Scene:
    """What the simulator scans (docs/formats.md "Scene YAML")."""

    @staticmethod
    def load(path: _PathLike) -> Scene: ...
    @property
    def name(self) -> str: ...
    def to_dict(self) -> dict[str, Any]: ...

class ImageSet:
    """A capture folder, real or virtual (docs/formats.md "ImageSet")."""

    @staticmethod
    def open(dir: _PathLike) -> ImageSet: ...
    @property
    def dir(self) -> str: ...
    @property
    def rig(self) -> Rig: ...
    @property
    def patterns(self) -> PatternSpec: ...
    @property
    def extra(self) -> dict[str, Any]: ...
    @property
    def cameras(self) -> list[str]: ...
    @property
    def pattern_count(self) -> int: ...
    def image(self, camera: str, index: int) -> npt.NDArray[Any]: ...
    def images(self, camera: str) -> npt.NDArray[Any]: ...

def write_image_set(
    dir: _PathLike,
    rig: Rig,
    patterns: Union[PatternSpec, dict[str, Any], _PathLike],
    images: dict[str, _ImageStack],
    *,
    encoding: str = "png",
    png_compression: int = 1,
    overwrite: bool = False,
    exposure_us: float = 0.0,
    source: str = "device",
    extra: Optional[dict[str, Any]] = None,
) -> ImageSet: ...

class PatternSpec:
    """What is projected and how it is decoded (docs/formats.md "Pattern spec")."""

    @staticmethod
    def load(path: _PathLike) -> PatternSpec: ...
    @staticmethod
    def from_dict(tree: dict[str, Any]) -> PatternSpec: ...
    def to_dict(self) -> dict[str, Any]: ...
    @property
    def kind(self) -> str: ...
    @property
    def projector_width(self) -> int: ...
    @property
    def projector_height(self) -> int: ...
    @property
    def code_x(self) -> bool: ...
    @property
    def code_y(self) -> bool: ...
    @property
    def phase_steps(self) -> int: ...
    @property
    def period_px(self) -> float: ...
    @property
    def periods_px(self) -> list[float]: ...
    @property
    def num_images(self) -> int: ...
    @property
    def frames(self) -> list[dict[str, Any]]: ...
    @property
    def frame_names(self) -> list[str]: ...
    @property
    def white_frame_index(self) -> int: ...
    @property
    def black_frame_index(self) -> int: ...
    def generate(self) -> npt.NDArray[np.uint8]: ...

class ProjectorMap:
    """Decoded projector coordinates per camera pixel (arrays share memory)."""

    @property
    def proj_x(self) -> npt.NDArray[np.float32]: ...
    @property
    def proj_y(self) -> npt.NDArray[np.float32]: ...
    @property
    def status(self) -> npt.NDArray[np.uint8]: ...
    @property
    def quality(self) -> npt.NDArray[np.float32]: ...
    @property
    def modulation(self) -> npt.NDArray[np.float32]: ...
    @property
    def mask(self) -> npt.NDArray[np.bool_]: ...
    @property
    def has_x(self) -> bool: ...
    @property
    def has_y(self) -> bool: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    def counts(self) -> dict[str, int]: ...

def decode(
    images: _ImageStack, patterns: Union[PatternSpec, dict[str, Any], _PathLike], **options: Any
) -> ProjectorMap: ...

class Scan:
    """A virtual scan in memory (simulate())."""

    @property
    def rig(self) -> Rig: ...
    @property
    def patterns(self) -> PatternSpec: ...
    @property
    def cameras(self) -> list[str]: ...
    def images(self, camera: str) -> npt.NDArray[Any]: ...
    def image(self, camera: str, index: int) -> npt.NDArray[Any]: ...
    def ground_truth(self, camera: str) -> dict[str, npt.NDArray[Any]]: ...
    def visible_surface(self, camera: str) -> PointCloud: ...
    @property
    def summary(self) -> str: ...
    def write(self, dir: _PathLike, *, encoding: str = "png", overwrite: bool = False) -> ImageSet: ...

def simulate(
    rig: Rig,
    scene: Scene,
    patterns: Union[PatternSpec, dict[str, Any], _PathLike],
    *,
    ground_truth: bool = False,
    trace_mode: str = "packet16",
    progress: _Progress = None,
) -> Scan: ...

class Reconstruction:
    """The result of reconstruct(): the merged cloud (rig frame, mm) and its summaries."""

    @property
    def cloud(self) -> PointCloud: ...
    @property
    def points(self) -> npt.NDArray[np.float64]: ...
    @property
    def normals(self) -> Optional[npt.NDArray[np.float32]]: ...
    @property
    def colors(self) -> None: ...
    @property
    def quality(self) -> npt.NDArray[np.float32]: ...
    @property
    def camera(self) -> npt.NDArray[np.float32]: ...
    @property
    def source_pixel(self) -> npt.NDArray[np.float32]: ...
    @property
    def cameras(self) -> list[str]: ...
    @property
    def summaries(self) -> list[dict[str, Any]]: ...
    @property
    def warnings(self) -> list[str]: ...
    @property
    def notices(self) -> list[str]: ...
    @property
    def residual_maps(self) -> dict[str, npt.NDArray[np.float32]]: ...
    @property
    def report(self) -> str: ...
    def to_dict(self) -> dict[str, Any]: ...
    def write(
        self, path: _PathLike, summary: Optional[_PathLike] = None, binary: bool = True
    ) -> str: ...
    def __len__(self) -> int: ...

def reconstruct(
    source: Union[ImageSet, Scan, dict[str, _ImageStack]],
    patterns: Union[PatternSpec, dict[str, Any], _PathLike, None] = None,
    *,
    rig: Optional[Rig] = None,
    progress: _Progress = None,
    **options: Any,
) -> Reconstruction: ...

class Reference:
    """A mesh (C2M) or cloud (C2C) reference, built once for many comparisons."""

    @staticmethod
    def load(path: _PathLike, mesh_samples: int = 200000) -> Reference: ...
    @staticmethod
    def from_cloud(cloud: PointCloud, source: str = "cloud") -> Reference: ...
    @property
    def source(self) -> str: ...
    @property
    def is_mesh(self) -> bool: ...

class Comparison:
    """The result of compare()."""

    @property
    def figures(self) -> dict[str, Any]: ...
    @property
    def deviations(self) -> npt.NDArray[np.float64]: ...
    @property
    def compared(self) -> PointCloud: ...
    @property
    def reference_from_cloud(self) -> npt.NDArray[np.float64]: ...
    @property
    def coverage(self) -> float: ...
    @property
    def summary(self) -> str: ...

def compare(
    cloud: Union[PointCloud, Reconstruction, npt.ArrayLike, _PathLike],
    reference: Union[Reference, PointCloud, Reconstruction, npt.ArrayLike, _PathLike],
    *,
    out: Optional[_PathLike] = None,
    mesh_samples: int = 200000,
    cloud_source: Optional[str] = None,
    view_rig: Optional[Rig] = None,
    view_camera: Optional[str] = None,
    overwrite: bool = True,
    progress: _Progress = None,
    **options: Any,
) -> Comparison: ...

def shadow(
    real: Union[ImageSet, _PathLike],
    part: _PathLike,
    *,
    out: Optional[_PathLike] = None,
    rig: Optional[Rig] = None,
    pose: Optional[npt.ArrayLike] = None,
    refine_pose: bool = True,
    fit_physics: bool = True,
    min_fitness: float = 0.5,
    max_rmse_mm: float = 0.5,
    write_clouds: bool = True,
    overwrite: bool = False,
    progress: _Progress = None,
    **options: Any,
) -> dict[str, Any]: ...

def calibrate_camera(
    images: Union[_PathLike, Sequence[_PathLike]],
    target: _PathLike,
    out: _PathLike,
    *,
    camera: str = "camera",
    report: Optional[_PathLike] = None,
    opencv_out: Optional[_PathLike] = None,
    name: str = "calibrated",
    fix_aspect: bool = False,
    fix_principal_point: bool = False,
    zero_tangential: bool = False,
    fix_k3: bool = False,
    loss: str = "none",
    loss_scale_px: float = 1.0,
    board_warp: bool = False,
    cross_validate: bool = True,
    min_views: int = 10,
    progress: _Progress = None,
) -> dict[str, Any]: ...

def calibrate_stereo(
    left: Union[_PathLike, Sequence[_PathLike]],
    right: Union[_PathLike, Sequence[_PathLike]],
    target: _PathLike,
    out: _PathLike,
    *,
    left_name: str = "left",
    right_name: str = "right",
    report: Optional[_PathLike] = None,
    opencv_out: Optional[_PathLike] = None,
    name: str = "calibrated",
    fix_aspect: bool = False,
    fix_principal_point: bool = False,
    zero_tangential: bool = False,
    fix_k3: bool = False,
    loss: str = "none",
    loss_scale_px: float = 1.0,
    board_warp: bool = False,
    cross_validate: bool = True,
    min_views: int = 10,
    progress: _Progress = None,
) -> dict[str, Any]: ...

def calibrate_projector(
    captures: Union[_PathLike, Sequence[_PathLike]],
    patterns: Union[PatternSpec, dict[str, Any], _PathLike],
    target: _PathLike,
    out: _PathLike,
    *,
    camera: str = "camera",
    camera_rig: Optional[_PathLike] = None,
    shadow_threshold: float = 12.0,
    contrast_threshold: float = 4.0,
    window: int = 20,
    select_model: bool = False,
    principal_point_inside: bool = False,
    report: Optional[_PathLike] = None,
    opencv_out: Optional[_PathLike] = None,
    name: str = "calibrated",
    fix_aspect: bool = False,
    fix_principal_point: bool = False,
    zero_tangential: bool = False,
    fix_k3: bool = False,
    loss: str = "none",
    loss_scale_px: float = 1.0,
    board_warp: bool = False,
    cross_validate: bool = True,
    min_views: int = 10,
    progress: _Progress = None,
) -> dict[str, Any]: ...

def calibrate_rig(
    imagesets: Sequence[Union[ImageSet, _PathLike]],
    target: _PathLike,
    out: _PathLike,
    *,
    shadow_threshold: float = 12.0,
    contrast_threshold: float = 4.0,
    window: int = 20,
    select_model: bool = False,
    principal_point_inside: bool = False,
    report: Optional[_PathLike] = None,
    opencv_out: Optional[_PathLike] = None,
    name: str = "calibrated",
    fix_aspect: bool = False,
    fix_principal_point: bool = False,
    zero_tangential: bool = False,
    fix_k3: bool = False,
    loss: str = "none",
    loss_scale_px: float = 1.0,
    board_warp: bool = False,
    cross_validate: bool = True,
    min_views: int = 10,
    progress: _Progress = None,
) -> dict[str, Any]: ...

def calibrate_corners(
    object_points: Sequence[npt.ArrayLike],
    image_points: Union[
        Sequence[Optional[npt.ArrayLike]], dict[str, Sequence[Optional[npt.ArrayLike]]]
    ],
    image_size: Union[tuple[int, int], dict[str, tuple[int, int]]],
    out: _PathLike,
    *,
    camera: str = "camera",
    labels: Optional[Sequence[str]] = None,
    report: Optional[_PathLike] = None,
    opencv_out: Optional[_PathLike] = None,
    name: str = "calibrated",
    fix_aspect: bool = False,
    fix_principal_point: bool = False,
    zero_tangential: bool = False,
    fix_k3: bool = False,
    loss: str = "none",
    loss_scale_px: float = 1.0,
    board_warp: bool = False,
    cross_validate: bool = True,
    min_views: int = 10,
    progress: _Progress = None,
) -> dict[str, Any]: ...

def detect_target(
    image: Union[npt.NDArray[np.uint8], npt.NDArray[np.uint16], _PathLike], target: _PathLike
) -> dict[str, Any]: ...

def calibrate_refine(
    rig: _PathLike,
    imageset: Union[ImageSet, _PathLike],
    out: _PathLike,
    *,
    camera: str = "",
    stereo: str = "",
    baseline_mm: float = 0.0,
    known_distance: Optional[Sequence[float]] = None,
    refine_focal: bool = False,
) -> dict[str, Any]: ...
def calibrate_import(
    opencv_file: _PathLike,
    out: Optional[_PathLike] = None,
    *,
    image_size: Optional[tuple[int, int]] = None,
    projector_size: Optional[tuple[int, int]] = None,
    map: Optional[str] = None,
) -> Rig: ...
def calibrate_export(rig: Union[Rig, _PathLike], out: _PathLike) -> None: ...
def _sweep(
    study: _PathLike,
    out: _PathLike,
    *,
    shard: str = "0/1",
    verbose: bool = False,
    progress: _Progress = None,
) -> dict[str, Any]: ...
