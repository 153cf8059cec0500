// An honest information for a pair of views with a hand-placed view (workflows/multiview/merge.h,
// step 3): a pair's information J^T W J / sigma^2 takes its ~5000 point residuals as independent,
// but they are correlated (the same reconstruction error over a whole face), and where the overlap
// leaves a direction weak (the rotation about the vertical of a part standing on a table) the
// pose along it is off by several of the stated sigmas (docs/benchmarks/log/
// 2026-12-07-hand-sigma.md). A table pair is held by the table's prior there; a hand pair is not.
// The spread of the pair's solution over spatial blocks of its overlap (a delete-one-block
// jackknife: blocks are contiguous runs of the Morton-ordered ICP sample, so patches of the
// surface, which carry the correlation) measures it; the information is widened along each
// eigen-direction where the spread exceeds what it states. The jackknife cannot see a bias common
// to the whole overlap, and a hand pair's cost can have its minimum 5 of its stated sigmas off
// along the weak direction (docs/benchmarks/log/2026-12-08-hand-views.md): only a loop of pairs
// shows that, so a weak pair no loop tests is given a floor (WidenWeakEdges' pair_floor_rad).
// Internal to workflows/multiview/.
#pragma once

#include <cstddef>
#include <vector>

#include "core/rigid3.h"
#include "workflows/multiview/internal/pairwise.h"
#include "workflows/multiview/internal/pose_graph.h"
#include "workflows/multiview/merge.h"

namespace slshadow::multiview::internal {

struct PairSpread {
  bool ok = false;  // false: too few correspondences (information left as given)
  // The pair's information at a_from_b (left perturbation in frame a, pairwise.h), widened: in the
  // coordinates of SolveStep (rotations about the matched points' centroid scaled by their RMS
  // radius), along each weak eigenvector k of the information (eigenvalue lambda_k below
  // weak_ratio x the largest), lambda_k divided by F_k = lambda_k x the jackknife variance along
  // it where F_k exceeds critical_factor (the stated information rejected at the 1 % level over
  // the six directions), else kept. Well-fixed directions keep theirs: there the spread is within
  // a small factor of the stated variance (F median 1.4, 90 % below 3.6, at most 14 over the 144
  // directions of multiview_merge_test's 24 pairs, none weak), along the weak ones of the hand
  // fixture 2.4 - 52 (docs/benchmarks/log/2026-12-07-hand-sigma.md).
  Matrix6d information = Matrix6d::Zero();
  double weakest_factor = 1;   // F along the weakest eigen-direction (variance ratio, raw)
  double max_factor = 1;       // the largest factor applied (1: none)
  double critical_factor = 0;  // chi^2_{K-1} 0.99^(1/6) quantile / (K - 1): 3.3 at K = 8
  // 1-sigma along the weakest eigen-direction (mm of displacement at the matched points' RMS
  // radius) stated by the information, and from the blocks' spread.
  double weakest_sigma_stated_mm = 0, weakest_sigma_spread_mm = 0;
  int blocks = 0;
  bool floored = false;  // the weakest direction's 1-sigma raised to the floor (floor_rad)
};

// The pair a <- b at a_from_b (a converged registration: the joint refinement's) with its final
// gate and residual bound: the full sample and each of `blocks` leave-one-block-out subsets of
// b's ICP sample re-solved from a_from_b by `iterations` Gauss-Newton steps (LinearizePair,
// correspondences found again each step; options as the pair's, no degenerate hold), the
// jackknife covariance (K - 1) / K sum (y_k - mean)(y_k - mean)^T of their solutions.
// floor_rad > 0: the weakest direction's 1-sigma is at least floor_rad x the matched points' RMS
// radius (a rotation of floor_rad about their centroid).
PairSpread BlockSpread(const ViewGeometry& a, const ViewGeometry& b, const Rigid3d& a_from_b,
                       double gate_mm, double max_residual_mm, const MergeOptions& options,
                       int blocks, double weak_ratio, double floor_rad = 0, int iterations = 3);

// The graph's edges (edge e from pair edge_pair[e], its ICP outcome icp[edge_pair[e]]) with the
// information of each pair marked in weak_pair widened by BlockSpread at the views' poses
// part_from_rig, its weakest direction floored at pair_floor_rad[k] (sized as the pairs; 0: none);
// pair_factor[k] and pair_floored[k] (sized as the pairs) set to the pair's weakest_factor and
// floored. Returns how many edges were widened.
int WidenWeakEdges(const std::vector<ViewGeometry>& geo, const std::vector<Rigid3d>& part_from_rig,
                   const std::vector<size_t>& edge_pair, const std::vector<IcpOutcome>& icp,
                   const std::vector<bool>& weak_pair, const MergeOptions& pair_options, int blocks,
                   double weak_ratio, const std::vector<double>& pair_floor_rad,
                   std::vector<GraphEdge>* edges, std::vector<double>* pair_factor,
                   std::vector<bool>* pair_floored);

}  // namespace slshadow::multiview::internal
