// The general method behind compare::MedianSpacing (compare/statistics.h), for its tests and
// benchmarks.
#pragma once

#include <cstddef>
#include <vector>

#include <Eigen/Core>

namespace slshadow::compare::internal {

// MedianSpacing(points, max_samples), the same double, for any cloud: a uniform grid of cells from
// the bounding box (assuming a surface, ~4 points a cell) around the samples answers those whose
// nearest other point lies within a cell, one of cells 8 times larger those within 8 cells, a
// KdTree the others. MedianSpacing asks it when the cloud's array order does not follow space.
double MedianSpacingByCells(const std::vector<Eigen::Vector3d>& points, size_t max_samples);

// What MedianSpacing tries first, for a cloud whose array order follows space (a scan's cloud,
// in grid order): the nearest-neighbour distance of every stride-th point into (*spacings)[k]
// for point k stride (spacings sized by the caller), each the square root of
// (points[i] - points[j]).squaredNorm() minimised over the finite points j != i, as
// MedianSpacingByCells computes it. Returns false, with nothing to conclude, when a sample is not
// finite, when array neighbours lie much farther apart than the points' bounding box implies for
// a surface (not a scan's cloud), when more than 16 samples have no point within 7.5 cells
// (isolated: each is compared with every point), when the cells do not fit the hash's 21-bit
// coordinates, or, in a cloud with non-finite points, when a sample's nearest point lies beyond
// MedianSpacingByCells's grids (its tree answers those, and may not skip non-finite points as
// the grids do).
bool ScanOrderSpacings(const std::vector<Eigen::Vector3d>& points, size_t stride,
                       std::vector<double>* spacings);

}  // namespace slshadow::compare::internal
