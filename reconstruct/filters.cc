#include "reconstruct/filters.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

namespace slshadow {

namespace {

constexpr uint8_t kAccepted = static_cast<uint8_t>(RejectReason::kAccepted);

// Per-thread scratch buffers, kept between calls: a 1920x1200 grid needs ~20 MB of temporaries
// per filter, and fresh allocations of that size are fresh pages from the kernel every call
// (page faults cost ~10 % of a reconstruction). The caller's thread owns them; the row-parallel
// workers reach them through the caller's reference.
// Fills v[0, n) with `value`, row-parallel (blocks of 64k elements).
template <typename T>
void ParallelFill(std::vector<T>& v, size_t n, const T& value) {
  v.resize(n);
  constexpr size_t kBlock = size_t{1} << 16;
  const int blocks = static_cast<int>((n + kBlock - 1) / kBlock);
  cv::parallel_for_(cv::Range(0, blocks), [&](const cv::Range& r) {
    const size_t a = static_cast<size_t>(r.start) * kBlock,
                 b = std::min(n, static_cast<size_t>(r.end) * kBlock);
    std::fill(v.begin() + static_cast<std::ptrdiff_t>(a),
              v.begin() + static_cast<std::ptrdiff_t>(b), value);
  });
}

thread_local std::vector<double> scratch_doubles;
thread_local std::array<std::vector<uint8_t>, 2> scratch_bytes;

std::vector<double>& ScratchDoubles(size_t n, double fill) {
  std::vector<double>& b = scratch_doubles;
  ParallelFill(b, n, fill);
  return b;
}
std::vector<uint8_t>& ScratchBytes(size_t n, int slot) {
  std::vector<uint8_t>& buffer = scratch_bytes[static_cast<size_t>(slot)];
  ParallelFill(buffer, n, uint8_t{0});
  return buffer;
}

double Range(const DenseGrid& grid, size_t i) {
  return (grid.point_in_rig[i] - grid.viewpoint_in_rig).norm();
}

}  // namespace

void ReleaseFilterScratch() {
  std::vector<double>().swap(scratch_doubles);
  for (auto& b : scratch_bytes) std::vector<uint8_t>().swap(b);
}

int64_t FilterDepthDiscontinuities(DenseGrid& grid, double max_jump_footprints, int dilation_px) {
  const int w = grid.width, h = grid.height;
  std::vector<double>& range = ScratchDoubles(grid.reason.size(), 0.0);
  cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      for (int u = 0; u < w; ++u) {
        const size_t i = grid.Index(u, v);
        if (grid.Accepted(i)) range[i] = Range(grid, i);
      }
    }
  });
  std::vector<uint8_t>& jump = ScratchBytes(grid.reason.size(), 0);
  cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      for (int u = 0; u < w; ++u) {
        const size_t i = grid.Index(u, v);
        if (!grid.Accepted(i)) continue;
        const double limit = max_jump_footprints * range[i] / grid.focal_px;
        const int du[4] = {-1, 1, 0, 0};
        const int dv[4] = {0, 0, -1, 1};
        for (int k = 0; k < 4; ++k) {
          const int un = u + du[k], vn = v + dv[k];
          if (un < 0 || vn < 0 || un >= w || vn >= h) continue;
          const size_t j = grid.Index(un, vn);
          if (grid.Accepted(j) && std::abs(range[j] - range[i]) > limit) {
            jump[i] = 1;
            break;
          }
        }
      }
    }
  });
  const int r = std::max(0, dilation_px);
  std::atomic<int64_t> rejected{0};
  // The (2r + 1)^2 dilation as two separable passes: `near` marks cells with a jump within r along
  // their row; a cell is then hit when `near` is set within r along its column. Each cell of the
  // second pass reads `near` only and writes its own reason: rows can be marked in place.
  std::vector<uint8_t>& near = ScratchBytes(grid.reason.size(), 1);
  cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      const uint8_t* in = jump.data() + grid.Index(0, v);
      uint8_t* out = near.data() + grid.Index(0, v);
      int last = -1 - 2 * r;  // column of the last jump seen, left to right
      for (int u = 0; u < std::min(w, r); ++u) {
        if (in[u]) last = u;
      }
      for (int u = 0; u < w; ++u) {
        if (u + r < w && in[u + r]) last = u + r;
        out[u] = last >= u - r ? 1 : 0;
      }
    }
  });
  cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
    int64_t local = 0;
    for (int v = rows.start; v < rows.end; ++v) {
      const int v0 = std::max(0, v - r), v1 = std::min(h - 1, v + r);
      for (int u = 0; u < w; ++u) {
        const size_t i = grid.Index(u, v);
        if (!grid.Accepted(i)) continue;
        bool hit = false;
        for (int vn = v0; vn <= v1 && !hit; ++vn) hit = near[grid.Index(u, vn)] != 0;
        if (hit) {
          grid.reason[i] = static_cast<uint8_t>(RejectReason::kDepthDiscontinuity);
          ++local;
        }
      }
    }
    rejected += local;
  });
  return rejected.load();
}

