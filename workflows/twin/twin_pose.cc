#include "workflows/twin/internal/twin_pose.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <unordered_map>

#include <nlohmann/json.hpp>

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <opencv2/core/utility.hpp>

#include "compare/mesh_distance.h"
#include "core/error.h"
#include "core/statistics.h"

namespace slshadow::twin::internal {
namespace {

using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat6 = Eigen::Matrix<double, 6, 6>;

// The point set and its geometry at one pose.
struct Problem {
  const compare::MeshDistance& mesh;
  std::vector<Eigen::Vector3d> points;  // rig frame, the fixed set
  std::vector<uint32_t> hints;          // last closest triangle per point (warm start)
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();  // part frame, at the starting pose
  double radius_mm = 1;      // RMS distance of the points from the centroid: scales rotations
  std::vector<uint8_t> use;  // 0: in a crease band this stage (not counted); empty: all counted
};

// Per triangle, its edges that are creases (the faces on the two sides differ by more than 10
// degrees) or open (no face on the other side, matched by vertex position): a point within a few
// noise sigmas of such an edge may be nearer the other face than its own, so its closest-point
// distance is biased towards zero (the nearer of two faces), by up to a sigma. Such points are
// left out of a stage (CreaseBandMembership).
struct CreaseEdges {
  const TriangleMesh& mesh;
  std::vector<uint8_t> flags;  // bit k: edge (k, k+1 mod 3) of the triangle is a crease / open

  explicit CreaseEdges(const TriangleMesh& m) : mesh(m), flags(m.NumTriangles(), 0) {
    const auto key = [&](int v) {
      const Eigen::Vector3d& x = mesh.vertices[static_cast<size_t>(v)];
      return std::array<int64_t, 3>{std::llround(x.x() * 1e5), std::llround(x.y() * 1e5),
                                    std::llround(x.z() * 1e5)};
    };
    std::map<std::pair<std::array<int64_t, 3>, std::array<int64_t, 3>>, std::vector<uint32_t>>
        edges;
    for (size_t t = 0; t < mesh.NumTriangles(); ++t) {
      for (int k = 0; k < 3; ++k) {
        auto a = key(mesh.triangles[t][k]), b = key(mesh.triangles[t][(k + 1) % 3]);
        if (b < a) std::swap(a, b);
        edges[{a, b}].push_back(static_cast<uint32_t>(t * 3 + static_cast<size_t>(k)));
      }
    }
    const double cos_limit = std::cos(10.0 * M_PI / 180.0);
    for (const auto& [e, sides] : edges) {
      bool crease = sides.size() != 2;
      if (!crease) {
        crease = mesh.FaceNormal(sides[0] / 3).dot(mesh.FaceNormal(sides[1] / 3)) < cos_limit;
      }
      if (!crease) continue;
      for (uint32_t s : sides) flags[s / 3] |= static_cast<uint8_t>(1u << (s % 3));
    }
  }

