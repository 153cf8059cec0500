#include "calib/calibration_io.h"

#include <gtest/gtest.h>

#include <fstream>
#include <functional>
#include <numbers>

#include <opencv2/core.hpp>

#include "calib/synthetic.h"
#include "core/error.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

void ExpectSameModel(const CameraModel& a, const CameraModel& b, double tol) {
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  for (int i = 0; i < CameraModel::kNumParams; ++i)
    EXPECT_NEAR(a.params[i], b.params[i], tol * (1 + std::abs(a.params[i]))) << i;
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
  rig.calibration =
      CalibrationEvidenceToJson(data.input, options, result, CrossValidate(data.input, options));
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
    EXPECT_LT((again.intrinsics_covariance_view_correlated.at(d) -
               result.intrinsics_covariance_view_correlated.at(d))
                  .norm(),
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
  EXPECT_TRUE(
      CalibrationOptionsFromJson(CalibrationOptionsToJson(options), "x").correlated_carried_noise);
  options.principal_point_inside = true;  // and the principal-point bound
  EXPECT_TRUE(
      CalibrationOptionsFromJson(CalibrationOptionsToJson(options), "x").principal_point_inside);
  EXPECT_FALSE(CalibrationOptionsFromJson(CalibrationOptionsToJson(CalibrationOptions{}), "x")
                   .principal_point_inside);
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
  proj.cam_from_rig =
      Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.2, Eigen::Vector3d(0.1, 1, 0.2).normalized())),
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
  ExpectSameModel(ReadOpenCvCalibration(tmp / "one.yaml").cameras[0].model, one.cameras[0].model,
                  1e-12);
}

TEST(CalibrationIo, ReadsUpstreamFiles) {
  const Rig left = ReadOpenCvCalibration(testing::SharedDataDir() /
                                         "opencv-stereo-chessboard/left_intrinsics.yml");
  ASSERT_EQ(left.cameras.size(), 1u);
  EXPECT_NEAR(left.cameras[0].model.fx(), 535.9157, 1e-4);
  EXPECT_NEAR(left.cameras[0].model.cy(), 235.5708, 1e-4);
  EXPECT_NEAR(left.cameras[0].model.params[CameraModel::kK3], 0.23839, 1e-5);
  EXPECT_EQ(left.cameras[0].model.width, 640);
  const Rig procam = ReadOpenCvCalibration(
      testing::SharedDataDir() / "kamino-procam-graycode/calibration_result_ccf1cd8.xml", 0, 0,
      1024, 768);
  ASSERT_TRUE(procam.projector);
  EXPECT_EQ(procam.cameras[0].model.width, 1280);
  EXPECT_EQ(procam.cameras[0].model.height, 1024);
  EXPECT_NEAR(procam.cameras[0].model.fx(), 3452.39, 0.01);
  EXPECT_NEAR(procam.projector->model.fx(), 1947.16, 0.01);
  EXPECT_NEAR(procam.projector->cam_from_rig.translation.y(), -278.3, 0.05);
  // No projector size: a clear error.
  EXPECT_THROW(ReadOpenCvCalibration(testing::SharedDataDir() /
                                     "kamino-procam-graycode/calibration_result.xml"),
               Error);
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
  // Not "not an OpenCV calibration file": the file is one; the message lists what it has.
  expect_error(tmp / "empty.yml",
               "no known calibration layout among the nodes found: foo (number)");
  std::ofstream(tmp / "rational.yml")
      << "%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   "
         "data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\n"
         "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 8\n   dt: d\n   data: [ "
         "0.1, 0.01, 0., 0., 0., 0.2, 0., 0. ]\n";
  expect_error(tmp / "rational.yml", "rational");
  std::ofstream(tmp / "garbage.yml") << "this is: [not, closed\n";
  expect_error(tmp / "garbage.yml", "garbage.yml");
}

