// Synthetic fixtures shared by the compare/ tests: meshes with analytic signed distances and
// sampled analytic surfaces. Deterministic (fixed seeds).
#pragma once

#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <vector>

#include <Eigen/Core>

#include "core/mesh.h"

namespace slshadow::compare::testing {

// Axis-aligned box [-h, h] as 12 outward-facing triangles.
inline TriangleMesh BoxMesh(const Eigen::Vector3d& h) {
  TriangleMesh m;
  for (int i = 0; i < 8; ++i) {
    m.vertices.emplace_back((i & 1) ? h.x() : -h.x(), (i & 2) ? h.y() : -h.y(),
                            (i & 4) ? h.z() : -h.z());
  }
  // Quads as (v0, v1, v2, v3) counter-clockwise seen from outside.
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads) {
    m.triangles.emplace_back(q[0], q[1], q[2]);
    m.triangles.emplace_back(q[0], q[2], q[3]);
  }
  return m;
}

// Exact signed distance to the box [-h, h] (positive outside).
inline double BoxSdf(const Eigen::Vector3d& p, const Eigen::Vector3d& h) {
  const Eigen::Vector3d q = p.cwiseAbs() - h;
  return q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
}

// Icosphere of the given radius: 20 * 4^subdivisions outward triangles.
inline TriangleMesh IcoSphere(double radius, int subdivisions) {
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  TriangleMesh m;
  m.vertices = {{-1, t, 0},  {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t},  {0, 1, t},
                {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
  m.triangles = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                 {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                 {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                 {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (auto& v : m.vertices) v.normalize();
  for (int s = 0; s < subdivisions; ++s) {
    std::vector<Eigen::Vector3i> next;
    std::map<std::pair<int, int>, int> midpoint;  // shared edge midpoints keep the mesh closed
    for (const auto& f : m.triangles) {
      int mid[3];
      for (int k = 0; k < 3; ++k) {
        const int i = f[k], j = f[(k + 1) % 3];
        const auto key = std::minmax(i, j);
        auto it = midpoint.find(key);
        if (it == midpoint.end()) {
          m.vertices.push_back(
              (m.vertices[static_cast<size_t>(i)] + m.vertices[static_cast<size_t>(j)])
                  .normalized());
          it = midpoint.emplace(key, static_cast<int>(m.vertices.size()) - 1).first;
        }
        mid[k] = it->second;
      }
      next.emplace_back(f[0], mid[0], mid[2]);
      next.emplace_back(f[1], mid[1], mid[0]);
      next.emplace_back(f[2], mid[2], mid[1]);
      next.emplace_back(mid[0], mid[1], mid[2]);
    }
    m.triangles = std::move(next);
  }
  for (auto& v : m.vertices) v *= radius;
  return m;
}

// A "part" with enough shape for registration: a height field over [-s/2, s/2]^2
// z = s * (0.08 sin(3x/s * pi) cos(2y/s * pi) + 0.15 (x/s)^2 - 0.1 x y / s^2 + 0.05
// exp(-((x-0.2s)^2 + y^2)/(0.02 s^2))), sampled at n uniformly random (x, y).
inline double PartHeight(double x, double y, double s) {
  const double u = x / s, v = y / s;
  return s * (0.08 * std::sin(3 * M_PI * u) * std::cos(2 * M_PI * v) + 0.15 * u * u - 0.1 * u * v +
              0.05 * std::exp(-((u - 0.2) * (u - 0.2) + v * v) / 0.02));
}

inline std::vector<Eigen::Vector3d> SamplePart(size_t n, double s, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-s / 2, s / 2);
  std::vector<Eigen::Vector3d> pts(n);
  for (auto& p : pts) {
    const double x = u(rng), y = u(rng);
    p = {x, y, PartHeight(x, y, s)};
  }
  return pts;
}

// A cloud like a structured-light reconstruction's: the points a width x height camera 500 mm
// above a table sees of the part (PartHeight, s = 0.6 of the field, raised 20 mm on a block)
// through pixels of pitch_mm at the table, in scan order (row by row), with 0.02 mm of noise
// along the ray; pixels that see nothing are left out (a shadow band beside the block, a round
// hole in the table, 3 % of single pixels at random), so rows have gaps and differ in length.
inline std::vector<Eigen::Vector3d> ScanOrderCloud(int width, int height, double pitch_mm,
                                                   unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.02);
  const double distance = 500.0, fw = width * pitch_mm, s = 0.6 * fw;
  std::vector<Eigen::Vector3d> pts;
  pts.reserve(static_cast<size_t>(width) * static_cast<size_t>(height));
  for (int v = 0; v < height; ++v) {
    for (int c = 0; c < width; ++c) {
      // The ray through the pixel, at the table (z = 0).
      const double x0 = (c - 0.5 * width) * pitch_mm, y0 = (v - 0.5 * height) * pitch_mm;
      const bool on_block = std::abs(x0) < s / 2 && std::abs(y0) < s / 2;
      double z = on_block ? 20.0 + PartHeight(x0, y0, s) : 0.0;
      if (!on_block && x0 >= s / 2 && x0 < s / 2 + 6 && std::abs(y0) < s / 2) continue;  // shadow
      if (!on_block && std::hypot(x0 + 0.42 * fw, y0) < 0.04 * fw) continue;             // hole
      if (u(rng) < 0.03) continue;
      z += noise(rng);
      const double scale = (distance - z) / distance;  // perspective: nearer is denser
      pts.emplace_back(x0 * scale, y0 * scale, z);
    }
  }
  return pts;
}

inline std::vector<Eigen::Vector3d> RandomPoints(size_t n, double extent, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-extent, extent);
  std::vector<Eigen::Vector3d> pts(n);
  for (auto& p : pts) p = {u(rng), u(rng), u(rng)};
  return pts;
}

}  // namespace slshadow::compare::testing
