#include "workflows/multiview/internal/hand_views.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>

#include "compare/registration.h"
#include "core/string_printf.h"
#include "workflows/multiview/internal/hand_sigma.h"

namespace slshadow::multiview::internal {
namespace {

Eigen::Matrix3d Skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d s;
  s << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return s;
}

double SqrtLargestEigenvalue(const Eigen::Matrix3d& c) {
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(0.5 * (c + c.transpose()));
  return std::sqrt(std::max(0.0, eig.eigenvalues().maxCoeff()));
}

}  // namespace

std::vector<bool> PoseByGlobalRegistration(const std::vector<ViewCloud>& views,
                                           const std::vector<ViewGeometry>& geo,
                                           const MergeOptions& options,
                                           std::vector<ViewPose>* poses) {
  const size_t n = views.size();
  std::vector<bool> posed(n, false);
  for (size_t i = 0; i < n; ++i) posed[i] = views[i].has_initial;
  if (!options.refine) {
    for (size_t i = 0; i < n; ++i) {
      if (!posed[i]) (*poses)[i].reason = "no initial pose, and registration is off";
    }
  }
  for (size_t i = 0; i < n && options.refine; ++i) {
    if (views[i].has_initial) continue;
    ViewPose& v = (*poses)[i];
    std::vector<Eigen::Vector3d> ref_points, ref_normals, cloud;
    for (size_t j = 0; j < n; ++j) {
      if (!posed[j]) continue;
      const Rigid3d& pose = (*poses)[j].part_from_rig;
      for (uint32_t k : geo[j].icp_sample) {
        ref_points.push_back(pose * (*geo[j].points)[k]);
        ref_normals.push_back(pose.rotation * geo[j].normals[k]);
      }
    }
    if (ref_points.empty()) {  // the first view to be posed defines the part frame
      v.part_from_rig = v.part_from_rig_initial = Rigid3d();
      posed[i] = true;
      continue;
    }
    for (uint32_t k : geo[i].icp_sample) cloud.push_back((*geo[i].points)[k]);
    compare::RegistrationOptions g = options.global;
    g.method = compare::RegistrationMethod::kGlobalIcp;
    const compare::RegistrationResult r = compare::Register(cloud, ref_points, ref_normals, g);
    if (!r.global_found || r.fitness < options.min_pair_fitness) {
      v.reason =
          StringPrintf("global registration found no pose (global fitness %.3f, ICP fitness %.3f)",
                       r.global_fitness, r.fitness);
      continue;
    }
    v.part_from_rig = v.part_from_rig_initial = r.reference_from_cloud;
    posed[i] = true;
  }
  return posed;
}

MergeOptions HandPairOptions(const MergeOptions& options) {
  MergeOptions hand = options;
  hand.icp_degenerate_ratio = 0;
  hand.icp_noise_tolerance = 0;
  return hand;
}

void WorstSigmas(const Matrix6d& covariance, const Rigid3d& part_from_rig,
                 const Eigen::Vector3d& centroid_in_rig, double* deg, double* mm) {
  const Eigen::Vector3d centroid = part_from_rig * centroid_in_rig;
  Eigen::Matrix<double, 3, 6> jac;  // displacement of the centroid per (w, dt)
  jac.leftCols<3>() = -Skew(centroid - part_from_rig.translation);
  jac.rightCols<3>() = Eigen::Matrix3d::Identity();
  *deg = SqrtLargestEigenvalue(covariance.topLeftCorner<3, 3>()) * 180.0 / M_PI;
  *mm = SqrtLargestEigenvalue(jac * covariance * jac.transpose());
}