// The two-camera layouts other tools write, each as cv::FileStorage writes it, import to the
// same rig; an unknown layout is named node by node and imports with an explicit node map.
class OpenCvLayouts : public ::testing::Test {
 protected:
  void SetUp() override {
    const SyntheticRig truth = SyntheticRig::Stereo();
    rig_.cameras = truth.devices;
    rig_.cameras[1].model =
        CameraModel(1280, 1024, 2410, 2405, 650, 500, -0.08, 0.12, 0.0005, -0.0007, 0.01);
    const Rigid3d second_from_first =
        rig_.cameras[1].cam_from_rig * rig_.cameras[0].cam_from_rig.Inverse();
    const Eigen::Matrix3d r = second_from_first.rotation.toRotationMatrix();
    r_ = cv::Mat(3, 3, CV_64F);
    t_ = cv::Mat(3, 1, CV_64F);
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) r_.at<double>(a, b) = r(a, b);
      t_.at<double>(a) = second_from_first.translation(a);
    }
    const Eigen::AngleAxisd aa(second_from_first.rotation);
    rvec_ = (cv::Mat_<double>(3, 1) << aa.angle() * aa.axis().x(), aa.angle() * aa.axis().y(),
             aa.angle() * aa.axis().z());
  }
  cv::Mat K(int i) const {
    const CameraModel& m = rig_.cameras[static_cast<size_t>(i)].model;
    return (cv::Mat_<double>(3, 3) << m.fx(), 0, m.cx(), 0, m.fy(), m.cy(), 0, 0, 1);
  }
  cv::Mat D(int i) const {
    const auto& p = rig_.cameras[static_cast<size_t>(i)].model.params;
    return (cv::Mat_<double>(1, 5) << p[4], p[5], p[6], p[7], p[8]);
  }
  cv::Size Size(int i) const {
    const CameraModel& m = rig_.cameras[static_cast<size_t>(i)].model;
    return {m.width, m.height};
  }
  void ExpectSameRig(const Rig& back) const {
    ASSERT_EQ(back.cameras.size(), 2u);
    EXPECT_FALSE(back.projector);
    for (size_t i = 0; i < 2; ++i)
      ExpectSameModel(back.cameras[i].model, rig_.cameras[i].model, 1e-12);
    // The file holds the relative pose; the rig frame is the first camera's.
    const Rigid3d expected = rig_.cameras[1].cam_from_rig * rig_.cameras[0].cam_from_rig.Inverse();
    ExpectSamePose(back.cameras[0].cam_from_rig, Rigid3d(), 1e-12);
    ExpectSamePose(back.cameras[1].cam_from_rig, expected, 1e-9);
  }
  Rig rig_;
  cv::Mat r_, t_, rvec_;
  testing::TempDir tmp_;
};

