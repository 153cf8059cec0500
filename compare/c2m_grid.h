// Signed point-to-mesh distances for many clouds measured against one mesh (a sweep's ground
// truth, workflows/studies/sweep_reuse.h GroundTruthScorer): compare::MeshDistance's results, bit
// for bit, from a uniform grid of small cells near the surface, each holding the few triangles that
// can be the closest one for a point in it.
//
// A cell's candidates: with c its centre, r its half diagonal and U = |c - mesh| + r, every point
// of the cell lies within U of the triangle closest to c, so its own closest triangle (and every
// triangle tied with it) has a lower bound of its distance to the cell (box gap, plane and edge
// planes) of at most U. The candidates are kept sorted by that bound: a point stops at the first
// whose bound exceeds its best distance so far. The result is the smallest squared distance of
// compare::ClosestPointOnTriangle over all triangles, ties to the lowest triangle index, and its
// sign from the same angle-weighted pseudo-normals: what MeshDistance::Closest returns, whatever
// the cell. Cells too far from the surface (U > 4 cells) or with too many candidates, and points
// outside the grid, are answered by MeshDistance itself.
//
// Cells are built on demand (Prepare for given points, BuildMissed for those SignedDistances
// found unbuilt) and kept: the clouds of a noise sweep fall in the same cells job after job.
#pragma once

#include "compare/mesh_distance.h"
#include "core/mesh.h"

#include <Eigen/Core>

#include <cstdint>
#include <memory>
#include <vector>

namespace slshadow::compare {

class C2mGrid {
 public:
  // `distance` must be built from `mesh` and outlive the grid. Cells are as large as the mesh's
  // median longest edge. With the clouds' point spacing above a third of that (fewer than ~9
  // points of a cloud per cell: the demo's part seen by the quarter-size rig, a tessellated
  // sphere), the cells would not repay their building: no grid then (enabled() false, every
  // point answered by `distance`).
  C2mGrid(const TriangleMesh& mesh, const compare::MeshDistance& distance,
          double point_spacing_mm = 0);
  ~C2mGrid();

  // Builds the cells that `points` fall in and that are not built yet (parallel). Not to be
  // called while SignedDistances runs.
  void Prepare(const std::vector<Eigen::Vector3d>& points);

  // Builds the cells that earlier SignedDistances calls found unbuilt (their points were answered
  // by MeshDistance), as Prepare would have for those points. Not to be called while
  // SignedDistances runs.
  void BuildMissed();

  // distance.Closest(points[i]).signed_distance_mm for every point, into (*out)[i] (resized);
  // cells not built are answered by `distance` (and noted for BuildMissed). Thread-safe (const).
  void SignedDistances(const std::vector<Eigen::Vector3d>& points, std::vector<double>* out) const;

  bool enabled() const;
  size_t built_cells() const;  // including those answered by MeshDistance
  size_t far_cells() const;    // built, but answered by MeshDistance
  double cell_mm() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace slshadow::compare
