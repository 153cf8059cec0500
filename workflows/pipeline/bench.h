// `slshadow bench` (the command only parses and prints): the pipeline's speed on the demo, measured
// in one run against peers where a peer runs here. Every entry repeats its work and reports the
// median wall time (and the CPU time of that run), so a noisy machine moves figures less; ratios
// are taken within the run.
//
// Entries (the demo rig scanning the demo part, images rendered by the simulator in memory):
//   simulate     render 2 cameras x 38 patterns (ray casting + pattern passes; no encoding)
//   decode       DecodePatterns, Gray code + phase shift, both cameras; peer: OpenCV 4.6
//                GrayCodePattern's per-pixel decoding (shadow mask + getProjPixel) on the same
//                camera viewing an OpenCV-order Gray code, on one camera, scaled per pixel
//   reconstruct  decode + triangulate both cameras (camera-projector; in turn with parallel loops,
//                then concurrently one camera per core), and stereo; per-stage wall and CPU
//   compare      C2M of the stereo cloud against the ground-truth mesh (the whole Compare, then
//                CloudToMesh alone); peer: Open3D's RaycastingScene signed distance
//                (bench/c2m_peer/open3d_c2m.py, run by /usr/bin/python3) on the same cloud and
//                mesh; C2C of the stereo cloud's even points to its odd ones (~1 M each); peer:
//                Open3D's compute_point_cloud_distance. Where CloudCompare is installed, one more
//                entry repeats the C2C figure against CloudCompare's -C2C_DIST (its logged compute
//                time, file loading excluded; float coordinates)
#pragma once

#include <string>
#include <vector>

namespace slshadow::pipeline {

struct BenchOptions {
  int repetitions = 5;            // per entry; the median is reported
  std::vector<std::string> only;  // entry names to run; empty: all
  bool with_opencv = true;        // run the OpenCV peer (the slowest part of the bench)
  bool with_open3d = true;        // run the Open3D C2M peer (skipped with a message when absent)
  bool with_cloudcompare = true;  // run CloudCompare's C2C (skipped with a message when absent)
  void Check() const;
};

// One stage of an entry's median run (reconstruct: decode, rays, triangulate, filters, ...), summed
// over the cameras.
struct BenchStage {
  std::string name;
  double wall_s = 0;
  double cpu_s = 0;
};

struct BenchEntry {
  std::string name;
  std::string what;
  double median_wall_s = 0;
  double cpu_s = 0;       // CPU time of the median run
  double throughput = 0;  // in `unit`
  std::string unit;
  std::string peer;  // empty when none
  double peer_median_wall_s = 0;
  double peer_throughput = 0;
  double ratio = 0;                // throughput / peer throughput (per pixel), 0 without a peer
  std::vector<BenchStage> stages;  // of the median run; empty when the entry has none
};

std::vector<BenchEntry> RunBench(const BenchOptions& options);
std::string FormatBench(const std::vector<BenchEntry>& entries);

// The entries as JSON text (`slshadow bench --json FILE`; docs/formats.md, "Bench results"):
// {"format": "slshadow-bench", "version": 1, "repetitions": N, "entries": [{"name", "what",
// "median_wall_s", "cpu_s", "throughput", "unit", "peer", "peer_median_wall_s",
// "peer_throughput", "ratio", "stages": [{"name", "wall_s", "cpu_s"}]}]}. Numbers are written
// exactly (round-trip doubles); docs/benchmarks.md is rendered from such a file.
std::string BenchToJson(const std::vector<BenchEntry>& entries, const BenchOptions& options);

}  // namespace slshadow::pipeline