TEST_F(OpenCvLayouts, EachImportsToTheSameRig) {
  // slshadow's own / stereo_calib.cpp's layout.
  Rig relative = rig_;
  relative.cameras[1].cam_from_rig =
      rig_.cameras[1].cam_from_rig * rig_.cameras[0].cam_from_rig.Inverse();
  relative.cameras[0].cam_from_rig = Rigid3d();
  WriteOpenCvCalibration(relative, tmp_ / "stereo_calib.yml");
  ExpectSameRig(ReadOpenCvCalibration(tmp_ / "stereo_calib.yml"));
  for (const std::string ext : {".yml", ".xml"}) {
    SCOPED_TRACE(ext);
    {  // The stereo structured-light sample's layout (with its spelling "distorsion").
      cv::FileStorage fs((tmp_ / ("sample" + ext)).string(), cv::FileStorage::WRITE);
      fs << "cam1_intrinsics" << K(0) << "cam1_distorsion" << D(0) << "cam2_intrinsics" << K(1)
         << "cam2_distorsion" << D(1) << "R" << r_ << "T" << t_ << "cam1_size" << Size(0)
         << "cam2_size" << Size(1);
    }
    ExpectSameRig(ReadOpenCvCalibration(tmp_ / ("sample" + ext)));
    {  // The binocular layout: M1 D1 M2 D2, Rlr Tlr, the image size in S (one size for both).
      cv::FileStorage fs((tmp_ / ("binocular" + ext)).string(), cv::FileStorage::WRITE);
      fs << "M1" << K(0) << "D1" << D(0) << "M2" << K(1) << "D2" << D(1) << "Rlr" << r_ << "Tlr"
         << t_ << "S" << Size(0);
    }
    const Rig binocular = ReadOpenCvCalibration(tmp_ / ("binocular" + ext));
    ASSERT_EQ(binocular.cameras.size(), 2u);
    EXPECT_EQ(binocular.cameras[1].model.width,
              rig_.cameras[0].model.width);  // S is both cameras' size
    EXPECT_NEAR(binocular.cameras[1].model.fx(), rig_.cameras[1].model.fx(), 1e-9);
    ExpectSamePose(binocular.cameras[1].cam_from_rig,
                   rig_.cameras[1].cam_from_rig * rig_.cameras[0].cam_from_rig.Inverse(), 1e-9);
    {  // A layout of its own: plain number lists, a Rodrigues vector, the size as a 1x2 matrix.
      cv::FileStorage fs((tmp_ / ("own" + ext)).string(), cv::FileStorage::WRITE);
      const cv::Mat m0 = K(0), m1 = K(1);
      std::vector<double> k0(m0.begin<double>(), m0.end<double>()),
          k1(m1.begin<double>(), m1.end<double>());
      fs << "left_K" << k0 << "left_D" << D(0) << "right_K" << k1 << "right_D" << D(1) << "rvec"
         << rvec_ << "tvec" << t_ << "left_size"
         << (cv::Mat_<int>(1, 2) << Size(0).width, Size(0).height) << "right_size" << Size(1);
    }
    try {
      ReadOpenCvCalibration(tmp_ / ("own" + ext));
      ADD_FAILURE() << "an unknown layout imported";
    } catch (const Error& e) {
      // The message names every node found, with its shape, and the way out.
      const std::string m = e.what();
      EXPECT_NE(m.find("left_K ([9 values])"), std::string::npos) << m;
      EXPECT_NE(m.find("left_D (1x5 matrix)"), std::string::npos) << m;
      EXPECT_NE(m.find("rvec (3x1 matrix)"), std::string::npos) << m;
      EXPECT_NE(m.find("--map K1=NODE"), std::string::npos) << m;
    }
    const OpenCvNodeMap map = ParseOpenCvNodeMap(
        "K1=left_K,D1=left_D,K2=right_K,D2=right_D,R=rvec,T=tvec,size1=left_size,size2=right_size");
    ExpectSameRig(ReadOpenCvCalibration(tmp_ / ("own" + ext), 0, 0, 0, 0, map));
    // The map overrides a known layout too, and names a node it does not find.
    OpenCvNodeMap wrong = map;
    wrong.r = "Rlr";
    try {
      ReadOpenCvCalibration(tmp_ / ("own" + ext), 0, 0, 0, 0, wrong);
      ADD_FAILURE() << "a missing mapped node imported";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("Rlr: missing (nodes found: left_K"), std::string::npos)
          << e.what();
    }
  }
}

