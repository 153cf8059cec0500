#include "compare/median_spacing.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include "compare/internal/median_spacing.h"
#include "compare/internal/point_grid.h"
#include "core/error.h"
#include "core/kdtree.h"

namespace slshadow::compare {

namespace {

// The cell of MedianSpacingByCells's first grid, from the finite points' bounding box [lo, hi]
// and the number of points, assuming a surface: ~4 points per cell.
double SurfaceCell(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, size_t num_points) {
  Eigen::Vector3d e = hi - lo;
  std::sort(e.data(), e.data() + 3, std::greater<>());
  const double n = static_cast<double>(num_points);
  const double cell = e[1] > 0 ? 2.0 * std::sqrt(e[0] * e[1] / n) : 2.0 * e[0] / n;
  return std::max(cell, 1e-9 * std::max(e[0], 1.0));
}

}  // namespace

namespace internal {

// Each sample's squared distance to its array neighbours bounds its nearest. Hashed cells twice
// the median bound (~4 points each on a surface) list the samples searching them (those within
// whose bound they lie, or within 7.5 cells when the bound is larger); one pass over the points
// compares each with the samples searching its cell. That answers every sample exactly but the
// isolated ones (nothing within 7.5 cells), which are compared with every point.
bool ScanOrderSpacings(const std::vector<Eigen::Vector3d>& pts, size_t stride,
                       std::vector<double>* spacings) {
  const size_t n = pts.size();
  if (n < 2 || n >= std::numeric_limits<uint32_t>::max()) return false;
  std::vector<uint32_t> samples;
  for (size_t i = 0; i < n; i += stride) samples.push_back(static_cast<uint32_t>(i));
  const size_t ns = samples.size();
  // Upper bounds: the squared distance to the array neighbours (a non-finite neighbour gives NaN
  // or infinity, which std::min keeps out unless both are).
  std::vector<double> best(ns);
  for (size_t k = 0; k < ns; ++k) {
    const size_t i = samples[k];
    if (!pts[i].allFinite()) return false;
    double b = std::numeric_limits<double>::infinity();
    if (i > 0) b = std::min(b, (pts[i] - pts[i - 1]).squaredNorm());
    if (i + 1 < n) b = std::min(b, (pts[i] - pts[i + 1]).squaredNorm());
    best[k] = b;
  }
  std::vector<double> sorted = best;
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(ns / 2),
                   sorted.end());
  const double h = 2 * std::sqrt(sorted[ns / 2]);
  if (!(h > 0) || !std::isfinite(h)) return false;
  {
    // Array neighbours apart by far more than a surface of this many points spreads them over the
    // samples' bounding box: not a scan's cloud (the cells would hold too many points).
    Eigen::Vector3d lo = pts[samples[0]], hi = lo;
    for (const uint32_t i : samples) {
      lo = lo.cwiseMin(pts[i]);
      hi = hi.cwiseMax(pts[i]);
    }
    if (h > 8 * SurfaceCell(lo, hi, n)) return false;
  }
  // A sample searching within a squared distance D finds every point nearer than sqrt(D) within
  // floor(1.001 sqrt(D) / h) + 1 cells of its own (the margin covers the rounding of the cell
  // coordinates): its bound, or (7.5 h)^2 (8 cells) when the bound is larger.
  const double inv = 1 / h;
  const auto rings_of = [&](double bound) {
    return std::floor(std::sqrt(bound) * inv * 1.001) + 1;
  };
  std::vector<double> reach2(ns);
  for (size_t k = 0; k < ns; ++k) {
    reach2[k] = rings_of(best[k]) <= 8 ? best[k] : (7.5 * h) * (7.5 * h);
  }
  const auto cell = [&](const Eigen::Vector3d& p) {
    return Eigen::Array3d(((p * inv).array().floor()));
  };
  // The cells sample k searches: of the cells within its rings, those whose box lies within its
  // bound of it (in cell units, with margins for the rounding of cell coordinates); every point
  // nearer than its bound is in one of them. visit(x, y, z) for each.
  const auto for_cells = [&](size_t k, auto&& visit) {
    const Eigen::Vector3d& p = pts[samples[k]];
    const auto reach = static_cast<int64_t>(rings_of(reach2[k]));
    const Eigen::Array3d t = (p * inv).array();
    const Eigen::Array3d c = t.floor();
    const double r = std::sqrt(reach2[k]) * inv * 1.001 + 1e-6, r2 = r * r;
    const auto gap = [](int64_t cell_index, double coordinate) {
      const auto lo = static_cast<double>(cell_index);
      return std::max({0.0, lo - coordinate, coordinate - (lo + 1)});
    };
    const auto cx = static_cast<int64_t>(c.x()), cy = static_cast<int64_t>(c.y()),
               cz = static_cast<int64_t>(c.z());
    for (int64_t z = cz - reach; z <= cz + reach; ++z) {
      const double gz = gap(z, t.z());
      for (int64_t y = cy - reach; y <= cy + reach; ++y) {
        const double gy = gap(y, t.y());
        if (gz * gz + gy * gy > r2) continue;
        for (int64_t x = cx - reach; x <= cx + reach; ++x) {
          const double gx = gap(x, t.x());
          if (gz * gz + gy * gy + gx * gx > r2) continue;
          visit(x, y, z);
        }
      }
    }
  };
  // The samples' cells must fit the hash's 21 bits a coordinate (checked below for every point).
  for (size_t k = 0; k < ns; ++k) {
    if (!(cell(pts[samples[k]]).abs() < 1e6).all()) return false;
  }
  // The cells each sample searches, as (cell key, sample) pairs; buckets: a power of two, at
  // least 4 per pair (few points of unsearched cells share a bucket with a searched one: they
  // are only compared in vain), at most 2 per point.
  const auto key_of = [](int64_t x, int64_t y, int64_t z) {
    return (static_cast<uint64_t>(x + (1 << 20)) << 42) |
           (static_cast<uint64_t>(y + (1 << 20)) << 21) | static_cast<uint64_t>(z + (1 << 20));
  };
  std::vector<std::pair<uint64_t, uint32_t>> visits;
  visits.reserve(16 * ns);
  for (size_t k = 0; k < ns; ++k) {
    for_cells(k, [&](int64_t x, int64_t y, int64_t z) {
      visits.emplace_back(key_of(x, y, z), static_cast<uint32_t>(k));
    });
  }
  size_t buckets = 1024;
  while (buckets < 4 * visits.size() && buckets < 2 * n && buckets < (size_t{1} << 31)) {
    buckets *= 2;
  }
  const auto bucket_of = [&](uint64_t key) {
    return static_cast<uint32_t>(((key * 0x9E3779B97F4A7C15ull) >> 32) & (buckets - 1));
  };
  // Per bucket, the samples searching it (first[b], first[b + 1]) in `searchers`; a bit per
  // bucket says whether any does.
  std::vector<uint32_t> first(buckets + 1, 0), searchers(visits.size());
  std::vector<uint64_t> searched((buckets + 63) / 64, 0);
  for (auto& [key, k] : visits) {
    const uint32_t b = bucket_of(key);
    key = b;
    ++first[b + 1];
    searched[b >> 6] |= uint64_t{1} << (b & 63);
  }
  for (size_t b = 1; b <= buckets; ++b) first[b] += first[b - 1];
  {
    std::vector<uint32_t> fill(first.begin(), first.end() - 1);
    for (const auto& [b, k] : visits) searchers[fill[b]++] = k;
  }
  std::vector<Eigen::Vector3d> sample_points(ns);
  for (size_t k = 0; k < ns; ++k) sample_points[k] = pts[samples[k]];
  // One pass over the points: each finite one in a searched bucket is compared with the samples
  // searching it (the smallest squared distance per sample, in a copy of the bounds per thread:
  // the same minimum however the points are shared out); whether all cells are in range, and
  // whether all points are finite.
  tbb::enumerable_thread_specific<std::vector<double>> nearest([&] { return best; });
  struct Scan {
    bool in_range = true, finite = true;
  };
  const Scan scan = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, n, 65536), Scan(),
      [&](const tbb::blocked_range<size_t>& r, Scan acc) {
        std::vector<double>& mine = nearest.local();
        for (size_t i = r.begin(); i < r.end(); ++i) {
          const Eigen::Vector3d& p = pts[i];
          const Eigen::Array3d t = (p * inv).array();
          if (!(t.abs() < 1e6).all()) {  // out of range, or not finite
            if (p.allFinite()) {
              acc.in_range = false;
            } else {
              acc.finite = false;  // never the nearest of a finite sample
            }
            continue;
          }
          // floor(t), as cell(p) gives it, without a call to floor.
          const auto floor_of = [](double x) {
            const auto f = static_cast<int64_t>(x);  // toward zero
            return f - static_cast<int64_t>(static_cast<double>(f) > x);
          };
          const uint32_t b = bucket_of(key_of(floor_of(t.x()), floor_of(t.y()), floor_of(t.z())));
          if (!((searched[b >> 6] >> (b & 63)) & 1)) continue;
          for (uint32_t m = first[b]; m < first[b + 1]; ++m) {
            const uint32_t k = searchers[m];
            if (samples[k] == i) continue;
            const double d2 = (sample_points[k] - p).squaredNorm();
            if (d2 < mine[k]) mine[k] = d2;
          }
        }
        return acc;
      },
      [](Scan a, const Scan& b) {
        a.in_range = a.in_range && b.in_range;
        a.finite = a.finite && b.finite;
        return a;
      });
  if (!scan.in_range) return false;
  *spacings = best;
  for (const std::vector<double>& mine : nearest) {
    for (size_t k = 0; k < ns; ++k) (*spacings)[k] = std::min((*spacings)[k], mine[k]);
  }
  // Isolated samples (no point within their search): compared with every point.
  std::vector<size_t> isolated;
  for (size_t k = 0; k < ns; ++k) {
    if (!((*spacings)[k] <= reach2[k])) isolated.push_back(k);
  }
  if (isolated.size() > 16) return false;
  for (const size_t k : isolated) {
    const size_t i = samples[k];
    double b = (*spacings)[k];
    for (size_t j = 0; j < n; ++j) {
      if (j != i) b = std::min(b, (pts[i] - pts[j]).squaredNorm());
    }
    (*spacings)[k] = b;
  }
  // MedianSpacingByCells answers from its grids the samples whose nearest lies within 8 of its
  // cells (the same squared distance), the others from its tree: the same squared distance too
  // (core/kdtree.h) when every point is finite; with non-finite points in the tree, it is left
  // to answer them.
  if (!scan.finite) {
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d hi = -lo;
    for (const Eigen::Vector3d& p : pts) {
      if (!p.allFinite()) continue;
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
    }
    const double wide = 8.0 * SurfaceCell(lo, hi, n);
    for (const double b : *spacings) {
      if (!(b <= wide * wide)) return false;
    }
  }
  for (double& b : *spacings) b = std::sqrt(b);
  return true;
}

