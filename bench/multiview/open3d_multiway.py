#!/usr/bin/env python3
"""Same-run peer for bench/multiview/merge_bench: Open3D's multiway registration, run as its
tutorial does (docs: open3d.org "Multiway registration"): every cloud voxel-downsampled with
normals (hybrid search, radius 2 voxels, 30 neighbours); point-to-plane ICP for every pair
(coarse at 15 voxels, fine at 1.5 voxels) with its information matrix; a PoseGraph with odometry
edges (i, i+1) and uncertain loop-closure edges (all other pairs); global_optimization with
Levenberg-Marquardt, max_correspondence_distance 1.5 voxels, edge_prune_threshold 0.25,
reference_node 0.

The one change from the tutorial: it starts from the same initial poses slshadow gets (pose
graph nodes = the initial part_from_rig, each pairwise ICP from the initial relative pose)
instead of identity, so both solve the same problem.

  /usr/bin/python3 bench/multiview/open3d_multiway.py DIR

DIR holds view_XX.ply and poses.json ({"initial": [[16 numbers, row-major] per view],
"voxel_mm": v}); writes DIR/open3d_result.json with the optimised poses and the times. Exit code 3
when Open3D is not installed.
"""
import json
import os
import sys
import time

try:
    import numpy as np
    import open3d as o3d
except ImportError as e:
    print(f"open3d not available: {e}", file=sys.stderr)
    sys.exit(3)


def main():
    folder = sys.argv[1]
    with open(os.path.join(folder, "poses.json")) as f:
        spec = json.load(f)
    voxel = float(spec["voxel_mm"])
    initial = [np.array(m, dtype=float).reshape(4, 4) for m in spec["initial"]]
    n = len(initial)
    reg = o3d.pipelines.registration

    t0 = time.perf_counter()
    raw = [o3d.io.read_point_cloud(os.path.join(folder, f"view_{i:02d}.ply")) for i in range(n)]
    t_read = time.perf_counter() - t0

    t0 = time.perf_counter()
    pcds = []
    for pcd in raw:
        down = pcd.voxel_down_sample(voxel_size=voxel)
        down.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=voxel * 2, max_nn=30))
        # Orient towards the camera (the rig origin), as the views' normals face it.
        down.orient_normals_towards_camera_location(np.zeros(3))
        pcds.append(down)
    t_pre = time.perf_counter() - t0

    coarse = voxel * 15
    fine = voxel * 1.5
    t0 = time.perf_counter()
    pose_graph = reg.PoseGraph()
    for i in range(n):
        pose_graph.nodes.append(reg.PoseGraphNode(initial[i]))
    for s in range(n):
        for t in range(s + 1, n):
            init = np.linalg.inv(initial[t]) @ initial[s]  # target_from_source
            icp_coarse = reg.registration_icp(pcds[s], pcds[t], coarse, init,
                                              reg.TransformationEstimationPointToPlane())
            icp_fine = reg.registration_icp(pcds[s], pcds[t], fine, icp_coarse.transformation,
                                            reg.TransformationEstimationPointToPlane())
            info = reg.get_information_matrix_from_point_clouds(pcds[s], pcds[t], fine,
                                                                icp_fine.transformation)
            pose_graph.edges.append(
                reg.PoseGraphEdge(s, t, icp_fine.transformation, info, uncertain=(t != s + 1)))
    t_pair = time.perf_counter() - t0

    t0 = time.perf_counter()
    option = reg.GlobalOptimizationOption(max_correspondence_distance=fine,
                                          edge_prune_threshold=0.25, reference_node=0)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        reg.global_optimization(pose_graph, reg.GlobalOptimizationLevenbergMarquardt(),
                                reg.GlobalOptimizationConvergenceCriteria(), option)
    t_opt = time.perf_counter() - t0

    out = {
        "version": o3d.__version__,
        "voxel_mm": voxel,
        "points_after_downsampling": [len(p.points) for p in pcds],
        "pairs": n * (n - 1) // 2,
        "time_read_s": t_read,
        "time_downsample_normals_s": t_pre,
        "time_pairwise_s": t_pair,
        "time_optimize_s": t_opt,
        "time_s": t_pre + t_pair + t_opt,
        "poses": [node.pose.reshape(-1).tolist() for node in pose_graph.nodes],
    }
    with open(os.path.join(folder, "open3d_result.json"), "w") as f:
        json.dump(out, f)


if __name__ == "__main__":
    main()
