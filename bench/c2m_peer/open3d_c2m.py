#!/usr/bin/env python3
"""Same-run peer for `slshadow bench`'s compare entry: Open3D's RaycastingScene distances.

Reads the cloud and mesh slshadow's benchmark wrote (raw little-endian arrays), then times, per
repetition, a fresh scene (add_triangles) plus compute_signed_distance, and the same with
compute_distance (unsigned), and prints one JSON line with the median wall seconds of each, the
CPU seconds of that run and the mean |distance| (a sanity check against slshadow's). Exit code 3 when Open3D is not installed.

  python3 bench/c2m_peer/open3d_c2m.py POINTS.f64 VERTICES.f64 TRIANGLES.u32 REPETITIONS

With `c2c` first, the cloud-to-cloud peer instead: PointCloud.compute_point_cloud_distance (a kd-tree
over the reference, nearest-neighbour distance per compared point), timed the same way:

  python3 bench/c2m_peer/open3d_c2m.py c2c COMPARED.f64 REFERENCE.f64 REPETITIONS
"""
import json
import sys
import time

try:
    import numpy as np
    import open3d as o3d
except ImportError as e:  # the benchmark prints the message and skips the peer
    print(f"open3d not available: {e}", file=sys.stderr)
    sys.exit(3)


def c2c():
    compared = np.fromfile(sys.argv[2], dtype="<f8").reshape(-1, 3)
    reference = np.fromfile(sys.argv[3], dtype="<f8").reshape(-1, 3)
    reps = int(sys.argv[4])
    a = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(compared))
    b = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(reference))
    times, mean = [], 0.0
    for _ in range(reps):
        c0 = time.process_time()
        t0 = time.perf_counter()
        d = np.asarray(a.compute_point_cloud_distance(b))
        times.append((time.perf_counter() - t0, time.process_time() - c0))
        mean = float(np.mean(d))
    times.sort()
    wall, cpu = times[len(times) // 2]
    print(json.dumps({"compared": len(compared), "reference": len(reference), "c2c_s": wall,
                      "c2c_cpu_s": cpu, "c2c_mean_mm": mean, "open3d": o3d.__version__}))
    return 0


def main():
    if len(sys.argv) == 5 and sys.argv[1] == "c2c":
        return c2c()
    if len(sys.argv) != 5:
        print(__doc__, file=sys.stderr)
        return 2
    points = np.fromfile(sys.argv[1], dtype="<f8").reshape(-1, 3).astype(np.float32)
    vertices = np.fromfile(sys.argv[2], dtype="<f8").reshape(-1, 3).astype(np.float32)
    triangles = np.fromfile(sys.argv[3], dtype="<u4").reshape(-1, 3)
    reps = int(sys.argv[4])
    query = o3d.core.Tensor(points, dtype=o3d.core.Dtype.Float32)
    verts = o3d.core.Tensor(vertices, dtype=o3d.core.Dtype.Float32)
    tris = o3d.core.Tensor(triangles, dtype=o3d.core.Dtype.UInt32)

    def run(signed):
        times, mean_abs = [], 0.0
        for _ in range(reps):
            c0 = time.process_time()
            t0 = time.perf_counter()
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(verts, tris)
            d = scene.compute_signed_distance(query) if signed else scene.compute_distance(query)
            d = d.numpy()
            times.append((time.perf_counter() - t0, time.process_time() - c0))
            mean_abs = float(np.mean(np.abs(d)))
        times.sort()
        return times[len(times) // 2], mean_abs  # the median wall time's run (wall, CPU)

    (signed_s, signed_cpu_s), signed_mean = run(True)
    (unsigned_s, unsigned_cpu_s), unsigned_mean = run(False)
    print(json.dumps({"points": len(points), "triangles": len(triangles), "signed_s": signed_s,
                      "signed_cpu_s": signed_cpu_s, "unsigned_s": unsigned_s,
                      "unsigned_cpu_s": unsigned_cpu_s, "signed_mean_abs_mm": signed_mean,
                      "unsigned_mean_abs_mm": unsigned_mean, "open3d": o3d.__version__}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
