// The free-space check of a registered pair (workflows/multiview/merge.h, step 2): a view's
// camera sees along straight lines from the origin of its rig frame, so where it measured a
// surface at range r along a line it saw through the space in front of it. At a right relative
// pose the other view's points lie on that surface or behind it (occluded), never in front of it
// by more than the noise; at a wrong one (a wrong table angle held where the overlap leaves a
// direction free: only a top face matches and the pair is degenerate about the axis) the other
// view's walls stand in space this view saw through (Huber & Hebert 2003, "Fully automatic
// registration of multiple 3D data sets": the visibility consistency of a match). The part's
// geometry cannot cause it, so it tells a degeneracy of the part (the self-occluding part's
// views share only horizontal faces, their other points hidden) from one a wrong start causes.
// Internal to workflows/multiview/.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "core/kdtree.h"
#include "core/rigid3.h"

namespace slshadow::multiview::internal {

// A view's lines of sight: each measured point's direction (x / z, y / z) from the camera and
// its range, the backdrop's (points measured but cropped from the model, e.g. the table) too.
struct Sightlines {
  std::vector<Eigen::Vector3d> direction;  // (x / z, y / z, 0) in the rig frame
  std::vector<float> range;                // distance from the camera, mm
  std::unique_ptr<KdTree> tree;
  double radius = 0;  // pixels x the angular point spacing (the pitch of the pixel grid)
};

// Builds the lines of sight of a view (points with z <= 0 are skipped); radius = pixels x the
// median distance of a direction to its 4th nearest. Fewer than 5 points: no tree (no say).
void BuildSightlines(const std::vector<Eigen::Vector3d>& points,
                     const std::vector<Eigen::Vector3d>* backdrop, double pixels, Sightlines* out);

struct SeenThrough {
  int judged = 0;   // points on lines the view measured (3 or more of its points within radius)
  int through = 0;  // of those, points in front of all of them by more than tol_mm
  double Share() const { return judged > 0 ? static_cast<double>(through) / judged : 0.0; }
};

// Which of `points` (moved into the view's rig frame by view_from_points) lie where the view
// saw through: every one of its measurements along the point's line of sight lies beyond the
// point by more than tol_mm.
SeenThrough CountSeenThrough(const Sightlines& view, const std::vector<Eigen::Vector3d>& points,
                             const std::vector<uint32_t>& indices, const Rigid3d& view_from_points,
                             double tol_mm);

}  // namespace slshadow::multiview::internal
