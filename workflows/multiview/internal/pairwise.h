// Per-view geometry (PCA normals, surface variation, k-d tree, samples) and the point-to-plane
// ICP between two views with its information matrix (workflows/multiview/merge.h, step 2).
// Internal to workflows/multiview/.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "core/kdtree.h"
#include "core/point_cloud.h"
#include "core/rigid3.h"
#include "workflows/multiview/merge.h"

namespace slshadow::multiview::internal {

using Matrix6d = Eigen::Matrix<double, 6, 6>;

// One view prepared for registration, in its rig frame. Borrows the cloud's points.
struct ViewGeometry {
  const std::vector<Eigen::Vector3d>* points = nullptr;
  std::vector<Eigen::Vector3d> normals;  // unit; the cloud's, else PCA oriented to the origin
  // Unit, oriented as `normals`: PCA over MergeOptions::icp_normal_neighbors (a copy of `normals`
  // when that is 0). The pairwise ICP's residuals and Jacobians use these.
  std::vector<Eigen::Vector3d> icp_normals;
  std::vector<float> variation;  // PCA lambda_min / (lambda_0 + lambda_1 + lambda_2)
  // Each point's noise variance along its normal, measured: the PCA plane fit's residual variance
  // lambda_min / (k - 3) over its k neighbours (mm^2), floored at a quarter of the view's median
  // (a few neighbours can fit a plane by chance). It weights the point in the ICP.
  std::vector<float> noise_var;
  std::unique_ptr<KdTree> tree;
  double spacing_mm = 0;       // median nearest-neighbour distance
  double area_spacing_mm = 0;  // sqrt(area per point), from the median k-neighbour radius
  // Flat points (variation below the bound), Morton order: evenly strided, and for a table view
  // a share (MergeOptions::icp_table_share) drawn with probability proportional to |g|,
  // g = n . (u x (p - c)), how far the point moves along its normal per radian of table turn.
  std::vector<uint32_t> icp_sample;
  // With MergeOptions::icp_table_angles (and a table axis, a share > 0): icp_sample is strided
  // only and this the sample with the table share, for the table angles' re-fit; else empty.
  std::vector<uint32_t> table_sample;
  std::vector<uint32_t> overlap_sample;  // evenly strided over all points
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
};

// Throws slshadow::Error when the cloud has fewer than normal_neighbors + 1 points. table_axis:
// the rig's turntable axis for a table view (its ICP sample then favours the points that fix the
// table angle), null for a view placed by hand.
void PrepareView(const PointCloud& cloud, const MergeOptions& options, ViewGeometry* view,
                 const TurntableAxis* table_axis = nullptr);

// Share of b's overlap samples that, moved by a_from_b, have a point of a within gate_mm whose
// normal is within max_normal_angle_deg of theirs.
double OverlapShare(const ViewGeometry& a, const ViewGeometry& b, const Rigid3d& a_from_b,
                    double gate_mm, double max_normal_angle_deg);

// A direction in which a pair's point-to-plane cost is (nearly) flat: the overlap does not fix it
// (a part made of planes slides along them). Gelfand et al. 2003, Zhang et al. 2016: an
// eigenvector of the normal-equation matrix, in coordinates where a rotation about the matched
// points' centroid is scaled by their RMS radius, whose eigenvalue is below
// icp_degenerate_ratio x the largest. The ICP does not move along it; the pair measures the
// prior (its initial relative pose: the table's) there, with the prior's information.
struct DegenerateDirection {
  bool rotation = false;  // a rotation about `axis` through the centroid, else a translation
  Eigen::Vector3d axis = Eigen::Vector3d::Zero();  // unit, in frame a
  double ratio = 0;                                // eigenvalue / the largest
};

struct IcpOutcome {
  Rigid3d a_from_b;
  // Information of the left perturbation (rotation vector, translation) of a_from_b in frame a:
  // J^T J / sigma^2 at the result.
  Matrix6d information = Matrix6d::Zero();
  double rms_mm = 0;   // point-to-plane
  double fitness = 0;  // matched share of b's ICP sample
  int correspondences = 0;
  int iterations = 0;
  bool converged = false;
  double last_motion_mm = 0;   // how far the last iteration moved the farthest sample point
  double gate_mm = 0;          // final correspondence gate
  double max_residual_mm = 0;  // final bound on |point-to-plane residual| (inf: none)
  Eigen::Vector3d centroid_in_a = Eigen::Vector3d::Zero();  // of the matched points
  double radius_mm = 0;  // RMS distance of the matched points from their centroid
  std::vector<DegenerateDirection> degenerate;  // at the result (empty: every direction fixed)
  double min_eigen_ratio = 0;  // the smallest eigenvalue / the largest, at the result
  // MergeOptions::icp_hold_gate_sigmas: the pair's free result was kept (nothing held although
  // a direction is weak); its re-linearisations then hold nothing either.
  bool hold_released = false;
};

// Point-to-plane ICP of b's ICP sample onto all of a's flat points from a_from_b_initial, each
// correspondence weighted by 1 / (its two points' noise variances). Degenerate directions
// (above) are held at a_from_b_initial, the prior, whose information there is that of
// options.prior_sigma_deg / prior_sigma_mm.
IcpOutcome RegisterPair(const ViewGeometry& a, const ViewGeometry& b,
                        const Rigid3d& a_from_b_initial, const MergeOptions& options);

// RegisterPair with MergeOptions::icp_hold_gate_sigmas: first without the hold; that result
// (hold_released) when it converged and departs from a_from_b_initial along its weak directions
// by at most icp_hold_gate_sigmas of the prior's 1-sigmas, else RegisterPair with the hold. As
// RegisterPair when the gate or icp_degenerate_ratio is 0.
IcpOutcome RegisterTablePair(const ViewGeometry& a, const ViewGeometry& b,
                             const Rigid3d& a_from_b_initial, const MergeOptions& options);

// One Gauss-Newton step of the pair's point-to-plane cost from a_from_b with the correspondences
// found there (gate, residual bound): a_from_b is the minimiser of the linearised cost and
// information its curvature J^T J / sigma^2 (the joint refinement of merge.cc re-linearises every
// pair at the graph's poses this way); along degenerate directions the minimiser is a_from_b_prior
// with the prior's information.
// `sample`: b's points to match (null: its ICP sample; MergeOptions::icp_table_angles passes
// its table sample).
IcpOutcome LinearizePair(const ViewGeometry& a, const ViewGeometry& b, const Rigid3d& a_from_b,
                         const Rigid3d& a_from_b_prior, double gate_mm, double max_residual_mm,
                         const MergeOptions& options,
                         const std::vector<uint32_t>* sample = nullptr);

// The same statistics at a fixed a_from_b (no iteration), with the given gate and residual bound.
IcpOutcome EvaluatePair(const ViewGeometry& a, const ViewGeometry& b, const Rigid3d& a_from_b,
                        double gate_mm, double max_residual_mm, const MergeOptions& options);

// The ICP step's well-scaled unknowns about the overlap's centroid c and radius l: y = tm x, with
// x = (rotation vector, translation) and y = (l x rotation, translation + c x rotation); ti its
// inverse (x = ti y).
void CentredScaling(const Eigen::Vector3d& c, double l, Matrix6d* tm, Matrix6d* ti);

}  // namespace slshadow::multiview::internal
