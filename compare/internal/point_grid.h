// compare's uniform grid of points, behind Coverages() (compare/coverage.h) and MedianSpacing()
// (compare/median_spacing.h).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <Eigen/Core>

namespace slshadow::compare::internal {

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

}  // namespace slshadow::compare::internal
