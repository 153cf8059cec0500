#!/usr/bin/python3
"""The digital-model paper's virtual scanner, re-implemented as a same-run benchmark peer.

"A Digital Model for a Structured Light Scanning System" (../shared/seeds/000_409493f4bc767cf7.txt)
simulates a scan in Python with Open3D: the object is a point cloud; the points visible from a
viewpoint come from Open3D's hidden-point removal (Katz et al. 2007); cameras are pinholes with
radial distortion only (k1, k2, no skew); the projector is an inverse camera; shading is
Lambertian. This script follows that method on slshadow's benchmark workload
(bench/sim/sim_bench.cc, BM_PaperWorkloadWritten: the demo part at about 1 M triangles on its
table, the demo rig, 22 patterns x 2 cameras, 8-bit PGM written to disk):

  1. load     the part and table meshes in the rig frame (export_bench_part writes them)
  2. sample   mesh.sample_points_uniformly: N points on the part, the table at the same density
  3. hpr      PointCloud.hidden_point_removal from each camera's centre and from the projector's
              centre (points the projector does not see are in shadow), radius = 100 x the
              cloud's bounding-box diagonal (Open3D's documented choice)
  4. project  per camera: pinhole + radial k1, k2 into the camera; z-buffer splat (each visible
              point goes to its nearest pixel, the nearest point to the camera wins); the
              projector pixel of each winning point (inverse camera, radial k1, k2) and its
              Lambertian factor exposure * albedo * cos_p * (d_ref / d_p)^2, 0 if in shadow
  5. images   per pattern and camera: the pattern at the point's projector pixel (nearest) times
              the factor, splatted into an 8-bit image written as binary PGM

Geometry (steps 2-4) is done once and reused for all 22 patterns, the cheapest reading of the
paper's method. Holes: pixels inside the part's silhouette (slshadow's ray-cast object id,
silhouette_<camera>.pgm) that receive no point at all.

Usage: paper_scanner.py --scene DIR --rig RIG.yaml --out DIR --points N [--points N2 ...]
Prints one line per N with stage times (wall seconds) and the hole fraction; with --json FILE
writes them as JSON too.
"""
import argparse
import json
import os
import sys
import time

import numpy as np
import open3d as o3d

try:
    import yaml
except ImportError:  # pragma: no cover
    yaml = None


def quat_to_matrix(w, x, y, z):
    n = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


class Device:
    """A pinhole with radial distortion k1, k2 (the paper's model), pose cam_from_rig."""

    def __init__(self, node):
        self.name = node["name"]
        self.width = int(node["width"])
        self.height = int(node["height"])
        k = node["intrinsics"]
        self.fx, self.fy, self.cx, self.cy = (float(k[a]) for a in ("fx", "fy", "cx", "cy"))
        d = node.get("distortion", {}) or {}
        self.k1, self.k2 = float(d.get("k1", 0)), float(d.get("k2", 0))
        pose = node["cam_from_rig"]
        self.R = quat_to_matrix(*[float(v) for v in pose["rotation_quat_wxyz"]])
        self.t = np.array([float(v) for v in pose["translation_mm"]])
        self.centre = -self.R.T @ self.t  # optical centre in the rig frame

    def project(self, points):
        """Rig-frame points (n x 3) -> pixel u, v (float) and camera-frame points."""
        pc = points @ self.R.T + self.t
        z = pc[:, 2]
        xn, yn = pc[:, 0] / z, pc[:, 1] / z
        r2 = xn * xn + yn * yn
        f = 1 + self.k1 * r2 + self.k2 * r2 * r2
        return self.fx * xn * f + self.cx, self.fy * yn * f + self.cy, pc


def load_rig(path):
    with open(path) as f:
        node = yaml.safe_load(f)
    return [Device(c) for c in node["cameras"]], Device(node["projector"])


def load_scene(directory):
    objects, settings = [], {}
    with open(os.path.join(directory, "scene.txt")) as f:
        for line in f:
            parts = line.split()
            if len(parts) == 3:
                objects.append((parts[0], os.path.join(directory, parts[1]), float(parts[2])))
            elif len(parts) == 2:
                settings[parts[0]] = float(parts[1])
    return objects, settings


