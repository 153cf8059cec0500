// The global pose graph of workflows/multiview/merge.h (step 3): view poses part_from_rig, one
// relative-pose residual per pair weighted by its information, the anchor fixed. Ceres stays in
// pose_graph.cc. Internal to workflows/multiview/.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "core/rigid3.h"
#include "workflows/multiview/internal/pairwise.h"

namespace slshadow::multiview::internal {

struct GraphEdge {
  int a = 0, b = 0;                         // view indices
  Rigid3d a_from_b;                         // measured
  Matrix6d information = Matrix6d::Zero();  // of the left perturbation in frame a (pairwise.h)
};

struct GraphSolution {
  std::vector<Rigid3d> part_from_rig;  // one per view (inactive views keep their initial pose)
  // Per view: covariance of (w, dt), rad and mm, where the pose varies as R -> Exp(w) R,
  // t -> t + dt (so a point x_in_part moves by w x (x_in_part - t) + dt), relative to the anchor;
  // zero for the anchor and inactive views. covariance_ok is false when ceres::Covariance could not
  // compute it.
  std::vector<Matrix6d> covariance;
  bool covariance_ok = false;
  // The pairs' disagreement with the solution (OptimizePoseGraph): the reduced chi^2 of all
  // edges' whitened residuals, sum r^2 / (6 edges - 6 free views), and per view the same over
  // its own edges (each edge's expected r^2 the mean, 6 - 6 free views / edges). A pair's
  // information J^T W J / sigma^2 assumes independent point errors; its residuals are correlated
  // and biased (a curved surface sampled twice, a weakly fixed direction), which shows as pairs
  // that disagree with each other beyond their stated information. Each view's covariance is
  // scaled by max(1, variance_factor, view_variance_factor[i]). 1 when there is no redundancy.
  double variance_factor = 1;
  std::vector<double> view_variance_factor;
  int iterations = 0;
  double initial_cost = 0, final_cost = 0;
};

// Minimises sum over edges of |S Log(P_a^-1 P_b M^-1)|^2, S^T S = information, Log = (rotation
// vector, translation) of the small discrepancy transform. Views with active[i] false are not
// optimised; edges must join active views; the anchor is held at its initial pose.
GraphSolution OptimizePoseGraph(const std::vector<Rigid3d>& initial,
                                const std::vector<bool>& active, int anchor,
                                const std::vector<GraphEdge>& edges, bool with_covariance);

// S with S^T S = information (eigen decomposition; negative round-off eigenvalues clamped).
Matrix6d SqrtInformation(const Matrix6d& information);

// The discrepancy P_a^-1 P_b M^-1 of one edge at the given poses (identity when consistent).
Rigid3d EdgeDiscrepancy(const std::vector<Rigid3d>& part_from_rig, const GraphEdge& edge);

}  // namespace slshadow::multiview::internal
