// Per-point deviations between a compared cloud and a reference (cloud or mesh):
//  - C2C: distance from each compared point to the nearest reference point, with CloudCompare's
//    options (maximum search distance; optional local model fitted on the reference around the
//    nearest point, reporting min(nearest distance, distance to the model) as CloudCompare does);
//  - C2M: signed distance from each compared point to the nearest triangle
//  (compare/mesh_distance.h);
//  - M3C2 (Lague, Brodu & Leroux 2013): signed distance along a normal between the mean positions
//    of both clouds inside a cylinder, with its level of detection at 95 %:
//      LoD95 = 1.96 * (sqrt(sigma1^2 / n1 + sigma2^2 / n2) + registration_error)
//    where sigma_i is the standard deviation of cloud i's points along the normal in the cylinder
//    and n_i their number. A change is significant when |distance| > LoD95.
// All distances in millimetres. Queries run in parallel (TBB); results do not depend on threads.
#pragma once

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/mesh.h"
#include "core/point_cloud.h"

namespace slshadow {
class KdTree;
}  // namespace slshadow

namespace slshadow::compare {

class MeshDistance;

enum class LocalModel { kNone, kPlane, kQuadric };
std::string ToString(LocalModel model);                    // "none", "plane", "quadric"
LocalModel LocalModelFromString(const std::string& name);  // throws slshadow::Error on others

struct C2COptions {
  // Points farther than this from every reference point get distance = max_distance_mm and
  // count as not found (CloudCompare's "max. dist"). 0: unlimited.
  double max_distance_mm = 0.0;
  LocalModel local_model = LocalModel::kNone;
  // Reference neighbours of the nearest reference point the local model is fitted on
  // (the nearest point included). 0: 6 for a plane, 12 for a quadric.
  int local_model_neighbors = 0;
  void Check() const;  // throws slshadow::Error naming the bad field
};

struct C2CResult {
  std::vector<double> distances_mm;  // one per compared point, >= 0
  std::vector<uint32_t> nearest;     // index of the nearest reference point (valid if found)
  size_t num_not_found = 0;          // points with no reference point within max_distance_mm
};

// Local-model distances: a least-squares plane through the neighbours (distance to the plane),
// or a quadric height field h = a + b u + c v + d u^2 + e u v + f v^2 over the neighbours' PCA
// frame (distance = |h(q) - f(u_q, v_q)| along the frame's normal axis, as CloudCompare does).
C2CResult CloudToCloud(const std::vector<Eigen::Vector3d>& compared, const KdTree& reference,
                       const C2COptions& options = {});

struct C2MResult {
  std::vector<double> signed_distances_mm;  // + on the side the mesh normals point to
  std::vector<uint32_t> triangles;          // nearest triangle per point
};
C2MResult CloudToMesh(const std::vector<Eigen::Vector3d>& compared, const TriangleMesh& mesh);
// The same with a hierarchy built once (compare/mesh_distance.h), e.g. for several clouds.
C2MResult CloudToMesh(const std::vector<Eigen::Vector3d>& compared, const MeshDistance& mesh);

// Unit normals by PCA of the k nearest points of `tree` around each query point. Each normal is
// oriented to agree with `hints` (one per query, e.g. the reference's stored normals) when given,
// else to point towards `viewpoint` (e.g. the scanner's optical centre).
std::vector<Eigen::Vector3d> EstimateNormals(
    const std::vector<Eigen::Vector3d>& queries, const KdTree& tree, int k,
    const std::vector<Eigen::Vector3d>& hints,
    const Eigen::Vector3d& viewpoint = Eigen::Vector3d::Zero());

struct M3C2Options {
  double projection_radius_mm = 0.5;   // cylinder radius (M3C2's d / 2)
  double max_depth_mm = 2.0;           // cylinder half-length along the normal
  double registration_error_mm = 0.0;  // added inside LoD95 (see above)
  int min_points = 3;                  // per cloud in the cylinder, else the core point is skipped
  void Check() const;
};

struct M3C2Result {
  // Per core point; distance and lod95 are NaN where either cloud has < min_points in the cylinder.
  std::vector<double> distance_mm;  // mean(cloud2) - mean(cloud1) along the normal
  std::vector<double> lod95_mm;
  std::vector<int> n1, n2;
  std::vector<double> sigma1_mm, sigma2_mm;
  size_t num_valid = 0;
  size_t num_significant = 0;  // |distance| > lod95
};

// cloud1 is the reference epoch, cloud2 the compared one; normals one per core point, unit.
M3C2Result M3C2(const std::vector<Eigen::Vector3d>& core_points,
                const std::vector<Eigen::Vector3d>& normals, const KdTree& cloud1,
                const KdTree& cloud2, const M3C2Options& options = {});

}  // namespace slshadow::compare
