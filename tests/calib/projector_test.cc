#include "calib/projector.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>

#include "calib/calibration.h"
#include "calib/calibration_io.h"
#include "core/config.h"
#include "core/error.h"
#include "core/image_set.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "patterns/synthetic.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

PatternSpec KaminoSpec() {
  return LoadPatternSpec(testing::SourceDir() / "config/patterns/kamino_opencv_graycode.yaml");
}

// Camera sees the projector through a known homography; the local homography must put each
// "corner" where the homography does, to a small fraction of a projector pixel.
TEST(ProjectorCorners, LocalHomographyRecoversKnownMapping) {
  const PatternSpec spec = KaminoSpec();
  const cv::Matx33d proj_from_cam(0.75, 0.04, 40, -0.03, 0.72, 60, 1e-5, 2e-5, 1);
  cv::Mat mx, my;
  HomographyMaps(proj_from_cam, 1280, 1024, &mx, &my);
  CameraSimOptions sim;
  sim.blur_sigma_px = 0.8;
  sim.noise_sigma = 2.0;
  const auto images = SimulateCameraImages(GeneratePatterns(spec), mx, my, sim);
  const ProjectorMap map = DecodePatterns(spec, images);
  TargetDetection det;
  det.found = true;
  det.width = 1280;
  det.height = 1024;
  for (int i = 0; i < 20; ++i) {
    det.pixels_px.emplace_back(100 + 53.3 * i, 120 + 41.7 * i);
    det.point_ids.push_back(i);
  }
  const ProjectorCorners pc = ProjectorCornersByLocalHomography(map, det);
  ASSERT_EQ(pc.corners.size(), 20u) << (pc.skipped.empty() ? "" : pc.skipped[0]);
  double worst = 0;
  for (const auto& c : pc.corners) {
    const cv::Vec3d t = proj_from_cam * cv::Vec3d(c.camera_px.x(), c.camera_px.y(), 1);
    worst = std::max(worst, (c.projector_px - Eigen::Vector2d(t[0] / t[2], t[1] / t[2])).norm());
  }
  EXPECT_LT(worst, 0.05);
  // A corner in a shadow (no decoded pixels) is skipped with a reason.
  ProjectorMap shadowed = map;
  shadowed.status = map.status.clone();
  shadowed.status(cv::Rect(0, 0, 150, 150)).setTo(static_cast<int>(PixelStatus::kShadow));
  const ProjectorCorners ps = ProjectorCornersByLocalHomography(shadowed, det);
  ASSERT_EQ(ps.skipped.size(), 1u);
  EXPECT_NE(ps.skipped[0].find("corner 0"), std::string::npos) << ps.skipped[0];
  // Mismatched sizes and bad options throw.
  TargetDetection small = det;
  small.width = 640;
  EXPECT_THROW(ProjectorCornersByLocalHomography(map, small), Error);
  LocalHomographyOptions bad;
  bad.half_window_px = 0;
  EXPECT_THROW(ProjectorCornersByLocalHomography(map, det, bad), Error);
}

struct KaminoRun {
  CalibrationInput input;
  CalibrationResult result;
  int skipped = 0;
};