// A camera + projector rig as other tools write it: the projector under camera-like names (M4 D4),
// its pose from the camera in Rlp Tlp, the camera's size in S. The projector stands 300 mm to the
// right of the camera and is turned so that the two image centres meet 3000 mm ahead.
class ProcamFiles : public ::testing::Test {
 protected:
  void SetUp() override {
    camera_ = CameraModel(1920, 1200, 2400, 2400, 959.5, 599.5, -0.05, 0.02, 0, 0, 0);
    projector_ = CameraModel(1280, 800, 2000, 2000, 639.5, 399.5, 0.01, 0, 0, 0, 0);
    const Eigen::Vector3d centre(300, 0, 0), target(0, 0, 3000);
    const Eigen::Vector3d z = (target - centre).normalized(), y = Eigen::Vector3d::UnitY();
    Eigen::Matrix3d cam_from_proj;
    cam_from_proj << y.cross(z), y, z;
    const Eigen::Matrix3d r = cam_from_proj.transpose();
    proj_from_cam_ = Rigid3d(Eigen::Quaterniond(r), -(r * centre));
    r_ = cv::Mat(3, 3, CV_64F);
    t_ = cv::Mat(3, 1, CV_64F);
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) r_.at<double>(a, b) = r(a, b);
      t_.at<double>(a) = proj_from_cam_.translation(a);
    }
  }
  static cv::Mat K(const CameraModel& m) {
    return (cv::Mat_<double>(3, 3) << m.fx(), 0, m.cx(), 0, m.fy(), m.cy(), 0, 0, 1);
  }
  static cv::Mat D(const CameraModel& m) {
    return (cv::Mat_<double>(1, 5) << m.k1(), m.k2(), m.p1(), m.p2(), m.k3());
  }
  // The layout of the issue: M1 D1 (camera), M4 D4 (projector), Rlp Tlp, S; and a note.
  std::filesystem::path WriteBinocularProcam(const std::string& name) const {
    const std::filesystem::path path = tmp_ / name;
    cv::FileStorage fs(path.string(), cv::FileStorage::WRITE);
    fs << "calibration_time"
       << "Mon Nov 30 10:00:00 2026";
    fs << "M1" << K(camera_) << "D1" << D(camera_) << "M4" << K(projector_) << "D4" << D(projector_)
       << "Rlp" << r_ << "Tlp" << t_ << "S" << cv::Size(camera_.width, camera_.height);
    fs << "rms" << 0.21;
    return path;
  }
  void ExpectProcam(const Rig& rig) const {
    ASSERT_EQ(rig.cameras.size(), 1u);
    ASSERT_TRUE(rig.projector);
    ExpectSameModel(rig.cameras[0].model, camera_, 1e-12);
    ExpectSameModel(rig.projector->model, projector_, 1e-12);
    ExpectSamePose(rig.cameras[0].cam_from_rig, Rigid3d(), 1e-12);
    ExpectSamePose(rig.projector->cam_from_rig, proj_from_cam_, 1e-9);
    // The working distance is where the image centres' rays meet, not the default 500 mm.
    EXPECT_NEAR(rig.working_distance_mm, 3000, 1e-6);
  }
  static std::string ErrorOf(const std::function<void()>& f) {
    try {
      f();
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  }
  CameraModel camera_, projector_;
  Rigid3d proj_from_cam_;
  cv::Mat r_, t_;
  testing::TempDir tmp_;
};

TEST_F(ProcamFiles, BinocularLayoutWithRlpImportsTheProjector) {
  for (const std::string ext : {".yml", ".xml"}) {
    SCOPED_TRACE(ext);
    const std::filesystem::path path = WriteBinocularProcam("procam" + ext);
    // The camera's size comes from S; the projector's, absent from the file, must be given.
    EXPECT_NE(ErrorOf([&] {
                ReadOpenCvCalibration(path);
              }).find("M4: no projector size in the file; give it (--projector-size)"),
              std::string::npos)
        << ErrorOf([&] { ReadOpenCvCalibration(path); });
    ExpectProcam(ReadOpenCvCalibration(path, 0, 0, 1280, 800));
    OpenCvImportOptions options;
    options.projector_width = 1280;
    options.projector_height = 800;
    const OpenCvImport imported = ImportOpenCvCalibration(path, options);
    ExpectProcam(imported.rig);
    // Every node the rig was not read from is listed, with its shape.
    ASSERT_EQ(imported.unused_nodes.size(), 2u);
    EXPECT_EQ(imported.unused_nodes[0], "calibration_time (string)");
    EXPECT_EQ(imported.unused_nodes[1], "rms (number)");
    ASSERT_EQ(imported.warnings.size(), 1u);
    EXPECT_NE(imported.warnings[0].find("2 nodes not imported: calibration_time (string), rms "
                                        "(number)"),
              std::string::npos)
        << imported.warnings[0];
    EXPECT_NE(imported.working_distance_source.find("come closest"), std::string::npos);
    // A projector size the file does not contradict but the option does: no, the file has none;
    // an image size that contradicts S is refused, naming both.
    options.image_width = 1280;
    options.image_height = 1024;
    EXPECT_NE(ErrorOf([&] { ImportOpenCvCalibration(path, options); })
                  .find("camera 'camera' is 1920x1200 px in the file, but --image-size says "
                        "1280x1024"),
              std::string::npos)
        << ErrorOf([&] { ImportOpenCvCalibration(path, options); });
    // A working distance given wins.
    options.image_width = options.image_height = 0;
    options.working_distance_mm = 2500;
    EXPECT_EQ(ImportOpenCvCalibration(path, options).rig.working_distance_mm, 2500);
  }
  // Two matrices that could be the projector's: refused, naming them and the way out.
  {
    cv::FileStorage fs((tmp_ / "two.yml").string(), cv::FileStorage::WRITE);
    fs << "M1" << K(camera_) << "D1" << D(camera_) << "M3" << K(projector_) << "D3" << D(projector_)
       << "M4" << K(projector_) << "D4" << D(projector_) << "Rlp" << r_ << "Tlp" << t_ << "S"
       << cv::Size(camera_.width, camera_.height);
  }
  const std::string two =
      ErrorOf([&] { ReadOpenCvCalibration(tmp_ / "two.yml", 0, 0, 1280, 800); });
  EXPECT_NE(two.find("which matrix is the projector's? (M3, M4); name it with --map KP=NODE"),
            std::string::npos)
      << two;
}

