#include "core/rig.h"

#include <fstream>

#include <gtest/gtest.h>

#include "core/config.h"
#include "core/error.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

constexpr double kDeg = M_PI / 180.0;

Rig DemoRig() { return LoadRig(testing::SourceDir() / "config/demo/rig.yaml"); }

std::string ErrorOf(const std::string& yaml) {
  try {
    RigFromConfig(ConfigNode::ParseYaml(yaml, "bad.yaml"));
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(Rig, DemoGeometry) {
  const Rig rig = DemoRig();
  ASSERT_EQ(rig.cameras.size(), 2u);
  ASSERT_TRUE(rig.projector.has_value());
  EXPECT_EQ(rig.cameras[0].model.width, 1920);
  EXPECT_EQ(rig.projector->model.width, 1280);
  EXPECT_NEAR(rig.BaselineMm(rig.cameras[0], rig.cameras[1]), 200.0, 1e-6);
  // Both cameras converge on the working point: the right camera's axis passes through it.
  const Eigen::Vector3d wp = rig.WorkingPointInRig();
  EXPECT_NEAR((wp - Eigen::Vector3d(0, 0, 500)).norm(), 0, 1e-9);
  const auto& right = rig.cameras[1];
  const Eigen::Vector3d to_wp = (wp - right.CenterInRig()).normalized();
  EXPECT_NEAR(to_wp.dot(right.AxisInRig()), 1.0, 1e-12);
  // Convergence angle 2 asin(100 / 500).
  EXPECT_NEAR(Rig::TriangulationAngleRad(rig.cameras[0], right, wp), 2 * std::asin(0.2), 1e-9);
  EXPECT_GT(rig.OverlapAtWorkingDistance(rig.cameras[0], right), 0.8);
  EXPECT_GT(rig.OverlapAtWorkingDistance(rig.cameras[0], *rig.projector), 0.8);
  EXPECT_NEAR(rig.cameras[0].model.HorizontalFovRad(), 39.0 * kDeg, 1.0 * kDeg);
}

TEST(Rig, YamlAndJsonRoundTripBitExact) {
  testing::TempDir dir;
  Rig rig = DemoRig();
  rig.calibration = {{"rms_px", 0.123}, {"views", 17}};
  SaveRig(rig, dir / "rig.yaml");
  SaveRig(rig, dir / "rig.json");
  for (const char* name : {"rig.yaml", "rig.json"}) {
    const Rig back = LoadRig(dir / name);
    EXPECT_EQ(RigToJson(back), RigToJson(rig)) << name;
  }
}

TEST(Rig, RotationForms) {
  const std::string head =
      "cameras:\n  - name: a\n    width: 10\n    height: 10\n    intrinsics: {fx: 5, fy: 5, cx: 5, "
      "cy: 5}\n    cam_from_rig:\n";
  const Rig r1 = RigFromConfig(ConfigNode::ParseYaml(
      head + "      rotation_rvec_rad: [0, 0.3, 0]\n      translation_mm: [1, 2, 3]\n", "a.yaml"));
  const Rig r2 = RigFromConfig(ConfigNode::ParseYaml(
      head + "      rotation_matrix: [" + std::to_string(std::cos(0.3)) + ", 0, " +
          std::to_string(std::sin(0.3)) + ", 0, 1, 0, " + std::to_string(-std::sin(0.3)) + ", 0, " +
          std::to_string(std::cos(0.3)) + "]\n      translation_mm: [1, 2, 3]\n",
      "b.yaml"));
  EXPECT_NEAR(
      r1.cameras[0].cam_from_rig.rotation.angularDistance(r2.cameras[0].cam_from_rig.rotation), 0,
      1e-6);
  EXPECT_EQ(r1.cameras[0].cam_from_rig.translation, Eigen::Vector3d(1, 2, 3));
}

// docs/formats.md: rotation_quat_wxyz is Hamilton's quaternion acting on rig-frame vectors
// (X_cam = R(q) X_rig + t): [cos 45 deg, 0, 0, sin 45 deg] turns +x into +y; unit norm within 1e-6.
TEST(Rig, QuaternionConvention) {
  const std::string head =
      "cameras:\n  - name: a\n    width: 10\n    height: 10\n    intrinsics: {fx: 5, fy: 5, cx: 5, "
      "cy: 5}\n    cam_from_rig:\n";
  const double h = std::sqrt(0.5);
  const Rig rig = RigFromConfig(
      ConfigNode::ParseYaml(head + "      rotation_quat_wxyz: [" + std::to_string(h) + ", 0, 0, " +
                                std::to_string(h) + "]\n      translation_mm: [1, 2, 3]\n",
                            "q.yaml"));
  const Eigen::Vector3d x_in_cam = rig.cameras[0].cam_from_rig * Eigen::Vector3d(1, 0, 0);
  EXPECT_NEAR((x_in_cam - Eigen::Vector3d(1, 3, 3)).norm(), 0, 1e-6);
  // The same rotation as rotation_rvec_rad [0, 0, pi/2] (OpenCV's Rodrigues).
  const Rig rv = RigFromConfig(ConfigNode::ParseYaml(
      head +
          "      rotation_rvec_rad: [0, 0, 1.5707963267948966]\n      translation_mm: [0, 0, 0]\n",
      "r.yaml"));
  EXPECT_NEAR(
      rv.cameras[0].cam_from_rig.rotation.angularDistance(rig.cameras[0].cam_from_rig.rotation), 0,
      1e-6);
  // Norm 1 + 5e-7 is accepted (and renormalised); 1 + 2e-6 is refused.
  EXPECT_NO_THROW(RigFromConfig(ConfigNode::ParseYaml(
      head + "      rotation_quat_wxyz: [1.0000005, 0, 0, 0]\n      translation_mm: [0, 0, 0]\n",
      "n.yaml")));
  EXPECT_NE(
      ErrorOf(head +
              "      rotation_quat_wxyz: [1.000002, 0, 0, 0]\n      translation_mm: [0, 0, 0]\n")
          .find("unit norm"),
      std::string::npos);
}

TEST(Rig, MalformedRigsGiveClearErrors) {
  const std::string cam =
      "  - name: a\n    width: 10\n    height: 10\n    intrinsics: {fx: 5, fy: 5, cx: 5, cy: 5}\n";
  EXPECT_EQ(ErrorOf("name: x\n"), "bad.yaml: cameras: missing required field");
  EXPECT_EQ(ErrorOf("cameras:\n  - name: a\n    width: 10\n    height: 10\n    intrinsics: {fx: "
                    "-5, fy: 5, cx: 5, cy: 5}\n"),
            "bad.yaml: cameras[0].intrinsics.fx: focal length must be positive (got -5)");
  EXPECT_EQ(ErrorOf("cameras:\n  - name: a\n    width: ten\n"),
            "bad.yaml: cameras[0].width: expected a whole number (got \"ten\")");
  EXPECT_EQ(ErrorOf("cameras:\n  - name: a\n    width: 10\n    height: 10\n    intrinsics: {fx: "
                    ".nan, fy: 5, cx: 5, cy: 5}\n"),
            "bad.yaml: cameras[0].intrinsics.fx: must be a finite number (got NaN)");
  EXPECT_EQ(ErrorOf("cameras:\n" + cam + cam),
            "bad.yaml: cameras[1].name: duplicate camera name (got \"a\")");
  EXPECT_NE(
      ErrorOf("cameras:\n" + cam +
              "    cam_from_rig: {rotation_quat_wxyz: [1, 1, 0, 0], translation_mm: [0, 0, 0]}\n")
          .find("cameras[0].cam_from_rig.rotation_quat_wxyz: quaternion must have unit norm"),
      std::string::npos);
  EXPECT_NE(ErrorOf("cameras:\n" + cam + "    lens: 16mm\n").find("cameras[0].lens: unknown field"),
            std::string::npos);
  EXPECT_NE(ErrorOf("working_distance_mm: -3\ncameras:\n" + cam)
                .find("working_distance_mm: must be positive"),
            std::string::npos);
}

TEST(Rig, TurntableAxisRoundTripAndMotion) {
  testing::TempDir dir;
  Rig rig = DemoRig();
  TurntableAxis axis;
  axis.direction_in_rig = Eigen::Vector3d(0.1, -0.9, -0.3).normalized();
  axis.point_in_rig_mm = Eigen::Vector3d(2, 10, 545);
  axis.angle_offset_deg = 0.25;
  axis.angle_scale = 1.001;
  axis.sigma_direction_deg = 0.002;
  rig.turntable = axis;
  SaveRig(rig, dir / "rig.yaml");
  const Rig back = LoadRig(dir / "rig.yaml");
  ASSERT_TRUE(back.turntable.has_value());
  EXPECT_EQ(RigToJson(back), RigToJson(rig));
  // The motion against its definition: points on the axis stay; others turn by the true angle
  // about it, counter-clockwise seen from the direction's tip.
  const double commanded = 30.0;
  const Rigid3d m = axis.RigFromTableTurn(commanded);
  const Eigen::Vector3d on_axis = axis.point_in_rig_mm + 17.0 * axis.direction_in_rig;
  EXPECT_NEAR((m * on_axis - on_axis).norm(), 0, 1e-9);
  const Eigen::Vector3d off = axis.point_in_rig_mm + Eigen::Vector3d(40, 3, -7);
  const Eigen::Vector3d a = off - axis.point_in_rig_mm, b = m * off - axis.point_in_rig_mm;
  const Eigen::Vector3d n = axis.direction_in_rig;
  const Eigen::Vector3d a_perp = a - a.dot(n) * n, b_perp = b - b.dot(n) * n;
  EXPECT_NEAR(a.dot(n), b.dot(n), 1e-9);
  const double angle = std::atan2(a_perp.cross(b_perp).dot(n), a_perp.dot(b_perp));
  EXPECT_NEAR(angle / kDeg, 1.001 * commanded + 0.25, 1e-9);
  // Without a turntable the rig writes no key.
  EXPECT_FALSE(RigToJson(DemoRig()).contains("turntable"));
  const std::string cam =
      "cameras:\n  - name: a\n    width: 10\n    height: 10\n    intrinsics: "
      "{fx: 5, fy: 5, cx: 5, cy: 5}\n";
  EXPECT_NE(ErrorOf(cam + "turntable: {axis_direction: [0, 0, 0], axis_point_mm: [0, 0, 0]}\n")
                .find("turntable.axis_direction: must be a non-zero finite vector"),
            std::string::npos);
  EXPECT_NE(ErrorOf(cam + "turntable: {axis_direction: [0, 1, 0]}\n")
                .find("turntable.axis_point_mm: missing required field"),
            std::string::npos);
  EXPECT_NE(ErrorOf(cam + "turntable: {axis_direction: [0, 1, 0], axis_point_mm: [0, 0, 0], "
                          "angle_scale: 0}\n")
                .find("turntable.angle_scale: must be a number in (0.5, 2)"),
            std::string::npos);
}

}  // namespace
}  // namespace slshadow