def make_patterns(width, height, count=22):
    """The first patterns of config/patterns/graycode_phase.yaml's kind (16 px period): 4-step
    phase shift along x, complementary Gray code of the x period index, 4-step phase along y."""
    x = np.arange(width)
    y = np.arange(height)
    out = []
    for k in range(4):
        row = 127.5 + 127.5 * np.cos(2 * np.pi * x / 16 - k * np.pi / 2)
        out.append(np.broadcast_to(np.round(row).astype(np.uint8), (height, width)))
    code = x // 16
    gray = code ^ (code >> 1)
    bits = int(np.ceil(np.log2(code.max() + 1)))
    for b in reversed(range(bits)):
        row = (((gray >> b) & 1) * 255).astype(np.uint8)
        out.append(np.broadcast_to(row, (height, width)))
        out.append(np.broadcast_to(255 - row, (height, width)))
    for k in range(4):
        col = 127.5 + 127.5 * np.cos(2 * np.pi * y / 16 - k * np.pi / 2)
        out.append(np.broadcast_to(np.round(col).astype(np.uint8)[:, None], (height, width)))
    return [np.ascontiguousarray(p) for p in out[:count]]


def read_pgm(path):
    with open(path, "rb") as f:
        data = f.read()
    fields, pos = [], 0
    while len(fields) < 4:  # P5 width height maxval, whitespace separated
        while data[pos:pos + 1].isspace():
            pos += 1
        start = pos
        while not data[pos:pos + 1].isspace():
            pos += 1
        fields.append(data[start:pos])
    w, h = int(fields[1]), int(fields[2])
    return np.frombuffer(data, np.uint8, w * h, pos + 1).reshape(h, w)


def write_pgm(path, image):
    with open(path, "wb") as f:
        f.write(b"P5\n%d %d\n255\n" % (image.shape[1], image.shape[0]))
        f.write(image.tobytes())