int64_t FilterStatisticalOutliers(DenseGrid& grid, int window_radius_px, int neighbors,
                                  double std_ratio, double min_distance_footprints) {
  const int w = grid.width, h = grid.height, r = std::max(1, window_radius_px);
  const int k = std::max(1, neighbors);
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<double>& score =
      ScratchDoubles(grid.reason.size(), -1.0);  // -1: not an accepted cell
  if (r == 1 && k <= 8) {
    // 3x3 window: the 8 squared distances (+inf where no accepted neighbour) ordered by a
    // branch-free sorting network; the sum of the k smallest in ascending order is then the same
    // as the insertion below computes.
    cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
      for (int v = rows.start; v < rows.end; ++v) {
        for (int u = 0; u < w; ++u) {
          const size_t i = grid.Index(u, v);
          if (!grid.Accepted(i)) continue;
          const Eigen::Vector3d& p = grid.point_in_rig[i];
          double d[8];
          int m = 0, q = 0;
          if (u > 0 && v > 0 && u < w - 1 && v < h - 1) {
            // Interior cell: no bounds tests.
            const size_t row = static_cast<size_t>(w);
            const size_t js[8] = {i - row - 1, i - row,     i - row + 1, i - 1,
                                  i + 1,       i + row - 1, i + row,     i + row + 1};
            for (size_t j : js) {
              const bool ok = grid.reason[j] == kAccepted;
              d[q++] = ok ? (grid.point_in_rig[j] - p).squaredNorm() : inf;
              m += ok ? 1 : 0;
            }
          } else {
            for (int dv = -1; dv <= 1; ++dv) {
              for (int du = -1; du <= 1; ++du) {
                if (du == 0 && dv == 0) continue;
                const int un = u + du, vn = v + dv;
                double dist = inf;
                if (un >= 0 && vn >= 0 && un < w && vn < h) {
                  const size_t j = grid.Index(un, vn);
                  if (grid.reason[j] == kAccepted) {
                    dist = (grid.point_in_rig[j] - p).squaredNorm();
                    ++m;
                  }
                }
                d[q++] = dist;
              }
            }
          }
          if (m == 0) {
            score[i] = inf;
            continue;
          }
          auto cswap = [&d](int a, int b) {
            const double lo = std::min(d[a], d[b]), hi = std::max(d[a], d[b]);
            d[a] = lo;
            d[b] = hi;
          };
          // Batcher's odd-even merge sort for 8 inputs (19 comparators).
          cswap(0, 1);
          cswap(2, 3);
          cswap(4, 5);
          cswap(6, 7);
          cswap(0, 2);
          cswap(1, 3);
          cswap(4, 6);
          cswap(5, 7);
          cswap(1, 2);
          cswap(5, 6);
          cswap(0, 4);
          cswap(1, 5);
          cswap(2, 6);
          cswap(3, 7);
          cswap(2, 4);
          cswap(3, 5);
          cswap(1, 2);
          cswap(3, 4);
          cswap(5, 6);
          const int take = std::min(m, k);
          double sum = 0;
          for (int t = 0; t < take; ++t) sum += d[t];
          score[i] = std::sqrt(sum / take * (grid.focal_px * grid.focal_px) /
                               (p - grid.viewpoint_in_rig).squaredNorm());
        }
      }
    });
  } else {
    cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
      // The k smallest squared distances so far, ascending (insertion: k is small; no allocation
      // per cell).
      std::vector<double> best(static_cast<size_t>(k));
      for (int v = rows.start; v < rows.end; ++v) {
        const int v0 = std::max(0, v - r), v1 = std::min(h - 1, v + r);
        for (int u = 0; u < w; ++u) {
          const size_t i = grid.Index(u, v);
          if (!grid.Accepted(i)) continue;
          const Eigen::Vector3d& p = grid.point_in_rig[i];
          const int u0 = std::max(0, u - r), u1 = std::min(w - 1, u + r);
          int m = 0;
          for (int vn = v0; vn <= v1; ++vn) {
            const size_t row = grid.Index(0, vn);
            for (int un = u0; un <= u1; ++un) {
              const size_t j = row + static_cast<size_t>(un);
              if (j == i || grid.reason[j] != kAccepted) continue;
              const double d = (grid.point_in_rig[j] - p).squaredNorm();
              if (m == k && d >= best[static_cast<size_t>(k - 1)]) continue;
              int pos = m < k ? m++ : k - 1;
              while (pos > 0 && best[static_cast<size_t>(pos - 1)] > d) {
                best[static_cast<size_t>(pos)] = best[static_cast<size_t>(pos - 1)];
                --pos;
              }
              best[static_cast<size_t>(pos)] = d;
            }
          }
          if (m == 0) {
            score[i] = inf;
            continue;
          }
          double sum = 0;
          for (int q = 0; q < m; ++q) sum += best[static_cast<size_t>(q)];
          // RMS distance to the m nearest, in footprints (one square root per cell).
          score[i] = std::sqrt(sum / m * (grid.focal_px * grid.focal_px) /
                               (p - grid.viewpoint_in_rig).squaredNorm());
        }
      }
    });
  }
  // Mean and spread of the scores: per-row partial sums (row-parallel), added in row order.
  std::vector<std::array<double, 3>> row_sums(static_cast<size_t>(h));
  cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      double sum = 0, sum2 = 0, n = 0;
      for (size_t i = grid.Index(0, v), end = i + static_cast<size_t>(w); i < end; ++i) {
        const double s = score[i];
        if (s >= 0 && std::isfinite(s)) {
          sum += s;
          sum2 += s * s;
          n += 1;
        }
      }
      row_sums[static_cast<size_t>(v)] = {sum, sum2, n};
    }
  });
  double sum = 0, sum2 = 0;
  int64_t n = 0;
  for (const auto& r : row_sums) {
    sum += r[0];
    sum2 += r[1];
    n += static_cast<int64_t>(r[2]);
  }
  const double mean = n > 0 ? sum / static_cast<double>(n) : 0.0;
  const double var = n > 1 ? std::max(0.0, (sum2 - sum * mean) / static_cast<double>(n - 1)) : 0.0;
  const double limit = std::max(mean + std_ratio * std::sqrt(var), min_distance_footprints);
  std::atomic<int64_t> rejected{0};
  cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
    int64_t local = 0;
    for (int v = rows.start; v < rows.end; ++v) {
      for (size_t i = grid.Index(0, v), end = i + static_cast<size_t>(w); i < end; ++i) {
        if (score[i] >= 0 && score[i] > limit) {
          grid.reason[i] = static_cast<uint8_t>(RejectReason::kOutlier);
          ++local;
        }
      }
    }
    rejected += local;
  });
  return rejected.load();
}

