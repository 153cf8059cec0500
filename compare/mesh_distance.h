// Signed distance from points to a triangle mesh: exact closest point on the nearest triangle,
// found through a bounding-volume hierarchy: binned surface-area-heuristic splits down to one
// triangle per leaf, collapsed into 4-wide nodes whose child boxes are stored in float, rounded
// outwards. A node's four box distances are computed together in float and pruned only when a
// conservative lower bound (float rounding of the point and of the arithmetic accounted for)
// exceeds the best squared distance so far; the triangles that survive are evaluated in double
// with ClosestPointOnTriangle. The result is therefore the same as a brute-force scan over all
// triangles: the smallest squared distance, ties broken towards the lowest triangle index, so it
// does not depend on the traversal, the warm-start hint or the threads.
//
// Sign: positive on the side the outward normals point to (outside a closed mesh whose
// triangles are counter-clockwise seen from outside). The sign is taken from the angle-weighted
// pseudo-normal of the closest feature (face, edge or vertex; Baerentzen & Aanaes, "Signed
// distance computation using the angle weighted pseudonormal", IEEE TVCG 2005), which is exact
// for closed manifold meshes, also where the closest point lies on an edge or a vertex. Where
// the closest point is inside a face this is the face normal, as in CloudCompare's C2M.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "core/mesh.h"

namespace slshadow::compare {

struct MeshHit {
  double signed_distance_mm = 0.0;                    // |p - closest|, signed by the pseudo-normal
  Eigen::Vector3d closest = Eigen::Vector3d::Zero();  // closest point on the mesh
  uint32_t triangle = 0;                              // index of the closest triangle
};

class MeshDistance {
 public:
  // Builds the hierarchy; the mesh is copied (vertices and triangles).
  explicit MeshDistance(const TriangleMesh& mesh);

  MeshHit Closest(const Eigen::Vector3d& point) const;
  // The same result, warm-started with triangle `hint` (e.g. the previous query's hit when
  // queries run in spatially coherent order): its distance bounds the search from the start, so
  // fewer boxes are opened. Out-of-range hints are ignored.
  MeshHit Closest(const Eigen::Vector3d& point, uint32_t hint) const;
  size_t NumTriangles() const { return normals_.size(); }
  // Unit normal of triangle `t` (input order), (b - a) x (c - a) normalised; zero if degenerate.
  const Eigen::Vector3d& FaceNormal(uint32_t t) const { return normals_[t].face; }
  // The signed distance of `point` whose closest point on the mesh is `closest`, on `triangle` at
  // its `feature` (ClosestPointOnTriangle's), squared_distance = |point - closest|^2: the square
  // root, negative when point - closest points against that feature's angle-weighted
  // pseudo-normal. What Closest returns as signed_distance_mm (for searches of their own over
  // this mesh's triangles, e.g. compare/c2m_grid.h).
  double SignedDistance(const Eigen::Vector3d& point, const Eigen::Vector3d& closest,
                        uint32_t triangle, int feature, double squared_distance) const;

 private:
  // 4-wide node: the boxes of up to four children, float, rounded outwards.
  struct alignas(16) Node {
    float lo[3][4];
    float hi[3][4];
    uint32_t child[4];  // inner child: node index; leaf: slot of its first triangle in geom_
    uint32_t count[4];  // 0: inner child; 1..: leaf of that many triangles; kEmpty: no child
  };
  struct TriGeom {
    Eigen::Vector3d a, b, c;
  };
  // Float planes of a triangle: its own plane and the three edges' outward in-plane planes, each
  // (unit normal, offset). Give a cheap lower bound of the distance before the exact one.
  struct TriBound {
    float plane[4][4];
  };
  struct TriNormals {
    Eigen::Vector3d face;       // unit
    Eigen::Vector3d vertex[3];  // angle-weighted pseudo-normals of a, b, c
    Eigen::Vector3d edge[3];    // ab, bc, ca: sum of the adjacent face normals
  };
  struct BuildNode;
  static constexpr uint32_t kEmpty = 0xffffffffu;

  std::vector<TriGeom> geom_;        // in leaf order
  std::vector<TriBound> bound_;      // in leaf order
  std::vector<uint32_t> index_;      // leaf slot -> triangle index
  std::vector<uint32_t> slot_;       // triangle index -> leaf slot
  std::vector<TriNormals> normals_;  // by triangle index
  std::vector<Node> nodes_;          // nodes_[0] is the root
  double max_abs_ = 0;               // largest |coordinate| of the mesh
};

// Closest point on triangle (a, b, c) to p (Ericson, "Real-Time Collision Detection", 5.1.5).
// feature: 0 = face interior, 1..3 = vertex a, b, c, 4..6 = edge ab, bc, ca.
Eigen::Vector3d ClosestPointOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                       const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                                       int* feature);

}  // namespace slshadow::compare
