#include "workflows/multiview/internal/hand_sigma.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <tbb/parallel_for.h>
#include <Eigen/Eigenvalues>

namespace slshadow::multiview::internal {
namespace {

using Vector6d = Eigen::Matrix<double, 6, 1>;

// b's geometry with another ICP sample (Correspond reads b's points, normals, ICP normals, noise
// and sample; no tree: b is the moving view).
ViewGeometry WithSample(const ViewGeometry& b, std::vector<uint32_t> sample) {
  ViewGeometry s;
  s.points = b.points;
  s.normals = b.normals;
  s.icp_normals = b.icp_normals;
  s.variation = b.variation;
  s.noise_var = b.noise_var;
  s.icp_sample = std::move(sample);
  s.spacing_mm = b.spacing_mm;
  s.area_spacing_mm = b.area_spacing_mm;
  s.centroid = b.centroid;
  return s;
}

struct Solved {
  Rigid3d a_from_b;
  IcpOutcome last;
};

Solved Solve(const ViewGeometry& a, const ViewGeometry& b, const Rigid3d& start, double gate_mm,
             double max_residual_mm, const MergeOptions& options, int iterations) {
  Solved s{start, {}};
  for (int it = 0; it < iterations; ++it) {
    s.last = LinearizePair(a, b, s.a_from_b, s.a_from_b, gate_mm, max_residual_mm, options);
    if (s.last.correspondences < 7) break;
    s.a_from_b = s.last.a_from_b;
  }
  return s;
}

Vector6d LeftPerturbation(const Rigid3d& to, const Rigid3d& from) {
  const Rigid3d d = to * from.Inverse();
  Vector6d x;
  x.head<3>() = RotationVectorFromQuaternion(d.rotation);
  x.tail<3>() = d.translation;
  return x;
}

}  // namespace

PairSpread BlockSpread(const ViewGeometry& a, const ViewGeometry& b, const Rigid3d& a_from_b,
                       double gate_mm, double max_residual_mm, const MergeOptions& options,
                       int blocks, double weak_ratio, double floor_rad, int iterations) {
  PairSpread out;
  MergeOptions o = options;
  o.icp_degenerate_ratio = 0;  // solve all six: the spread is what is measured
  const Solved full = Solve(a, b, a_from_b, gate_mm, max_residual_mm, o, iterations);
  const size_t n = b.icp_sample.size();
  if (full.last.correspondences < 7 || blocks < 2 || n < static_cast<size_t>(blocks) * 8) {
    return out;
  }
  // The information at the full solution (LinearizePair's, all six solved).
  const Matrix6d h = full.last.information;
  const Eigen::Vector3d c = full.last.centroid_in_a;
  const double l = std::max(full.last.radius_mm, 1e-3);
  Matrix6d tm, ti;  // y = tm x, x = ti y (SolveStep's unknowns)
  CentredScaling(c, l, &tm, &ti);

  std::vector<Vector6d> y(static_cast<size_t>(blocks), Vector6d::Zero());
  std::vector<bool> good(static_cast<size_t>(blocks), false);
  tbb::parallel_for(0, blocks, [&](int k) {
    const size_t begin = n * static_cast<size_t>(k) / static_cast<size_t>(blocks);
    const size_t end = n * static_cast<size_t>(k + 1) / static_cast<size_t>(blocks);
    std::vector<uint32_t> sample;
    sample.reserve(n - (end - begin));
    for (size_t i = 0; i < n; ++i)
      if (i < begin || i >= end) sample.push_back(b.icp_sample[i]);
    const ViewGeometry sub = WithSample(b, std::move(sample));
    const Solved s = Solve(a, sub, full.a_from_b, gate_mm, max_residual_mm, o, iterations);
    if (s.last.correspondences < 7) return;
    y[static_cast<size_t>(k)] = tm * LeftPerturbation(s.a_from_b, full.a_from_b);
    good[static_cast<size_t>(k)] = true;
  });
  Vector6d mean = Vector6d::Zero();
  int used = 0;
  for (int k = 0; k < blocks; ++k)
    if (good[static_cast<size_t>(k)]) {
      mean += y[static_cast<size_t>(k)];
      ++used;
    }
  if (used < 2) return out;
  mean /= used;
  Matrix6d jack = Matrix6d::Zero();
  for (int k = 0; k < blocks; ++k)
    if (good[static_cast<size_t>(k)]) {
      const Vector6d d = y[static_cast<size_t>(k)] - mean;
      jack += d * d.transpose();
    }
  jack *= static_cast<double>(used - 1) / static_cast<double>(used);

  // A jackknife variance over K blocks is itself an estimate with K - 1 degrees of freedom: where
  // the stated information is right, lambda x spread is about chi^2_{K-1} / (K - 1), often above
  // 1 by chance. A direction is widened only where that hypothesis fails at the 1 % level over
  // the six directions (Bonferroni: 0.17 % each; the chi^2 quantile by Wilson-Hilferty), so a
  // well-constrained pair keeps its information.
  const double dof = static_cast<double>(used - 1);
  const double z = 2.935;  // the standard normal's 1 - 0.01 / 6 quantile
  const double wh = 1.0 - 2.0 / (9.0 * dof) + z * std::sqrt(2.0 / (9.0 * dof));
  out.critical_factor = wh * wh * wh;
  const Matrix6d hy = ti.transpose() * h * ti;
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(0.5 * (hy + hy.transpose()));
  const double largest = std::max(eig.eigenvalues().maxCoeff(), 1e-300);
  // The floor of the weakest direction's 1-sigma, as a displacement at the matched points' radius.
  const double floor_mm = floor_rad * l;
  const double cap =
      floor_mm > 0 ? 1.0 / (floor_mm * floor_mm) : std::numeric_limits<double>::infinity();
  Matrix6d widened = Matrix6d::Zero();
  for (int k = 0; k < 6; ++k) {
    const Vector6d u = eig.eigenvectors().col(k);
    const double lambda = std::max(eig.eigenvalues()[k], 0.0);
    const double spread = u.dot(jack * u);
    const double ratio = lambda * spread;
    const bool weak = lambda < weak_ratio * largest;
    const double factor = weak && ratio > out.critical_factor ? ratio : 1.0;
    const double kept = k == 0 ? std::min(lambda / factor, cap) : lambda / factor;
    widened += u * u.transpose() * kept;
    out.max_factor = std::max(out.max_factor, factor);
    if (k == 0) {
      out.floored = kept < lambda / factor;
      out.weakest_factor = ratio;
      out.weakest_sigma_stated_mm = lambda > 0 ? std::sqrt(1.0 / lambda) : 0.0;
      out.weakest_sigma_spread_mm = std::sqrt(std::max(spread, 0.0));
    }
  }
  out.information = tm.transpose() * widened * tm;
  out.information = 0.5 * (out.information + out.information.transpose());
  out.blocks = used;
  out.ok = true;
  return out;
}

int WidenWeakEdges(const std::vector<ViewGeometry>& geo, const std::vector<Rigid3d>& part_from_rig,
                   const std::vector<size_t>& edge_pair, const std::vector<IcpOutcome>& icp,
                   const std::vector<bool>& weak_pair, const MergeOptions& pair_options, int blocks,
                   double weak_ratio, const std::vector<double>& pair_floor_rad,
                   std::vector<GraphEdge>* edges, std::vector<double>* pair_factor,
                   std::vector<bool>* pair_floored) {
  int widened = 0;
  for (size_t e = 0; e < edges->size(); ++e) {
    const size_t k = edge_pair[e];
    if (!weak_pair[k]) continue;
    GraphEdge& edge = (*edges)[e];
    const size_t a = static_cast<size_t>(edge.a), b = static_cast<size_t>(edge.b);
    const PairSpread s =
        BlockSpread(geo[a], geo[b], part_from_rig[a].Inverse() * part_from_rig[b], icp[k].gate_mm,
                    icp[k].max_residual_mm, pair_options, blocks, weak_ratio, pair_floor_rad[k]);
    if (!s.ok) continue;
    (*pair_factor)[k] = s.weakest_factor;
    (*pair_floored)[k] = s.floored;
    edge.information = s.information;
    ++widened;
  }
  return widened;
}

}  // namespace slshadow::multiview::internal
