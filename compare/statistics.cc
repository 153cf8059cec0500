#include "compare/statistics.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <utility>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include "compare/internal/median_spacing.h"
#include "compare/kdtree.h"
#include "core/error.h"
#include "core/statistics.h"

namespace slshadow::compare {
namespace {

// A uniform grid over points (points copied cell by cell, cells found through an open-addressing
// hash table): the points within one cell size of a query lie in the 27 cells around the query's
// cell. Built in O(n): cell keys in parallel, a stable radix sort of the points by key.
//
// With `focus` (indices into points), only the points in the 27 cells around each focus point's
// cell are kept: ForNeighbours(points[focus[k]], f, 1) still sees every point it would see in
// the full grid, for a fraction of the sorting and copying. With `selected` (one flag per point),
// only the points flagged non-zero are in the grid.
class PointGrid {
 public:
  PointGrid(const std::vector<Eigen::Vector3d>& points, double cell,
            const std::vector<size_t>* focus = nullptr, const uint8_t* selected = nullptr) {
    lo_ = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d hi = -lo_;
    for (size_t i = 0; i < points.size(); ++i) {
      const Eigen::Vector3d& p = points[i];
      if (!p.allFinite()) continue;  // never within a finite distance of anything
      if (selected && !selected[i]) continue;
      lo_ = lo_.cwiseMin(p);
      hi = hi.cwiseMax(p);
    }
    if (!(lo_.x() <= hi.x())) return;  // no finite point
    // At most 2^20 cells per axis; a larger cell stays correct (27 cells still cover the radius).
    cell_ = std::max({cell, (hi - lo_).maxCoeff() / double(1 << 20), 1e-12});
    inv_ = 1.0 / cell_;
    for (int a = 0; a < 3; ++a) {
      max_cell_[a] = static_cast<int64_t>(std::floor((hi[a] - lo_[a]) * inv_));
      bits_[a] = 1;
      while ((int64_t{1} << bits_[a]) <= max_cell_[a]) ++bits_[a];
    }
    // The cells around the focus points (the ranges ForNeighbours visits with reach 1), as an
    // open-addressing set of keys.
    std::vector<uint64_t> marked;
    size_t marked_mask = 0;
    const auto mark_hash = [](uint64_t key) {
      return static_cast<size_t>((key * 0x9E3779B97F4A7C15ull) >> 20);
    };
    if (focus) {
      size_t capacity = 16;
      while (capacity < 2 * 27 * focus->size()) capacity *= 2;
      marked.assign(capacity, kNoKey);
      marked_mask = capacity - 1;
      for (const size_t i : *focus) {
        if (!points[i].allFinite()) continue;
        const Eigen::Vector3d c = ((points[i] - lo_) * inv_).array().floor();
        const auto cx = static_cast<int64_t>(c.x()), cy = static_cast<int64_t>(c.y()),
                   cz = static_cast<int64_t>(c.z());
        for (int64_t z = std::max<int64_t>(cz - 1, 0); z <= std::min(cz + 1, max_cell_[2]); ++z) {
          for (int64_t y = std::max<int64_t>(cy - 1, 0); y <= std::min(cy + 1, max_cell_[1]); ++y) {
            for (int64_t x = std::max<int64_t>(cx - 1, 0); x <= std::min(cx + 1, max_cell_[0]);
                 ++x) {
              const uint64_t key = Key(x, y, z);
              size_t h = mark_hash(key) & marked_mask;
              while (marked[h] != kNoKey && marked[h] != key) h = (h + 1) & marked_mask;
              marked[h] = key;
            }
          }
        }
      }
    }
    const auto is_marked = [&](uint64_t key) {
      for (size_t h = mark_hash(key) & marked_mask;; h = (h + 1) & marked_mask) {
        if (marked[h] == key) return true;
        if (marked[h] == kNoKey) return false;
      }
    };
    // Keys of the finite points (packed cell coordinates), then a stable LSD radix sort by key in
    // passes of 16 bits.
    const size_t n = points.size();
    std::vector<uint64_t> keys(n, kNoKey);
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, n, 16384), [&](const tbb::blocked_range<size_t>& r) {
          for (size_t i = r.begin(); i != r.end(); ++i) {
            if (!points[i].allFinite() || (selected && !selected[i])) continue;
            const Eigen::Vector3d c = ((points[i] - lo_) * inv_).array().floor();
            const uint64_t key = Key(std::min(static_cast<int64_t>(c.x()), max_cell_[0]),
                                     std::min(static_cast<int64_t>(c.y()), max_cell_[1]),
                                     std::min(static_cast<int64_t>(c.z()), max_cell_[2]));
            if (focus && !is_marked(key)) continue;
            keys[i] = key;
          }
        });
    std::vector<uint32_t> order;
    order.reserve(n);
    for (size_t i = 0; i < n; ++i) {
      if (keys[i] != kNoKey) order.push_back(static_cast<uint32_t>(i));
    }
    const int total_bits = bits_[0] + bits_[1] + bits_[2];
    std::vector<uint32_t> tmp(order.size());
    std::vector<uint32_t> count(1u << 16);
    for (int shift = 0; shift < total_bits; shift += 16) {
      std::fill(count.begin(), count.end(), 0u);
      for (uint32_t i : order) ++count[(keys[i] >> shift) & 0xFFFFu];
      uint32_t sum = 0;
      for (uint32_t& c : count) sum += std::exchange(c, sum);
      for (uint32_t i : order) tmp[count[(keys[i] >> shift) & 0xFFFFu]++] = i;
      order.swap(tmp);
    }
    points_.resize(order.size());
    index_ = order;
    size_t cells = 0;
    for (size_t k = 0; k < order.size(); ++k) {
      points_[k] = points[order[k]];
      cells += k == 0 || keys[order[k]] != keys[order[k - 1]];
    }
    size_t capacity = 16;
    while (capacity < 2 * cells) capacity *= 2;
    table_.assign(capacity, Slot{kNoKey, 0, 0});
    mask_ = capacity - 1;
    for (size_t k = 0; k < order.size();) {
      const uint64_t key = keys[order[k]];
      size_t end = k + 1;
      while (end < order.size() && keys[order[end]] == key) ++end;
      size_t h = Hash(key);
      while (table_[h].key != kNoKey) h = (h + 1) & mask_;
      table_[h] = {key, static_cast<uint32_t>(k), static_cast<uint32_t>(end)};
      k = end;
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
    if ((c.array() < -static_cast<double>(reach)).any() ||
        (c.array() > kMax + static_cast<double>(reach)).any())
      return;
    const auto cx = static_cast<int64_t>(c.x()), cy = static_cast<int64_t>(c.y()),
               cz = static_cast<int64_t>(c.z());
    for (int64_t z = std::max<int64_t>(cz - reach, 0); z <= std::min(cz + reach, max_cell_[2]);
         ++z) {
      for (int64_t y = std::max<int64_t>(cy - reach, 0); y <= std::min(cy + reach, max_cell_[1]);
           ++y) {
        for (int64_t x = std::max<int64_t>(cx - reach, 0); x <= std::min(cx + reach, max_cell_[0]);
             ++x) {
          if (const Slot* slot = Find(Key(x, y, z))) {
            for (uint32_t k = slot->begin; k < slot->end; ++k) f(points_[k], index_[k]);
          }
        }
      }
    }
  }

