#include "compare/neighbour_grid.h"

#include <algorithm>
#include <cmath>

namespace slshadow::compare {
namespace {

// At most this many cells per point (and 2^24 in all): the table of cell starts stays small.
constexpr double kMaxCellsPerPoint = 4.0;
constexpr double kMaxCells = 16777216.0;
// Boxes are widened by this relative margin (and an absolute one) so that rounding in the cell
// arithmetic never leaves out a point on the ball's boundary.
constexpr double kMargin = 1e-9;

// A function object (inlined by the sorts, unlike a function pointer).
struct Less {
  bool operator()(const Neighbor& a, const Neighbor& b) const {
    return a.distance_sq < b.distance_sq || (a.distance_sq == b.distance_sq && a.index < b.index);
  }
};

}  // namespace

NeighbourGrid::NeighbourGrid(const std::vector<Eigen::Vector3d>& points, int k_hint)
    : points_(&points) {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  size_t finite = 0;
  for (const auto& p : points) {
    if (!p.allFinite()) continue;
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
    ++finite;
  }
  if (finite == 0) return;
  origin_ = lo;
  const Eigen::Vector3d extent = hi - lo;
  diagonal_ = extent.norm();
  // A scan is a surface: area ~ the product of the two largest extents. The cell is the radius of
  // a disc holding k_hint points, so a k-neighbourhood spans ~2-3 cells per axis. Rounding, holes
  // or folds only change the speed, never the result.
  double e[3] = {extent.x(), extent.y(), extent.z()};
  std::sort(e, e + 3);
  const double area = std::max(e[2] * e[1], 1e-12);
  const double n = static_cast<double>(finite);
  double cell = std::sqrt(std::max(1, k_hint) * area / (M_PI * n));
  cell = std::max({cell, diagonal_ * 1e-6, 1e-9});
  const auto cells = [&](double s) {
    return (std::floor(extent.x() / s) + 1) * (std::floor(extent.y() / s) + 1) *
           (std::floor(extent.z() / s) + 1);
  };
  const double max_cells = std::min(kMaxCells, kMaxCellsPerPoint * n + 4096);
  while (cells(cell) > max_cells) cell *= 1.25;
  Bin(cell);
  // Points per occupied cell: ~k_hint / pi x the share of a cell a surface crosses. Far off (a
  // cloud that is not one surface), re-binned once at the size that brings it near.
  size_t occupied = 0;
  for (size_t i = 0; i + 1 < start_.size(); ++i) occupied += start_[i + 1] > start_[i];
  const double per_cell = n / static_cast<double>(std::max<size_t>(1, occupied));
  const double target = 0.2 * std::max(1, k_hint);
  if (per_cell < 0.25 * target || per_cell > 4 * target) {
    cell *= std::sqrt(target / per_cell);
    cell = std::max({cell, diagonal_ * 1e-6, 1e-9});
    while (cells(cell) > max_cells) cell *= 1.25;
    Bin(cell);
  }
}

void NeighbourGrid::Bin(double cell) {
  cell_ = cell;
  const Eigen::Vector3d extent = [&] {
    Eigen::Vector3d hi = origin_;
    for (const auto& p : *points_) {
      if (p.allFinite()) hi = hi.cwiseMax(p);
    }
    return Eigen::Vector3d(hi - origin_);
  }();
  nx_ = static_cast<int>(std::floor(extent.x() / cell)) + 1;
  ny_ = static_cast<int>(std::floor(extent.y() / cell)) + 1;
  nz_ = static_cast<int>(std::floor(extent.z() / cell)) + 1;
  const size_t num_cells = static_cast<size_t>(nx_) * static_cast<size_t>(ny_) * nz_;
  const auto cell_of = [&](const Eigen::Vector3d& p) {
    const int ix = std::min(nx_ - 1, static_cast<int>((p.x() - origin_.x()) / cell));
    const int iy = std::min(ny_ - 1, static_cast<int>((p.y() - origin_.y()) / cell));
    const int iz = std::min(nz_ - 1, static_cast<int>((p.z() - origin_.z()) / cell));
    return (static_cast<size_t>(iz) * static_cast<size_t>(ny_) + static_cast<size_t>(iy)) *
               static_cast<size_t>(nx_) +
           static_cast<size_t>(ix);
  };
  start_.assign(num_cells + 1, 0);
  std::vector<uint32_t> cell_index(points_->size(), 0);
  size_t finite = 0;
  for (size_t i = 0; i < points_->size(); ++i) {
    const Eigen::Vector3d& p = (*points_)[i];
    if (!p.allFinite()) continue;
    const size_t c = cell_of(p);
    cell_index[i] = static_cast<uint32_t>(c);
    ++start_[c + 1];
    ++finite;
  }
  for (size_t c = 0; c < num_cells; ++c) start_[c + 1] += start_[c];
  sorted_.resize(finite);
  index_.resize(finite);
  std::vector<uint32_t> next(start_.begin(), start_.end() - 1);
  for (size_t i = 0; i < points_->size(); ++i) {
    const Eigen::Vector3d& p = (*points_)[i];
    if (!p.allFinite()) continue;
    const uint32_t slot = next[cell_index[i]]++;
    sorted_[slot] = p;
    index_[slot] = static_cast<uint32_t>(i);
  }
}

template <typename F>
void NeighbourGrid::ForEachRun(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, F&& f) const {
  if (sorted_.empty()) return;
  int from[3], to[3];
  const int n[3] = {nx_, ny_, nz_};
  for (int d = 0; d < 3; ++d) {
    const double a = std::floor((lo[d] - origin_[d]) / cell_);
    const double b = std::floor((hi[d] - origin_[d]) / cell_);
    if (b < 0 || a > n[d] - 1) return;
    from[d] = static_cast<int>(std::max(a, 0.0));
    to[d] = static_cast<int>(std::min(b, static_cast<double>(n[d] - 1)));
  }
  for (int iz = from[2]; iz <= to[2]; ++iz) {
    for (int iy = from[1]; iy <= to[1]; ++iy) {
      const size_t row =
          (static_cast<size_t>(iz) * static_cast<size_t>(ny_) + static_cast<size_t>(iy)) *
          static_cast<size_t>(nx_);
      const uint32_t first = start_[row + static_cast<size_t>(from[0])];
      const uint32_t end = start_[row + static_cast<size_t>(to[0]) + 1];
      if (first < end) f(first, end);
    }
  }
}

void NeighbourGrid::KNearest(const Eigen::Vector3d& query, int k, Scratch* scratch,
                             std::vector<Neighbor>* out) const {
  out->clear();
  const size_t want = std::min(static_cast<size_t>(std::max(k, 0)), sorted_.size());
  if (want == 0 || !query.allFinite()) return;
  std::vector<Neighbor>& cand = scratch->candidates;
  const double* q = query.data();
  // The ball grows until it holds `want` points: those are then the nearest (every point within
  // the ball's radius was gathered; every other one is farther than all of them).
  double radius = scratch->radius > 0 ? scratch->radius * 1.05 : cell_;
  for (;;) {
    cand.clear();
    const double r2 = radius * radius;
    const double box = radius * (1 + kMargin) + kMargin * cell_;
    ForEachRun(query - Eigen::Vector3d::Constant(box), query + Eigen::Vector3d::Constant(box),
               [&](uint32_t first, uint32_t end) {
                 for (uint32_t i = first; i < end; ++i) {
                   const Eigen::Vector3d& p = sorted_[i];
                   const double dx = q[0] - p.x(), dy = q[1] - p.y(), dz = q[2] - p.z();
                   const double d2 = dx * dx + dy * dy + dz * dz;
                   if (d2 <= r2) cand.push_back({index_[i], d2});
                 }
               });
    if (cand.size() >= want) break;
    // Not enough: grow (want <= the number of points, so a ball over the bounding box holds it).
    radius = std::max(radius * 1.5, cell_);
  }
  if (cand.size() > want) {
    std::nth_element(cand.begin(), cand.begin() + static_cast<std::ptrdiff_t>(want - 1), cand.end(),
                     Less());
    cand.resize(want);
  }
  std::sort(cand.begin(), cand.end(), Less());
  out->assign(cand.begin(), cand.end());
  scratch->radius = std::sqrt(out->back().distance_sq);
}

bool NeighbourGrid::Nearest(const Eigen::Vector3d& query, Neighbor* nearest,
                            double max_distance) const {
  if (sorted_.empty() || !query.allFinite()) return false;
  if (!std::isfinite(max_distance)) {
    Scratch scratch;
    std::vector<Neighbor> one;
    KNearest(query, 1, &scratch, &one);
    if (one.empty()) return false;
    *nearest = one.front();
    return true;
  }
  const double* q = query.data();
  const double limit = max_distance * max_distance;
  Neighbor best{0, limit};
  bool found = false;
  const double box = max_distance * (1 + kMargin) + kMargin * cell_;
  ForEachRun(query - Eigen::Vector3d::Constant(box), query + Eigen::Vector3d::Constant(box),
             [&](uint32_t first, uint32_t end) {
               for (uint32_t i = first; i < end; ++i) {
                 const Eigen::Vector3d& p = sorted_[i];
                 const double dx = q[0] - p.x(), dy = q[1] - p.y(), dz = q[2] - p.z();
                 const double d2 = dx * dx + dy * dy + dz * dz;
                 if (d2 < best.distance_sq ||
                     (found && d2 == best.distance_sq && index_[i] < best.index)) {
                   best = {index_[i], d2};
                   found = true;
                 }
               }
             });
  if (found) *nearest = best;
  return found;
}

}  // namespace slshadow::compare