def run(args, n_points, meshes, settings, cameras, projector, patterns, silhouettes):
    t = {}
    t0 = time.perf_counter()
    # 2. sample: N points on the part, the other objects at the same density
    part_area = meshes[0][1].get_surface_area()
    clouds, albedo = [], []
    for name, mesh, a in meshes:
        n = n_points if not clouds else int(round(args.table_density * n_points * mesh.get_surface_area() / part_area))
        if n == 0:
            continue
        pcd = mesh.sample_points_uniformly(number_of_points=n, use_triangle_normal=True)
        clouds.append(pcd)
        albedo.append(np.full(n, a))
    cloud = o3d.geometry.PointCloud()
    for c in clouds:
        cloud += c
    points = np.asarray(cloud.points)
    normals = np.asarray(cloud.normals)
    albedo = np.concatenate(albedo)
    t["sample"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    # 3. hidden-point removal from every device's centre
    radius = 100 * np.linalg.norm(cloud.get_max_bound() - cloud.get_min_bound())
    visible = []
    for dev in cameras + [projector]:
        _, idx = cloud.hidden_point_removal(dev.centre, radius)
        visible.append(np.asarray(idx, dtype=np.int64))
    t["hpr"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    # projector (inverse camera): every lit point's projector pixel and Lambertian factor
    lit = np.zeros(len(points), bool)
    lit[visible[-1]] = True
    d_ref = settings.get("reference_distance_mm", 500.0)
    exposure = settings.get("exposure", 0.8)
    # 4. per camera: project, z-buffer splat
    splats = []
    for ci, cam in enumerate(cameras):
        idx = visible[ci]
        u, v, pc = cam.project(points[idx])
        px, py = np.rint(u).astype(np.int64), np.rint(v).astype(np.int64)
        ok = (pc[:, 2] > 0) & (px >= 0) & (px < cam.width) & (py >= 0) & (py < cam.height)
        idx, px, py, depth = idx[ok], px[ok], py[ok], np.linalg.norm(pc[ok], axis=1)
        pixel = py * cam.width + px
        order = np.lexsort((depth, pixel))  # by pixel, nearest first
        pixel, idx = pixel[order], idx[order]
        first = np.ones(len(pixel), bool)
        first[1:] = pixel[1:] != pixel[:-1]
        pixel, idx = pixel[first], idx[first]  # the nearest point of each pixel wins
        # projector pixel and shading of the winners
        pu, pv, pp = projector.project(points[idx])
        qx, qy = np.rint(pu).astype(np.int64), np.rint(pv).astype(np.int64)
        in_proj = lit[idx] & (pp[:, 2] > 0) & (qx >= 0) & (qx < projector.width) & (qy >= 0) & (qy < projector.height)
        to_proj = projector.centre - points[idx]
        d_p = np.linalg.norm(to_proj, axis=1)
        cos_p = np.abs(np.einsum("ij,ij->i", normals[idx], to_proj)) / d_p
        factor = np.where(in_proj, exposure * 255.0 * albedo[idx] * cos_p * (d_ref / d_p) ** 2, 0.0)
        qflat = np.where(in_proj, np.clip(qy, 0, projector.height - 1) * projector.width + np.clip(qx, 0, projector.width - 1), 0)
        splats.append((pixel, factor.astype(np.float32), qflat))
    t["project"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    # 5. images: pattern lookup, shade, splat, write
    os.makedirs(args.out, exist_ok=True)
    for pi, pattern in enumerate(patterns):
        flat = pattern.reshape(-1)
        for ci, cam in enumerate(cameras):
            pixel, factor, qflat = splats[ci]
            image = np.zeros(cam.width * cam.height, np.uint8)
            image[pixel] = np.clip(np.rint(factor * flat[qflat].astype(np.float32) / 255.0), 0, 255).astype(np.uint8)
            write_pgm(os.path.join(args.out, "%s_%02d.pgm" % (cam.name, pi)), image.reshape(cam.height, cam.width))
    t["images"] = time.perf_counter() - t1
    t["total"] = time.perf_counter() - t0
    # holes inside the part's silhouette
    holes, inside = 0, 0
    for ci, cam in enumerate(cameras):
        covered = np.zeros(cam.width * cam.height, bool)
        covered[splats[ci][0]] = True
        sil = silhouettes[ci].reshape(-1) > 0
        holes += int(np.count_nonzero(sil & ~covered))
        inside += int(np.count_nonzero(sil))
    return {"points_part": n_points, "points_total": len(points), "hole_fraction": holes / inside,
            "seconds": t}


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", required=True, help="directory written by export_bench_part")
    p.add_argument("--rig", required=True, help="rig YAML (docs/formats.md)")
    p.add_argument("--out", required=True, help="output directory for the PGM images")
    p.add_argument("--points", type=int, nargs="+", required=True, help="points sampled on the part")
    p.add_argument("--patterns", type=int, default=22)
    p.add_argument("--table-density", type=float, default=1.0,
                   help="point density on the other objects (the table) relative to the part's; 0 leaves them out")
    p.add_argument("--json", help="write the results as JSON here")
    args = p.parse_args()

    t0 = time.perf_counter()
    objects, settings = load_scene(args.scene)
    meshes = []
    for name, path, a in objects:
        mesh = o3d.io.read_triangle_mesh(path)
        if not mesh.has_triangles():
            sys.exit("paper_scanner: %s has no triangles" % path)
        meshes.append((name, mesh, a))
    cameras, projector = load_rig(args.rig)
    silhouettes = [read_pgm(os.path.join(args.scene, "silhouette_%s.pgm" % c.name)) for c in cameras]
    patterns = make_patterns(projector.width, projector.height, args.patterns)
    load_s = time.perf_counter() - t0
    print("load (meshes %s, rig, patterns): %.2f s" % ([m[1].triangles.__len__() for m in meshes], load_s))
    results = []
    for n in args.points:
        r = run(args, n, meshes, settings, cameras, projector, patterns, silhouettes)
        r["seconds"]["load"] = load_s
        r["seconds"]["total_with_load"] = r["seconds"]["total"] + load_s
        s = r["seconds"]
        print("N=%d (total %d points): sample %.2f s, hpr %.2f s, project %.2f s, images %.2f s; "
              "total %.2f s (+ load %.2f s = %.2f s); holes in part silhouette %.1f %%"
              % (n, r["points_total"], s["sample"], s["hpr"], s["project"], s["images"], s["total"], load_s,
                 s["total_with_load"], 100 * r["hole_fraction"]), flush=True)
        results.append(r)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
