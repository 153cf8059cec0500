#include "compare/statistics.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <unordered_map>
#include <utility>

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_sort.h>

#include "compare/kdtree.h"
#include "core/error.h"
#include "core/statistics.h"

namespace slshadow::compare {
namespace {

// Index of the nearest-rank percentile p in n sorted values (n > 0).
size_t PercentileIndex(size_t n, double p) {
  return PercentileRank(n, p);  // core/statistics.h
}

// A uniform grid over points (cells hashed, points copied cell by cell): the points within one
// cell size of a query lie in the 27 cells around the query's cell.
class PointGrid {
 public:
  PointGrid(const std::vector<Eigen::Vector3d>& points, double cell) {
    lo_ = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d hi = -lo_;
    for (const auto& p : points) {
      if (!p.allFinite()) continue;  // never within a finite distance of anything
      lo_ = lo_.cwiseMin(p);
      hi = hi.cwiseMax(p);
    }
    if (!(lo_.x() <= hi.x())) return;  // no finite point
    // At most 2^20 cells per axis; a larger cell stays correct (27 cells still cover the radius).
    cell_ = std::max({cell, (hi - lo_).maxCoeff() / double(1 << 20), 1e-12});
    inv_ = 1.0 / cell_;
    std::vector<std::pair<uint64_t, uint32_t>> keyed;
    keyed.reserve(points.size());
    for (size_t i = 0; i < points.size(); ++i) {
      if (!points[i].allFinite()) continue;
      const Eigen::Vector3d c = ((points[i] - lo_) * inv_).array().floor();
      keyed.emplace_back(Key(static_cast<int64_t>(c.x()), static_cast<int64_t>(c.y()), static_cast<int64_t>(c.z())),
                         static_cast<uint32_t>(i));
    }
    tbb::parallel_sort(keyed.begin(), keyed.end());
    points_.resize(keyed.size());
    index_.resize(keyed.size());
    cells_.reserve(keyed.size() / 8 + 16);
    for (size_t k = 0; k < keyed.size(); ++k) {
      points_[k] = points[keyed[k].second];
      index_[k] = keyed[k].second;
      if (k == 0 || keyed[k].first != keyed[k - 1].first) {
        cells_[keyed[k].first] = {static_cast<uint32_t>(k), static_cast<uint32_t>(k)};
      }
      cells_[keyed[k].first].second = static_cast<uint32_t>(k + 1);
    }
  }
  double cell() const { return cell_; }

  // f(point, original index) for every point in the (2 reach + 1)^3 cells around q: all the
  // points within reach cells of q.
  template <typename F>
  void ForNeighbours(const Eigen::Vector3d& q, F&& f, int64_t reach = 1) const {
    if (points_.empty() || !q.allFinite()) return;
    const Eigen::Vector3d c = ((q - lo_) * inv_).array().floor();
    constexpr double kMax = double(1 << 21);
    if ((c.array() < -static_cast<double>(reach)).any() || (c.array() > kMax + static_cast<double>(reach)).any()) return;
    const auto cx = static_cast<int64_t>(c.x()), cy = static_cast<int64_t>(c.y()), cz = static_cast<int64_t>(c.z());
    for (int64_t z = std::max<int64_t>(cz - reach, 0); z <= std::min(cz + reach, kCells - 1); ++z) {
      for (int64_t y = std::max<int64_t>(cy - reach, 0); y <= std::min(cy + reach, kCells - 1); ++y) {
        for (int64_t x = std::max<int64_t>(cx - reach, 0); x <= std::min(cx + reach, kCells - 1); ++x) {
          if (x < 0 || y < 0 || z < 0 || x >= kCells || y >= kCells || z >= kCells) continue;
          const auto it = cells_.find(Key(x, y, z));
          if (it == cells_.end()) continue;
          for (uint32_t k = it->second.first; k < it->second.second; ++k) f(points_[k], index_[k]);
        }
      }
    }
  }

