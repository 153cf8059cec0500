// multiview::MergeViews against Open3D's multiway registration (bench/multiview/open3d_multiway.py)
// on the same clouds, from the same initial poses, in the same run: the synthetic turntable views
// of tests/multiview/synthetic_views.h (the demo part, 12 table angles, noise along the normal,
// initial poses perturbed by 0.5 deg and 1 mm), written as PLY and read back by both. Prints each
// one's pose errors against the truth (rotation; largest displacement of a view's points) and
// wall time, and the ratios. Figures: docs/benchmarks/log/2026-12-01-multiview-merge.md.
//
//   build/bench/multiview/merge_bench [--out DIR] [--views 12] [--spacing-mm 0.6]
//       [--noise-mm 0.02] [--voxel-mm 1.0] [--repetitions 3] [--no-peer]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/point_cloud.h"
#include "core/statistics.h"
#include "core/string_printf.h"
#include "tests/multiview/synthetic_views.h"
#include "workflows/multiview/merge.h"

namespace mv = slshadow::multiview;
using slshadow::Rigid3d;

namespace {

struct Errors {
  std::vector<double> rotation_deg, displacement_um;
};

double Median(std::vector<double> v) {  // core/statistics.h's nearest rank; 0 for none
  return v.empty() ? 0.0 : slshadow::Median(v);
}
double Max(const std::vector<double>& v) {
  return v.empty() ? 0.0 : *std::max_element(v.begin(), v.end());
}

Errors Compare(const std::vector<Rigid3d>& estimated, const mv::testing::TurntableScan& scan,
               const std::vector<slshadow::PointCloud>& clouds) {
  Errors e;
  for (size_t k = 1; k < estimated.size(); ++k) {  // view 0 is the fixed reference of both
    e.rotation_deg.push_back(mv::RotationErrorDeg(estimated[k], scan.part_from_rig[k]));
    e.displacement_um.push_back(
        1000.0 * mv::MaxDisplacementMm(estimated[k], scan.part_from_rig[k], clouds[k].points));
  }
  return e;
}

nlohmann::json Matrix(const Rigid3d& t) {
  const Eigen::Matrix4d m = t.ToMatrix();
  nlohmann::json a = nlohmann::json::array();
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) a.push_back(m(r, c));
  return a;
}

}  // namespace