  // Distance from a point on triangle t to its nearest crease or open edge (infinity if none).
  double DistanceToCrease(uint32_t t, const Eigen::Vector3d& x) const {
    double best = std::numeric_limits<double>::infinity();
    if (!flags[t]) return best;
    for (int k = 0; k < 3; ++k) {
      if (!(flags[t] & (1u << k))) continue;
      const Eigen::Vector3d& a = mesh.vertices[static_cast<size_t>(mesh.triangles[t][k])];
      const Eigen::Vector3d& b = mesh.vertices[static_cast<size_t>(mesh.triangles[t][(k + 1) % 3])];
      const Eigen::Vector3d ab = b - a;
      const double u = std::clamp((x - a).dot(ab) / std::max(ab.squaredNorm(), 1e-30), 0.0, 1.0);
      best = std::min(best, (x - (a + u * ab)).norm());
    }
    return best;
  }
};

// Which points a stage counts: those whose closest point at `part_from_rig` lies farther than
// `band_mm` from a crease or open edge.
void CreaseBandMembership(Problem& p, const CreaseEdges& creases, const Rigid3d& part_from_rig,
                          double band_mm) {
  p.use.assign(p.points.size(), 1);
  cv::parallel_for_(cv::Range(0, static_cast<int>(p.points.size())), [&](const cv::Range& r) {
    for (int i = r.start; i < r.end; ++i) {
      const size_t k = static_cast<size_t>(i);
      const compare::MeshHit hit = p.mesh.Closest(part_from_rig * p.points[k], p.hints[k]);
      p.hints[k] = hit.triangle;
      if (creases.DistanceToCrease(hit.triangle, hit.closest) < band_mm) p.use[k] = 0;
    }
  });
}

struct Evaluation {
  double cost = 0;  // mean rho
  Mat6 a = Mat6::Zero();
  Vec6 b = Vec6::Zero();              // sum w J r
  std::vector<double> r;              // per point
  std::vector<Eigen::Vector3d> q, g;  // part-frame point and distance gradient per point
};

constexpr int kChunks = 64;  // fixed split: the same sums in the same order on any machine

Evaluation Evaluate(Problem& p, const Rigid3d& part_from_rig, double scale_mm, bool normal_eq,
                    bool keep_points = false) {
  const size_t n = p.points.size();
  Evaluation e;
  e.r.resize(n);
  if (keep_points) e.q.resize(n), e.g.resize(n);
  std::vector<double> cost(kChunks, 0.0);
  std::vector<int64_t> counted(kChunks, 0);
  std::vector<Mat6> a(normal_eq ? kChunks : 0, Mat6::Zero());
  std::vector<Vec6> b(normal_eq ? kChunks : 0, Vec6::Zero());
  const double inv_s2 = 1.0 / (scale_mm * scale_mm);
  const double inv_radius = 1.0 / p.radius_mm;
  cv::parallel_for_(cv::Range(0, kChunks), [&](const cv::Range& range) {
    for (int c = range.start; c < range.end; ++c) {
      const size_t lo = n * static_cast<size_t>(c) / kChunks;
      const size_t hi = n * static_cast<size_t>(c + 1) / kChunks;
      for (size_t i = lo; i < hi; ++i) {
        if (!p.use.empty() && !p.use[i]) {
          e.r[i] = std::numeric_limits<double>::quiet_NaN();
          continue;
        }
        ++counted[static_cast<size_t>(c)];
        const Eigen::Vector3d q = part_from_rig * p.points[i];
        const compare::MeshHit hit = p.mesh.Closest(q, p.hints[i]);
        p.hints[i] = hit.triangle;
        const double r = hit.signed_distance_mm;
        // The exact gradient of the signed distance: from the closest point to q (outward); on
        // the surface itself, the face normal.
        const Eigen::Vector3d g = std::abs(r) > 1e-9 ? Eigen::Vector3d((q - hit.closest) / r)
                                                     : p.mesh.FaceNormal(hit.triangle);
        e.r[i] = r;
        if (keep_points) e.q[i] = q, e.g[i] = g;
        const double u2 = r * r * inv_s2;
        cost[static_cast<size_t>(c)] += u2 / (1 + u2);
        if (!normal_eq) continue;
        const double w = 1.0 / ((1 + u2) * (1 + u2));
        Vec6 j;
        j.head<3>() = g;
        j.tail<3>() = (q - p.centroid).cross(g) * inv_radius;
        a[static_cast<size_t>(c)].selfadjointView<Eigen::Lower>().rankUpdate(j, w);
        b[static_cast<size_t>(c)] += w * r * j;
      }
    }
  });
  int64_t total = 0;
  for (int c = 0; c < kChunks; ++c) {
    e.cost += cost[static_cast<size_t>(c)];
    total += counted[static_cast<size_t>(c)];
    if (normal_eq) e.a += a[static_cast<size_t>(c)], e.b += b[static_cast<size_t>(c)];
  }
  e.a = e.a.selfadjointView<Eigen::Lower>();
  e.cost /= static_cast<double>(std::max<int64_t>(1, total));
  return e;
}

// The motion of the part frame for a scaled step x = (dt, radius dw) about the centroid.
Rigid3d StepMotion(const Problem& p, const Vec6& x) {
  const Eigen::Vector3d w = x.tail<3>() / p.radius_mm;
  const Eigen::Quaterniond r = QuaternionFromRotationVector(w);
  // q -> c + R (q - c) + dt
  return Rigid3d(r, p.centroid + x.head<3>() - r * p.centroid);
}

// Robust scale of the residuals within 3 s: 1.4826 x their median absolute value.
double RobustScale(const std::vector<double>& r, double s) {
  std::vector<double> a;
  a.reserve(r.size());
  for (double x : r) {
    if (std::abs(x) < 3 * s) a.push_back(std::abs(x));  // NaN (not counted) fails the test
  }
  if (a.empty()) return s;
  return 1.4826 * Median(std::vector<double>(a));
}

std::string Vec(const Eigen::Vector3d& v) {
  char buf[96];
  std::snprintf(buf, sizeof(buf), "(%.2f, %.2f, %.2f)", v.x(), v.y(), v.z());
  return buf;
}

}  // namespace

double PoseUncertainty::PointSigmaMm(const Eigen::Vector3d& q_in_part,
                                     const Eigen::Vector3d& n_in_part) const {
  Vec6 j;
  j.head<3>() = n_in_part;
  j.tail<3>() = (q_in_part - centroid_in_part).cross(n_in_part);
  return std::sqrt(std::max(0.0, j.dot(covariance * j)));
}

double PoseCost(const TriangleMesh& part_surface, const std::vector<Eigen::Vector3d>& cloud_in_rig,
                const Rigid3d& part_from_rig, double scale_mm, double gate_mm) {
  const compare::MeshDistance mesh(part_surface);
  Problem p{mesh, {}, {}, Eigen::Vector3d::Zero(), 1.0, {}};
  for (const auto& x : cloud_in_rig) {
    if (std::abs(mesh.Closest(part_from_rig * x).signed_distance_mm) < gate_mm)
      p.points.push_back(x);
  }
  p.hints.assign(p.points.size(), 0);
  return Evaluate(p, part_from_rig, scale_mm, false).cost;
}

PoseFit MeasurePoseFit(const compare::MeshDistance& part,
                       const std::vector<Eigen::Vector3d>& cloud_in_rig,
                       const Rigid3d& part_from_rig, double gate_mm, int max_points) {
  PoseFit fit;
  const size_t step =
      std::max<size_t>(1, cloud_in_rig.size() / static_cast<size_t>(std::max(1, max_points)));
  std::vector<size_t> index;
  for (size_t i = 0; i < cloud_in_rig.size(); i += step) index.push_back(i);
  std::vector<double> d(index.size());
  cv::parallel_for_(cv::Range(0, static_cast<int>(index.size())), [&](const cv::Range& r) {
    for (int i = r.start; i < r.end; ++i) {
      const size_t k = static_cast<size_t>(i);
      d[k] = std::abs(part.Closest(part_from_rig * cloud_in_rig[index[k]]).signed_distance_mm);
    }
  });
  std::vector<double> in;
  for (double x : d) {
    if (x < gate_mm) in.push_back(x);
  }
  fit.points = static_cast<int>(d.size());
  fit.fitness = d.empty() ? 0.0 : static_cast<double>(in.size()) / static_cast<double>(d.size());
  fit.median_abs_mm =
      in.empty() ? std::numeric_limits<double>::quiet_NaN() : Median(std::vector<double>(in));
  return fit;
}

bool WithinRefinementBasin(const PoseFit& fit, const PoseRefineOptions& o) {
  return fit.points >= 100 && fit.fitness >= 0.9 && fit.median_abs_mm < 0.25 * o.start_scale_mm;
}

PoseRefinement RefinePoseOnSurface(const TriangleMesh& part_surface,
                                   const std::vector<Eigen::Vector3d>& cloud_in_rig,
                                   const std::vector<Rigid3d>& starts, const PoseRefineOptions& o) {
  const compare::MeshDistance mesh(part_surface);
  return RefinePoseOnSurface(mesh, part_surface, cloud_in_rig, starts, o);
}

PoseRefinement RefinePoseOnSurface(const compare::MeshDistance& mesh,
                                   const TriangleMesh& part_surface,
                                   const std::vector<Eigen::Vector3d>& cloud_in_rig,
                                   const std::vector<Rigid3d>& starts, const PoseRefineOptions& o) {
  SLSHADOW_THROW_IF(starts.empty(), "RefinePoseOnSurface: no starting pose");
  const Rigid3d& start = starts.front();
  PoseRefinement out;
  out.part_from_rig = start;
  out.kept_start = true;
  Problem p{mesh, {}, {}, Eigen::Vector3d::Zero(), 1.0, {}};
  // The fixed set: an evenly strided subset, the points within the gate at any starting pose.
  {
    const size_t step =
        std::max<size_t>(1, cloud_in_rig.size() / static_cast<size_t>(std::max(1, o.max_points)));
    std::vector<Eigen::Vector3d> sample;
    for (size_t i = 0; i < cloud_in_rig.size(); i += step) sample.push_back(cloud_in_rig[i]);
    std::vector<uint32_t> tri(sample.size());
    std::vector<uint8_t> in(sample.size(), 0);
    cv::parallel_for_(cv::Range(0, static_cast<int>(sample.size())), [&](const cv::Range& r) {
      for (int i = r.start; i < r.end; ++i) {
        const size_t k = static_cast<size_t>(i);
        for (const Rigid3d& t : starts) {
          const compare::MeshHit hit = mesh.Closest(t * sample[k]);
          if (std::abs(hit.signed_distance_mm) < o.gate_mm) {
            in[k] = 1, tri[k] = hit.triangle;
            break;
          }
        }
      }
    });
    for (size_t i = 0; i < sample.size(); ++i) {
      if (!in[i]) continue;
      p.points.push_back(sample[i]);
      p.hints.push_back(tri[i]);
      p.centroid += start * sample[i];
    }
  }
  out.points = static_cast<int>(p.points.size());
  if (p.points.size() < 100) return out;
  p.centroid /= static_cast<double>(p.points.size());
  double ss = 0;
  for (const auto& x : p.points) ss += ((start * x) - p.centroid).squaredNorm();
  p.radius_mm = std::max(1.0, std::sqrt(ss / static_cast<double>(p.points.size())));

  double s = std::max(o.start_scale_mm, o.min_scale_mm);
  // The best start at the first scale.
  Rigid3d pose = start;
  double sigma = s;  // the residuals' robust sigma, as last measured
  {
    Evaluation first = Evaluate(p, start, s, false);
    double best = first.cost;
    sigma = RobustScale(first.r, s);
    for (size_t k = 1; k < starts.size(); ++k) {
      Evaluation e = Evaluate(p, starts[k], s, false);
      if (e.cost < best) best = e.cost, pose = starts[k], sigma = RobustScale(e.r, s);
    }
  }
  const CreaseEdges creases(part_surface);
  // A coarse stage (its scale still above coarse_factor x the final scale the residuals point
  // to) moves the pose by far more than the noise, and every coarse_stride-th point measures
  // that as well as all of them: it runs on that subset. The last stage, which the result,
  // its judgement and its uncertainty come from, always runs on every point.
  // Only the last stage's pose is returned: a stage that is not the last (its scale above the
  // final one the residuals point to) converges to 1e-3 of its scale, the last one to 1 nm.
  bool last_coarse = false, force_full = false;
  for (int stage = 0; stage < 12; ++stage) {
    ++out.stages;
    const double final_scale = std::max(o.scale_sigmas * sigma, o.min_scale_mm);
    const bool coarse = !force_full && o.coarse_stride > 1 && s > o.coarse_factor * final_scale;
    const bool tight = force_full || s <= 1.05 * final_scale;
    const double tolerance_mm = tight ? 1e-6 : std::max(1e-6, 1e-3 * s);
    last_coarse = coarse;
    CreaseBandMembership(p, creases, pose, 3 * s);
    if (coarse) {
      for (size_t i = 0; i < p.use.size(); ++i) {
        if (i % static_cast<size_t>(o.coarse_stride) != 0) p.use[i] = 0;
      }
      ++out.coarse_stages;
    }
    Evaluation cur = Evaluate(p, pose, s, true);
    double mu = 1e-4;  // LM damping, relative to the largest eigenvalue
    for (int it = 0; it < o.max_iterations; ++it) {
      ++out.iterations;
      const Eigen::SelfAdjointEigenSolver<Mat6> eig(cur.a);
      const Vec6 lambda = eig.eigenvalues();
      const double lmax = lambda.maxCoeff();
      if (!(lmax > 0)) break;
      const Vec6 bv = eig.eigenvectors().transpose() * cur.b;
      bool improved = false;
      Vec6 x = Vec6::Zero();
      for (int attempt = 0; attempt < 8; ++attempt) {
        Vec6 xe = Vec6::Zero();
        for (int k = 0; k < 6; ++k) {
          if (lambda[k] < o.weak_ratio * lmax) continue;  // unconstrained: not moved
          xe[k] = -bv[k] / (lambda[k] + mu * lmax);
        }
        x = eig.eigenvectors() * xe;
        const Rigid3d next = StepMotion(p, x) * pose;
        Evaluation e = Evaluate(p, next, s, true);
        if (e.cost < cur.cost) {
          pose = next;
          cur = std::move(e);
          ++out.accepted_steps;
          mu = std::max(mu / 4, 1e-9);
          improved = true;
          break;
        }
        ++out.rejected_steps;
        mu *= 8;
      }
      // Converged: no step improves, or the last one moved the points by less than the
      // tolerance.
      if (!improved || x.norm() < tolerance_mm) break;
    }
    sigma = RobustScale(cur.r, s);
    const double next_s = std::max({s / 2, o.scale_sigmas * sigma, o.min_scale_mm});
    if (next_s >= 0.95 * s) {
      if (!coarse && tight) break;
      force_full = true;  // the same scale once more, on every point, to 1 nm
      continue;
    }
    s = next_s;
  }
  if (last_coarse) CreaseBandMembership(p, creases, pose, 3 * s);  // every point counts below
  out.scale_mm = s;
  // Judged at the final scale over the same points: the refined pose only if it beats every
  // start (the first, the given pose, wins ties).
  out.start_cost = Evaluate(p, start, s, false).cost;
  out.final_cost = Evaluate(p, pose, s, false).cost;
  Rigid3d best = start;
  double best_cost = out.start_cost;
  for (size_t k = 1; k < starts.size(); ++k) {
    const double c = Evaluate(p, starts[k], s, false).cost;
    if (c < best_cost) best_cost = c, best = starts[k];
  }
  if (out.final_cost < best_cost) {
    out.kept_start = false;
  } else {
    pose = best;
    out.final_cost = best_cost;
    out.kept_start = (best_cost == out.start_cost);
  }
  out.part_from_rig = pose;

  // Uncertainty at the returned pose: the clustered sandwich in unscaled (dt mm, dw rad).
  const Evaluation fin = Evaluate(p, pose, s, true, /*keep_points=*/true);
  const double inv_s2 = 1.0 / (s * s);
  Mat6 a = Mat6::Zero();
  std::unordered_map<int64_t, Vec6> cells;
  double ss_in = 0;
  int64_t n_in = 0;
  for (size_t i = 0; i < p.points.size(); ++i) {
    const double r = fin.r[i];
    if (!std::isfinite(r)) continue;  // in a crease band
    if (std::abs(r) < 3 * s) ss_in += r * r, ++n_in;
    const double u2 = r * r * inv_s2;
    const double w = 1.0 / ((1 + u2) * (1 + u2));
    Vec6 j;
    j.head<3>() = fin.g[i];
    j.tail<3>() = (fin.q[i] - p.centroid).cross(fin.g[i]);
    // The bread is the derivative of the influence w r: (1 - 3 u^2) / (1 + u^2)^3, not the IRLS
    // weight (which would understate the covariance ~2.5 x at a scale of one sigma).
    a.selfadjointView<Eigen::Lower>().rankUpdate(j,
                                                 (1 - 3 * u2) / ((1 + u2) * (1 + u2) * (1 + u2)));
    const Eigen::Vector3d c = (fin.q[i] / o.cell_mm).array().floor();
    const int64_t key = (static_cast<int64_t>(c.x()) * 73856093) ^
                        (static_cast<int64_t>(c.y()) * 19349663) ^
                        (static_cast<int64_t>(c.z()) * 83492791);
    auto [it, inserted] = cells.try_emplace(key, Vec6::Zero());
    it->second += w * r * j;
  }
  a = a.selfadjointView<Eigen::Lower>();
  out.rms_mm = n_in ? std::sqrt(ss_in / static_cast<double>(n_in)) : 0.0;
  Mat6 b = Mat6::Zero();
  for (const auto& [key, v] : cells) b += v * v.transpose();
  const double groups = static_cast<double>(cells.size());
  if (groups > 1) b *= groups / (groups - 1);
  // Pseudo-inverse of A without its weak directions (judged with rotations scaled by the radius).
  Mat6 scale = Mat6::Identity();
  scale.bottomRightCorner<3, 3>() *= 1.0 / p.radius_mm;
  const Mat6 a_scaled = scale * a * scale;
  const Eigen::SelfAdjointEigenSolver<Mat6> eig(a_scaled);
  const double lmax = eig.eigenvalues().maxCoeff();
  Mat6 a_pinv_scaled = Mat6::Zero();
  PoseUncertainty& u = out.uncertainty;
  const Eigen::Matrix3d rig_from_part_r = pose.rotation.conjugate().toRotationMatrix();
  for (int k = 0; k < 6; ++k) {
    const Vec6 v = eig.eigenvectors().col(k);
    if (eig.eigenvalues()[k] < o.weak_ratio * lmax || !(lmax > 0)) {
      const Eigen::Vector3d t = v.head<3>(), w = v.tail<3>();
      if (t.norm() >= w.norm()) {
        u.weak_directions.push_back("translation along " + Vec(rig_from_part_r * t.normalized()) +
                                    " of the rig frame");
      } else {
        u.weak_directions.push_back("rotation about " + Vec(rig_from_part_r * w.normalized()) +
                                    " of the rig frame, through the part's visible centre");
      }
      continue;
    }
    a_pinv_scaled += v * v.transpose() / eig.eigenvalues()[k];
  }
  const Mat6 a_pinv = scale * a_pinv_scaled * scale;
  u.covariance = a_pinv * b * a_pinv;
  u.cells = static_cast<int>(cells.size());
  u.centroid_in_part = p.centroid;
  u.sigma_translation_mm = std::sqrt(std::max(
      0.0, Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(u.covariance.topLeftCorner<3, 3>())
               .eigenvalues()
               .maxCoeff()));
  u.sigma_rotation_deg = std::sqrt(std::max(0.0, Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(
                                                     u.covariance.bottomRightCorner<3, 3>())
                                                     .eigenvalues()
                                                     .maxCoeff())) *
                         180.0 / M_PI;
  return out;
}

// The refinement's figures for the report: its objective, and the pose's uncertainty; with a
// given pose, how far the pose moved from it in units of that uncertainty.
nlohmann::json PoseRefinementToJson(const PoseRefinement& f,
                                    const std::optional<Rigid3d>& given_part_from_rig) {
  const PoseUncertainty& u = f.uncertainty;
  nlohmann::json j = {{"objective", "mean Geman-McClure loss of the exact signed C2M to the part"},
                      {"scale_mm", f.scale_mm},
                      {"points", f.points},
                      {"start_cost", f.start_cost},
                      {"final_cost", f.final_cost},
                      {"kept_start", f.kept_start},
                      {"stages", f.stages},
                      {"coarse_stages", f.coarse_stages},
                      {"iterations", f.iterations},
                      {"accepted_steps", f.accepted_steps},
                      {"rejected_steps", f.rejected_steps},
                      {"rms_mm", f.rms_mm}};
  j["uncertainty"] = {{"method", "cluster-robust covariance over 5 mm cells of the part"},
                      {"sigma_translation_mm", u.sigma_translation_mm},
                      {"sigma_rotation_deg", u.sigma_rotation_deg},
                      {"cells", u.cells},
                      {"weak_directions", u.weak_directions}};
  if (given_part_from_rig) {
    // The move from the given pose as the left update about the centroid, (dt, dw), and its
    // Mahalanobis length under the covariance (its constrained directions).
    const Rigid3d& given = *given_part_from_rig;
    const Rigid3d d = f.part_from_rig * given.Inverse();
    const Eigen::Vector3d c = u.centroid_in_part;
    Eigen::Matrix<double, 6, 1> delta;
    delta.head<3>() = d.rotation * c + d.translation - c;
    delta.tail<3>() = RotationVectorFromQuaternion(d.rotation);
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eig(u.covariance);
    const double emax = eig.eigenvalues().maxCoeff();
    double m2 = 0;
    for (int k = 0; k < 6; ++k) {
      const double e = eig.eigenvalues()[k];
      if (e > 1e-12 * emax && e > 0) m2 += std::pow(eig.eigenvectors().col(k).dot(delta), 2) / e;
    }
    j["moved_from_given"] = {{"translation_at_centre_mm", delta.head<3>().norm()},
                             {"rotation_deg", Eigen::AngleAxisd(d.rotation).angle() * 180.0 / M_PI},
                             {"sigmas", std::sqrt(m2)}};
  }
  return j;
}

}  // namespace slshadow::twin::internal
