// Hand-placed views in MergeViews (workflows/multiview/merge.h): a view without an initial pose
// found by global registration against the views posed so far (step 1), the options of a pair
// with a hand view (nothing held at a prior, step 2), and the hand views' honest covariance from
// the spread of their weak pairs (hand_sigma.h), with which a view whose pairs do not fix its
// pose is left out, named (step 3). Internal to workflows/multiview/.
#pragma once

#include <functional>
#include <vector>

#include <Eigen/Core>

#include "core/rigid3.h"
#include "workflows/multiview/internal/pairwise.h"
#include "workflows/multiview/internal/pose_graph.h"
#include "workflows/multiview/merge.h"

namespace slshadow::multiview::internal {

// Step 1. Each view without has_initial, in input order, registered by compare::Register
// (options.global, method forced to global+icp) of its ICP sample against the ICP samples of the
// views posed so far, at their poses; the first view to be posed defines the part frame.
// (*poses)[i].part_from_rig and part_from_rig_initial are set where a pose is found (global
// registration found and ICP fitness at least min_pair_fitness), its reason where not. Returns
// which views are posed (views with has_initial included). When options.refine is false only
// the views with has_initial are posed (the others get their reason).
std::vector<bool> PoseByGlobalRegistration(const std::vector<ViewCloud>& views,
                                           const std::vector<ViewGeometry>& geo,
                                           const MergeOptions& options,
                                           std::vector<ViewPose>* poses);

// The options of a pair with a hand view: a hand view's initial pose (a guess, or the global
// registration's) is no prior to keep, so nothing is held (icp_degenerate_ratio 0) and the ICP
// does not stop at its noise level (icp_noise_tolerance 0).
MergeOptions HandPairOptions(const MergeOptions& options);

// 1-sigma of a view's pose from its covariance of (w, dt) (pose_graph.h): the rotation's worst
// axis, deg, and the displacement of the view's centroid (rig frame) along its worst axis, mm.
void WorstSigmas(const Matrix6d& covariance, const Rigid3d& part_from_rig,
                 const Eigen::Vector3d& centroid_in_rig, double* deg, double* mm);

// Solves the pose graph over the given edges (merge.cc: the six-unknown graph or the turntable's).
using GraphSolver =
    std::function<GraphSolution(const std::vector<GraphEdge>& edges, bool with_covariance)>;

// The hand views' honest covariance: the graph's edges (edge e from pair edge_pair[e]) with the
// information of each pair marked in weak_pair widened by the spread over
// options.hand_spread_blocks blocks of its overlap (WidenWeakEdges, pair_options: the hand
// pairs'), at the views' poses part_from_rig, solved by `solve` with the covariance.
// A weak pair no loop tests (a bridge of the graph over `edges`) gets a floor on its weakest
// direction's 1-sigma: the largest graph_error_deg of a weak pair (*pairs, weak_pair), i.e. the
// largest disagreement a loop showed (hand_sigma.h, merge.h hand_spread_blocks).
// (*pairs)[k].spread_factor and untested_floor_deg set for every pair (0: none). Empty when
// options.hand_spread_blocks is 0, no edge was widened, or the covariance failed.
std::vector<Matrix6d> HandCovariance(
    const std::vector<ViewGeometry>& geo, const std::vector<Rigid3d>& part_from_rig,
    const std::vector<GraphEdge>& edges, const std::vector<size_t>& edge_pair,
    const std::vector<IcpOutcome>& icp, const std::vector<bool>& weak_pair,
    const MergeOptions& pair_options, const MergeOptions& options, const GraphSolver& solve,
    std::vector<PairRegistration>* pairs);

// The active hand view (no table angle, not the anchor) whose 1-sigma from hand_cov exceeds
// max_initial_departure_deg / _mm by the largest factor, its reason set in (*poses)[i]; -1: none.
int WidestHandView(const std::vector<Matrix6d>& hand_cov, const std::vector<ViewCloud>& views,
                   const std::vector<bool>& active, int anchor,
                   const std::vector<Rigid3d>& part_from_rig, const std::vector<ViewGeometry>& geo,
                   const MergeOptions& options, std::vector<ViewPose>* poses);

}  // namespace slshadow::multiview::internal