  // Whether some point p has (q - p).squaredNorm() < bound, for bound <= cell^2: the query's own
  // cell first, then its 26 neighbours, stopping at the first such point.
  bool AnyWithin(const Eigen::Vector3d& q, double bound) const {
    if (points_.empty() || !q.allFinite()) return false;
    const Eigen::Vector3d c = ((q - lo_) * inv_).array().floor();
    if ((c.array() < -1.0).any() || (c.array() > double(1 << 21) + 1.0).any()) return false;
    const auto cx = static_cast<int64_t>(c.x()), cy = static_cast<int64_t>(c.y()),
               cz = static_cast<int64_t>(c.z());
    const auto cell_has = [&](int64_t x, int64_t y, int64_t z) {
      if (x < 0 || y < 0 || z < 0 || x > max_cell_[0] || y > max_cell_[1] || z > max_cell_[2])
        return false;
      const Slot* slot = Find(Key(x, y, z));
      if (!slot) return false;
      for (uint32_t k = slot->begin; k < slot->end; ++k) {
        if ((q - points_[k]).squaredNorm() < bound) return true;
      }
      return false;
    };
    if (cell_has(cx, cy, cz)) return true;
    for (int64_t z = cz - 1; z <= cz + 1; ++z) {
      for (int64_t y = cy - 1; y <= cy + 1; ++y) {
        for (int64_t x = cx - 1; x <= cx + 1; ++x) {
          if ((x != cx || y != cy || z != cz) && cell_has(x, y, z)) return true;
        }
      }
    }
    return false;
  }

