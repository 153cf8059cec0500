#include "workflows/multiview/internal/fusion.h"

#include <algorithm>
#include <cmath>
#include <cstdint>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

namespace slshadow::multiview::internal {
namespace {

struct Entry {
  uint64_t key;
  uint32_t view;   // index into the fusion views
  uint32_t point;  // index into that view's points
  bool operator<(const Entry& o) const {
    return key != o.key ? key < o.key : (view != o.view ? view < o.view : point < o.point);
  }
};

struct OutPoint {
  Eigen::Vector3d position;
  Eigen::Vector3d normal;
  int view;
  uint8_t views;
  float sigma;
  uint8_t disagree;
};

// One view's points of one surface in one cell.
struct ViewPart {
  int view = 0;  // index into the fusion views
  int n = 0;
  Eigen::Vector3d sum_p = Eigen::Vector3d::Zero();
  Eigen::Vector3d sum_n = Eigen::Vector3d::Zero();
  double height = 0;
};

uint64_t CellKey(const Eigen::Vector3d& p, double inv_cell) {
  const Eigen::Vector3d q = (p * inv_cell).array().floor();
  auto c = [](double v) { return static_cast<uint64_t>(static_cast<int64_t>(v) & 0x1FFFFF); };
  return (c(q.x()) << 42) | (c(q.y()) << 21) | c(q.z());
}

// Fuses one surface of a cell: the largest set of mutually agreeing views becomes one point,
// every other view keeps its own.
void FuseSurface(std::vector<ViewPart>& parts, const std::vector<FusionView>& views, double k_sigma,
                 double min_dis, std::vector<OutPoint>* out) {
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();
  for (const auto& p : parts) normal += p.sum_n;
  normal.normalize();
  for (auto& p : parts) p.height = normal.dot(p.sum_p) / p.n;
  const size_t m = parts.size();
  auto agree = [&](const ViewPart& a, const ViewPart& b) {
    const double sa = views[static_cast<size_t>(a.view)].sigma_mm;
    const double sb = views[static_cast<size_t>(b.view)].sigma_mm;
    const double tol = std::max(min_dis, k_sigma * std::sqrt(sa * sa / a.n + sb * sb / b.n));
    return std::abs(a.height - b.height) <= tol;
  };
  size_t best = 0;
  int best_support = -1, best_n = -1;
  for (size_t i = 0; i < m; ++i) {
    int support = 0;
    for (size_t j = 0; j < m; ++j) support += agree(parts[i], parts[j]) ? 1 : 0;
    if (support > best_support || (support == best_support && parts[i].n > best_n)) {
      best = i;
      best_support = support;
      best_n = parts[i].n;
    }
  }
  const uint8_t flag = static_cast<size_t>(best_support) < m ? 1 : 0;
  Eigen::Vector3d sum_p = Eigen::Vector3d::Zero(), sum_n = Eigen::Vector3d::Zero();
  double sum_w = 0;
  int top_view = -1, top_n = -1, fused = 0;
  for (size_t j = 0; j < m; ++j) {
    const ViewPart& p = parts[j];
    const double sigma = views[static_cast<size_t>(p.view)].sigma_mm;
    if (agree(parts[best], p)) {
      const double w = 1.0 / (sigma * sigma);
      sum_p += w * p.sum_p;
      sum_n += w * p.sum_n;
      sum_w += w * p.n;
      ++fused;
      if (p.n > top_n) {
        top_n = p.n;
        top_view = views[static_cast<size_t>(p.view)].view;
      }
    } else {
      out->push_back({p.sum_p / p.n, p.sum_n.normalized(), views[static_cast<size_t>(p.view)].view,
                      1, static_cast<float>(sigma / std::sqrt(static_cast<double>(p.n))), 1});
    }
  }
  out->push_back({sum_p / sum_w, sum_n.normalized(), top_view,
                  static_cast<uint8_t>(std::min(fused, 255)),
                  static_cast<float>(1.0 / std::sqrt(sum_w)), flag});
}

}  // namespace

void FuseViews(const std::vector<FusionView>& views, double cell_mm, double k_sigma,
               double min_disagreement_mm, MergeResult* result) {
  std::vector<std::vector<Eigen::Vector3d>> pos(views.size()), nrm(views.size());
  size_t total = 0;
  for (const auto& v : views) total += v.points->size();
  std::vector<Entry> entries(total);
  const double inv_cell = 1.0 / cell_mm;
  size_t offset = 0;
  for (size_t k = 0; k < views.size(); ++k) {
    const auto& v = views[k];
    const size_t n = v.points->size();
    pos[k].resize(n);
    nrm[k].resize(n);
    const Eigen::Matrix3d r = v.part_from_rig.rotation.toRotationMatrix();
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, n, 8192), [&](const tbb::blocked_range<size_t>& range) {
          for (size_t i = range.begin(); i != range.end(); ++i) {
            pos[k][i] = r * (*v.points)[i] + v.part_from_rig.translation;
            nrm[k][i] = r * (*v.normals)[i];
            entries[offset + i] = {CellKey(pos[k][i], inv_cell), static_cast<uint32_t>(k),
                                   static_cast<uint32_t>(i)};
          }
        });
    offset += n;
  }
  tbb::parallel_sort(entries.begin(), entries.end());
  std::vector<size_t> cell_begin;
  for (size_t i = 0; i < entries.size(); ++i)
    if (i == 0 || entries[i].key != entries[i - 1].key) cell_begin.push_back(i);
  cell_begin.push_back(entries.size());
  const size_t cells = cell_begin.size() - 1;

  constexpr size_t kChunk = 4096;  // cells per task: fixed, so the output order is too
  const size_t chunks = (cells + kChunk - 1) / kChunk;
  std::vector<std::vector<OutPoint>> chunk_out(chunks);
  constexpr double kSameSurface = 0.5;  // cos 60 deg
  tbb::parallel_for(size_t{0}, chunks, [&](size_t c) {
    std::vector<Eigen::Vector3d> seeds;
    std::vector<std::vector<ViewPart>> surfaces;
    for (size_t cell = c * kChunk; cell < std::min(cells, (c + 1) * kChunk); ++cell) {
      seeds.clear();
      surfaces.clear();
      for (size_t e = cell_begin[cell]; e < cell_begin[cell + 1]; ++e) {
        const Entry& en = entries[e];
        const Eigen::Vector3d& n = nrm[en.view][en.point];
        size_t s = 0;
        while (s < seeds.size() && seeds[s].dot(n) < kSameSurface) ++s;
        if (s == seeds.size()) {
          seeds.push_back(n);
          surfaces.emplace_back();
        }
        auto& parts = surfaces[s];
        if (parts.empty() || parts.back().view != static_cast<int>(en.view)) {
          parts.emplace_back();
          parts.back().view = static_cast<int>(en.view);
        }
        // Entries are sorted by view within a cell, so a view's points of a surface are
        // consecutive among that surface's.
        ViewPart& part = parts.back();
        ++part.n;
        part.sum_p += pos[en.view][en.point];
        part.sum_n += n;
      }
      for (auto& parts : surfaces)
        FuseSurface(parts, views, k_sigma, min_disagreement_mm, &chunk_out[c]);
    }
  });

  size_t out_n = 0;
  for (const auto& v : chunk_out) out_n += v.size();
  PointCloud& cloud = result->merged;
  cloud = PointCloud();
  cloud.points.reserve(out_n);
  cloud.normals.reserve(out_n);
  result->point_view.clear();
  result->point_views.clear();
  result->point_sigma_mm.clear();
  result->disagree.clear();
  result->disagree_points = 0;
  for (const auto& v : chunk_out) {
    for (const OutPoint& p : v) {
      cloud.points.push_back(p.position);
      cloud.normals.push_back(p.normal.cast<float>());
      result->point_view.push_back(p.view);
      result->point_views.push_back(p.views);
      result->point_sigma_mm.push_back(p.sigma);
      result->disagree.push_back(p.disagree);
      result->disagree_points += p.disagree;
    }
  }
  auto to_float = [](const auto& values) {
    std::vector<float> f(values.size());
    for (size_t i = 0; i < values.size(); ++i) f[i] = static_cast<float>(values[i]);
    return f;
  };
  cloud.SetScalar("view", to_float(result->point_view));
  cloud.SetScalar("views_fused", to_float(result->point_views));
  cloud.SetScalar("sigma_mm", result->point_sigma_mm);
  cloud.SetScalar("disagree", to_float(result->disagree));
  result->input_points = total;
}

}  // namespace slshadow::multiview::internal
