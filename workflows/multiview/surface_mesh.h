// A watertight surface mesh from the merged cloud of a multi-view scan (issue 32, "The merged
// model"): screened Poisson reconstruction (Kazhdan, Bolitho & Hoppe 2006; PCL's pcl::Poisson,
// pcl_surface, kept inside surface_mesh.cc) of the oriented points, then trimmed where no view saw
// the surface: a vertex farther than trim_distance_mm from every merged point is removed with its
// triangles (Poisson closes the surface everywhere, also across the face on the table and the
// bottoms of deep holes, which no view saw). Units: mm; the cloud's frame.
#pragma once

#include <cstddef>
#include <string>

#include "core/mesh.h"
#include "core/point_cloud.h"

namespace slshadow::multiview {

struct SurfaceMeshOptions {
  // Octree depth: the finest cells are the cloud's bounding cube (x scale) / 2^depth.
  int depth = 8;
  double scale = 1.1;           // bounding cube / the cloud's bounding box
  double samples_per_node = 2;  // points per finest cell at which the octree stops refining
  double point_weight = 4;      // screening: how strongly the surface is held to the points
  // A vertex farther than this from every merged point is trimmed (0: 2 x the larger of the
  // octree's finest cell and the cloud's median point spacing).
  double trim_distance_mm = 0;
  int threads = 2;
  void Check() const;  // throws slshadow::Error naming the bad field
};

struct SurfaceMeshResult {
  TriangleMesh mesh;  // trimmed; triangles counter-clockwise seen from outside
  // The Poisson surface before trimming: watertight when every edge has exactly two triangles
  // (PCL 1.13's marching cubes leaves a few small holes: about 0.05 % of the edges are boundary).
  size_t poisson_vertices = 0, poisson_triangles = 0;
  size_t poisson_boundary_edges = 0, poisson_non_manifold_edges = 0;
  // After trimming: boundary edges (one triangle: where the trimming cut), non-manifold edges
  // (more than two triangles: none expected).
  size_t boundary_edges = 0, non_manifold_edges = 0;
  double cell_mm = 0;                         // the octree's finest cell
  double trim_distance_mm = 0;                // the trim distance used
  double area_mm2 = 0, trimmed_area_mm2 = 0;  // kept, and removed by the trimming
  double poisson_seconds = 0, trim_seconds = 0;
  std::string Summary() const;  // one line
};

// Throws slshadow::Error when the cloud has no normals or fewer than 100 points, or when the
// reconstruction yields no surface.
SurfaceMeshResult BuildSurfaceMesh(const PointCloud& cloud, const SurfaceMeshOptions& options = {});

// Edges used by exactly one triangle (boundary) and by more than two (non-manifold).
void CountMeshEdges(const TriangleMesh& mesh, size_t* boundary_edges, size_t* non_manifold_edges);

}  // namespace slshadow::multiview