 private:
  static constexpr uint64_t kNoKey = ~uint64_t{0};
  struct Slot {
    uint64_t key;
    uint32_t begin, end;  // the cell's points: points_[begin, end)
  };
  uint64_t Key(int64_t x, int64_t y, int64_t z) const {
    return (static_cast<uint64_t>(z) << (bits_[0] + bits_[1])) |
           (static_cast<uint64_t>(y) << bits_[0]) | static_cast<uint64_t>(x);
  }
  const Slot* Find(uint64_t key) const {
    for (size_t h = Hash(key);; h = (h + 1) & mask_) {
      if (table_[h].key == key) return &table_[h];
      if (table_[h].key == kNoKey) return nullptr;
    }
  }
  size_t Hash(uint64_t key) const {
    return static_cast<size_t>((key * 0x9E3779B97F4A7C15ull) >> 20) & mask_;
  }
  Eigen::Vector3d lo_ = Eigen::Vector3d::Zero();
  double cell_ = 1.0, inv_ = 1.0;
  int64_t max_cell_[3] = {0, 0, 0};  // largest cell coordinate of a point, per axis
  int bits_[3] = {1, 1, 1};          // bits of the packed key per axis
  std::vector<Eigen::Vector3d> points_;
  std::vector<uint32_t> index_;
  std::vector<Slot> table_;
  size_t mask_ = 0;
};

// ComputeStats's figures of |d| (shared by the signed and unsigned figures), the signed mean and
// std, and the histograms asked for, from three passes over the distances: the sums in order (so
// the same doubles) and a count of the top 16 bits of |d|; the values of the (at most three)
// buckets holding the ranks of the median, p95 and p99, a selection among which gives each (the
// value a full sort puts at that rank); the deviations from the means (ComputeStats's two-pass
// standard deviations) and the histograms, whose range the 99th percentile sets.
struct AbsFigures {
  DistanceStats stats;  // its histogram unset, its signed figures NaN
  double signed_mean = 0, signed_std = 0;
  Histogram signed_histogram, unsigned_histogram;  // of d over [-hi, hi], of |d| over [0, hi]
};

AbsFigures ComputeAbsFigures(const std::vector<double>& distances_mm, double threshold_mm, int bins,
                             double range_mm, bool bin_signed, bool bin_unsigned) {
  SLSHADOW_THROW_IF(!(range_mm >= 0) || !std::isfinite(range_mm),
                    "colour range: must be finite and >= 0 (got ", range_mm, ")");
  SLSHADOW_THROW_IF(!(threshold_mm >= 0) || !std::isfinite(threshold_mm),
                    "threshold_mm: must be finite and >= 0 (got ", threshold_mm, ")");
  SLSHADOW_THROW_IF(bins < 1, "histogram bins: must be >= 1 (got ", bins, ")");
  AbsFigures out;
  DistanceStats& s = out.stats;
  s.threshold_mm = threshold_mm;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  s.signed_mean_mm = s.signed_std_mm = nan;
  out.signed_mean = out.signed_std = nan;
  std::vector<uint32_t> counts(kAbsBuckets, 0);
  double sum = 0, sum2 = 0, ssum = 0, max = 0;
  for (const double d : distances_mm) {
    if (!std::isfinite(d)) {
      ++s.num_invalid;
      continue;
    }
    const double a = std::abs(d);
    ++s.count;
    sum += a;
    sum2 += a * a;
    ssum += d;
    if (a <= threshold_mm) ++s.inliers;
    ++counts[AbsBucket(a)];
    max = std::max(max, a);
  }
  s.outliers = s.count - s.inliers;
  double hi = range_mm > 0 ? range_mm : std::max(threshold_mm, 1e-3);  // for no values
  if (s.count > 0) {
    const double n = static_cast<double>(s.count);
    s.mean_mm = sum / n;
    s.rms_mm = std::sqrt(sum2 / n);
    s.max_mm = max;
    const size_t ranks[3] = {PercentileRank(s.count, 50), PercentileRank(s.count, 95),
                             PercentileRank(s.count, 99)};
    double at[3];
    AbsValuesAtRanks(distances_mm.data(), distances_mm.data() + distances_mm.size(), counts, ranks,
                     3, at);
    s.median_mm = at[0];
    s.p95_mm = at[1];
    hi = range_mm > 0 ? range_mm : std::max(at[2], 1e-6);
  }
  Histogram &hs = out.signed_histogram, &hu = out.unsigned_histogram;
  hs.hi_mm = hu.hi_mm = hi;
  hs.lo_mm = -hi;
  hu.lo_mm = 0.0;
  if (bin_signed) hs.counts.assign(static_cast<size_t>(bins), 0);
  if (bin_unsigned) hu.counts.assign(static_cast<size_t>(bins), 0);
  if (s.count == 0) return out;
  // The deviations from the means, and the histograms.
  const double n = static_cast<double>(s.count);
  const double ws = hs.BinWidth(), wu = hu.BinWidth();
  const size_t last = static_cast<size_t>(bins) - 1;
  double var = 0, svar = 0;
  const double smean = ssum / n;
  for (const double d : distances_mm) {
    if (!std::isfinite(d)) continue;
    const double a = std::abs(d);
    var += (a - s.mean_mm) * (a - s.mean_mm);
    svar += (d - smean) * (d - smean);
    if (bin_signed) {
      if (d < hs.lo_mm) {
        ++hs.underflow;
      } else if (d > hs.hi_mm) {
        ++hs.overflow;
      } else {
        ++hs.counts[std::min(static_cast<size_t>((d - hs.lo_mm) / ws), last)];
      }
    }
    if (bin_unsigned) {
      if (a > hu.hi_mm) {
        ++hu.overflow;
      } else {
        ++hu.counts[std::min(static_cast<size_t>((a - hu.lo_mm) / wu), last)];
      }
    }
  }
  s.std_mm = std::sqrt(var / n);
  out.signed_mean = smean;
  out.signed_std = std::sqrt(svar / n);
  return out;
}

}  // namespace