TEST_F(ProcamFiles, NodeMapNamesTheProjector) {
  const std::filesystem::path path = tmp_ / "own.yml";
  {
    cv::FileStorage fs(path.string(), cv::FileStorage::WRITE);
    fs << "cam_K" << K(camera_) << "cam_D" << D(camera_) << "proj_K" << K(projector_) << "proj_D"
       << D(projector_) << "R_cp" << r_ << "T_cp" << t_ << "cam_size"
       << cv::Size(camera_.width, camera_.height) << "proj_size"
       << cv::Size(projector_.width, projector_.height) << "reprojection_error" << 0.3;
  }
  OpenCvImportOptions options;
  options.node_map = ParseOpenCvNodeMap(
      "K1=cam_K,D1=cam_D,KP=proj_K,DP=proj_D,RP=R_cp,TP=T_cp,size1=cam_size,sizeP=proj_size");
  EXPECT_EQ(options.node_map.kp, "proj_K");
  EXPECT_EQ(options.node_map.size_p, "proj_size");
  const OpenCvImport imported = ImportOpenCvCalibration(path, options);
  ExpectProcam(imported.rig);  // the projector, not a second camera; both sizes from the file
  EXPECT_EQ(imported.unused_nodes, std::vector<std::string>{"reprojection_error (number)"});
  // --projector-size against the file's size: refused, naming both.
  options.projector_width = 1920;
  options.projector_height = 1080;
  EXPECT_NE(ErrorOf([&] { ImportOpenCvCalibration(path, options); })
                .find("the projector is 1280x800 px in the file, but --projector-size says "
                      "1920x1080"),
            std::string::npos)
      << ErrorOf([&] { ImportOpenCvCalibration(path, options); });
  // The projector's size from --projector-size when the map names none.
  options.node_map.size_p.clear();
  options.projector_width = 1280;
  options.projector_height = 800;
  ExpectProcam(ImportOpenCvCalibration(path, options).rig);
  // A projector without its pose, or half a projector, is refused.
  OpenCvNodeMap no_pose =
      ParseOpenCvNodeMap("K1=cam_K,D1=cam_D,KP=proj_K,DP=proj_D,size1=cam_size");
  EXPECT_NE(ErrorOf([&] {
              ReadOpenCvCalibration(path, 0, 0, 1280, 800, no_pose);
            }).find("names a projector (KP) but not its pose (RP and TP)"),
            std::string::npos);
  OpenCvNodeMap half = ParseOpenCvNodeMap("K1=cam_K,D1=cam_D,KP=proj_K,RP=R_cp,TP=T_cp");
  EXPECT_NE(ErrorOf([&] {
              ReadOpenCvCalibration(path, 0, 0, 1280, 800, half);
            }).find("needs both KP and DP"),
            std::string::npos);
}

