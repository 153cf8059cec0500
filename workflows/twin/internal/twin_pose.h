// The part's pose refined on its own surface (`slshadow shadow`'s pose stage, issue 30).
//
// Objective, the one the pose is judged by: the mean Geman-McClure loss of the exact signed
// distances r_i from the real cloud's points to the part's triangles (compare::MeshDistance),
//   F(T) = mean_i rho(r_i(T) / s),  rho(u) = u^2 / (1 + u^2)   (bounded: an outlier counts <= 1),
// over a fixed set of points (those within `gate_mm` of the part at the starting pose) and a fixed
// scale s. Levenberg-Marquardt on the iteratively re-weighted normal equations, with the exact
// distance gradient (closest point to query point) as each point's normal; a step is taken only
// when F decreases. Graduated scale: s starts at `start_scale_mm`, so that the features which
// fix the in-plane pose of a part standing on a dominant plane (its walls) pull at the start,
// and halves after each converged stage down to `scale_sigmas` x the residuals' own robust sigma
// (1.4826 MAD; at least `min_scale_mm`). A small scale from the start leaves those walls' points as
// outliers: a pose slid in the plane then stays slid. The result is the better, at the final scale,
// of the refined pose and the starting one: the refinement never makes the pose worse by its
// objective.
//
// Directions the surface leaves unconstrained (a plane: the two in-plane translations and the
// rotation about its normal) are not moved: the step is solved in the normal matrix's eigenbasis
// and its components along eigenvalues below `weak_ratio` x the largest are dropped.
//
// The update is a small motion of the part frame about the used points' centroid c: q -> c +
// R(dw)(q - c) + dt, with J = [g, (q - c) x g] for a point q with distance gradient g.
// Uncertainty: the cluster-robust ("sandwich") covariance of (dt mm, dw rad),  A^-1 B A^-1  with
// A = sum psi'(r) J^T J (psi(r) = w r, w the IRLS weight) and B = sum over cells
// (sum w J r)(sum w J r)^T, the points grouped by
// `cell_mm` cells of the part frame: errors correlated within a cell (reconstruction ripple, edge
// bias) are not counted as independent evidence (Liang & Zeger 1986). Propagated to a point q
// with normal n: sigma(q) = sqrt(J Sigma J^T).
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include <Eigen/Core>

#include "compare/mesh_distance.h"
#include "core/mesh.h"
#include "core/rigid3.h"

namespace slshadow::twin::internal {

struct PoseRefineOptions {
  double gate_mm = 1.0;         // points farther than this at the starting pose are not used
  int max_points = 60000;       // an evenly strided subset of the cloud
  double start_scale_mm = 0.2;  // loss scale of the first stage
  double min_scale_mm = 0.002;  // floor of the final scale
  double scale_sigmas = 2.0;    // the final scale: this x the residuals' robust sigma
  int max_iterations = 12;      // LM iterations per stage
  double weak_ratio = 1e-5;     // eigenvalue / largest (rotations scaled by the cloud's radius)
  double cell_mm = 5.0;         // cells of correlated residuals, for the covariance
  // Stages whose scale exceeds coarse_factor x the final scale the residuals point to use every
  // coarse_stride-th point (1: all points in every stage).
  int coarse_stride = 4;
  double coarse_factor = 2.0;
};

struct PoseUncertainty {
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();  // (dt mm, dw rad)
  double sigma_translation_mm = 0;  // 1-sigma along the worst direction
  double sigma_rotation_deg = 0;    // 1-sigma about the worst axis
  // The directions the surface does not constrain, in words (e.g. "translation along (0.00,
  // 0.34, 0.94) of the rig frame"); empty when the pose is fully constrained.
  std::vector<std::string> weak_directions;
  int cells = 0;  // clusters the covariance is built on
  Eigen::Vector3d centroid_in_part = Eigen::Vector3d::Zero();  // c above
  // 1-sigma of the signed distance at part-frame point q with unit normal n due to the pose (the
  // weak directions left out: along them the pose is the starting one).
  double PointSigmaMm(const Eigen::Vector3d& q_in_part, const Eigen::Vector3d& n_in_part) const;
};

struct PoseRefinement {
  Rigid3d part_from_rig;
  double start_cost = 0, final_cost = 0;  // F at the final scale, starting and returned pose
  double scale_mm = 0;                    // the final scale s
  int points = 0;                         // points in the fixed set
  int stages = 0, iterations = 0, accepted_steps = 0, rejected_steps = 0;
  int coarse_stages = 0;    // stages run on the coarse subset (PoseRefineOptions::coarse_stride)
  bool kept_start = false;  // the first start was at least as good: returned unchanged
  double rms_mm = 0;        // RMS of r over the points with |r| < 3 s, at the returned pose
  PoseUncertainty uncertainty;
};

// The cost F (above) of `part_from_rig` at scale `scale_mm` over the points of `cloud_in_rig`
// within `gate_mm` of the part at that pose; for tests and the report.
double PoseCost(const TriangleMesh& part_surface, const std::vector<Eigen::Vector3d>& cloud_in_rig,
                const Rigid3d& part_from_rig, double scale_mm, double gate_mm = 1.0);

// Refines part_from_rig from the best of `starts` (e.g. the given pose and ICP's; the first one is
// "the start": the given pose when there is one), over the points within the gate at any start.
// `part_surface` in the part frame, the cloud in the rig frame. Returned: the refined pose when it
// beats every start at the final scale, else the best start (kept_start when that is the first).
// Fewer than 100 points within the gate: the first start, kept, with no uncertainty.
PoseRefinement RefinePoseOnSurface(const TriangleMesh& part_surface,
                                   const std::vector<Eigen::Vector3d>& cloud_in_rig,
                                   const std::vector<Rigid3d>& starts,
                                   const PoseRefineOptions& options = {});
// The same with the part's distance field already built (`part` of `part_surface`).
PoseRefinement RefinePoseOnSurface(const compare::MeshDistance& part,
                                   const TriangleMesh& part_surface,
                                   const std::vector<Eigen::Vector3d>& cloud_in_rig,
                                   const std::vector<Rigid3d>& starts,
                                   const PoseRefineOptions& options = {});

// How well one pose fits the cloud, before any refinement: over an evenly strided subset of at
// most `max_points` points of the cloud (rig frame), the share within `gate_mm` of the part and
// the median |signed C2M| of those.
struct PoseFit {
  int points = 0;            // points in the subset
  double fitness = 0;        // share of them within the gate
  double median_abs_mm = 0;  // median |r| of the points within the gate (NaN: none)
};
PoseFit MeasurePoseFit(const compare::MeshDistance& part,
                       const std::vector<Eigen::Vector3d>& cloud_in_rig,
                       const Rigid3d& part_from_rig, double gate_mm, int max_points);

// Whether the refinement can start from `fit` alone, with no wider search (ICP) first: nearly all
// points within the gate (>= 0.9) and their median |r| below a quarter of the first stage's
// scale, so every point pulls with nearly full weight from the start.
bool WithinRefinementBasin(const PoseFit& fit, const PoseRefineOptions& options = {});

// The refinement's figures for report.json's `pose.refinement` (docs/formats.md "Shadow report"):
// its objective and the pose's uncertainty; with a given pose, how far the returned pose moved
// from it, in mm, degrees and units of that uncertainty (its Mahalanobis length).
nlohmann::json PoseRefinementToJson(const PoseRefinement& refinement,
                                    const std::optional<Rigid3d>& given_part_from_rig);

}  // namespace slshadow::twin::internal
