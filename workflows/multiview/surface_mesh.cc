#include "workflows/multiview/surface_mesh.h"

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/surface/poisson.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <tuple>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include "compare/median_spacing.h"
#include "core/error.h"
#include "core/kdtree.h"
#include "core/string_printf.h"

namespace slshadow::multiview {
namespace {

double SecondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

void SurfaceMeshOptions::Check() const {
  SLSHADOW_THROW_IF(depth < 5 || depth > 12, "mesh: depth must be in 5..12 (got ", depth, ")");
  SLSHADOW_THROW_IF(!(scale >= 1.0 && scale <= 2.0), "mesh: scale must be in [1, 2] (got ", scale,
                    ")");
  SLSHADOW_THROW_IF(!(samples_per_node >= 1.0 && samples_per_node <= 50.0),
                    "mesh: samples_per_node must be in [1, 50] (got ", samples_per_node, ")");
  SLSHADOW_THROW_IF(!(point_weight >= 0.0 && point_weight <= 100.0),
                    "mesh: point_weight must be in [0, 100] (got ", point_weight, ")");
  SLSHADOW_THROW_IF(!(trim_distance_mm >= 0.0) || !std::isfinite(trim_distance_mm),
                    "mesh: trim_distance_mm must be finite and >= 0 (got ", trim_distance_mm, ")");
  SLSHADOW_THROW_IF(threads < 1, "mesh: threads must be >= 1 (got ", threads, ")");
}

void CountMeshEdges(const TriangleMesh& mesh, size_t* boundary_edges, size_t* non_manifold_edges) {
  std::vector<uint64_t> edges;
  edges.reserve(3 * mesh.triangles.size());
  for (const Eigen::Vector3i& t : mesh.triangles) {
    for (int k = 0; k < 3; ++k) {
      const auto a = static_cast<uint32_t>(t[k]), b = static_cast<uint32_t>(t[(k + 1) % 3]);
      edges.push_back((static_cast<uint64_t>(std::min(a, b)) << 32) | std::max(a, b));
    }
  }
  std::sort(edges.begin(), edges.end());
  *boundary_edges = *non_manifold_edges = 0;
  for (size_t i = 0; i < edges.size();) {
    size_t j = i;
    while (j < edges.size() && edges[j] == edges[i]) ++j;
    if (j - i == 1) ++*boundary_edges;
    if (j - i > 2) ++*non_manifold_edges;
    i = j;
  }
}

std::string SurfaceMeshResult::Summary() const {
  return StringPrintf(
      "mesh: Poisson %zu vertices, %zu triangles (%zu boundary, %zu non-manifold edges; cell "
      "%.3f mm), trimmed at %.3f mm from the merged points to %zu vertices, %zu triangles, "
      "%.0f mm2 (%.0f mm2 removed; %zu boundary, %zu non-manifold edges); %.2f s + %.2f s",
      poisson_vertices, poisson_triangles, poisson_boundary_edges, poisson_non_manifold_edges,
      cell_mm, trim_distance_mm, mesh.vertices.size(), mesh.triangles.size(), area_mm2,
      trimmed_area_mm2, boundary_edges, non_manifold_edges, poisson_seconds, trim_seconds);
}

SurfaceMeshResult BuildSurfaceMesh(const PointCloud& cloud, const SurfaceMeshOptions& options) {
  options.Check();
  SLSHADOW_THROW_IF(!cloud.HasNormals(), "mesh: the merged cloud has no normals");
  SLSHADOW_THROW_IF(cloud.size() < 100, "mesh: the merged cloud has ", cloud.size(),
                    " points (need at least 100)");
  SurfaceMeshResult result;
  auto t0 = std::chrono::steady_clock::now();

  // Points relative to their centre, so that float coordinates keep their precision.
  Eigen::Vector3d lo = cloud.points.front(), hi = cloud.points.front();
  for (const auto& p : cloud.points) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  const Eigen::Vector3d centre = 0.5 * (lo + hi);
  result.cell_mm = options.scale * (hi - lo).maxCoeff() / std::ldexp(1.0, options.depth);
  auto input = std::make_shared<pcl::PointCloud<pcl::PointNormal>>();
  input->resize(cloud.size());
  for (size_t i = 0; i < cloud.size(); ++i) {
    pcl::PointNormal& q = (*input)[i];
    const Eigen::Vector3f p = (cloud.points[i] - centre).cast<float>();
    const Eigen::Vector3f n = cloud.normals[i].normalized();
    q.x = p.x();
    q.y = p.y();
    q.z = p.z();
    q.normal_x = n.x();
    q.normal_y = n.y();
    q.normal_z = n.z();
  }
  pcl::Poisson<pcl::PointNormal> poisson;
  poisson.setDepth(options.depth);
  poisson.setScale(static_cast<float>(options.scale));
  poisson.setSamplesPerNode(static_cast<float>(options.samples_per_node));
  poisson.setPointWeight(static_cast<float>(options.point_weight));
  poisson.setManifold(true);
  poisson.setOutputPolygons(false);
  poisson.setThreads(options.threads);
  poisson.setInputCloud(input);
  pcl::PointCloud<pcl::PointNormal> vertices;
  std::vector<pcl::Vertices> polygons;
  poisson.reconstruct(vertices, polygons);
  SLSHADOW_THROW_IF(polygons.empty(), "mesh: the Poisson reconstruction of ", cloud.size(),
                    " points yielded no surface");
  // Poisson's marching cubes emits a vertex once per octree node that finds it, so one position
  // may come under several indices: welded (exact float equality) so the surface is closed in its
  // topology too; triangles collapsed by the welding are dropped.
  std::vector<uint32_t> order(vertices.size());
  for (uint32_t i = 0; i < order.size(); ++i) order[i] = i;
  auto key = [&](uint32_t i) {
    return std::make_tuple(vertices[i].x, vertices[i].y, vertices[i].z);
  };
  std::sort(order.begin(), order.end(),
            [&](uint32_t a, uint32_t b) { return key(a) < key(b) || (key(a) == key(b) && a < b); });
  std::vector<int> weld(vertices.size());
  TriangleMesh full;
  for (size_t k = 0; k < order.size(); ++k) {
    if (k == 0 || key(order[k]) != key(order[k - 1])) {
      const auto& v = vertices[order[k]];
      full.vertices.push_back(Eigen::Vector3d(v.x, v.y, v.z) + centre);
    }
    weld[order[k]] = static_cast<int>(full.vertices.size() - 1);
  }
  full.triangles.reserve(polygons.size());
  for (const pcl::Vertices& poly : polygons) {
    if (poly.vertices.size() != 3) continue;
    const Eigen::Vector3i t(weld[poly.vertices[0]], weld[poly.vertices[1]], weld[poly.vertices[2]]);
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) continue;
    full.triangles.push_back(t);
  }
  input.reset();
  result.poisson_vertices = full.vertices.size();
  result.poisson_triangles = full.triangles.size();
  CountMeshEdges(full, &result.poisson_boundary_edges, &result.poisson_non_manifold_edges);
  result.poisson_seconds = SecondsSince(t0);