TEST_F(ProcamFiles, SizesFromTheFileAndOptionsThatWouldBeIgnored) {
  // stereo_calib's layout with one camera and its size in S: S is read, no --image-size needed.
  {
    cv::FileStorage fs((tmp_ / "one.yml").string(), cv::FileStorage::WRITE);
    fs << "M1" << K(camera_) << "D1" << D(camera_) << "S"
       << cv::Size(camera_.width, camera_.height);
  }
  const OpenCvImport one = ImportOpenCvCalibration(tmp_ / "one.yml", {});
  ASSERT_EQ(one.rig.cameras.size(), 1u);
  ExpectSameModel(one.rig.cameras[0].model, camera_, 1e-12);
  EXPECT_TRUE(one.unused_nodes.empty());
  EXPECT_TRUE(one.warnings.empty());  // one device: no working distance to derive, none to warn
  // --projector-size with no projector in the import: refused, listing what was not read.
  const std::filesystem::path stray = WriteBinocularProcam("stray.yml");
  OpenCvImportOptions options;
  options.projector_width = 1280;
  options.projector_height = 800;
  EXPECT_NE(ErrorOf([&] { ImportOpenCvCalibration(tmp_ / "one.yml", options); })
                .find("--projector-size 1280x800 given, but no projector was imported (nodes not "
                      "read: none)"),
            std::string::npos)
      << ErrorOf([&] { ImportOpenCvCalibration(tmp_ / "one.yml", options); });
  // A map of the camera alone leaves the projector's nodes unread: they are named.
  options.node_map = ParseOpenCvNodeMap("K1=M1,D1=D1,size1=S");
  const std::string e = ErrorOf([&] { ImportOpenCvCalibration(stray, options); });
  EXPECT_NE(e.find("no projector was imported (nodes not read: calibration_time (string), M4 (3x3 "
                   "matrix), D4 (1x5 matrix), Rlp (3x3 matrix), Tlp (3x1 matrix), rms (number))"),
            std::string::npos)
      << e;
  options.projector_width = options.projector_height = 0;
  const OpenCvImport camera_only = ImportOpenCvCalibration(stray, options);
  EXPECT_FALSE(camera_only.rig.projector);
  ASSERT_EQ(camera_only.warnings.size(), 1u);
  EXPECT_NE(camera_only.warnings[0].find("6 nodes not imported: calibration_time (string), M4"),
            std::string::npos)
      << camera_only.warnings[0];
}

TEST_F(ProcamFiles, WorkingDistanceOfParallelDevicesIsTheDefaultWithAWarning) {
  // Two cameras looking the same way (parallel central rays): nothing to derive.
  Rig parallel;
  parallel.cameras.push_back({"camera1", camera_, Rigid3d()});
  parallel.cameras.push_back(
      {"camera2", camera_, Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(-120, 0, 0))});
  WriteOpenCvCalibration(parallel, tmp_ / "parallel.yml");
  const OpenCvImport imported = ImportOpenCvCalibration(tmp_ / "parallel.yml", {});
  EXPECT_EQ(imported.rig.working_distance_mm, Rig().working_distance_mm);
  ASSERT_EQ(imported.warnings.size(), 1u);
  EXPECT_NE(imported.warnings[0].find("are parallel or meet behind a device; 500 mm assumed"),
            std::string::npos)
      << imported.warnings[0];
  // Toed in by 2 degrees each, they meet: the working distance is the crossing's depth.
  const double a = 2 * std::numbers::pi / 180;
  Rig toed = parallel;
  const Eigen::Quaterniond in(Eigen::AngleAxisd(-a, Eigen::Vector3d::UnitY()));  // axis to +x
  const Eigen::Quaterniond out(Eigen::AngleAxisd(a, Eigen::Vector3d::UnitY()));  // axis to -x
  toed.cameras[0].cam_from_rig = Rigid3d(in, Eigen::Vector3d::Zero());
  toed.cameras[1].cam_from_rig = Rigid3d(out, -(out * Eigen::Vector3d(120, 0, 0)));
  WriteOpenCvCalibration(toed, tmp_ / "toed.yml");
  const OpenCvImport met = ImportOpenCvCalibration(tmp_ / "toed.yml", {});
  EXPECT_TRUE(met.warnings.empty());
  // The axes cross at x = 60 mm, 60 / sin(2 deg) along the first camera's axis.
  EXPECT_NEAR(met.rig.working_distance_mm, 60 / std::sin(a), 1e-6);
}

