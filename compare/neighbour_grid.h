// Exact k-nearest-neighbour queries on surface scans queried in cloud order: the twin's diagnosis
// smoothes a scalar over the k nearest points of ~40 k query points in clouds of a few 100 k points
// (workflows/twin/diagnose.h, the part test), and the real - twin cloud difference asks for the
// nearest twin point. For such queries it answers what KdTree answers, with less work per query
// (docs/benchmarks/log/2026-11-25-shadow-speed.md has the figures).
//
// The points are binned in a uniform grid of cubic cells (a dense table of cell starts, the points
// copied in cell order), sized from the cloud so that a k-neighbourhood spans a few cells. A k
// query gathers the points of the cells that cover a ball around the query, radius a guess (the
// previous query's k-th distance: queries in cloud order are neighbours), grown until the ball
// holds k points; the k nearest of them are then the k nearest of the cloud. Distances are
// computed as KdTree computes them ((q - p) per axis, dx dx + dy dy + dz dz in double),
// so the result equals its KNearest / Nearest bit for bit (the same points in the same order)
// except for ties in distance, which KdTree breaks by its search order and this grid by
// the lower index.
#pragma once

#include <cstdint>
#include <limits>
#include <vector>

#include <Eigen/Core>

#include "core/kdtree.h"

namespace slshadow::compare {

class NeighbourGrid {
 public:
  // `points` is borrowed (it must outlive the grid, unmodified); `k_hint` the neighbourhood size
  // the cell size is chosen for. Non-finite points are never returned.
  explicit NeighbourGrid(const std::vector<Eigen::Vector3d>& points, int k_hint = 64);

  size_t size() const { return points_->size(); }

  // Per-thread state of KNearest: scratch buffers and the radius guess.
  struct Scratch {
    std::vector<Neighbor> candidates;
    double radius = 0;  // the last query's k-th distance (0: none yet)
  };
  // The k nearest points, sorted by distance, then by index (fewer when the grid holds fewer
  // finite points).
  void KNearest(const Eigen::Vector3d& query, int k, Scratch* scratch,
                std::vector<Neighbor>* out) const;
  // The nearest point strictly closer than max_distance (the lower index among equals), or false.
  bool Nearest(const Eigen::Vector3d& query, Neighbor* nearest,
               double max_distance = std::numeric_limits<double>::infinity()) const;

  double cell_mm() const { return cell_; }

 private:
  // Calls f(first, end) for each run of points (cell order) of the cells overlapping the box
  // [lo, hi].
  template <typename F>
  void ForEachRun(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, F&& f) const;
  void Bin(double cell);

  const std::vector<Eigen::Vector3d>* points_;
  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();
  double cell_ = 1;
  int nx_ = 0, ny_ = 0, nz_ = 0;
  std::vector<uint32_t> start_;          // per cell (x fastest), + 1: first point in cell order
  std::vector<Eigen::Vector3d> sorted_;  // the finite points in cell order
  std::vector<uint32_t> index_;          // sorted_[i] == (*points_)[index_[i]]
  double diagonal_ = 0;                  // of the bounding box
};

}  // namespace slshadow::compare