double MedianSpacingByCells(const std::vector<Eigen::Vector3d>& points, size_t max_samples) {
  if (points.size() < 2) return 0.0;
  const size_t stride = std::max<size_t>(1, points.size() / std::max<size_t>(1, max_samples));
  // Cell from the bounding box, assuming a surface: ~4 points per cell.
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (const auto& p : points) {
    if (!p.allFinite()) continue;
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  std::vector<double> d;
  std::vector<size_t> missed;  // samples with no other point within the cell: answered by a tree
  if (lo.x() <= hi.x()) {
    const double cell = SurfaceCell(lo, hi, points.size());
    const double reach = cell * cell;  // within it, the grid's answer is exact
    std::vector<size_t> samples;
    for (size_t i = 0; i < points.size(); i += stride) samples.push_back(i);
    // The 27 cells around the point's cell: exact as soon as the nearest lies within one cell
    // (the cube's inscribed radius), from a grid of the points around the samples only (most
    // samples are answered there).
    std::vector<size_t> pending;
    {
      const PointGrid near(points, cell * 1.001, &samples);
      for (const size_t i : samples) {
        double best = std::numeric_limits<double>::infinity();
        near.ForNeighbours(
            points[i],
            [&](const Eigen::Vector3d& p, uint32_t j) {
              if (j != i) best = std::min(best, (points[i] - p).squaredNorm());
            },
            1);
        if (best <= reach) {
          d.push_back(std::sqrt(best));
        } else {
          pending.push_back(i);
        }
      }
    }
    // The rest (isolated points, usually a handful): a grid of cells 8 times larger, again of
    // only the points around them. Its 27 cells around a sample hold every point within 8 cells
    // of it, so a nearest point found within that distance is exact.
    if (!pending.empty()) {
      const double wide = 8.0 * cell;
      const PointGrid far(points, wide * 1.001, &pending);
      for (const size_t i : pending) {
        double best = std::numeric_limits<double>::infinity();
        far.ForNeighbours(
            points[i],
            [&](const Eigen::Vector3d& p, uint32_t j) {
              if (j != i) best = std::min(best, (points[i] - p).squaredNorm());
            },
            1);
        if (best <= wide * wide) {
          d.push_back(std::sqrt(best));
        } else {
          missed.push_back(i);
        }
      }
    }
  } else {
    for (size_t i = 0; i < points.size(); i += stride) missed.push_back(i);
  }
  if (!missed.empty()) {
    const KdTree tree(points);
    std::vector<Neighbor> nn;
    for (size_t i : missed) {
      tree.KNearest(points[i], 2, &nn);
      if (nn.size() == 2) d.push_back(std::sqrt(nn[1].distance_sq));
    }
  }
  if (d.empty()) return 0.0;
  std::nth_element(d.begin(), d.begin() + static_cast<long>(d.size() / 2), d.end());
  return d[d.size() / 2];
}

}  // namespace internal