DistanceStats ComputeStats(const std::vector<double>& distances_mm, bool is_signed,
                           double threshold_mm, int bins, double range_mm) {
  AbsFigures f =
      ComputeAbsFigures(distances_mm, threshold_mm, bins, range_mm, is_signed, !is_signed);
  DistanceStats s = std::move(f.stats);
  s.is_signed = is_signed;
  s.histogram = std::move(is_signed ? f.signed_histogram : f.unsigned_histogram);
  if (is_signed && s.count > 0) {
    s.signed_mean_mm = f.signed_mean;
    s.signed_std_mm = f.signed_std;
  }
  return s;
}

UnsignedAndSigned ComputeUnsignedAndSignedStats(const std::vector<double>& distances_mm,
                                                double threshold_mm, int bins, double range_mm) {
  AbsFigures f = ComputeAbsFigures(distances_mm, threshold_mm, bins, range_mm, true, true);
  UnsignedAndSigned out;
  out.unsigned_stats = f.stats;
  out.unsigned_stats.histogram = std::move(f.unsigned_histogram);
  DistanceStats& s = out.signed_stats;
  s = std::move(f.stats);
  s.is_signed = true;
  s.histogram = std::move(f.signed_histogram);
  if (s.count > 0) {
    s.signed_mean_mm = f.signed_mean;
    s.signed_std_mm = f.signed_std;
  }
  return out;
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
          if (reached.Nearest(reference_samples[order[k]], &nb, std::nextafter(radius_mm, 1e300)))
            ++acc;
        }
        return acc;
      },
      [](size_t a, size_t b) { return a + b; });
  return static_cast<double>(covered) / static_cast<double>(reference_samples.size());
}

double Coverage(const std::vector<Eigen::Vector3d>& reference_samples,
                const std::vector<Eigen::Vector3d>& reached, double radius_mm) {
  return Coverages({&reference_samples}, reached, radius_mm).front();
}

std::vector<double> Coverages(const std::vector<const std::vector<Eigen::Vector3d>*>& sample_sets,
                              const std::vector<Eigen::Vector3d>& reached, double radius_mm) {
  return Coverages(sample_sets, reached, std::vector<uint8_t>(reached.size(), 1), radius_mm);
}

