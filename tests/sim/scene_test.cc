#include "sim/scene.h"

#include <fstream>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "core/config.h"
#include "core/error.h"
#include "tests/sim/sim_test_util.h"

namespace slshadow {
namespace {

using ::testing::AllOf;
using ::testing::HasSubstr;

Scene ParseScene(const std::string& yaml, const std::filesystem::path& base = ".") {
  return SceneFromConfig(ConfigNode::ParseYaml(yaml, "scene.yaml"), base);
}

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

void WriteText(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
}

TEST(SceneTest, DemoSceneLoads) {
  const Scene scene = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
  ASSERT_EQ(scene.objects.size(), 2u);
  EXPECT_EQ(scene.objects[0].type, ObjectType::kMesh);
  EXPECT_GT(scene.objects[0].mesh->NumTriangles(), 10000u);
  EXPECT_EQ(scene.objects[1].type, ObjectType::kPlane);
  EXPECT_TRUE(scene.artefacts.contains("part"));
  EXPECT_EQ(SceneToJson(scene)["objects"].size(), 2u);
}

TEST(SceneTest, EveryExampleSceneLoads) {
  int n = 0;
  for (const auto& entry :
       std::filesystem::directory_iterator(testing::SourceDir() / "config/scenes")) {
    if (entry.path().extension() != ".yaml") continue;
    SCOPED_TRACE(entry.path().string());
    const Scene scene = LoadScene(entry.path());
    EXPECT_FALSE(scene.objects.empty());
    ++n;
  }
  EXPECT_GE(n, 3);
}

TEST(SceneTest, PrimitivesArtefactsAndLayersParse) {
  const Scene s = ParseScene(R"(
format: slshadow-scene
version: 1
name: t
radiometry: {exposure: 0.5, adc_bits: 12, lookup: nearest}
layers:
  supersampling: {samples_per_axis: 3}
  camera_defocus: {f_number: 2.8, focus_distance_mm: 450}
  projector_defocus: {enabled: false}
  projector_response: {gamma: 2.2}
  vignetting: {model: polynomial, coefficients: [-0.1, 0.01, 0]}
  ambient: {level: 0.02}
  noise: {full_well_e: 20000, read_noise_e: 3, seed: 9}
  fill_factor: {fill_factor: 0.8}
objects:
  - {type: sphere, name: s, diameter_mm: 25.4, rig_from_object: {rotation_quat_wxyz: [1, 0, 0, 0], translation_mm: [0, 0, 500]}}
  - {type: ball_bar, name: bar, radius_mm: 10, distance_mm: 200, rig_from_object: {rotation_rvec_rad: [0, 0, 0.5], translation_mm: [0, 0, 520]}}
  - {type: plane, size_mm: [100, 50], albedo: {type: checkerboard, square_mm: 10, squares_x: 5, squares_y: 4}}
  - {type: cylinder, radius_mm: 5, height_mm: 20, albedo: 0.3}
  - {type: box, size_mm: [1, 2, 3]}
)");
  EXPECT_EQ(s.radiometry.adc_bits, 12);
  EXPECT_FALSE(s.radiometry.bilinear_lookup);
  EXPECT_EQ(s.layers.supersampling, 3);
  EXPECT_TRUE(s.layers.camera_defocus.enabled);
  EXPECT_FALSE(s.layers.projector_defocus.enabled);
  EXPECT_DOUBLE_EQ(s.layers.gamma, 2.2);
  EXPECT_FALSE(s.layers.vignetting_cos4);
  EXPECT_TRUE(s.layers.noise_enabled);
  EXPECT_EQ(s.layers.seed, 9u);
  EXPECT_DOUBLE_EQ(s.layers.fill_factor, 0.8);
  // sphere, two ball-bar spheres + bar, plane, cylinder, box
  ASSERT_EQ(s.objects.size(), 7u);
  EXPECT_DOUBLE_EQ(s.objects[0].radius_mm, 12.7);
  const auto& bar = s.artefacts["bar"];
  EXPECT_DOUBLE_EQ(bar["distance_mm"].get<double>(), 200);
  const auto c = bar["centers_in_rig_mm"];
  const Eigen::Vector3d a(c[0][0].get<double>(), c[0][1].get<double>(), c[0][2].get<double>());
  const Eigen::Vector3d b(c[1][0].get<double>(), c[1][1].get<double>(), c[1][2].get<double>());
  EXPECT_NEAR((a - b).norm(), 200, 1e-9);
  EXPECT_NEAR(s.artefacts["s"]["diameter_mm"].get<double>(), 25.4, 1e-12);
  EXPECT_EQ(s.objects[4].albedo.kind, Albedo::Kind::kCheckerboard);
}

TEST(SceneTest, CheckerboardAlbedoFollowsOpenCvCorners) {
  Albedo a;
  a.kind = Albedo::Kind::kCheckerboard;
  a.square_mm = 10;
  a.squares_x = 4;
  a.squares_y = 3;
  EXPECT_EQ(a.Evaluate(-5, -5), a.dark) << "the corner square before the first inner corner";
  EXPECT_EQ(a.Evaluate(5, -5), a.light);
  EXPECT_EQ(a.Evaluate(5, 5), a.dark);
  EXPECT_EQ(a.Evaluate(-15, 5), a.light) << "margin";
  EXPECT_EQ(a.Evaluate(25, 15), a.light) << "margin beyond the last square";
  EXPECT_EQ(a.Evaluate(24, 14), a.light);
  EXPECT_EQ(a.Evaluate(15, 15), a.dark);
}

TEST(SceneTest, MeshUnitsAndRelativePaths) {
  testing::TempDir tmp;
  TriangleMesh m;
  m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  m.triangles = {{0, 1, 2}};
  WriteMesh(tmp / "tri.stl", m);
  const std::filesystem::path path = tmp / "scene.yaml";
  WriteText(path, "objects:\n  - {type: mesh, file: tri.stl, units: cm}\n");
  const Scene s = LoadScene(path);
  EXPECT_NEAR(s.objects[0].mesh->vertices[1].x(), 10, 1e-6);
}

// Bad scenes: one clear line naming the file, the field and what is wrong.
TEST(SceneTest, BadScenesGiveClearErrors) {
  testing::TempDir tmp;
  // Missing file.
  WriteText(tmp / "missing.yaml", "objects:\n  - {type: mesh, file: nowhere.stl}\n");
  EXPECT_THAT(
      ErrorOf([&] { LoadScene(tmp / "missing.yaml"); }),
      AllOf(HasSubstr("missing.yaml"), HasSubstr("objects[0].file"), HasSubstr("not found")));
  // Empty mesh: an ASCII STL without facets.
  WriteText(tmp / "empty.stl", "solid empty\nendsolid empty\n");
  WriteText(tmp / "empty.yaml", "objects:\n  - {type: mesh, file: empty.stl}\n");
  EXPECT_THAT(ErrorOf([&] { LoadScene(tmp / "empty.yaml"); }),
              AllOf(HasSubstr("empty"), HasSubstr("objects[0]")));
  // Degenerate triangle (zero area).
  TriangleMesh degenerate;
  degenerate.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {2, 0, 0}};
  degenerate.triangles = {{0, 1, 2}, {0, 1, 3}};
  WriteMesh(tmp / "degenerate.ply", degenerate);
  WriteText(tmp / "degenerate.yaml", "objects:\n  - {type: mesh, file: degenerate.ply}\n");
  EXPECT_THAT(ErrorOf([&] { LoadScene(tmp / "degenerate.yaml"); }),
              AllOf(HasSubstr("degenerate.ply"), HasSubstr("area")));
  // Non-manifold: three triangles on one edge.
  TriangleMesh fan;
  fan.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}};
  fan.triangles = {{0, 1, 2}, {1, 0, 3}, {0, 1, 4}};
  WriteMesh(tmp / "fan.ply", fan);
  WriteText(tmp / "fan.yaml", "objects:\n  - {type: mesh, file: fan.ply}\n");
  EXPECT_THAT(ErrorOf([&] { LoadScene(tmp / "fan.yaml"); }),
              AllOf(HasSubstr("fan.ply"), HasSubstr("non-manifold")));
  WriteText(tmp / "fan_ok.yaml",
            "objects:\n  - {type: mesh, file: fan.ply, allow_non_manifold: true}\n");
  EXPECT_NO_THROW(LoadScene(tmp / "fan_ok.yaml"));
  // NaN pose.
  EXPECT_THAT(ErrorOf([&] {
                ParseScene(
                    "objects:\n  - {type: sphere, radius_mm: 5, rig_from_object: "
                    "{rotation_quat_wxyz: [1, 0, 0, 0], "
                    "translation_mm: [.nan, 0, 500]}}\n");
              }),
              AllOf(HasSubstr("scene.yaml"), HasSubstr("translation_mm")));
  // Unknown layer.
  EXPECT_THAT(
      ErrorOf([&] {
        ParseScene("layers: {motion_blur: {}}\nobjects:\n  - {type: sphere, radius_mm: 5}\n");
      }),
      AllOf(HasSubstr("scene.yaml"), HasSubstr("layers"), HasSubstr("motion_blur")));
  // Unknown object type, bad values, point cloud without normals, empty scene.
  EXPECT_THAT(ErrorOf([&] { ParseScene("objects:\n  - {type: torus}\n"); }),
              HasSubstr("unknown object type"));
  EXPECT_THAT(ErrorOf([&] { ParseScene("objects:\n  - {type: sphere, radius_mm: -1}\n"); }),
              AllOf(HasSubstr("radius_mm"), HasSubstr("positive")));
  EXPECT_THAT(ErrorOf([&] { ParseScene("objects: []\n"); }), HasSubstr("no objects"));
  EXPECT_THAT(
      ErrorOf([&] {
        ParseScene(
            "layers: {noise: {full_well_e: 0}}\nobjects:\n  - {type: sphere, radius_mm: 5}\n");
      }),
      HasSubstr("full_well_e"));
  // reference_distance_mm: 0 is the rig's working distance (docs/formats.md); negative is refused.
  EXPECT_EQ(
      ParseScene(
          "radiometry: {reference_distance_mm: 0}\nobjects:\n  - {type: sphere, radius_mm: 5}\n")
          .radiometry.reference_distance_mm,
      0);
  EXPECT_THAT(
      ErrorOf([&] {
        ParseScene(
            "radiometry: {reference_distance_mm: -1}\nobjects:\n  - {type: sphere, radius_mm: "
            "5}\n");
      }),
      AllOf(HasSubstr("scene.yaml"), HasSubstr("reference_distance_mm"), HasSubstr(">= 0")));
  PointCloud cloud;
  cloud.points = {{0, 0, 0}, {1, 0, 0}};
  WritePly(tmp / "cloud.ply", cloud);
  WriteText(tmp / "cloud.yaml", "objects:\n  - {type: point_cloud, file: cloud.ply}\n");
  EXPECT_THAT(ErrorOf([&] { LoadScene(tmp / "cloud.yaml"); }), HasSubstr("no normals"));
}

TEST(SceneTest, DiscRadiiFollowSpacing) {
  std::vector<Eigen::Vector3d> grid;
  for (int i = 0; i < 30; ++i) {
    for (int j = 0; j < 30; ++j) grid.emplace_back(i * 0.5, j * 0.5, 0);
  }
  const auto radii = DiscRadiiFromSpacing(grid, 1.0);
  // Interior points: the four nearest neighbours are at exactly the spacing.
  EXPECT_FLOAT_EQ(radii[15 * 30 + 15], 0.5f);
  const auto scaled = DiscRadiiFromSpacing(grid, 0.75);
  EXPECT_FLOAT_EQ(scaled[15 * 30 + 15], 0.375f);
}

}  // namespace
}  // namespace slshadow