double MedianSpacing(const KdTree& tree, size_t max_samples) {
  const auto& pts = tree.points();
  if (pts.size() < 2) return 0.0;
  const size_t stride = std::max<size_t>(1, pts.size() / std::max<size_t>(1, max_samples));
  std::vector<double> d;
  std::vector<Neighbor> nn;
  for (size_t i = 0; i < pts.size(); i += stride) {
    tree.KNearest(pts[i], 2, &nn);
    if (nn.size() == 2) d.push_back(std::sqrt(nn[1].distance_sq));
  }
  if (d.empty()) return 0.0;
  std::nth_element(d.begin(), d.begin() + static_cast<long>(d.size() / 2), d.end());
  return d[d.size() / 2];
}

double MedianSpacing(const std::vector<Eigen::Vector3d>& points, size_t max_samples) {
  if (points.size() < 2) return 0.0;
  const size_t stride = std::max<size_t>(1, points.size() / std::max<size_t>(1, max_samples));
  std::vector<double> d((points.size() + stride - 1) / stride);
  if (!internal::ScanOrderSpacings(points, stride, &d)) {
    return internal::MedianSpacingByCells(points, max_samples);
  }
  std::nth_element(d.begin(), d.begin() + static_cast<long>(d.size() / 2), d.end());
  return d[d.size() / 2];
}
}  // namespace slshadow::compare