 private:
  static constexpr int64_t kCells = int64_t{1} << 21;
  static uint64_t Key(int64_t x, int64_t y, int64_t z) {
    return (static_cast<uint64_t>(z) << 42) | (static_cast<uint64_t>(y) << 21) | static_cast<uint64_t>(x);
  }
  Eigen::Vector3d lo_ = Eigen::Vector3d::Zero();
  double cell_ = 1.0, inv_ = 1.0;
  std::vector<Eigen::Vector3d> points_;
  std::vector<uint32_t> index_;
  std::unordered_map<uint64_t, std::pair<uint32_t, uint32_t>> cells_;
};

}  // namespace

DistanceStats ComputeStats(const std::vector<double>& distances_mm, bool is_signed,
                           double threshold_mm, int bins) {
  SLSHADOW_THROW_IF(!(threshold_mm >= 0) || !std::isfinite(threshold_mm),
                    "threshold_mm: must be finite and >= 0 (got ", threshold_mm, ")");
  SLSHADOW_THROW_IF(bins < 1, "histogram bins: must be >= 1 (got ", bins, ")");
  DistanceStats s;
  s.is_signed = is_signed;
  s.threshold_mm = threshold_mm;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  s.signed_mean_mm = s.signed_std_mm = nan;
  std::vector<double> abs_d;
  abs_d.reserve(distances_mm.size());
  double sum = 0, sum2 = 0, ssum = 0;
  for (double d : distances_mm) {
    if (!std::isfinite(d)) {
      ++s.num_invalid;
      continue;
    }
    const double a = std::abs(d);
    abs_d.push_back(a);
    sum += a;
    sum2 += a * a;
    ssum += d;
    if (a <= threshold_mm) ++s.inliers;
  }
  s.count = abs_d.size();
  s.outliers = s.count - s.inliers;
  if (s.count == 0) {
    s.histogram.counts.assign(static_cast<size_t>(bins), 0);
    s.histogram.hi_mm = std::max(threshold_mm, 1e-3);
    s.histogram.lo_mm = is_signed ? -s.histogram.hi_mm : 0.0;
    return s;
  }
  const double n = static_cast<double>(s.count);
  s.mean_mm = sum / n;
  s.rms_mm = std::sqrt(sum2 / n);
  // Two-pass for the standard deviations (numerically safe).
  double var = 0, svar = 0;
  const double smean = ssum / n;
  for (double d : distances_mm) {
    if (!std::isfinite(d)) continue;
    var += (std::abs(d) - s.mean_mm) * (std::abs(d) - s.mean_mm);
    svar += (d - smean) * (d - smean);
  }
  s.std_mm = std::sqrt(var / n);
  if (is_signed) {
    s.signed_mean_mm = smean;
    s.signed_std_mm = std::sqrt(svar / n);
  }
  // The nearest-rank percentiles by successive selections (each on the part above the previous
  // rank): the same values a full sort gives, in O(n).
  const size_t i50 = PercentileIndex(abs_d.size(), 50), i95 = PercentileIndex(abs_d.size(), 95),
               i999 = PercentileIndex(abs_d.size(), 99.9);
  const auto at = [&](size_t i) { return abs_d.begin() + static_cast<std::ptrdiff_t>(i); };
  std::nth_element(abs_d.begin(), at(i50), abs_d.end());
  s.median_mm = abs_d[i50];
  std::nth_element(at(i50), at(i95), abs_d.end());
  s.p95_mm = abs_d[i95];
  std::nth_element(at(i95), at(i999), abs_d.end());
  Histogram& h = s.histogram;
  h.hi_mm = std::max({abs_d[i999], threshold_mm, 1e-6});
  s.max_mm = *std::max_element(at(i999), abs_d.end());
  h.lo_mm = is_signed ? -h.hi_mm : 0.0;
  h.counts.assign(static_cast<size_t>(bins), 0);
  const double w = h.BinWidth();
  for (double d : distances_mm) {
    if (!std::isfinite(d)) continue;
    const double v = is_signed ? d : std::abs(d);
    if (v < h.lo_mm) {
      ++h.underflow;
    } else if (v > h.hi_mm) {
      ++h.overflow;
    } else {
      const auto b = std::min(static_cast<size_t>((v - h.lo_mm) / w), h.counts.size() - 1);
      ++h.counts[b];
    }
  }
  return s;
}

double Coverage(const std::vector<Eigen::Vector3d>& reference_samples, const KdTree& reached,
                double radius_mm) {
  if (reference_samples.empty() || reached.size() == 0) return 0.0;
  const std::vector<uint32_t> order = SpatialOrder(reference_samples);
  const size_t covered = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, reference_samples.size(), 2048), size_t{0},
      [&](const tbb::blocked_range<size_t>& r, size_t acc) {
        Neighbor nb;
        for (size_t k = r.begin(); k != r.end(); ++k) {
          // Nearest() finds points strictly closer than the bound: nudge it to make it inclusive.
          if (reached.Nearest(reference_samples[order[k]], &nb, std::nextafter(radius_mm, 1e300))) ++acc;
        }
        return acc;
      },
      [](size_t a, size_t b) { return a + b; });
  return static_cast<double>(covered) / static_cast<double>(reference_samples.size());
}