std::vector<double> Coverages(const std::vector<const std::vector<Eigen::Vector3d>*>& sample_sets,
                              const std::vector<Eigen::Vector3d>& points,
                              const std::vector<uint8_t>& reached, double radius_mm) {
  SLSHADOW_THROW_IF(reached.size() != points.size(), "coverage: ", reached.size(), " flags for ",
                    points.size(), " points");
  std::vector<double> out(sample_sets.size(), 0.0);
  bool any = false;
  for (const auto* samples : sample_sets) any = any || !samples->empty();
  if (!any || std::none_of(reached.begin(), reached.end(), [](uint8_t f) { return f != 0; }))
    return out;
  // The criterion of the KdTree overload, bit for bit: squared distance < nextafter(radius)^2.
  const double r = std::nextafter(radius_mm, 1e300);
  const double bound = r * r;
  if (!(bound > 0) || !std::isfinite(bound)) {
    std::vector<Eigen::Vector3d> kept;
    for (size_t i = 0; i < points.size(); ++i) {
      if (reached[i]) kept.push_back(points[i]);
    }
    const KdTree tree(kept);
    for (size_t k = 0; k < sample_sets.size(); ++k) {
      out[k] = Coverage(*sample_sets[k], tree, radius_mm);
    }
    return out;
  }
  const PointGrid grid(points, r * 1.001, nullptr, reached.data());  // margin: cells round
  for (size_t k = 0; k < sample_sets.size(); ++k) {
    const std::vector<Eigen::Vector3d>& samples = *sample_sets[k];
    if (samples.empty()) continue;
    const std::vector<uint32_t> order = SpatialOrder(samples);
    const size_t covered = tbb::parallel_reduce(
        tbb::blocked_range<size_t>(0, samples.size(), 2048), size_t{0},
        [&](const tbb::blocked_range<size_t>& range, size_t acc) {
          for (size_t i = range.begin(); i != range.end(); ++i) {
            if (grid.AnyWithin(samples[order[i]], bound)) ++acc;
          }
          return acc;
        },
        [](size_t a, size_t b) { return a + b; });
    out[k] = static_cast<double>(covered) / static_cast<double>(samples.size());
  }
  return out;
}

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
  // (compare/kdtree.h) when every point is finite; with non-finite points in the tree, it is left
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

void AbsValuesAtRanks(const double* first, const double* last, const std::vector<uint32_t>& counts,
                      const size_t* ranks, int num_ranks, double* out) {
  SLSHADOW_CHECK(counts.size() == kAbsBuckets);
  // The bucket of each rank (ranks ascend), and the rank within its bucket.
  std::vector<uint32_t> bucket(static_cast<size_t>(num_ranks));
  std::vector<size_t> within(static_cast<size_t>(num_ranks));
  size_t below = 0;
  uint32_t b = 0;
  for (size_t r = 0; r < bucket.size(); ++r) {
    while (below + counts[b] <= ranks[r]) below += counts[b++];
    bucket[r] = b;
    within[r] = ranks[r] - below;
  }
  // The values of each distinct bucket, in the first rank's list that has it.
  std::vector<std::vector<double>> values(bucket.size());
  for (size_t r = 0; r < bucket.size(); ++r) {
    if (r == 0 || bucket[r] != bucket[r - 1]) values[r].reserve(counts[bucket[r]]);
  }
  for (const double* d = first; d != last; ++d) {
    const double a = std::abs(*d);
    const uint32_t k = AbsBucket(a);  // non-finite: beyond every finite bucket
    for (size_t r = 0; r < bucket.size(); ++r) {
      if (k == bucket[r]) {
        values[r].push_back(a);
        break;
      }
    }
  }
  for (size_t r = 0; r < bucket.size(); ++r) {
    size_t v = r;
    while (v > 0 && bucket[v - 1] == bucket[r]) --v;  // the bucket's values are in values[v]
    std::vector<double>& x = values[v];
    const auto k = x.begin() + static_cast<std::ptrdiff_t>(within[r]);
    std::nth_element(x.begin(), k, x.end());
    out[r] = *k;
  }
}

}  // namespace slshadow::compare
