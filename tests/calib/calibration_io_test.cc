#include "calib/calibration_io.h"

#include <gtest/gtest.h>

#include <fstream>

#include "calib/synthetic.h"
#include "core/error.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

void ExpectSameModel(const CameraModel& a, const CameraModel& b, double tol) {
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  for (int i = 0; i < CameraModel::kNumParams; ++i) EXPECT_NEAR(a.params[i], b.params[i], tol * (1 + std::abs(a.params[i]))) << i;
}

void ExpectSamePose(const Rigid3d& a, const Rigid3d& b, double tol) {
  EXPECT_LT(a.rotation.angularDistance(b.rotation), tol);
  EXPECT_LT((a.translation - b.translation).norm(), tol);
}

TEST(CalibrationIo, RigFileKeepsTheEvidenceToRecomputeTheCalibration) {
  testing::TempDir tmp;
  SyntheticData data = MakeSyntheticData(SyntheticRig::Stereo(), 8, 0.2, 3);
  data.input.devices[1].is_projector = true;  // the second device plays the projector
  for (auto& v : data.input.views) {  // its pixels carried from the first device's (any J, C)
    if (v.device != 1) continue;
    v.source_device = 0;
    for (size_t i = 0; i < v.pixels_px.size(); ++i) {
      v.source_points.push_back(static_cast<int>(i));
      v.source_jacobians.push_back((Eigen::Matrix2d() << 0.9, 0.05, -0.02, 1.1).finished());
      v.carry_covariances_px2.push_back((Eigen::Matrix2d() << 0.01, 0.002, 0.002, 0.02).finished());
    }
  }
  CalibrationOptions options;
  options.loss = LossType::kHuber;
  options.loss_scale_px = 2.0;
  const CalibrationResult result = Calibrate(data.input, options);
  Rig rig = RigFromCalibration(data.input, result, "test");
  ASSERT_EQ(rig.cameras.size(), 1u);
  ASSERT_TRUE(rig.projector);
  EXPECT_NEAR(rig.working_distance_mm, 650, 200);
  rig.calibration = CalibrationEvidenceToJson(data.input, options, result, CrossValidate(data.input, options));
  EXPECT_TRUE(rig.calibration.contains("projection_uncertainty"));
  EXPECT_TRUE(rig.calibration.contains("cross_validation"));
  EXPECT_TRUE(rig.calibration.contains("intrinsics_covariance_view_correlated"));
  EXPECT_TRUE(rig.calibration["summary"].contains("view_noise"));
  SaveRig(rig, tmp / "rig.yaml");
  const Rig back = LoadRig(tmp / "rig.yaml");
  const CalibrationEvidence ev = CalibrationEvidenceFromJson(back.calibration, "rig.yaml");
  EXPECT_EQ(ev.options.loss, LossType::kHuber);
  EXPECT_EQ(ev.options.loss_scale_px, 2.0);
  ASSERT_EQ(ev.input.views.size(), data.input.views.size());
  EXPECT_TRUE(ev.input.devices[1].is_projector);
  // Recomputing from the stored evidence gives the same calibration and covariance.
  const CalibrationResult again = Calibrate(ev.input, ev.options);
  for (size_t d = 0; d < 2; ++d) {
    ExpectSameModel(again.devices[d].model, result.devices[d].model, 1e-6);
    EXPECT_LT((again.intrinsics_covariance[d] - result.intrinsics_covariance[d]).norm(),
              1e-4 * result.intrinsics_covariance[d].norm());
    // ... and the view-correlated one, which needs the carried views' Jacobians.
    EXPECT_LT((again.intrinsics_covariance_view_correlated.at(d) - result.intrinsics_covariance_view_correlated.at(d)).norm(),
              1e-4 * result.intrinsics_covariance_view_correlated[d].norm());
  }
  for (size_t i = 0; i < ev.input.views.size(); ++i) {
    const BoardView& a = ev.input.views[i];
    const BoardView& b = data.input.views[i];
    EXPECT_EQ(a.source_device, b.source_device);
    EXPECT_EQ(a.source_points, b.source_points);
    ASSERT_EQ(a.source_jacobians.size(), b.source_jacobians.size());
    for (size_t k = 0; k < a.source_jacobians.size(); ++k) {
      EXPECT_EQ(a.source_jacobians[k], b.source_jacobians[k]);
      EXPECT_EQ(a.carry_covariances_px2[k], b.carry_covariances_px2[k]);
    }
  }
  options.correlated_carried_noise = true;  // the joint noise model's option is kept too
  EXPECT_TRUE(CalibrationOptionsFromJson(CalibrationOptionsToJson(options), "x").correlated_carried_noise);
  options.principal_point_inside = true;  // and the principal-point bound
  EXPECT_TRUE(CalibrationOptionsFromJson(CalibrationOptionsToJson(options), "x").principal_point_inside);
  EXPECT_FALSE(CalibrationOptionsFromJson(CalibrationOptionsToJson(CalibrationOptions{}), "x").principal_point_inside);
  // Malformed evidence names the field.
  nlohmann::json broken = back.calibration;
  broken["views"][0]["pixels_px"][0] = {1.0};
  try {
    CalibrationEvidenceFromJson(broken, "rig.yaml");
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("views[0].pixels_px[0]"), std::string::npos) << e.what();
  }
}

