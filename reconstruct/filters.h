// Filters and normals on an organised reconstruction (DenseGrid). Each filter marks cells with
// its RejectReason and returns how many accepted cells it rejected; none moves a point.
//
// The filters keep their per-cell temporaries in per-thread buffers reused by the next call (no
// page faults on ~20 MB per call; the memory stays with the calling thread).
//
// Distances are measured in pixel footprints, r / focal_px at the cell's range r from the
// reference viewpoint, so thresholds mean the same at every stand-off.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "reconstruct/dense_grid.h"

namespace slshadow {

// Depth-discontinuity filter. A cell whose range differs from an accepted 4-neighbour's by more
// than max_jump_footprints footprints sits on a jump (both sides of it are marked: the wrong
// points of a scanner are there, mixed pixels and interpolated codes). Then every accepted cell
// within dilation_px (Chebyshev distance) of a marked cell is rejected too. A slope of angle a to
// the viewing ray changes range by tan(a) footprints per pixel, so 8 keeps surfaces up to ~83 deg.
int64_t FilterDepthDiscontinuities(DenseGrid& grid, double max_jump_footprints, int dilation_px);

// Statistical outlier removal on the grid (PCL's StatisticalOutlierRemoval with the k nearest
// neighbours taken among the accepted cells of a (2 window_radius_px + 1)^2 window): per cell the
// RMS distance to its `neighbors` nearest, in footprints; cells above mean + std_ratio * stddev
// of that value over all cells, and above min_distance_footprints, are rejected, and so are cells
// with no accepted neighbour at all. (The floor keeps the border of a perfect grid, whose cells
// have fewer close neighbours, from being taken for outliers when the spread is tiny.)
int64_t FilterStatisticalOutliers(DenseGrid& grid, int window_radius_px, int neighbors,
                                  double std_ratio, double min_distance_footprints = 3.0);

// Unit normals per cell (zero for rejected cells) from the cross product of the grid tangents
// (central differences, one-sided at borders and holes), oriented toward the viewpoint. A cell
// without a horizontal and a vertical accepted neighbour gets the unit vector toward the
// viewpoint; `fallback_count` (optional) receives how many did.
std::vector<Eigen::Vector3f> EstimateNormals(const DenseGrid& grid,
                                             int64_t* fallback_count = nullptr);
// The same into `normals` (resized; its capacity is reused across calls).
void EstimateNormals(const DenseGrid& grid, std::vector<Eigen::Vector3f>* normals,
                     int64_t* fallback_count = nullptr);

// Frees the calling thread's filter buffers (the next filter call allocates them again).
void ReleaseFilterScratch();

}  // namespace slshadow