TEST(CalibrationIo, NodeMapParsing) {
  const OpenCvNodeMap one = ParseOpenCvNodeMap("K1=cam_K,D1=cam_D,size1=wh");
  EXPECT_EQ(one.k1, "cam_K");
  EXPECT_EQ(one.d1, "cam_D");
  EXPECT_EQ(one.size1, "wh");
  EXPECT_TRUE(one.k2.empty());
  const auto message = [](const std::string& text) {
    try {
      ParseOpenCvNodeMap(text);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(message("K1=a,D1=b,Q=c").find("unknown key 'Q'"), std::string::npos);
  EXPECT_NE(message("K1=a,D1").find("entry 'D1' is not KEY=NODE"), std::string::npos);
  EXPECT_NE(message("K2=a,D2=b").find("must name at least K1 and D1"), std::string::npos);
  EXPECT_NE(message("K1=a,D1=b,KQ=c").find("(keys: K1 D1 K2 D2 R T size1 size2 KP DP RP TP sizeP)"),
            std::string::npos);
}

// Fuzzer findings in the OpenCV import (fuzz/regressions/opencv_calibration/), each now one clear
// error naming the file: content whose top level is not a mapping (cv::Exception escaped), a
// size beyond int (undefined conversion), a matrix header claiming more than its data (OpenCV
// allocated rows x cols first).
TEST(CalibrationIo, FuzzerFindingsInOpenCvFilesAreClearErrors) {
  testing::TempDir tmp;
  const auto error_of = [&](const std::string& name, const std::string& text) {
    std::ofstream(tmp / name) << text;
    try {
      ReadOpenCvCalibration(tmp / name, 640, 480);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  const std::string not_map = error_of("list.yml", "%YAML:1.0\n---\n- 1\n- 2\n");
  EXPECT_EQ(not_map.find((tmp / "list.yml").string() + ": "), 0u) << not_map;
  const std::string camera =
      "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
      "   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\n"
      "distortion_coefficients: [ 0., 0., 0., 0., 0. ]\n";
  EXPECT_EQ(
      error_of("huge.yml", "%YAML:1.0\n---\nimage_width: 640\nimage_height: 1.7e308\n" + camera),
      (tmp / "huge.yml").string() +
          ": image_height: expected a whole number within +-1000000 (got 1.7e+308)");
  EXPECT_EQ(
      error_of("claims.yml",
               "%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 100000\n   cols: 100000\n"
               "   dt: d\n   data: [ 1., 2. ]\ndistortion_coefficients: [ 0., 0., 0., 0., 0. ]\n"),
      (tmp / "claims.yml").string() +
          ": camera_matrix: matrix claims 100000 x 100000 but holds 2 values");
  // OpenCV's YAML reader looped forever on these; yaml-cpp reads them (OpenCV reads them as JSON).
  EXPECT_EQ(error_of("dash.yml", "%YAML:1.0\n  - a\n--x-\n"),
            (tmp / "dash.yml").string() + ": the top level is not a mapping of named nodes");
  const std::string marker = error_of("marker.yml", "%YAML:1.0\n---\n---x: 1\n");
  EXPECT_EQ(marker.find((tmp / "marker.yml").string() +
                        ": no known calibration layout among the nodes found: ---x (number)"),
            0u)
      << marker;
  EXPECT_EQ(error_of("nan.yml", "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n" +
                                    std::string(camera).replace(camera.find("500.,"), 5, ".nan,")),
            (tmp / "nan.yml").string() + ": camera_matrix.data[0]: not a finite number (.nan)");
  EXPECT_EQ(error_of("empty.yml", "%YAML:1.0\n---\nimage_width:\n" + camera),
            (tmp / "empty.yml").string() + ": image_width: empty value");
  // Integers in a double matrix, CR LF line endings and keys in file order still read.
  std::string crlf =
      "%YAML:1.0\r\n---\r\nimage_width: 640\r\nimage_height: 480\r\ncamera_matrix: "
      "!!opencv-matrix\r\n"
      "   rows: 3\r\n   cols: 3\r\n   dt: d\r\n   data: [ 500, 0, 320, 0, 500, 240, 0, 0, 1 ]\r\n"
      "distortion_coefficients: [ 0.1, 0., 0., 0., 0. ]\r\n";
  std::ofstream(tmp / "crlf.yml") << crlf;
  const Rig rig = ReadOpenCvCalibration(tmp / "crlf.yml", 0, 0);
  ASSERT_EQ(rig.cameras.size(), 1u);
  EXPECT_EQ(rig.cameras[0].model.width, 640);
  EXPECT_DOUBLE_EQ(rig.cameras[0].model.fx(), 500.0);
  EXPECT_DOUBLE_EQ(rig.cameras[0].model.k1(), 0.1);
}

}  // namespace
}  // namespace slshadow
