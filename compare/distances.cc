#include "compare/distances.h"

#include <algorithm>
#include <cmath>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <Eigen/Eigenvalues>

#include "compare/mesh_distance.h"
#include "core/enum_names.h"
#include "core/error.h"
#include "core/kdtree.h"

namespace slshadow::compare {
namespace {

template <typename F>
void ParallelFor(size_t n, F&& f) {
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1024),
                    [&](const tbb::blocked_range<size_t>& r) {
                      for (size_t i = r.begin(); i != r.end(); ++i) f(i);
                    });
}

// f(i) for every query point, visited along a Morton curve (SpatialOrder) so that consecutive
// queries touch the same tree nodes; results are written per index, so they do not depend on
// the order.
template <typename F>
void ParallelForSpatial(const std::vector<Eigen::Vector3d>& queries, F&& f) {
  if (queries.size() < 20000) {
    ParallelFor(queries.size(), f);
    return;
  }
  const std::vector<uint32_t> order = SpatialOrder(queries);
  ParallelFor(order.size(), [&](size_t k) { f(order[k]); });
}

// f(begin, end, order) over chunks of the Morton order: a chunk's queries are neighbours, so
// f can carry state (a warm start) from one query to the next.
template <typename F>
void ParallelChunksSpatial(const std::vector<Eigen::Vector3d>& queries, F&& f) {
  const std::vector<uint32_t> order = SpatialOrder(queries);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, order.size(), 4096),
                    [&](const tbb::blocked_range<size_t>& r) { f(r.begin(), r.end(), order); });
}

// PCA frame of a point set: centroid, eigenvectors sorted by ascending eigenvalue (column 0 is
// the normal direction).
struct Frame {
  Eigen::Vector3d centroid;
  Eigen::Matrix3d axes;
};

Frame PcaFrame(const std::vector<Eigen::Vector3d>& pts, const std::vector<Neighbor>& nn,
               bool fast = false) {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (const auto& n : nn) c += pts[n.index];
  c /= static_cast<double>(nn.size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& n : nn) {
    const Eigen::Vector3d d = pts[n.index] - c;
    cov += d * d.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
  // The closed form is ~5x faster and accurate to ~1e-9 on the normal: enough for normals,
  // not for the local models whose distances tests compare at 1e-12.
  if (fast) {
    eig.computeDirect(cov);
  } else {
    eig.compute(cov);
  }
  return {c, eig.eigenvectors()};
}

double PlaneDistance(const std::vector<Eigen::Vector3d>& pts, const std::vector<Neighbor>& nn,
                     const Eigen::Vector3d& q) {
  const Frame f = PcaFrame(pts, nn);
  return std::abs(f.axes.col(0).dot(q - f.centroid));
}

// Quadric height field in the PCA frame; falls back to the plane with fewer than 6 neighbours
// or a rank-deficient system.
double QuadricDistance(const std::vector<Eigen::Vector3d>& pts, const std::vector<Neighbor>& nn,
                       const Eigen::Vector3d& q) {
  if (nn.size() < 6) return PlaneDistance(pts, nn, q);
  const Frame f = PcaFrame(pts, nn);
  const Eigen::Vector3d n = f.axes.col(0), u = f.axes.col(2), v = f.axes.col(1);
  Eigen::MatrixXd a(static_cast<long>(nn.size()), 6);
  Eigen::VectorXd h(static_cast<long>(nn.size()));
  for (size_t i = 0; i < nn.size(); ++i) {
    const Eigen::Vector3d d = pts[nn[i].index] - f.centroid;
    const double x = d.dot(u), y = d.dot(v);
    a.row(static_cast<long>(i)) << 1, x, y, x * x, x * y, y * y;
    h[static_cast<long>(i)] = d.dot(n);
  }
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(a);
  if (qr.rank() < 6) return PlaneDistance(pts, nn, q);
  const Eigen::VectorXd c = qr.solve(h);
  const Eigen::Vector3d d = q - f.centroid;
  const double x = d.dot(u), y = d.dot(v);
  const double model = c[0] + c[1] * x + c[2] * y + c[3] * x * x + c[4] * x * y + c[5] * y * y;
  return std::abs(d.dot(n) - model);
}

}  // namespace

