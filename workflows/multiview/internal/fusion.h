// Fusion of registered views into one cloud (workflows/multiview/merge.h, step 4): cubic cells in
// the part frame, surfaces within a cell split by normal, each point weighted by its own noise
// (the view's, raised at edges and grazing incidence), views' heights along the normal compared
// within their noise; then each point one view alone gave checked against the other views'
// points around it. Internal to workflows/multiview/.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "core/rigid3.h"
#include "workflows/multiview/merge.h"

namespace slshadow::multiview::internal {

struct FusionView {
  int view = 0;                                           // index reported in point_view
  const std::vector<Eigen::Vector3d>* points = nullptr;   // rig frame (camera at the origin)
  const std::vector<Eigen::Vector3d>* normals = nullptr;  // rig frame, unit
  // PCA surface variation per point (lambda_min / sum, internal/pairwise.h); null: all flat.
  const std::vector<float>* variation = nullptr;
  Rigid3d part_from_rig;
  double sigma_mm = 0;  // noise along the normal of a flat point seen head-on, > 0
  // Points the view measured that are not fused (e.g. the table), rig frame; may be null. Only
  // the free-space check uses them.
  const std::vector<Eigen::Vector3d>* backdrop = nullptr;
};

struct FusionOptions {
  double cell_mm = 0;  // > 0
  double k_sigma = 4;
  double min_disagreement_mm = 0.05;
  // A point's noise: sigma_mm x (1 + min(v, 5 v_ref) / v_ref) / sqrt(max(cos i,
  // min_incidence_cos)), v its surface variation, v_ref the larger of edge_variation and 3 x the
  // view's median variation (its noise's share on flat surfaces), i the angle between its normal
  // and the ray to the camera. A point with v > v_ref is an edge point. <= 0: no edge factor.
  double edge_variation = 0.001;
  double min_incidence_cos = 0.1;
  // Radius of the check of single-view points against the other views (0: no check).
  double support_radius_mm = 0;
  double reject_radius_mm = 0;  // of the other views' points that can contradict one
  // Single-view points whose noise factor (above) is at least this are checked.
  double support_min_factor = 2.0;
  // A point one view alone gave is rejected when at least see_through_views other views saw
  // through it: all their points (backdrop included) within see_through_pixels of their point
  // spacing of its line of sight from their camera lie beyond it by more than
  // max(min_disagreement_mm, k_sigma x the combined noise). 0: no such check.
  int see_through_views = 2;
  double see_through_pixels = 1.5;
};

// Fills result->merged (points, normals, scalar fields), point_view, point_views,
// point_sigma_mm, disagree, input_points, disagree_points, superseded_points, rejected_points.
// Deterministic.
void FuseViews(const std::vector<FusionView>& views, const FusionOptions& options,
               MergeResult* result);

}  // namespace slshadow::multiview::internal
