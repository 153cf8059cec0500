#include "sim/shapes.h"

#include <gtest/gtest.h>

#include <map>
#include <utility>

#include "core/error.h"
#include "sim/renderer.h"
#include "tests/sim/sim_test_util.h"

namespace slshadow {
namespace {

TEST(DemoPartTest, ValidMeshWithExpectedExtentAndScalableResolution) {
  const TriangleMesh coarse = MakeDemoPart(2.0);
  const TriangleMesh fine = MakeDemoPart(0.5);
  coarse.Check("demo part");
  fine.Check("demo part");
  EXPECT_EQ(coarse.CountNonManifoldEdges(), 0u);
  EXPECT_GT(fine.NumTriangles(), 10 * coarse.NumTriangles());
  EXPECT_NEAR(coarse.BoundsMin().x(), -80, 1e-9);
  EXPECT_NEAR(coarse.BoundsMax().x(), 80, 1e-9);
  EXPECT_NEAR(coarse.BoundsMin().y(), -50, 1e-9);
  EXPECT_NEAR(coarse.BoundsMax().y(), 50, 1e-9);
  EXPECT_NEAR(coarse.BoundsMin().z(), 0, 1e-9);
  const DemoPartFeatures f = DemoPartDescription();
  EXPECT_NEAR(coarse.BoundsMax().z(), f.sphere_center_mm.z() + f.sphere_radius_mm, 1e-9)
      << "the dome's top";
  // The flat faces are exact: their area does not change with resolution (only curved parts do).
  EXPECT_NEAR(coarse.SurfaceArea(), fine.SurfaceArea(), 0.01 * fine.SurfaceArea());
  // Every vertex of the dome lies on its sphere; hole-wall vertices on the hole cylinders.
  int on_dome = 0;
  for (const auto& v : fine.vertices) {
    if ((v - f.sphere_center_mm).norm() < f.sphere_radius_mm + 1e-9 &&
        v.z() > f.sphere_center_mm.z() - 4 + 1e-9) {
      EXPECT_NEAR((v - f.sphere_center_mm).norm(), f.sphere_radius_mm, 1e-9);
      ++on_dome;
    }
  }
  EXPECT_GT(on_dome, 100);
}

TEST(DemoPartTest, ResolutionForATriangleCount) {
  EXPECT_DOUBLE_EQ(DemoPartResolutionFor(86696), 1.0);
  for (const double n : {25000.0, 200000.0}) {
    const double got = static_cast<double>(MakeDemoPart(DemoPartResolutionFor(n)).NumTriangles());
    EXPECT_NEAR(got / n, 1.0, 0.15) << n << " triangles asked, " << got << " made";
  }
  EXPECT_THROW(DemoPartResolutionFor(0), Error);
}

TEST(DemoPartTest, OutwardNormals) {
  // Closed-ish solid: the signed volume from outward faces is positive and close to the block's.
  const TriangleMesh m = MakeDemoPart(2.0);
  double volume = 0;
  for (const auto& t : m.triangles) {
    volume += m.vertices[static_cast<size_t>(t[0])].dot(m.vertices[static_cast<size_t>(t[1])].cross(
                  m.vertices[static_cast<size_t>(t[2])])) /
              6;
  }
  // Steps 30/40/50 mm over 60/60/40 mm of x, 100 mm of y, minus the pocket (40 x 40 x 12),
  // minus three holes, plus the dome cap above the face.
  const DemoPartFeatures f = DemoPartDescription();
  const double block = 100 * (60 * 30 + 60 * 40 + 40 * 50) - 40 * 40 * 12;
  const double holes = 3 * M_PI * f.hole_radius_mm * f.hole_radius_mm * f.hole_depth_mm;
  const double h = f.sphere_radius_mm + 4;  // cap height above the face
  const double cap = M_PI * h * h * (3 * f.sphere_radius_mm - h) / 3;
  // The dome is open at the bottom and the tile face under it is closed, so the faces enclose
  // the block plus the cap above the face.
  EXPECT_NEAR(volume, block - holes + cap, 0.01 * block);
}

TEST(OcclusionPartTest, ClosedManifoldWithTheDefinedVolumeAtAnyResolution) {
  const TriangleMesh coarse = MakeOcclusionPart(5.0);
  const TriangleMesh fine = MakeOcclusionPart(1.0);
  for (const TriangleMesh* m : {&coarse, &fine}) {
    m->Check("occlusion part");
    EXPECT_EQ(m->CountNonManifoldEdges(), 0u);
    // Closed and consistently oriented: every directed edge has its reverse, once.
    std::map<std::pair<int, int>, int> edges;
    for (const auto& t : m->triangles) {
      for (int k = 0; k < 3; ++k) ++edges[{t[k], t[(k + 1) % 3]}];
    }
    for (const auto& [e, n] : edges) {
      ASSERT_EQ(n, 1) << "edge " << e.first << "-" << e.second;
      ASSERT_EQ(edges.count({e.second, e.first}), 1u) << "open edge " << e.first << "-" << e.second;
    }
    double volume = 0;
    for (const auto& t : m->triangles) {
      volume +=
          m->vertices[static_cast<size_t>(t[0])].dot(m->vertices[static_cast<size_t>(t[1])].cross(
              m->vertices[static_cast<size_t>(t[2])])) /
          6;
    }
    // Base 120 x 80 x 20, tower 50 x 80 x 40, overhang 40 x 80 x 10, minus the hole 10 x 10 x 50.
    EXPECT_NEAR(volume, 192000.0 + 160000.0 + 32000.0 - 5000.0, 1e-6);
    EXPECT_NEAR(m->BoundsMin().x(), -60, 1e-12);
    EXPECT_NEAR(m->BoundsMax().x(), 60, 1e-12);
    EXPECT_NEAR(m->BoundsMax().z(), 60, 1e-12);
  }
  EXPECT_NEAR(coarse.SurfaceArea(), fine.SurfaceArea(), 1e-6);
  EXPECT_EQ(fine.NumTriangles(), 25 * coarse.NumTriangles());
  // The hole's bottom is 50 mm down, at z = 10.
  bool bottom = false;
  for (size_t i = 0; i < fine.NumTriangles(); ++i) {
    const auto& t = fine.triangles[i];
    const Eigen::Vector3d c =
        (fine.vertices[static_cast<size_t>(t[0])] + fine.vertices[static_cast<size_t>(t[1])] +
         fine.vertices[static_cast<size_t>(t[2])]) /
        3;
    if (std::abs(c.z() - 10) < 1e-9 && c.x() > -40 && c.x() < -30 && std::abs(c.y()) < 5) {
      EXPECT_GT(fine.FaceNormal(i).z(), 0.999);
      bottom = true;
    }
  }
  EXPECT_TRUE(bottom);
  EXPECT_THROW(MakeOcclusionPart(0.01), Error);
}

TEST(SphereMeshTest, VerticesOnSphere) {
  const TriangleMesh m = MakeSphereMesh(12.5, 24);
  m.Check("sphere");
  EXPECT_EQ(m.CountNonManifoldEdges(), 0u);
  for (const auto& v : m.vertices) EXPECT_NEAR(v.norm(), 12.5, 1e-12);
  EXPECT_NEAR(m.SurfaceArea(), 4 * M_PI * 12.5 * 12.5, 0.03 * 4 * M_PI * 12.5 * 12.5);
}

// The board seen by the camera: dark/light squares where the ground-truth corners say.
TEST(CheckerboardSceneTest, CornersAndSquaresWhereTheCameraSeesThem) {
  const Rig rig = testing::SmallDemoRig(2);
  const Rigid3d rig_from_board =
      testing::Pose(Eigen::Vector3d(0.1, -0.2, 0.05), Eigen::Vector3d(-90, -60, 480));
  const BoardScene board = MakeCheckerboardScene(9, 6, 20, rig_from_board);
  ASSERT_EQ(board.corners_in_rig.size(), 54u);
  EXPECT_NEAR((board.corners_in_rig[1] - board.corners_in_rig[0]).norm(), 20, 1e-9);
  EXPECT_NEAR((board.corners_in_rig[9] - board.corners_in_rig[0]).norm(), 20, 1e-9);
  const RayCaster caster(board.scene);
  const CameraRays rays = ComputeCameraRays(rig.cameras[0].model, 1);
  const GeometryBuffer g = TraceGeometry(caster, rig, 0, rays);
  const cv::Mat img =
      PatternRenderer(board.scene, rig, 0, g).Render(testing::FlatProjectorImage(rig, 255), 0);
  // Sample the centre of each square next to corner (i, j): the square with both indices
  // +0.5 offsets is dark when (i + j) is even (the corner square at (-1,-1) is dark).
  int checked = 0;
  for (int j = 0; j < 5; ++j) {
    for (int i = 0; i < 8; ++i) {
      const Eigen::Vector3d center =
          rig_from_board * Eigen::Vector3d((i + 0.5) * 20, (j + 0.5) * 20, 0);
      const auto px = rig.cameras[0].model.Project(center);
      ASSERT_TRUE(px && rig.cameras[0].model.IsInImage(*px));
      const int x = static_cast<int>(std::lround(px->x())),
                y = static_cast<int>(std::lround(px->y()));
      if (g.visibility.at<uint8_t>(y, x) != 2) continue;
      const int v = img.at<uint8_t>(y, x);
      if ((i + j) % 2 == 0) {
        EXPECT_LT(v, 40) << i << "," << j;
      } else {
        EXPECT_GT(v, 100) << i << "," << j;
      }
      ++checked;
    }
  }
  EXPECT_GT(checked, 30);
}

// An image printed on a plane: the camera sees the image's pixels where they project.
TEST(ImageBoardSceneTest, CameraSeesThePrintedImage) {
  const Rig rig = testing::SmallDemoRig(2);
  cv::Mat image(60, 90, CV_8UC1, cv::Scalar(230));
  image(cv::Rect(30, 20, 30, 20)).setTo(10);  // a dark block in the middle
  const Rigid3d rig_from_board =
      testing::Pose(Eigen::Vector3d(0.05, 0.1, 0), Eigen::Vector3d(-90, -60, 500));
  const Scene scene = MakeImageBoardScene(image, 2.0, rig_from_board);
  const RayCaster caster(scene);
  const GeometryBuffer g =
      TraceGeometry(caster, rig, 0, ComputeCameraRays(rig.cameras[0].model, 1));
  const cv::Mat img =
      PatternRenderer(scene, rig, 0, g).Render(testing::FlatProjectorImage(rig, 255), 0);
  auto value_at = [&](double u, double v) {
    // Board coordinates of image pixel centre (u, v).
    const auto px = rig.cameras[0].model.Project(
        rig_from_board * Eigen::Vector3d((u + 0.5) * 2.0, (v + 0.5) * 2.0, 0));
    EXPECT_TRUE(px && rig.cameras[0].model.IsInImage(*px));
    return img.at<uint8_t>(static_cast<int>(std::lround(px->y())),
                           static_cast<int>(std::lround(px->x())));
  };
  EXPECT_LT(value_at(45, 30), 15);   // inside the dark block
  EXPECT_GT(value_at(10, 10), 100);  // light part of the image
  EXPECT_GT(value_at(-3, 30), 100);  // margin
}

}  // namespace
}  // namespace slshadow