TEST(CalibrationIo, OpenCvFilesRoundTripInYamlAndXml) {
  testing::TempDir tmp;
  const SyntheticRig truth = SyntheticRig::Stereo();
  Rig rig;
  rig.name = "x";
  rig.cameras = truth.devices;
  RigDevice proj;
  proj.name = "projector";
  proj.model = CameraModel(1024, 768, 1950, 1935, 500, 700, 0.01, -0.02, 0.001, 0.002, 0.0);
  proj.cam_from_rig = Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.2, Eigen::Vector3d(0.1, 1, 0.2).normalized())),
                              Eigen::Vector3d(40, -280, -60));
  rig.projector = proj;
  for (const std::string ext : {".yml", ".xml"}) {
    WriteOpenCvCalibration(rig, tmp / ("rig" + ext));
    const Rig back = ReadOpenCvCalibration(tmp / ("rig" + ext));
    ASSERT_EQ(back.cameras.size(), 2u) << ext;
    ASSERT_TRUE(back.projector);
    for (size_t i = 0; i < 2; ++i) {
      ExpectSameModel(back.cameras[i].model, rig.cameras[i].model, 1e-12);
      ExpectSamePose(back.cameras[i].cam_from_rig, rig.cameras[i].cam_from_rig, 1e-9);
      EXPECT_EQ(back.cameras[i].name, rig.cameras[i].name);
    }
    ExpectSameModel(back.projector->model, proj.model, 1e-12);
    ExpectSamePose(back.projector->cam_from_rig, proj.cam_from_rig, 1e-9);
  }
  // One camera: OpenCV's calibration sample layout.
  Rig one;
  one.cameras = {truth.devices[0]};
  WriteOpenCvCalibration(one, tmp / "one.yaml");
  ExpectSameModel(ReadOpenCvCalibration(tmp / "one.yaml").cameras[0].model, one.cameras[0].model, 1e-12);
}

TEST(CalibrationIo, ReadsUpstreamFiles) {
  const Rig left = ReadOpenCvCalibration(testing::SharedDataDir() / "opencv-stereo-chessboard/left_intrinsics.yml");
  ASSERT_EQ(left.cameras.size(), 1u);
  EXPECT_NEAR(left.cameras[0].model.fx(), 535.9157, 1e-4);
  EXPECT_NEAR(left.cameras[0].model.cy(), 235.5708, 1e-4);
  EXPECT_NEAR(left.cameras[0].model.params[CameraModel::kK3], 0.23839, 1e-5);
  EXPECT_EQ(left.cameras[0].model.width, 640);
  const Rig procam = ReadOpenCvCalibration(testing::SharedDataDir() / "kamino-procam-graycode/calibration_result_ccf1cd8.xml",
                                           0, 0, 1024, 768);
  ASSERT_TRUE(procam.projector);
  EXPECT_EQ(procam.cameras[0].model.width, 1280);
  EXPECT_EQ(procam.cameras[0].model.height, 1024);
  EXPECT_NEAR(procam.cameras[0].model.fx(), 3452.39, 0.01);
  EXPECT_NEAR(procam.projector->model.fx(), 1947.16, 0.01);
  EXPECT_NEAR(procam.projector->cam_from_rig.translation.y(), -278.3, 0.05);
  // No projector size: a clear error.
  EXPECT_THROW(ReadOpenCvCalibration(testing::SharedDataDir() / "kamino-procam-graycode/calibration_result.xml"), Error);
}

TEST(CalibrationIo, BadOpenCvFilesGiveClearErrors) {
  testing::TempDir tmp;
  auto expect_error = [](const std::filesystem::path& p, const std::string& needle) {
    try {
      ReadOpenCvCalibration(p, 640, 480);
      ADD_FAILURE() << "no error for " << p;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  expect_error(tmp / "missing.yml", "not found");
  std::ofstream(tmp / "empty.yml") << "%YAML:1.0\n---\nfoo: 1\n";
  expect_error(tmp / "empty.yml", "not an OpenCV calibration file");
  std::ofstream(tmp / "rational.yml")
      << "%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\n"
         "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 8\n   dt: d\n   data: [ 0.1, 0.01, 0., 0., 0., 0.2, 0., 0. ]\n";
  expect_error(tmp / "rational.yml", "rational");
  std::ofstream(tmp / "garbage.yml") << "this is: [not, closed\n";
  expect_error(tmp / "garbage.yml", "garbage.yml");
}

}  // namespace
}  // namespace slshadow
