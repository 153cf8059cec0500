// Geometry generated in code: the embedded demo part (no download), tessellated spheres for
// tessellation-error tests, and a scene with a printed checkerboard for calibration tests.
// Units: millimetres. Meshes are counter-clockwise seen from outside.
#pragma once

#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "core/mesh.h"
#include "core/rigid3.h"
#include "sim/scene.h"

namespace slshadow {

// The demo part: a machined block of 160 x 100 mm footprint (object frame: x in [-80, 80],
// y in [-50, 50], base at z = 0, top faces +z) built from 20 mm tiles with three steps along x
// (heights 30, 40, 50 mm), a 40 x 40 mm pocket 12 mm deep, three blind holes (radius 6 mm,
// 15 mm deep) and a dome (sphere of radius 10 mm whose centre is 4 mm above the top face).
// So it has shadows, occlusions and depth discontinuities. `resolution_mm` is the largest edge
// length of the flat parts' grid (and about the arc length of curved parts' segments):
// 2 mm gives ~25 k triangles, 0.25 mm ~1 M. The mesh is the part's ground truth: every
// triangle lies exactly on the part's surface (pieces are not welded; T-junctions are closed
// up to rounding).
TriangleMesh MakeDemoPart(double resolution_mm);

// The resolution (mm) at which MakeDemoPart gives about `triangles` triangles (86 696 at 1 mm;
// the count grows as 1 / resolution^2). Benchmarks size the part with it.
double DemoPartResolutionFor(double triangles);

// Description of the demo part's analytic features in its object frame (for tests and reports).
struct DemoPartFeatures {
  Eigen::Vector3d sphere_center_mm{0, 0, 0};
  double sphere_radius_mm = 0;
  std::vector<Eigen::Vector3d> hole_top_centers_mm;
  double hole_radius_mm = 0;
  double hole_depth_mm = 0;
};
DemoPartFeatures DemoPartDescription();

// The occlusion test part: a block no single view sees whole. Object frame: footprint x in
// [-60, 60], y in [-40, 40], base at z = 0, top towards +z; a base slab 20 mm high; a tower over
// x in [-60, -10] up to z = 60 with a deep square hole (x in [-40, -30], y in [-5, 5], from the
// tower's top at z = 60 down to z = 10: 10 mm wide, 50 mm deep); and an overhang, a slab at
// z in [50, 60] reaching from the tower over x in [-10, 30] (its underside 30 mm above the base
// slab's top). Built from 5 mm voxels whose faces are split into squares of at most
// resolution_mm, vertices welded: a closed manifold mesh, counter-clockwise seen from outside,
// every triangle exactly on the part's surface. Throws on resolution_mm outside (0.05, 5].
TriangleMesh MakeOcclusionPart(double resolution_mm);

// UV sphere centred at the origin: `segments` around the equator, segments/2 rings. Vertices lie
// on the sphere, so the mesh is inside it; the largest gap is r (1 - cos(pi / segments)).
TriangleMesh MakeSphereMesh(double radius_mm, int segments);

// A calibration board: a plane with a printed checkerboard of inner_corners_x x inner_corners_y
// inner corners and square_mm squares, posed at rig_from_board. The board frame is OpenCV's
// object frame: inner corner (i, j) at (i * square_mm, j * square_mm, 0), the board in z = 0
// with a one-square white margin around the squares.
struct BoardScene {
  Scene scene;
  // Inner corners in the rig frame, row-major (index j * inner_corners_x + i), mm.
  std::vector<Eigen::Vector3d> corners_in_rig;
  // The same corners in the board frame (z = 0).
  std::vector<Eigen::Vector3d> corners_in_board;
};
BoardScene MakeCheckerboardScene(int inner_corners_x, int inner_corners_y, double square_mm,
                                 const Rigid3d& rig_from_board, double dark = 0.05,
                                 double light = 0.9);

// A plane printed with an arbitrary grey image (e.g. a ChArUco board drawn with cv::aruco):
// image pixel (u, v) covers [u, u+1] x [v, v+1] * pixel_mm of the board frame's x-y plane, so
// the image's top-left corner is the board origin; a margin_mm white (`light`) border surrounds
// it. The image is CV_8UC1 (0..255 -> albedo 0..1).
Scene MakeImageBoardScene(const cv::Mat& image, double pixel_mm, const Rigid3d& rig_from_board,
                          double margin_mm = 10, double light = 0.9);

}  // namespace slshadow