  // Trim: vertices no merged point is near; orientation from the points' normals.
  t0 = std::chrono::steady_clock::now();
  const KdTree tree(cloud.points);
  const double spacing = compare::MedianSpacing(tree);
  result.trim_distance_mm = options.trim_distance_mm > 0 ? options.trim_distance_mm
                                                         : 2.0 * std::max(result.cell_mm, spacing);
  std::vector<uint8_t> keep(full.vertices.size());
  std::vector<uint32_t> nearest(full.vertices.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, full.vertices.size(), 4096),
                    [&](const tbb::blocked_range<size_t>& r) {
                      Neighbor nb;
                      for (size_t i = r.begin(); i != r.end(); ++i) {
                        keep[i] = tree.Nearest(full.vertices[i], &nb, result.trim_distance_mm);
                        nearest[i] = keep[i] ? static_cast<uint32_t>(nb.index) : 0;
                      }
                    });
  // Poisson orients its triangles by the normals' field; count agreement to be sure.
  const double agreement = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, full.triangles.size(), 4096), 0.0,
      [&](const tbb::blocked_range<size_t>& r, double sum) {
        for (size_t t = r.begin(); t != r.end(); ++t) {
          const auto v = static_cast<size_t>(full.triangles[t][0]);
          if (!keep[v]) continue;
          sum += full.FaceNormal(t).dot(cloud.normals[nearest[v]].cast<double>()) *
                 full.TriangleArea(t);
        }
        return sum;
      },
      [](double a, double b) { return a + b; });
  const bool flip = agreement < 0;
  std::vector<int> remap(full.vertices.size(), -1);
  TriangleMesh& mesh = result.mesh;
  for (size_t t = 0; t < full.triangles.size(); ++t) {
    Eigen::Vector3i tri = full.triangles[t];
    const double area = full.TriangleArea(t);
    if (!keep[static_cast<size_t>(tri[0])] || !keep[static_cast<size_t>(tri[1])] ||
        !keep[static_cast<size_t>(tri[2])]) {
      result.trimmed_area_mm2 += area;
      continue;
    }
    for (int k = 0; k < 3; ++k) {
      int& m = remap[static_cast<size_t>(tri[k])];
      if (m < 0) {
        m = static_cast<int>(mesh.vertices.size());
        mesh.vertices.push_back(full.vertices[static_cast<size_t>(tri[k])]);
      }
      tri[k] = m;
    }
    if (flip) std::swap(tri[1], tri[2]);
    mesh.triangles.push_back(tri);
    result.area_mm2 += area;
  }
  CountMeshEdges(mesh, &result.boundary_edges, &result.non_manifold_edges);
  result.trim_seconds = SecondsSince(t0);
  return result;
}

}  // namespace slshadow::multiview