constexpr EnumName<LocalModel> kLocalModelNames[] = {
    {LocalModel::kNone, "none"}, {LocalModel::kPlane, "plane"}, {LocalModel::kQuadric, "quadric"}};

std::string ToString(LocalModel value) { return EnumToString(value, kLocalModelNames); }

LocalModel LocalModelFromString(const std::string& name) {
  return EnumFromString("local model", name, kLocalModelNames);
}

void C2COptions::Check() const {
  SLSHADOW_THROW_IF(!(max_distance_mm >= 0) || !std::isfinite(max_distance_mm),
                    "c2c.max_distance_mm: must be finite and >= 0 (got ", max_distance_mm, ")");
  SLSHADOW_THROW_IF(
      local_model_neighbors < 0 || local_model_neighbors == 1 || local_model_neighbors == 2,
      "c2c.local_model_neighbors: must be 0 (auto) or >= 3 (got ", local_model_neighbors, ")");
}

C2CResult CloudToCloud(const std::vector<Eigen::Vector3d>& compared, const KdTree& reference,
                       const C2COptions& options) {
  options.Check();
  SLSHADOW_THROW_IF(reference.size() == 0, "cloud-to-cloud: the reference cloud is empty");
  const size_t n = compared.size();
  C2CResult result;
  result.distances_mm.resize(n);
  result.nearest.resize(n);
  const double max_d = options.max_distance_mm > 0 ? options.max_distance_mm
                                                   : std::numeric_limits<double>::infinity();
  const int k = options.local_model_neighbors > 0
                    ? options.local_model_neighbors
                    : (options.local_model == LocalModel::kQuadric ? 12 : 6);
  std::vector<uint8_t> found(n);
  const auto& ref_pts = reference.points();
  ParallelForSpatial(compared, [&](size_t i) {
    Neighbor nb;
    if (!reference.Nearest(compared[i], &nb, max_d)) {
      found[i] = 0;
      result.distances_mm[i] = options.max_distance_mm;
      result.nearest[i] = 0;
      return;
    }
    found[i] = 1;
    result.nearest[i] = nb.index;
    double d = std::sqrt(nb.distance_sq);
    if (options.local_model != LocalModel::kNone) {
      thread_local std::vector<Neighbor> nn;
      reference.KNearest(ref_pts[nb.index], k, &nn);
      if (nn.size() >= 3) {
        const double m = options.local_model == LocalModel::kPlane
                             ? PlaneDistance(ref_pts, nn, compared[i])
                             : QuadricDistance(ref_pts, nn, compared[i]);
        d = std::min(d, m);
      }
    }
    result.distances_mm[i] = d;
  });
  for (uint8_t f : found) result.num_not_found += f ? 0 : 1;
  return result;
}

C2MResult CloudToMesh(const std::vector<Eigen::Vector3d>& compared, const TriangleMesh& mesh) {
  return CloudToMesh(compared, MeshDistance(mesh));
}

C2MResult CloudToMesh(const std::vector<Eigen::Vector3d>& compared, const MeshDistance& md) {
  C2MResult result;
  result.signed_distances_mm.resize(compared.size());
  result.triangles.resize(compared.size());
  ParallelChunksSpatial(compared,
                        [&](size_t begin, size_t end, const std::vector<uint32_t>& order) {
                          uint32_t hint = std::numeric_limits<uint32_t>::max();
                          for (size_t k = begin; k < end; ++k) {
                            const size_t i = order[k];
                            const MeshHit hit = md.Closest(compared[i], hint);
                            result.signed_distances_mm[i] = hit.signed_distance_mm;
                            result.triangles[i] = hit.triangle;
                            hint = hit.triangle;
                          }
                        });
  return result;
}

std::vector<Eigen::Vector3d> EstimateNormals(const std::vector<Eigen::Vector3d>& queries,
                                             const KdTree& tree, int k,
                                             const std::vector<Eigen::Vector3d>& hints,
                                             const Eigen::Vector3d& viewpoint) {
  SLSHADOW_THROW_IF(k < 3, "normal estimation: needs k >= 3 neighbours (got ", k, ")");
  SLSHADOW_THROW_IF(!hints.empty() && hints.size() != queries.size(),
                    "normal estimation: ", hints.size(), " hints for ", queries.size(), " points");
  std::vector<Eigen::Vector3d> normals(queries.size());
  const auto& pts = tree.points();
  ParallelForSpatial(queries, [&](size_t i) {
    thread_local std::vector<Neighbor> nn;
    tree.KNearest(queries[i], k, &nn);
    Eigen::Vector3d n = Eigen::Vector3d::UnitZ();
    if (nn.size() >= 3) n = PcaFrame(pts, nn, /*fast=*/true).axes.col(0);
    const Eigen::Vector3d toward =
        hints.empty() ? Eigen::Vector3d(viewpoint - queries[i]) : hints[i];
    if (n.dot(toward) < 0) n = -n;
    normals[i] = n;
  });
  return normals;
}