int main(int argc, char** argv) {
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // lines survive a peer that is stopped
  std::filesystem::path out = std::filesystem::temp_directory_path() / "slshadow_merge_bench";
  mv::testing::TurntableScanOptions so;
  double voxel_mm = 1.0;
  int repetitions = 3;
  bool peer = true;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "merge_bench: %s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--out")
      out = next();
    else if (a == "--views")
      so.views = std::stoi(next());
    else if (a == "--spacing-mm")
      so.spacing_mm = std::stod(next());
    else if (a == "--noise-mm")
      so.noise_mm = std::stod(next());
    else if (a == "--voxel-mm")
      voxel_mm = std::stod(next());
    else if (a == "--repetitions")
      repetitions = std::max(1, std::stoi(next()));
    else if (a == "--no-peer")
      peer = false;
    else {
      std::fprintf(stderr, "merge_bench: unknown argument '%s'\n", a.c_str());
      return 2;
    }
  }
  std::filesystem::create_directories(out);
  const mv::testing::TurntableScan scan = mv::testing::MakeTurntableScan(so);
  const std::vector<Rigid3d> initial = mv::testing::PerturbedInitialPoses(scan, 0.5, 1.0, 7);
  nlohmann::json spec;
  spec["voxel_mm"] = voxel_mm;
  spec["initial"] = nlohmann::json::array();
  size_t points = 0;
  for (size_t k = 0; k < scan.clouds.size(); ++k) {
    slshadow::WritePly(out / slshadow::StringPrintf("view_%02zu.ply", k), scan.clouds[k],
                       {true, false});
    spec["initial"].push_back(Matrix(initial[k]));
    points += scan.clouds[k].size();
  }
  std::ofstream(out / "poses.json") << spec.dump();

  // Both read the same files.
  std::vector<slshadow::PointCloud> clouds;
  for (size_t k = 0; k < scan.clouds.size(); ++k)
    clouds.push_back(slshadow::ReadPly(out / slshadow::StringPrintf("view_%02zu.ply", k)));
  std::vector<mv::ViewCloud> views;
  for (size_t k = 0; k < clouds.size(); ++k)
    views.push_back(
        {slshadow::StringPrintf("view_%02zu", k), &clouds[k], initial[k], true, std::nullopt});
  std::printf(
      "%zu views, %zu points (spacing %.2f mm, noise %.3f mm), initial poses off by "
      "0.5 deg / 1 mm\n",
      views.size(), points, so.spacing_mm, so.noise_mm);

  std::vector<double> times;
  mv::MergeResult result;
  for (int r = 0; r < repetitions; ++r) {
    const auto t0 = std::chrono::steady_clock::now();
    result = mv::MergeViews(views);
    times.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  std::printf("%s", result.FullReport().c_str());
  std::vector<Rigid3d> ours;
  for (const auto& v : result.views) ours.push_back(v.part_from_rig);
  const Errors e = Compare(ours, scan, clouds);
  const double t_ours = Median(times);
  std::printf("\n%-10s %10s %10s %10s %10s %10s\n", "", "time s", "rot med", "rot max", "disp med",
              "disp max");
  std::printf("%-10s %10s %10s %10s %10s %10s\n", "", "", "deg", "deg", "um", "um");
  std::printf("%-10s %10.3f %10.5f %10.5f %10.2f %10.2f\n", "slshadow", t_ours,
              Median(e.rotation_deg), Max(e.rotation_deg), Median(e.displacement_um),
              Max(e.displacement_um));
  if (!peer) return 0;

  const std::string cmd = std::string("/usr/bin/python3 ") + SLSHADOW_SOURCE_DIR +
                          "/bench/multiview/open3d_multiway.py " + out.string();
  std::vector<double> peer_times;
  nlohmann::json o3d;
  for (int r = 0; r < repetitions; ++r) {
    const int rc = std::system(cmd.c_str());
    if (rc != 0) {
      std::printf("open3d peer failed (exit %d): skipped\n", rc);
      return 0;
    }
    std::ifstream(out / "open3d_result.json") >> o3d;
    peer_times.push_back(o3d["time_s"].get<double>());
  }
  std::vector<Rigid3d> theirs;
  for (const auto& m : o3d["poses"]) {
    Eigen::Matrix4d t;
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) t(r, c) = m[static_cast<size_t>(4 * r + c)].get<double>();
    theirs.push_back(Rigid3d::FromMatrix(t));
  }
  const Errors p = Compare(theirs, scan, clouds);
  const double t_peer = Median(peer_times);
  std::printf("%-10s %10.3f %10.5f %10.5f %10.2f %10.2f\n", "open3d", t_peer,
              Median(p.rotation_deg), Max(p.rotation_deg), Median(p.displacement_um),
              Max(p.displacement_um));
  std::printf(
      "open3d %s at a %.2f mm voxel (%d..%d points per view): down-sampling and "
      "normals %.2f s, %d pairwise ICPs %.2f s, global optimisation %.2f s\n",
      o3d["version"].get<std::string>().c_str(), voxel_mm,
      o3d["points_after_downsampling"].front().get<int>(),
      o3d["points_after_downsampling"].back().get<int>(),
      o3d["time_downsample_normals_s"].get<double>(), o3d["pairs"].get<int>(),
      o3d["time_pairwise_s"].get<double>(), o3d["time_optimize_s"].get<double>());
  std::printf(
      "ratios open3d / slshadow (median of %d runs each): time %.2fx, rotation error "
      "median %.2fx max %.2fx, displacement median %.2fx max %.2fx\n",
      repetitions, t_peer / t_ours, Median(p.rotation_deg) / Median(e.rotation_deg),
      Max(p.rotation_deg) / Max(e.rotation_deg),
      Median(p.displacement_um) / Median(e.displacement_um),
      Max(p.displacement_um) / Max(e.displacement_um));
  return 0;
}