std::vector<Matrix6d> HandCovariance(
    const std::vector<ViewGeometry>& geo, const std::vector<Rigid3d>& part_from_rig,
    const std::vector<GraphEdge>& edges, const std::vector<size_t>& edge_pair,
    const std::vector<IcpOutcome>& icp, const std::vector<bool>& weak_pair,
    const MergeOptions& pair_options, const MergeOptions& options, const GraphSolver& solve,
    std::vector<PairRegistration>* pairs) {
  if (options.hand_spread_blocks <= 0) return {};
  std::vector<GraphEdge> widened = edges;
  // The largest disagreement with the graph of a weak pair a loop tested (kept, or rejected for
  // it: graph_error_deg is set only where the graph had the pair), the floor of every weak pair no
  // loop tests (a bridge of the graph: without it its views lose their path to the anchor).
  double tested_rad = 0;
  for (size_t k = 0; k < pairs->size(); ++k)
    if (weak_pair[k]) tested_rad = std::max(tested_rad, (*pairs)[k].graph_error_deg * M_PI / 180);
  std::vector<double> floor_rad(pairs->size(), 0.0);
  for (size_t e = 0; e < edges.size(); ++e) {
    if (!weak_pair[edge_pair[e]]) continue;
    // Union-find over the other edges: a bridge when its two views stay apart.
    std::vector<int> root(geo.size());
    for (size_t i = 0; i < root.size(); ++i) root[i] = static_cast<int>(i);
    auto find = [&](int i) {
      while (root[static_cast<size_t>(i)] != i) i = root[static_cast<size_t>(i)];
      return i;
    };
    for (size_t f = 0; f < edges.size(); ++f)
      if (f != e) root[static_cast<size_t>(find(edges[f].a))] = find(edges[f].b);
    if (find(edges[e].a) != find(edges[e].b)) floor_rad[edge_pair[e]] = tested_rad;
  }
  std::vector<double> factor(pairs->size(), 0.0);
  std::vector<bool> floored(pairs->size(), false);
  const GraphSolution wide =
      WidenWeakEdges(geo, part_from_rig, edge_pair, icp, weak_pair, pair_options,
                     options.hand_spread_blocks, options.icp_degenerate_ratio, floor_rad, &widened,
                     &factor, &floored) > 0
          ? solve(widened, true)
          : GraphSolution{};
  for (size_t k = 0; k < pairs->size(); ++k) {
    (*pairs)[k].spread_factor = factor[k];
    (*pairs)[k].untested_floor_deg = floored[k] ? floor_rad[k] * 180 / M_PI : 0.0;
  }
  return wide.covariance_ok ? wide.covariance : std::vector<Matrix6d>{};
}

int WidestHandView(const std::vector<Matrix6d>& hand_cov, const std::vector<ViewCloud>& views,
                   const std::vector<bool>& active, int anchor,
                   const std::vector<Rigid3d>& part_from_rig, const std::vector<ViewGeometry>& geo,
                   const MergeOptions& options, std::vector<ViewPose>* poses) {
  int worst_view = -1;
  double worst_excess = 1.0, worst_deg = 0, worst_mm = 0;
  for (size_t i = 0; i < hand_cov.size(); ++i) {
    if (!active[i] || views[i].table_deg || static_cast<int>(i) == anchor) continue;
    double deg = 0, mm = 0;
    WorstSigmas(hand_cov[i], part_from_rig[i], geo[i].centroid, &deg, &mm);
    const double excess = std::max(
        options.max_initial_departure_deg > 0 ? deg / options.max_initial_departure_deg : 0.0,
        options.max_initial_departure_mm > 0 ? mm / options.max_initial_departure_mm : 0.0);
    if (excess <= worst_excess) continue;
    worst_excess = excess;
    worst_view = static_cast<int>(i);
    worst_deg = deg;
    worst_mm = mm;
  }
  if (worst_view >= 0) {
    (*poses)[static_cast<size_t>(worst_view)].reason = StringPrintf(
        "its pairs do not fix its pose: 1-sigma %.3f deg / %.3f mm from the spread of its pairs "
        "over %d blocks of their overlap (bounds %.3f deg / %.3f mm)",
        worst_deg, worst_mm, options.hand_spread_blocks, options.max_initial_departure_deg,
        options.max_initial_departure_mm);
  }
  return worst_view;
}

}  // namespace slshadow::multiview::internal