double Coverage(const std::vector<Eigen::Vector3d>& reference_samples, const std::vector<Eigen::Vector3d>& reached,
                double radius_mm) {
  if (reference_samples.empty() || reached.empty()) return 0.0;
  // The criterion of the KdTree overload, bit for bit: squared distance < nextafter(radius)^2.
  const double r = std::nextafter(radius_mm, 1e300);
  const double bound = r * r;
  if (!(bound > 0) || !std::isfinite(bound)) {
    const KdTree tree(reached);
    return Coverage(reference_samples, tree, radius_mm);
  }
  const PointGrid grid(reached, r * 1.001);  // margin: cell assignment rounds
  const std::vector<uint32_t> order = SpatialOrder(reference_samples);
  const size_t covered = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, reference_samples.size(), 2048), size_t{0},
      [&](const tbb::blocked_range<size_t>& range, size_t acc) {
        for (size_t k = range.begin(); k != range.end(); ++k) {
          const Eigen::Vector3d& q = reference_samples[order[k]];
          bool hit = false;
          grid.ForNeighbours(q, [&](const Eigen::Vector3d& p, uint32_t) { hit = hit || (q - p).squaredNorm() < bound; });
          if (hit) ++acc;
        }
        return acc;
      },
      [](size_t a, size_t b) { return a + b; });
  return static_cast<double>(covered) / static_cast<double>(reference_samples.size());
}

double MedianSpacing(const std::vector<Eigen::Vector3d>& points, size_t max_samples) {
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
    Eigen::Vector3d e = hi - lo;
    std::sort(e.data(), e.data() + 3, std::greater<>());
    const double n = static_cast<double>(points.size());
    double cell = e[1] > 0 ? 2.0 * std::sqrt(e[0] * e[1] / n) : 2.0 * e[0] / n;
    cell = std::max(cell, 1e-9 * std::max(e[0], 1.0));
    const PointGrid grid(points, cell * 1.001);
    const double reach = cell * cell;  // within it, the grid's answer is exact
    for (size_t i = 0; i < points.size(); i += stride) {
      // Cubes of 1, 2, 4, 8 cells around the point: exact as soon as the nearest lies within
      // the cube's inscribed radius.
      bool found = false;
      for (int64_t cells = 1; cells <= 8 && !found; cells *= 2) {
        double best = std::numeric_limits<double>::infinity();
        grid.ForNeighbours(
            points[i], [&](const Eigen::Vector3d& p, uint32_t j) {
              if (j != i) best = std::min(best, (points[i] - p).squaredNorm());
            },
            cells);
        if (best <= reach * static_cast<double>(cells * cells)) {
          d.push_back(std::sqrt(best));
          found = true;
        }
      }
      if (!found) missed.push_back(i);
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

}  // namespace slshadow::compare