KaminoRun CalibrateKamino(const DecodeOptions& decode, const LocalHomographyOptions& lh) {
  const PatternSpec spec = KaminoSpec();
  const TargetSpec target = LoadTargetSpec(testing::SourceDir() / "config/targets/kamino-procam-graycode.yaml");
  KaminoRun run;
  run.input.num_poses = 5;
  run.input.devices.resize(2);
  run.input.devices[0].name = "camera";
  run.input.devices[0].width = 1280;
  run.input.devices[0].height = 1024;
  run.input.devices[1].name = "projector";
  run.input.devices[1].width = 1024;
  run.input.devices[1].height = 768;
  run.input.devices[1].is_projector = true;
  for (int p = 0; p < 5; ++p) {
    const auto dir = testing::SharedDataDir() / "kamino-procam-graycode" / ("capture_" + std::to_string(p));
    std::vector<cv::Mat> images;
    for (int i = 0; i < spec.NumImages(); ++i) {
      char name[32];
      std::snprintf(name, sizeof(name), "graycode_%02d.png", i);
      images.push_back(ReadGrayImage(dir / name));
    }
    const ProcamPose pose = MakeProcamPose(spec, images, target, p, 0, 1, "capture_" + std::to_string(p), decode, lh);
    EXPECT_TRUE(pose.detection.found) << pose.detection.reason;
    EXPECT_EQ(pose.projector.corners.size(), 63u);
    run.skipped += static_cast<int>(pose.projector.skipped.size());
    run.input.views.push_back(pose.camera_view);
    run.input.views.push_back(pose.projector_view);
  }
  run.result = Calibrate(run.input, {});
  return run;
}

TEST(ProjectorCalibrationRealData, KaminoProcamGraycode) {
  DecodeOptions decode;  // upstream HEAD's thresholds: black 40 (shadow), white 5 (bit contrast)
  decode.shadow_threshold = 40;
  decode.contrast_threshold = 5;
  const KaminoRun run = CalibrateKamino(decode, {});
  const auto& s = run.result.summary;
  if (std::getenv("KAMINO_DUMP")) {
    std::ofstream(std::getenv("KAMINO_DUMP")) << CalibrationEvidenceToJson(run.input, {}, run.result).dump();
  }
  std::printf("%s\n", s.FullReport().c_str());
  const CameraModel& cam = run.result.devices[0].model;
  const CameraModel& proj = run.result.devices[1].model;
  std::printf("camera fx %.3f fy %.3f cx %.3f cy %.3f\nprojector fx %.3f fy %.3f cx %.3f cy %.3f, skipped %d\n", cam.fx(),
              cam.fy(), cam.cx(), cam.cy(), proj.fx(), proj.fy(), proj.cx(), proj.cy(), run.skipped);
  const Rigid3d& proj_from_cam = run.result.devices[1].cam_from_rig;
  std::printf("proj_from_cam t = %.2f %.2f %.2f\n", proj_from_cam.translation.x(), proj_from_cam.translation.y(),
              proj_from_cam.translation.z());
  EXPECT_TRUE(s.converged);
  ASSERT_EQ(s.devices.size(), 2u);
  EXPECT_LE(s.devices[1].rms_px, 0.43);
  EXPECT_GT(proj.cx(), 0);
  EXPECT_LT(proj.cx(), 1024);
  // The data put the projector's principal point just below its image (cy ~ 860 +- 8 px, 1 sigma
  // from the covariance; stable across decode thresholds, window sizes and corner detectors), as
  // for a projector throwing upwards with a lens offset: not inside 0..767 as the issue hoped (see
  // docs/benchmarks.md). Check it is at least at a physical place: within 1.5 image heights.
  EXPECT_GT(proj.cy(), 0);
  EXPECT_LT(proj.cy(), 1.5 * 768);
  ASSERT_EQ(run.result.intrinsics_covariance.size(), 2u);
  const double sigma_cy = std::sqrt(run.result.intrinsics_covariance[1](CameraModel::kCy, CameraModel::kCy));
  std::printf("projector cy sigma %.2f px\n", sigma_cy);
  EXPECT_GT(sigma_cy, 0.5);
  EXPECT_LT(sigma_cy, 30);
  // Joint refinement moves the camera's focal length by ~0.3 % from the camera-only value (5 poses).
  EXPECT_NEAR(cam.fx() / 3452.39, 1.0, 0.005);
  // The first upstream result (0.43 px) is the plausible one: same order of focal length.
  EXPECT_NEAR(proj.fx() / 1947.16, 1.0, 0.1);
}

}  // namespace
}  // namespace slshadow
