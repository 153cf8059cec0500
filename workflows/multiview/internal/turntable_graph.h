// The pose graph on the turntable's model (workflows/multiview/merge.h, step 3): a table view's
// pose is not 6 free unknowns but follows from the table's axis (direction and a point, in the rig
// frame) and its own table angle, so a systematic pair error can only bend one angle per view and
// the shared axis, not the views' other five directions. Hand-placed views keep 6 free unknowns.
// Ceres stays in turntable_graph.cc. Internal to workflows/multiview/.
//
// Model: part_from_rig_i = M * Turn(u, c, theta_i)^-1 for a table view i, Turn the rotation by
// theta about the line through c along u (TurntableAxis::RigFromTableTurn), M a fixed transform
// (the reference table view's initial pose times its initial turn; M is the gauge: any global
// motion of all views is absorbed by it). Unknowns: u (unit, 2 DOF), c (2 DOF, across the axis),
// every table view's theta except the reference view's, every hand view's pose. Afterwards all
// poses are moved by one rigid motion so that the anchor keeps its initial pose (the part frame).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "core/rigid3.h"
#include "workflows/multiview/internal/pose_graph.h"

namespace slshadow::multiview::internal {

struct TableModel {
  Eigen::Vector3d direction_in_rig = Eigen::Vector3d::UnitY();  // the axis to start from
  Eigen::Vector3d point_in_rig_mm = Eigen::Vector3d::Zero();
  std::vector<double> angle_rad;  // per view: its true table angle to start from; NaN: by hand
  // 0: plain least squares. Else a Huber loss on each pair's whitened residual norm, its corner at
  // robust_k x the median norm of a first plain solve.
  double robust_k = 3.0;
  // Hold the axis (direction_in_rig, point_in_rig_mm) as given: only the angles (and hand views'
  // poses) are fitted.
  bool fix_axis = false;
};

struct TableFit {
  Eigen::Vector3d direction_in_rig = Eigen::Vector3d::UnitY();
  Eigen::Vector3d point_in_rig_mm = Eigen::Vector3d::Zero();  // the point nearest the initial one
  std::vector<double> angle_rad;        // fitted true table angle per view (NaN: hand or inactive)
  std::vector<double> sigma_angle_deg;  // 1-sigma, relative to the reference view
  int reference = -1;                   // the table view whose angle is held
  double sigma_direction_deg = 0, sigma_point_mm = 0;  // worst axis, 1-sigma
  // Reduced chi^2 of the pairs' whitened residuals at the solution (sum r^2 / (6 edges -
  // unknowns)); the covariances are scaled by max(1, it), so a systematic pair error widens them.
  double variance_factor = 1;
  double huber_corner = 0;  // 0: no robust loss
};

// Whether the model applies: at least two active table views whose angles differ by > 1 deg.
bool TableModelApplies(const TableModel& model, const std::vector<bool>& active);

// As OptimizePoseGraph (same edges, same GraphSolution, covariances relative to the anchor), on
// the model. `fit` receives the axis and angles.
GraphSolution OptimizeTurntableGraph(const std::vector<Rigid3d>& initial,
                                     const std::vector<bool>& active, int anchor,
                                     const std::vector<GraphEdge>& edges, const TableModel& model,
                                     bool with_covariance, TableFit* fit);

}  // namespace slshadow::multiview::internal
