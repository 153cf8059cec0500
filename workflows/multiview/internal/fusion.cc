#include "workflows/multiview/internal/fusion.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <memory>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include "core/kdtree.h"

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
  uint64_t mask;  // bit (fusion view index % 64) of every view in the point
  float factor;   // noise factor of its points (1: flat and head-on), weighted
  float edge;     // the edge part of it (1 + min(v, 5 v0) / v0), weighted
};

// One view's points of one surface in one cell, each weighted by 1 / factor^2.
struct ViewPart {
  int view = 0;  // index into the fusion views
  int n = 0;
  double w = 0;       // sum of the weights
  double w_edge = 0;  // sum of weight x edge factor
  Eigen::Vector3d sum_p = Eigen::Vector3d::Zero();
  Eigen::Vector3d sum_n = Eigen::Vector3d::Zero();
  double height = 0;
  double sigma = 0;  // of the part's weighted mean along the normal
};

uint64_t CellKey(const Eigen::Vector3d& p, double inv_cell) {
  const Eigen::Vector3d q = (p * inv_cell).array().floor();
  auto c = [](double v) { return static_cast<uint64_t>(static_cast<int64_t>(v) & 0x1FFFFF); };
  return (c(q.x()) << 42) | (c(q.y()) << 21) | c(q.z());
}

uint64_t Bit(int view) { return uint64_t{1} << (static_cast<unsigned>(view) % 64); }

// Fuses one surface of a cell: the largest set of mutually agreeing views becomes one point,
// every other view keeps its own.
void FuseSurface(std::vector<ViewPart>& parts, const std::vector<FusionView>& views,
                 const FusionOptions& o, std::vector<OutPoint>* out) {
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();
  for (const auto& p : parts) normal += p.sum_n;
  normal.normalize();
  for (auto& p : parts) {
    p.height = normal.dot(p.sum_p) / p.w;
    p.sigma = views[static_cast<size_t>(p.view)].sigma_mm / std::sqrt(p.w);
  }
  const size_t m = parts.size();
  auto agree = [&](const ViewPart& a, const ViewPart& b) {
    const double tol = std::max(o.min_disagreement_mm,
                                o.k_sigma * std::sqrt(a.sigma * a.sigma + b.sigma * b.sigma));
    return std::abs(a.height - b.height) <= tol;
  };
  size_t best = 0;
  int best_support = -1;
  double best_w = -1;
  for (size_t i = 0; i < m; ++i) {
    int support = 0;
    for (size_t j = 0; j < m; ++j) support += agree(parts[i], parts[j]) ? 1 : 0;
    const double w = 1.0 / (parts[i].sigma * parts[i].sigma);
    if (support > best_support || (support == best_support && w > best_w)) {
      best = i;
      best_support = support;
      best_w = w;
    }
  }
  const uint8_t flag = static_cast<size_t>(best_support) < m ? 1 : 0;
  Eigen::Vector3d sum_p = Eigen::Vector3d::Zero(), sum_n = Eigen::Vector3d::Zero();
  double sum_w = 0, sum_n_pts = 0, sum_pw = 0, sum_pe = 0;
  int top_view = -1, top_n = -1, fused = 0;
  uint64_t mask = 0;
  for (size_t j = 0; j < m; ++j) {
    const ViewPart& p = parts[j];
    const double s = views[static_cast<size_t>(p.view)].sigma_mm;
    const double factor = std::sqrt(p.n / p.w);
    if (agree(parts[best], p)) {
      const double w = 1.0 / (s * s);  // per unit point weight
      sum_p += w * p.sum_p;
      sum_n += w * p.sum_n;
      sum_w += w * p.w;
      sum_n_pts += p.n;
      sum_pw += p.w;
      sum_pe += p.w_edge;
      ++fused;
      mask |= Bit(p.view);
      if (p.n > top_n) {
        top_n = p.n;
        top_view = views[static_cast<size_t>(p.view)].view;
      }
    } else {
      out->push_back({p.sum_p / p.w, p.sum_n.normalized(), views[static_cast<size_t>(p.view)].view,
                      1, static_cast<float>(p.sigma), 1, Bit(p.view), static_cast<float>(factor),
                      static_cast<float>(p.w_edge / p.w)});
    }
  }
  out->push_back(
      {sum_p / sum_w, sum_n.normalized(), top_view, static_cast<uint8_t>(std::min(fused, 255)),
       static_cast<float>(1.0 / std::sqrt(sum_w)), flag, mask,
       static_cast<float>(std::sqrt(sum_n_pts / sum_pw)), static_cast<float>(sum_pe / sum_pw)});
}

