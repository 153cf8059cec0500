// Synthetic turntable views for the merge tests and bench/multiview: the demo part (sim/shapes.h)
// on a table whose axis is known, sampled from each table angle as a camera at the rig origin
// sees it (back faces and grazing faces culled, occlusion by a coarse z-buffer), with Gaussian
// noise along the surface normal. Deterministic (fixed seed).
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/mesh.h"
#include "core/point_cloud.h"
#include "core/rig.h"
#include "core/rigid3.h"
#include "sim/shapes.h"

namespace slshadow::multiview::testing {

struct TurntableScanOptions {
  int views = 12;           // evenly spaced over a full turn
  double spacing_mm = 0.6;  // mean distance between samples on a surface facing the camera
  double noise_mm = 0.02;   // standard deviation along the normal
  double tilt_deg = 35;     // the camera looks down on the table by this much
  double working_distance_mm = 500;
  double min_cos_incidence = 0.15;  // grazing faces culled below this
  unsigned seed = 1;
  // > 0: a table disc of this radius about the axis, 0.05 mm under the part, is sampled too (it
  // occludes and is occluded like the part) into TurntableScan::backdrops, as a table view's
  // cropped table points are.
  double table_radius_mm = 0;
};

struct TurntableScan {
  TurntableAxis axis;        // in the rig frame
  Rigid3d part_from_object;  // the demo part's object frame in the part frame
  TriangleMesh part;         // the demo part in the part frame (= rig frame at angle 0)
  std::vector<double> angles_deg;
  std::vector<Rigid3d> part_from_rig;  // the truth per view: RigFromTableTurn(angle)^-1
  std::vector<PointCloud> clouds;      // per view, rig frame, no normals
  std::vector<PointCloud> backdrops;   // per view, rig frame: the table's points (table_radius_mm)
};

// Point on the demo part's top face (tile at height 40) that is flat within 10 mm, and its
// normal, in the object frame (for an injected bump).
inline Eigen::Vector3d FlatSpotInObject() { return Eigen::Vector3d(10, -20, 40); }

inline TurntableScan MakeTurntableScan(const TurntableScanOptions& o) {
  TurntableScan scan;
  const double tilt = o.tilt_deg * M_PI / 180.0;
  const Eigen::Vector3d up(0, -std::cos(tilt), -std::sin(tilt));
  scan.axis.direction_in_rig = up;
  scan.axis.point_in_rig_mm = Eigen::Vector3d(0, 0, o.working_distance_mm) - 25.0 * up;
  Eigen::Matrix3d r;
  r.col(0) = Eigen::Vector3d::UnitX();
  r.col(2) = up;
  r.col(1) = up.cross(Eigen::Vector3d::UnitX());
  scan.part_from_object = Rigid3d(Eigen::Quaterniond(r), scan.axis.point_in_rig_mm);
  scan.part = MakeDemoPart(2.0);
  scan.part.Transform(r, scan.axis.point_in_rig_mm);
  TriangleMesh table;
  if (o.table_radius_mm > 0) {
    constexpr int kSectors = 72;
    const Eigen::Vector3d centre = scan.axis.point_in_rig_mm - 0.05 * up;
    table.vertices.push_back(centre);
    for (int s = 0; s < kSectors; ++s) {
      const double a = 2 * M_PI * s / kSectors;
      table.vertices.push_back(centre + o.table_radius_mm *
                                            (std::cos(a) * r.col(0) + std::sin(a) * r.col(1)));
      table.triangles.emplace_back(0, 1 + s, 1 + (s + 1) % kSectors);
    }
  }

  std::mt19937 rng(o.seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::normal_distribution<double> gauss(0.0, 1.0);
  const double density = 1.0 / (o.spacing_mm * o.spacing_mm);
  // z-buffer: pixels of about 2 sample spacings at the working distance; a sample is hidden when
  // it lies behind its pixel's nearest sample by more than 1 mm plus the depth a surface of its
  // slope spans over two pixels.
  const double footprint = 2.0 * o.spacing_mm;
  const double focal = o.working_distance_mm / footprint;
  constexpr int kHalf = 400;
  for (int k = 0; k < o.views; ++k) {
    const double angle = 360.0 * k / o.views;
    scan.angles_deg.push_back(angle);
    const Rigid3d rig_from_part = scan.axis.RigFromTableTurn(angle);
    scan.part_from_rig.push_back(rig_from_part.Inverse());
    std::vector<Eigen::Vector3d> pts, nrm;
    size_t part_samples = 0;  // pts[part_samples...] are the table's
    for (const TriangleMesh* mesh : {&scan.part, &table}) {
      if (mesh == &table) part_samples = pts.size();
      for (size_t t = 0; t < mesh->NumTriangles(); ++t) {
        const Eigen::Vector3i& f = mesh->triangles[t];
        const Eigen::Vector3d a = rig_from_part * mesh->vertices[static_cast<size_t>(f[0])];
        const Eigen::Vector3d b = rig_from_part * mesh->vertices[static_cast<size_t>(f[1])];
        const Eigen::Vector3d c = rig_from_part * mesh->vertices[static_cast<size_t>(f[2])];
        const Eigen::Vector3d cr = (b - a).cross(c - a);
        const double area = 0.5 * cr.norm();
        if (area <= 0) continue;
        const Eigen::Vector3d n = cr.normalized();
        const Eigen::Vector3d centre = (a + b + c) / 3.0;
        const double expected = area * density;
        int count = static_cast<int>(expected);
        if (uni(rng) < expected - count) ++count;
        if (n.dot(-centre.normalized()) < o.min_cos_incidence) continue;
        for (int s = 0; s < count; ++s) {
          double u = uni(rng), v = uni(rng);
          if (u + v > 1) {
            u = 1 - u;
            v = 1 - v;
          }
          pts.push_back(a + u * (b - a) + v * (c - a));
          nrm.push_back(n);
        }
      }
    }
    std::vector<float> zbuf((2 * kHalf + 1) * (2 * kHalf + 1), std::numeric_limits<float>::max());
    auto pixel = [&](const Eigen::Vector3d& p, int* px, int* py) {
      *px = static_cast<int>(std::lround(focal * p.x() / p.z()));
      *py = static_cast<int>(std::lround(focal * p.y() / p.z()));
      return std::abs(*px) < kHalf && std::abs(*py) < kHalf;
    };
    for (const auto& p : pts) {
      int px, py;
      if (!pixel(p, &px, &py)) continue;
      float& z = zbuf[static_cast<size_t>((py + kHalf) * (2 * kHalf + 1) + px + kHalf)];
      z = std::min(z, static_cast<float>(p.norm()));
    }
    PointCloud cloud, backdrop;
    for (size_t i = 0; i < pts.size(); ++i) {
      int px, py;
      const double noise = o.noise_mm * gauss(rng);
      if (!pixel(pts[i], &px, &py)) continue;
      const float z = zbuf[static_cast<size_t>((py + kHalf) * (2 * kHalf + 1) + px + kHalf)];
      const double cos_i = std::max(0.15, nrm[i].dot(-pts[i].normalized()));
      const double slope = std::sqrt(1 - cos_i * cos_i) / cos_i;
      if (pts[i].norm() > z + 1.0 + 2.0 * footprint * slope) continue;
      (i < part_samples || table.empty() ? cloud : backdrop)
          .points.push_back(pts[i] + noise * nrm[i]);
    }
    scan.clouds.push_back(std::move(cloud));
    scan.backdrops.push_back(std::move(backdrop));
  }
  return scan;
}

// The truth moved by a random rotation of rotation_deg about an axis through the part's centre
// and a random translation of translation_mm (fixed seed), as an axis or angle error would.
inline std::vector<Rigid3d> PerturbedInitialPoses(const TurntableScan& scan, double rotation_deg,
                                                  double translation_mm, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> gauss(0.0, 1.0);
  const Eigen::Vector3d centre = scan.axis.point_in_rig_mm;
  std::vector<Rigid3d> out;
  for (size_t k = 0; k < scan.part_from_rig.size(); ++k) {
    const Eigen::Vector3d axis = Eigen::Vector3d(gauss(rng), gauss(rng), gauss(rng)).normalized();
    const Eigen::Vector3d shift =
        translation_mm * Eigen::Vector3d(gauss(rng), gauss(rng), gauss(rng)).normalized();
    const Eigen::Quaterniond r(Eigen::AngleAxisd(rotation_deg * M_PI / 180.0, axis));
    const Rigid3d perturbation(r, centre - r * centre + shift);
    // View 0 is the anchor: its initial pose defines the part frame, so it is exact.
    out.push_back(k == 0 ? scan.part_from_rig[k] : perturbation * scan.part_from_rig[k]);
  }
  return out;
}

// Raises the surface of one view's cloud around the flat spot by a cosine bump of height_mm and
// radius_mm (along the object's +z): a defect only that view sees.
inline void AddBump(const TurntableScan& scan, int view, double height_mm, double radius_mm,
                    PointCloud* cloud) {
  const Rigid3d rig_from_part = scan.part_from_rig[static_cast<size_t>(view)].Inverse();
  const Eigen::Vector3d centre = rig_from_part * (scan.part_from_object * FlatSpotInObject());
  const Eigen::Vector3d normal =
      rig_from_part.rotation * (scan.part_from_object.rotation * Eigen::Vector3d::UnitZ());
  for (auto& p : cloud->points) {
    const Eigen::Vector3d d = p - centre;
    if (std::abs(normal.dot(d)) > 1.0) continue;
    const double r = (d - normal.dot(d) * normal).norm();
    if (r < radius_mm) p += height_mm * 0.5 * (1 + std::cos(M_PI * r / radius_mm)) * normal;
  }
}

}  // namespace slshadow::multiview::testing
