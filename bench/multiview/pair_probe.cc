// Each pair of a demo project's neighbouring views (30 deg apart, and with PP_STEP=2 also 60 deg)
// registered by the merge's pairwise ICP (internal/pairwise.h) from its TRUE relative pose; its
// error about the turntable axis against the truth (projected onto the turntable model's
// direction with the pair's information as metric, as the pose graph sees it) and its stated
// 1-sigma. The graph cannot be better than its pairs: this separates the pairs' errors from the
// graph's (docs/benchmarks/log/2026-12-07-rotation-noise-2.md).
//   pair_probe ROOT SEED...   reads ROOT/recS/<view>/cloud.ply (slshadow merge --reconstructions),
//                             ROOT/sS/model/report.json (the truth), ROOT/sS/project/project.json
// Options by environment: PP_STEP (1: 30-deg pairs, 2: and 60-deg), PP_POINTS (icp_points),
// PP_ICPK (icp_normal_neighbors), PP_SHARE (icp_table_share), PP_K (normal_neighbors), PP_PCA=1
// (drop the cloud's normals), PP_NOWEIGHT=1, PP_RESID (icp_max_residual_sigmas), PP_VAR
// (icp_max_surface_variation).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include <tbb/parallel_for.h>
#include <nlohmann/json.hpp>

#include "bench/multiview/report_pose.h"
#include "core/point_cloud.h"
#include "core/rigid3.h"
#include "workflows/multiview/internal/pairwise.h"
#include "workflows/multiview/merge.h"

using slshadow::Rigid3d;
namespace mi = slshadow::multiview::internal;

namespace {
double Env(const char* n, double d) {
  const char* v = std::getenv(n);
  return v ? std::atof(v) : d;
}
}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: pair_probe ROOT SEED...\n");
    return 2;
  }
  const std::string root = argv[1];
  slshadow::multiview::MergeOptions o;
  o.icp_points = static_cast<int>(Env("PP_POINTS", o.icp_points));
  o.icp_noise_weights = Env("PP_NOWEIGHT", 0) == 0;
  o.icp_normal_neighbors = static_cast<int>(Env("PP_ICPK", o.icp_normal_neighbors));
  o.icp_table_share = Env("PP_SHARE", o.icp_table_share);
  o.normal_neighbors = static_cast<int>(Env("PP_K", o.normal_neighbors));
  o.icp_max_residual_sigmas = Env("PP_RESID", o.icp_max_residual_sigmas);
  o.icp_max_surface_variation = Env("PP_VAR", o.icp_max_surface_variation);
  const bool pca = Env("PP_PCA", 0) != 0;
  const int steps = static_cast<int>(Env("PP_STEP", 1));
  double sum2 = 0, sum_z2 = 0;
  int count = 0;
  for (int s = 2; s < argc; ++s) {
    const std::string seed = argv[s];
    nlohmann::json report, project;
    std::ifstream(root + "/s" + seed + "/model/report.json") >> report;
    std::ifstream(root + "/s" + seed + "/project/project.json") >> project;
    const auto& tt = project.at("rig").at("turntable");
    slshadow::TurntableAxis axis;
    axis.direction_in_rig = Eigen::Vector3d(tt["axis_direction"][0].get<double>(),
                                            tt["axis_direction"][1].get<double>(),
                                            tt["axis_direction"][2].get<double>());
    axis.point_in_rig_mm =
        Eigen::Vector3d(tt["axis_point_mm"][0].get<double>(), tt["axis_point_mm"][1].get<double>(),
                        tt["axis_point_mm"][2].get<double>());
    o.turntable = axis;
    const auto& views = report.at("views");
    const size_t n = views.size();
    std::vector<slshadow::PointCloud> clouds(n);
    std::vector<Rigid3d> truth(n);
    std::vector<mi::ViewGeometry> geo(n);
    tbb::parallel_for(size_t{0}, n, [&](size_t i) {
      const std::string name = views[i].at("name");
      truth[i] = slshadow::bench::ReportPose(views[i].at("part_from_rig_true"));
      slshadow::PointCloud c = slshadow::ReadPly(root + "/rec" + seed + "/" + name + "/cloud.ply");
      std::vector<bool> keep(c.size());
      for (size_t k = 0; k < c.size(); ++k)
        keep[k] = axis.direction_in_rig.dot(c.points[k] - axis.point_in_rig_mm) >= 0.5;
      clouds[i] = c.Select(keep);
      if (pca) clouds[i].normals.clear();
    });
    for (size_t i = 0; i < n; ++i) mi::PrepareView(clouds[i], o, &geo[i], &axis);
    const Eigen::Vector3d u = axis.direction_in_rig, c = axis.point_in_rig_mm;
    Eigen::Matrix<double, 6, 1> e;
    e.head<3>() = u;
    e.tail<3>() = c.cross(u);
    std::vector<std::string> lines(2 * n);
    tbb::parallel_for(size_t{0}, 2 * n, [&](size_t k) {
      const size_t a = k % n, b = (a + 1 + k / n) % n;
      if (k / n + 1 > static_cast<size_t>(steps)) return;
      const Rigid3d t = truth[a].Inverse() * truth[b];
      const mi::IcpOutcome r = mi::RegisterPair(geo[a], geo[b], t, o);
      const Rigid3d err = r.a_from_b * t.Inverse();
      Eigen::Matrix<double, 6, 1> x;
      x.head<3>() = slshadow::RotationVectorFromQuaternion(err.rotation);
      x.tail<3>() = err.translation;
      const double iee = e.dot(r.information * e);
      // The pair's table angle as the graph sees it: its error projected onto the turntable
      // direction with its information as metric (the translation held at the axis).
      const double w_u = e.dot(r.information * x) / iee * 180 / M_PI;
      const double sig = 1.0 / std::sqrt(iee) * 180 / M_PI;
      char buf[200];
      std::snprintf(buf, sizeof buf, "%zu-%zu %+.5f sig %.5f z %+.2f n %d", a, b, w_u, sig,
                    w_u / sig, r.correspondences);
      lines[k] = buf;
    });
    std::printf("seed %s:", seed.c_str());
    for (size_t k = 0; k < lines.size(); ++k) {
      if (lines[k].empty()) continue;
      std::printf(" [%s]", lines[k].c_str());
      double w, sg;
      std::sscanf(lines[k].c_str(), "%*s %lf sig %lf", &w, &sg);
      sum2 += w * w;
      sum_z2 += (w / sg) * (w / sg);
      ++count;
    }
    std::printf("\n");
  }
  std::printf("RMS pair angle error %.5f deg, RMS z %.2f over %d pairs\n", std::sqrt(sum2 / count),
              std::sqrt(sum_z2 / count), count);
  return 0;
}
