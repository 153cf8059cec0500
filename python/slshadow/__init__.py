"""slshadow: structured-light scanning and its digital shadow, from Python.

The project's C++ libraries with numpy in and out (docs/python.md): Rig, PatternSpec, ImageSet,
simulate, decode, reconstruct, compare, shadow, calibrate_*. Units: mm, rad, px; pixel (0, 0) is
the centre of the top-left pixel (OpenCV). Bad input raises slshadow.Error with the command line's
one-line message.

One source for each signature: the extension's names come from _slshadow (typed by
_slshadow.pyi), and the few functions written in Python are annotated here (no __init__.pyi), so
mypy's stubtest checks both against the running module (tests/python/test_stubs.py).
"""

import os
from typing import Any, Callable, Optional, Union

from ._slshadow import *  # noqa: F401,F403  (every public name of the extension)
from ._slshadow import PointCloud, Reconstruction, __version__, _sweep  # noqa: F401

_PathLike = Union[str, "os.PathLike[str]"]


def to_open3d(cloud: Union[PointCloud, Reconstruction]) -> Any:
    """An open3d.geometry.PointCloud of a PointCloud or Reconstruction (points, normals and
    colours copied; colours scaled to [0, 1])."""
    import numpy as np
    import open3d as o3d  # type: ignore

    if isinstance(cloud, Reconstruction):
        cloud = cloud.cloud
    out = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(cloud.points)))
    if cloud.normals is not None:
        out.normals = o3d.utility.Vector3dVector(np.array(cloud.normals, dtype=np.float64))
    if cloud.colors is not None:
        out.colors = o3d.utility.Vector3dVector(np.asarray(cloud.colors, dtype=np.float64) / 255.0)
    return out


def read_table(path: _PathLike) -> dict[str, Any]:
    """A CSV table written by slshadow (e.g. a sweep's results.csv) as a dict column -> numpy
    array: float64 where every value is a number (empty cells NaN), else str (also identifiers
    such as job ids "000001", numbers written with leading zeros)."""
    import csv

    import numpy as np

    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    table: dict[str, Any] = {}
    for i, name in enumerate(header):
        values = [row[i] if i < len(row) else "" for row in body]
        if any(len(v) > 1 and v[0] == "0" and v[1].isdigit() for v in values):
            table[name] = np.array(values, dtype=str)
            continue
        try:
            table[name] = np.array([float(v) if v != "" else np.nan for v in values])
        except ValueError:
            table[name] = np.array(values, dtype=str)
    return table


def sweep(
    study: _PathLike,
    out: _PathLike,
    *,
    shard: str = "0/1",
    verbose: bool = False,
    progress: Optional[Callable[[str, int, int], Any]] = None,
) -> dict[str, Any]:
    """Plans, runs and merges a study as `slshadow sweep study STUDY --out OUT` does (docs/sweeps.md;
    a second call resumes it). Returns the summaries (plan, run, merge) and the result tables as
    dicts of arrays: results (results.csv, one row per job and mode) and, when written, pareto,
    break_points, layers, effects. progress(stage, done, total) is called as ("plan", 0, 1) and
    ("plan", 1, 1) around the planning, ("jobs", k, n) per job of the shard (run, or found done by
    an earlier call), and ("done", 1, 1) after the merge."""
    summary = _sweep(study, out, shard=shard, verbose=verbose, progress=progress)
    tables = {}
    for name in ("results", "pareto", "break_points", "layers", "effects"):
        path = os.path.join(summary["out_dir"], name + ".csv")
        if os.path.exists(path):
            tables[name] = read_table(path)
    summary["tables"] = tables
    return summary
