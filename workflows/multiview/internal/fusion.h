// Fusion of registered views into one cloud (workflows/multiview/merge.h, step 4): cubic cells in
// the part frame, surfaces within a cell split by normal, views' heights along the normal compared
// within their noise. Internal to workflows/multiview/.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "core/rigid3.h"
#include "workflows/multiview/merge.h"

namespace slshadow::multiview::internal {

struct FusionView {
  int view = 0;                                           // index reported in point_view
  const std::vector<Eigen::Vector3d>* points = nullptr;   // rig frame
  const std::vector<Eigen::Vector3d>* normals = nullptr;  // rig frame, unit
  Rigid3d part_from_rig;
  double sigma_mm = 0;  // noise along the normal, > 0
};

// Fills result->merged (points, normals, scalar fields), point_view, point_views,
// point_sigma_mm, disagree, input_points, disagree_points. Deterministic.
void FuseViews(const std::vector<FusionView>& views, double cell_mm, double k_sigma,
               double min_disagreement_mm, MergeResult* result);

}  // namespace slshadow::multiview::internal