// The edge factor of a point and its noise factor (FusionOptions): edges and grazing incidence.
// v_ref: the view's reference variation (FuseViews), > 0; 0: no edge factor.
double EdgeFactor(double v_ref, float variation) {
  if (v_ref <= 0) return 1;
  const double v = std::min(static_cast<double>(variation), 5 * v_ref);
  return 1 + std::max(v, 0.0) / v_ref;
}
double NoiseFactor(const FusionOptions& o, double v_ref, const Eigen::Vector3d& p_rig,
                   const Eigen::Vector3d& n_rig, float variation) {
  double f = EdgeFactor(v_ref, variation);
  if (o.min_incidence_cos > 0) {
    const double r = p_rig.norm();
    const double c = r > 0 ? std::abs(n_rig.dot(p_rig)) / r : 1.0;
    f /= std::sqrt(std::max(c, o.min_incidence_cos));
  }
  return f;
}

// What the check of a single-view point decides (FuseViews, step 2).
enum class Support : uint8_t { kKeep, kSuperseded, kRejected, kDisagree };

}  // namespace

void FuseViews(const std::vector<FusionView>& views, const FusionOptions& o, MergeResult* result) {
  std::vector<std::vector<Eigen::Vector3d>> pos(views.size()), nrm(views.size());
  std::vector<std::vector<float>> weight(views.size());
  std::vector<std::vector<float>> edge(views.size());
  size_t total = 0;
  for (const auto& v : views) total += v.points->size();
  std::vector<Entry> entries(total);
  const double inv_cell = 1.0 / o.cell_mm;
  size_t offset = 0;
  for (size_t k = 0; k < views.size(); ++k) {
    const auto& v = views[k];
    const size_t n = v.points->size();
    pos[k].resize(n);
    nrm[k].resize(n);
    weight[k].resize(n);
    edge[k].resize(n);
    const Eigen::Matrix3d r = v.part_from_rig.rotation.toRotationMatrix();
    // The reference variation: edge_variation, or 3 x the view's median (what its noise alone
    // gives a flat surface) when that is larger.
    double v_ref = o.edge_variation;
    if (v_ref > 0 && v.variation && !v.variation->empty()) {
      std::vector<float> sorted = *v.variation;
      std::nth_element(sorted.begin(), sorted.begin() + static_cast<long>(sorted.size() / 2),
                       sorted.end());
      v_ref = std::max(v_ref, 3.0 * sorted[sorted.size() / 2]);
    }
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, n, 8192), [&](const tbb::blocked_range<size_t>& range) {
          for (size_t i = range.begin(); i != range.end(); ++i) {
            const Eigen::Vector3d& p = (*v.points)[i];
            const Eigen::Vector3d& nr = (*v.normals)[i];
            pos[k][i] = r * p + v.part_from_rig.translation;
            nrm[k][i] = r * nr;
            const float variation = v.variation ? (*v.variation)[i] : 0.0f;
            const double f = NoiseFactor(o, v_ref, p, nr, variation);
            weight[k][i] = static_cast<float>(1.0 / (f * f));
            edge[k][i] = static_cast<float>(EdgeFactor(v_ref, variation));
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

  // 1. Cells. A point off edges (surface variation at most the reference, so its normal is
  // reliable) seeds or joins a surface by normal; then each edge point joins the surface whose
  // normal is nearest its own (a surface of its own only in a cell of edge points).
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
      for (int pass = 0; pass < 2; ++pass) {
        for (size_t e = cell_begin[cell]; e < cell_begin[cell + 1]; ++e) {
          const Entry& en = entries[e];
          const float w = weight[en.view][en.point];
          const bool reliable = edge[en.view][en.point] <= 2.0f;  // v <= v_ref
          if (reliable != (pass == 0)) continue;
          const Eigen::Vector3d& n = nrm[en.view][en.point];
          size_t s = seeds.size();
          if (reliable || seeds.empty()) {
            s = 0;
            while (s < seeds.size() && seeds[s].dot(n) < kSameSurface) ++s;
          } else {
            double best = -2;
            for (size_t t = 0; t < seeds.size(); ++t) {
              if (seeds[t].dot(n) > best) {
                best = seeds[t].dot(n);
                s = t;
              }
            }
          }
          if (s == seeds.size()) {
            seeds.push_back(n);
            surfaces.emplace_back();
          }
          auto& parts = surfaces[s];
          size_t k = 0;
          while (k < parts.size() && parts[k].view != static_cast<int>(en.view)) ++k;
          if (k == parts.size()) {
            parts.emplace_back();
            parts.back().view = static_cast<int>(en.view);
          }
          ViewPart& part = parts[k];
          ++part.n;
          part.w += w;
          part.w_edge += w * edge[en.view][en.point];
          part.sum_p += w * pos[en.view][en.point];
          part.sum_n += w * n;
        }
      }
      for (auto& parts : surfaces) FuseSurface(parts, views, o, &chunk_out[c]);
    }
  });
  std::vector<OutPoint> out;
  {
    size_t out_n = 0;
    for (const auto& v : chunk_out) out_n += v.size();
    out.reserve(out_n);
    for (auto& v : chunk_out) {
      out.insert(out.end(), v.begin(), v.end());
      std::vector<OutPoint>().swap(v);
    }
  }

  // 2. A point one view alone gave, of a noisy kind (edge, grazing), against the other views'
  // points within support_radius_mm that are no noisier: on the surface of one of them within
  // their combined noise, it adds nothing they do not measure better (superseded); an edge point
  // (surface variation above the reference) in front of the surfaces of two or more other views
  // within reject_radius_mm (in the space they see through) and on none is that view's outlier
  // (rejected, e.g. a point off a depth edge); otherwise off another view's surface, the views
  // disagree (flagged, kept apart).
  std::vector<Support> support(out.size(), Support::kKeep);
  const double near_radius = std::max(o.support_radius_mm, o.reject_radius_mm);
  std::vector<Eigen::Vector3d> positions;
  std::unique_ptr<KdTree> out_tree;
  if (near_radius > 0 && !out.empty()) {
    positions.resize(out.size());
    for (size_t i = 0; i < out.size(); ++i) positions[i] = out[i].position;
    out_tree = std::make_unique<KdTree>(positions);
  }
  if (o.support_radius_mm > 0 && out_tree) {
    const KdTree& tree = *out_tree;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, out.size(), 2048),
                      [&](const tbb::blocked_range<size_t>& range) {
                        std::vector<Neighbor> nn;
                        for (size_t i = range.begin(); i != range.end(); ++i) {
                          const OutPoint& p = out[i];
                          if (p.views != 1 || p.disagree || p.factor < o.support_min_factor)
                            continue;
                          tree.Radius(p.position, near_radius, &nn);
                          uint64_t agree = 0, contra = 0;
                          for (const auto& q_n : nn) {
                            const OutPoint& q = out[q_n.index];
                            if ((q.mask & ~p.mask) == 0 || q.sigma > p.sigma) continue;
                            const double signed_h = q.normal.dot(p.position - q.position);
                            const double h = std::abs(signed_h);
                            const double tol = std::max(
                                o.min_disagreement_mm,
                                o.k_sigma * std::sqrt(static_cast<double>(p.sigma) * p.sigma +
                                                      static_cast<double>(q.sigma) * q.sigma));
                            const double d = std::sqrt(q_n.distance_sq);
                            if (h <= tol) {
                              if (d <= o.support_radius_mm) agree |= q.mask & ~p.mask;
                            } else if (signed_h > 0 && d <= o.reject_radius_mm) {
                              contra |= q.mask & ~p.mask;
                            }
                          }
                          if (agree != 0) {
                            support[i] = Support::kSuperseded;
                          } else if (std::popcount(contra) >= 2 && p.edge > 2.0f) {
                            support[i] = Support::kRejected;
                          } else if (contra != 0) {
                            support[i] = Support::kDisagree;
                          }
                        }
                      });
  }

  // 3. Free space. A point one view alone gave lies where other views saw through it when all
  // their points (the backdrop included) along their line of sight through it lie beyond it: a
  // surface there would have hidden them. Lines of sight are matched by direction from each
  // view's camera (the origin of its rig frame), within see_through_pixels of the view's point
  // spacing (the median distance of a direction to its 4th nearest: the pitch on a pixel grid);
  // fewer than 3 points there: that view says nothing. Points in front of it, or on it within
  // the combined noise, clear it (the view saw it, or something hid it). Seen through by
  // see_through_views or more: rejected when noisy (factor >= support_min_factor) or when no
  // other view's point lies within the check's radius (a ghost far from every surface);
  // otherwise, a clean point near another view's surface, it is flagged `disagree` and kept
  // apart, as step 1 keeps a view that disagrees within a cell (such a point is not checked).
  if (o.see_through_views > 0 && views.size() > 1) {
    std::vector<uint32_t> candidates;
    for (size_t i = 0; i < out.size(); ++i)
      if (out[i].views == 1 && !out[i].disagree && support[i] != Support::kSuperseded &&
          support[i] != Support::kRejected)
        candidates.push_back(static_cast<uint32_t>(i));
    struct Sight {
      std::vector<Eigen::Vector3d> direction;  // (x / z, y / z, 0) in the rig frame
      std::vector<float> range;                // distance from the camera
      std::unique_ptr<KdTree> tree;
      double radius = 0;
      Rigid3d rig_from_part;
    };
    std::vector<Sight> sights(candidates.empty() ? 0 : views.size());
    tbb::parallel_for(size_t{0}, sights.size(), [&](size_t k) {
      Sight& s = sights[k];
      s.rig_from_part = views[k].part_from_rig.Inverse();
      size_t own = 0;  // s.direction[0, own): the view's own points
      for (const auto* set : {views[k].points, views[k].backdrop}) {
        if (set == nullptr) continue;
        for (const Eigen::Vector3d& p : *set) {
          if (!(p.z() > 0)) continue;
          s.direction.emplace_back(p.x() / p.z(), p.y() / p.z(), 0.0);
          s.range.push_back(static_cast<float>(p.norm()));
        }
        if (set == views[k].points) own = s.direction.size();
      }
      if (own < 5) return;
      s.tree = std::make_unique<KdTree>(s.direction, 32);
      // The angular point spacing: the median distance of the view's own points (a sample of
      // them) to their 4th nearest other direction (the backdrop's lie between, on the same grid).
      const size_t step = std::max<size_t>(1, own / 2000);
      std::vector<double> spacing;
      std::vector<Neighbor> nn;
      for (size_t i = 0; i < own; i += step) {
        s.tree->KNearest(s.direction[i], 5, &nn);
        if (nn.size() == 5 && nn[4].distance_sq > 0)
          spacing.push_back(std::sqrt(nn[4].distance_sq));
      }
      if (spacing.empty()) {
        s.tree.reset();
        return;
      }
      std::nth_element(spacing.begin(), spacing.begin() + static_cast<long>(spacing.size() / 2),
                       spacing.end());
      s.radius = o.see_through_pixels * spacing[spacing.size() / 2];
    });
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, candidates.size(), 512),
        [&](const tbb::blocked_range<size_t>& range) {
          std::vector<Neighbor> nn;
          for (size_t c = range.begin(); c != range.end(); ++c) {
            const size_t i = candidates[c];
            const OutPoint& p = out[i];
            int through = 0;
            for (size_t k = 0; k < sights.size(); ++k) {
              const Sight& s = sights[k];
              if (!s.tree || s.radius <= 0 || (p.mask & Bit(static_cast<int>(k))) != 0) continue;
              const Eigen::Vector3d q = s.rig_from_part * p.position;
              if (!(q.z() > 0)) continue;
              s.tree->Radius(Eigen::Vector3d(q.x() / q.z(), q.y() / q.z(), 0.0), s.radius, &nn);
              if (nn.size() < 3) continue;
              const double sk = views[k].sigma_mm;
              const double tol =
                  std::max(o.min_disagreement_mm,
                           o.k_sigma * std::sqrt(static_cast<double>(p.sigma) * p.sigma + sk * sk));
              const double beyond = q.norm() + tol;
              bool all = true;
              for (const Neighbor& n : nn) {
                if (s.range[n.index] <= beyond) {
                  all = false;
                  break;
                }
              }
              through += all ? 1 : 0;
            }
            if (through < o.see_through_views) continue;
            bool near = false;
            if (p.factor < o.support_min_factor && out_tree) {
              out_tree->Radius(p.position, near_radius, &nn);
              for (const Neighbor& n : nn) near = near || (out[n.index].mask & ~p.mask) != 0;
            }
            support[i] = near ? Support::kDisagree : Support::kRejected;
          }
        });
  }

  PointCloud& cloud = result->merged;
  cloud = PointCloud();
  cloud.points.reserve(out.size());
  cloud.normals.reserve(out.size());
  result->point_view.clear();
  result->point_views.clear();
  result->point_sigma_mm.clear();
  result->disagree.clear();
  result->disagree_points = 0;
  result->superseded_points = 0;
  result->rejected_points = 0;
  for (size_t i = 0; i < out.size(); ++i) {
    const OutPoint& p = out[i];
    if (support[i] == Support::kSuperseded) {
      ++result->superseded_points;
      continue;
    }
    if (support[i] == Support::kRejected) {
      ++result->rejected_points;
      continue;
    }
    const uint8_t disagree = support[i] == Support::kDisagree ? 1 : p.disagree;
    cloud.points.push_back(p.position);
    cloud.normals.push_back(p.normal.cast<float>());
    result->point_view.push_back(p.view);
    result->point_views.push_back(p.views);
    result->point_sigma_mm.push_back(p.sigma);
    result->disagree.push_back(disagree);
    result->disagree_points += disagree;
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