std::vector<Eigen::Vector3f> EstimateNormals(const DenseGrid& grid, int64_t* fallback_count) {
  std::vector<Eigen::Vector3f> normals;
  EstimateNormals(grid, &normals, fallback_count);
  return normals;
}

void EstimateNormals(const DenseGrid& grid, std::vector<Eigen::Vector3f>* out,
                     int64_t* fallback_count) {
  const int w = grid.width, h = grid.height;
  out->resize(grid.reason.size());  // every cell is written below
  std::vector<Eigen::Vector3f>& normals = *out;
  std::atomic<int64_t> fallbacks{0};
  cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
    int64_t local = 0;
    auto accepted = [&](int u, int v) {
      return u >= 0 && v >= 0 && u < w && v < h && grid.Accepted(grid.Index(u, v));
    };
    auto tangent = [&](int u, int v, int du, int dv, Eigen::Vector3d* t) {
      const bool fwd = accepted(u + du, v + dv), back = accepted(u - du, v - dv);
      if (fwd && back) {
        *t = grid.point_in_rig[grid.Index(u + du, v + dv)] -
             grid.point_in_rig[grid.Index(u - du, v - dv)];
      } else if (fwd) {
        *t = grid.point_in_rig[grid.Index(u + du, v + dv)] - grid.point_in_rig[grid.Index(u, v)];
      } else if (back) {
        *t = grid.point_in_rig[grid.Index(u, v)] - grid.point_in_rig[grid.Index(u - du, v - dv)];
      } else {
        return false;
      }
      return true;
    };
    for (int v = rows.start; v < rows.end; ++v) {
      for (int u = 0; u < w; ++u) {
        const size_t i = grid.Index(u, v);
        if (!grid.Accepted(i)) {
          normals[i] = Eigen::Vector3f::Zero();
          continue;
        }
        const Eigen::Vector3d to_view = grid.viewpoint_in_rig - grid.point_in_rig[i];
        Eigen::Vector3d tu, tv;
        Eigen::Vector3d n = Eigen::Vector3d::Zero();
        if (tangent(u, v, 1, 0, &tu) && tangent(u, v, 0, 1, &tv)) n = tu.cross(tv);
        const double norm = n.norm();
        if (!(norm > 0) || !std::isfinite(norm)) {
          n = to_view.normalized();
          ++local;
        } else {
          n /= norm;
          if (n.dot(to_view) < 0) n = -n;
        }
        normals[i] = n.cast<float>();
      }
    }
    fallbacks += local;
  });
  if (fallback_count) *fallback_count = fallbacks.load();
}

}  // namespace slshadow
