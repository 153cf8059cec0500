#include "workflows/twin/internal/diagnose_part.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include <Eigen/Dense>
#include <opencv2/core/utility.hpp>

#include "compare/neighbour_grid.h"
#include "core/kdtree.h"
#include "core/statistics.h"
#include "core/string_printf.h"

namespace slshadow::twin::internal {
namespace {

// The mean smoothed difference (real - twin distance to the part) of one mode's points: one
// cluster's worth of evidence per mode.
struct PartMode {
  nlohmann::json evidence;
  bool found = false;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  double mean_deviation_mm = 0;
  // Where the twin's local scatter is small: the points and their differences (minus the median).
  std::vector<Eigen::Vector3d> points;
  std::vector<double> values;
};

// The largest connected cluster of significant points of one mode.
struct Cluster {
  size_t points = 0;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  double peak = 0, mean_deviation = 0, pose_bound = 0;
};

// The median spacing of the compared points, from a sample of their nearest neighbours.
double PointSpacing(const compare::NeighbourGrid& real_grid,
                    const std::vector<Eigen::Vector3d>& real_points, const std::vector<size_t>& idx,
                    size_t step) {
  std::vector<Neighbor> nb;
  std::vector<double> s;
  compare::NeighbourGrid::Scratch scratch;
  for (size_t i = 0; i < idx.size(); i += std::max<size_t>(1, idx.size() / 500)) {
    real_grid.KNearest(real_points[idx[i]], 2, &scratch, &nb);
    if (nb.size() == 2) s.push_back(std::sqrt(nb[1].distance_sq));
  }
  return Median(std::vector<double>(s)) * static_cast<double>(step);
}

// Significant points linked within 4 point spacings, same sign only (a bump and a dent next to
// each other are two findings): the largest such cluster.
Cluster LargestCluster(const std::vector<Eigen::Vector3d>& sig, const std::vector<double>& sig_d,
                       const std::vector<double>& sig_bound, double spacing) {
  Cluster out;
  const KdTree sig_tree(sig);
  std::vector<Neighbor> nb;
  std::vector<int> label(sig.size(), -1);
  std::vector<size_t> size_of;
  for (size_t i = 0; i < sig.size(); ++i) {
    if (label[i] >= 0) continue;
    const int id = static_cast<int>(size_of.size());
    size_of.push_back(0);
    std::vector<size_t> stack = {i};
    label[i] = id;
    while (!stack.empty()) {
      const size_t j = stack.back();
      stack.pop_back();
      ++size_of.back();
      sig_tree.Radius(sig[j], 4 * spacing, &nb);
      for (const auto& q : nb) {
        // Same sign only: a bump and a dent next to each other are two findings.
        if (label[q.index] < 0 && sig_d[q.index] * sig_d[j] > 0) {
          label[q.index] = id;
          stack.push_back(q.index);
        }
      }
    }
  }
  const int best =
      static_cast<int>(std::max_element(size_of.begin(), size_of.end()) - size_of.begin());
  for (size_t i = 0; i < sig.size(); ++i) {
    if (label[i] != best) continue;
    ++out.points;
    out.centroid += sig[i];
    out.peak = std::max(out.peak, std::abs(sig_d[i]));
    out.mean_deviation += sig_d[i];
    out.pose_bound = std::max(out.pose_bound, sig_bound[i]);
  }
  if (out.points) {
    out.centroid /= static_cast<double>(out.points);
    out.mean_deviation /= static_cast<double>(out.points);
  }
  return out;
}

// One mode of the part cause: the real minus the twin distance to the part, each smoothed over
// k neighbours, its significant points and their largest cluster.
PartMode EvaluatePartMode(const ModeEvidence& m, const DiagnoseOptions& options) {
  PartMode out;
  if (m.real_points.size() < 100 || m.virtual_points.size() < 100) {
    out.evidence = {{"mode", m.mode}, {"detected", false}, {"compared_points", 0}};
    return out;
  }
  // Exact k-nearest neighbours on uniform grids (compare/neighbour_grid.h: the same
  // neighbours in the same order as KdTree, ~5 x cheaper at k = 64).
  const int k = options.smoothing_neighbors;
  const compare::NeighbourGrid real_grid(m.real_points, k), virt_grid(m.virtual_points, k);
  const size_t step = std::max<size_t>(1, m.real_points.size() / 40000);
  std::vector<size_t> idx;
  for (size_t i = 0; i < m.real_points.size(); i += step) idx.push_back(i);
  std::vector<double> d(idx.size()), spread(idx.size());
  cv::parallel_for_(cv::Range(0, static_cast<int>(idx.size())), [&](const cv::Range& range) {
    std::vector<Neighbor> nb;
    compare::NeighbourGrid::Scratch real_scratch, virt_scratch;
    for (int i = range.start; i < range.end; ++i) {
      const Eigen::Vector3d& p = m.real_points[idx[static_cast<size_t>(i)]];
      real_grid.KNearest(p, k, &real_scratch, &nb);
      double sr = 0;
      for (const auto& q : nb) sr += m.real_c2m[q.index];
      sr /= static_cast<double>(nb.size());
      virt_grid.KNearest(p, k, &virt_scratch, &nb);
      double sv = 0, svv = 0;
      for (const auto& q : nb)
        sv += m.virtual_c2m[q.index], svv += m.virtual_c2m[q.index] * m.virtual_c2m[q.index];
      sv /= static_cast<double>(nb.size());
      d[static_cast<size_t>(i)] = sr - sv;
      // The twin's own local scatter: large at edges and mixed pixels, where the real scan
      // scatters too; such places say nothing about the part.
      spread[static_cast<size_t>(i)] =
          std::sqrt(std::max(0.0, svv / static_cast<double>(nb.size()) - sv * sv));
    }
  });
  const double spread_limit = 3 * Median(std::vector<double>(spread));
  const double med = Median(std::vector<double>(d)), sigma = Mad(d, med);
  const double thr = std::max(4 * sigma, options.part_min_mm);
  for (size_t i = 0; i < idx.size(); ++i) {
    if (spread[i] <= spread_limit)
      out.points.push_back(m.real_points[idx[i]]), out.values.push_back(d[i] - med);
  }
  // What the pose's uncertainty explains at each point.
  std::vector<double> pose_bound(idx.size(), 0.0);
  if (m.pose_sigma_mm) {
    cv::parallel_for_(cv::Range(0, static_cast<int>(idx.size())), [&](const cv::Range& r) {
      for (int i = r.start; i < r.end; ++i) {
        pose_bound[static_cast<size_t>(i)] =
            options.part_pose_sigmas * m.pose_sigma_mm(m.real_points[idx[static_cast<size_t>(i)]]);
      }
    });
  }
  std::vector<Eigen::Vector3d> sig;
  std::vector<double> sig_d, sig_bound;
  for (size_t i = 0; i < idx.size(); ++i) {
    if (std::abs(d[i] - med) > std::max(thr, pose_bound[i]) && spread[i] <= spread_limit) {
      sig.push_back(m.real_points[idx[i]]);
      sig_d.push_back(d[i] - med);
      sig_bound.push_back(pose_bound[i]);
    }
  }
  Cluster cluster;
  if (sig.size() >= 10) {
    cluster =
        LargestCluster(sig, sig_d, sig_bound, PointSpacing(real_grid, m.real_points, idx, step));
  }
  const double fraction = static_cast<double>(cluster.points) / static_cast<double>(idx.size());
  out.found = fraction >= options.part_min_fraction && cluster.points >= 20;
  out.centroid = cluster.centroid;
  out.mean_deviation_mm = cluster.mean_deviation;
  out.evidence = {
      {"mode", m.mode},
      {"compared_points", idx.size()},
      {"noise_sigma_mm", sigma},
      {"threshold_mm", thr},
      {"significant_points", sig.size()},
      {"clustered_points", cluster.points},
      {"clustered_fraction", fraction},
      {"mean_deviation_mm", cluster.mean_deviation},
      {"peak_deviation_mm", cluster.peak},
      {"centroid_in_rig_mm", {cluster.centroid.x(), cluster.centroid.y(), cluster.centroid.z()}},
      {"pose_bound_known", static_cast<bool>(m.pose_sigma_mm)},
      {"pose_bound_p95_mm", Percentile(pose_bound, 95)},
      {"pose_bound_at_cluster_mm", cluster.pose_bound},
      {"detected", out.found}};
  return out;
}

}  // namespace

// part: a deviation on the part's surface, found in every mode the same way and not explained
// by a calibration error.
Finding Part(const std::vector<ModeEvidence>& modes, const DiagnoseOptions& options,
             bool calibration_found) {
  Finding part;
  part.cause = "part";
  part.evidence["modes"] = nlohmann::json::array();
  std::vector<Eigen::Vector3d> centroids;
  std::vector<double> signs;
  std::vector<std::pair<std::vector<Eigen::Vector3d>, std::vector<double>>> mode_means;
  for (const ModeEvidence& m : modes) {
    PartMode mode = EvaluatePartMode(m, options);
    part.evidence["modes"].push_back(std::move(mode.evidence));
    mode_means.emplace_back(std::move(mode.points), std::move(mode.values));
    if (mode.found) {
      centroids.push_back(mode.centroid);
      signs.push_back(mode.mean_deviation_mm);
    }
  }
  // Consistent between modes: every other mode deviates the same way where the strongest
  // mode found its cluster (mean of its smoothed differences within 6 mm of that centroid at
  // least half the strongest mode's mean deviation, same sign).
  bool consistent = false;
  if (!centroids.empty()) {
    size_t primary = 0;
    for (size_t i = 1; i < centroids.size(); ++i) {
      if (std::abs(signs[i]) > std::abs(signs[primary])) primary = i;
    }
    consistent = true;
    for (size_t mi = 0; mi < mode_means.size(); ++mi) {
      const auto& [points, values] = mode_means[mi];
      double sum = 0;
      int64_t n = 0;
      for (size_t i = 0; i < points.size(); ++i) {
        if ((points[i] - centroids[primary]).norm() < 6.0) sum += values[i], ++n;
      }
      const double mean = n ? sum / static_cast<double>(n) : 0.0;
      part.evidence["modes"][mi]["mean_at_strongest_cluster_mm"] = mean;
      if (!(n > 0 && mean * signs[primary] > 0 && std::abs(mean) >= 0.5 * std::abs(signs[primary])))
        consistent = false;
    }
    centroids = {centroids[primary]};
    signs = {signs[primary]};
  }
  part.detected = consistent && !calibration_found;
  if (part.detected) {
    const auto& first = part.evidence["modes"][0];
    part.message = StringPrintf("deviation on the part's surface: %.3f mm mean, %.3f mm peak",
                                first["mean_deviation_mm"].get<double>(),
                                first["peak_deviation_mm"].get<double>()) +
                   StringPrintf(" around (%.1f, %.1f, %.1f) mm in the rig frame", centroids[0].x(),
                                centroids[0].y(), centroids[0].z()) +
                   (first["pose_bound_known"].get<bool>()
                        ? StringPrintf(" (the pose's uncertainty explains up to %.3f mm there)",
                                       first["pose_bound_at_cluster_mm"].get<double>())
                        : std::string(" (the pose's uncertainty is unknown)")) +
                   ", in every mode, not explained by the rig: the part differs from its model";
  } else if (consistent && calibration_found) {
    part.message = "surface deviations are explained by the calibration error";
  } else if (!centroids.empty()) {
    part.message = "a surface deviation in some modes only: not the part (a mode-specific error)";
  } else {
    part.message = "the real cloud follows the part as closely as the twin's";
  }
  return part;
}

}  // namespace slshadow::twin::internal