void M3C2Options::Check() const {
  SLSHADOW_THROW_IF(!(projection_radius_mm > 0) || !std::isfinite(projection_radius_mm),
                    "m3c2.projection_radius_mm: must be > 0 (got ", projection_radius_mm, ")");
  SLSHADOW_THROW_IF(!(max_depth_mm > 0) || !std::isfinite(max_depth_mm),
                    "m3c2.max_depth_mm: must be > 0 (got ", max_depth_mm, ")");
  SLSHADOW_THROW_IF(!(registration_error_mm >= 0), "m3c2.registration_error_mm: must be >= 0 (got ",
                    registration_error_mm, ")");
  SLSHADOW_THROW_IF(min_points < 2, "m3c2.min_points: must be >= 2 (got ", min_points, ")");
}

M3C2Result M3C2(const std::vector<Eigen::Vector3d>& core_points,
                const std::vector<Eigen::Vector3d>& normals, const KdTree& cloud1,
                const KdTree& cloud2, const M3C2Options& options) {
  options.Check();
  SLSHADOW_THROW_IF(normals.size() != core_points.size(), "M3C2: ", normals.size(), " normals for ",
                    core_points.size(), " core points");
  const size_t n = core_points.size();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  M3C2Result r;
  r.distance_mm.assign(n, nan);
  r.lod95_mm.assign(n, nan);
  r.n1.assign(n, 0);
  r.n2.assign(n, 0);
  r.sigma1_mm.assign(n, nan);
  r.sigma2_mm.assign(n, nan);
  const double search = std::hypot(options.projection_radius_mm, options.max_depth_mm);
  const double r2 = options.projection_radius_mm * options.projection_radius_mm;
  // Mean and standard deviation (n - 1) of the positions along the normal inside the cylinder.
  auto project = [&](const KdTree& tree, const Eigen::Vector3d& c, const Eigen::Vector3d& nrm,
                     double* mean, double* sigma) {
    thread_local std::vector<Neighbor> nb;
    tree.Radius(c, search, &nb);
    double s = 0, s2 = 0;
    int count = 0;
    for (const auto& x : nb) {
      const Eigen::Vector3d d = tree.points()[x.index] - c;
      const double h = d.dot(nrm);
      if (std::abs(h) > options.max_depth_mm || d.squaredNorm() - h * h > r2) continue;
      s += h;
      s2 += h * h;
      ++count;
    }
    if (count > 0) {
      *mean = s / count;
      *sigma = count > 1 ? std::sqrt(std::max(0.0, (s2 - s * s / count) / (count - 1))) : 0.0;
    }
    return count;
  };
  ParallelForSpatial(core_points, [&](size_t i) {
    double m1 = 0, m2 = 0, s1 = 0, s2 = 0;
    const int c1 = project(cloud1, core_points[i], normals[i], &m1, &s1);
    const int c2 = project(cloud2, core_points[i], normals[i], &m2, &s2);
    r.n1[i] = c1;
    r.n2[i] = c2;
    if (c1 < options.min_points || c2 < options.min_points) return;
    r.sigma1_mm[i] = s1;
    r.sigma2_mm[i] = s2;
    r.distance_mm[i] = m2 - m1;
    r.lod95_mm[i] = 1.96 * (std::sqrt(s1 * s1 / c1 + s2 * s2 / c2) + options.registration_error_mm);
  });
  for (size_t i = 0; i < n; ++i) {
    if (std::isnan(r.distance_mm[i])) continue;
    ++r.num_valid;
    if (std::abs(r.distance_mm[i]) > r.lod95_mm[i]) ++r.num_significant;
  }
  return r;
}

}  // namespace slshadow::compare
