// Simulated validation (the simulator as the fixture factory): sim/ renders a printed checkerboard
// in known poses for a known stereo rig with sensor noise on; the images go through the same
// detection and calibration as real ones, and the result is compared with the truth.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "calib/calibration.h"
#include "calib/synthetic.h"
#include "calib/target.h"
#include "core/rig.h"
#include "sim/shapes.h"
#include "sim/simulate.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

// Renders `num_poses` board poses for `truth` (noise on), detects the corners, calibrates.
CalibrationResult RenderAndCalibrate(const SyntheticRig& truth, int num_poses, uint32_t seed, int supersampling) {
  const SyntheticData poses = MakeSyntheticData(truth, num_poses, 0.0, seed);
  Rig rig;
  rig.name = "sim";
  rig.working_distance_mm = truth.distance_mm;
  rig.cameras = truth.devices;
  RigDevice projector;
  projector.name = "projector";
  projector.model = CameraModel(64, 48, 40, 40, 32, 24);  // lights the board uniformly: one white frame
  projector.cam_from_rig = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(-75, 0, 0));
  rig.projector = projector;
  const cv::Mat white(48, 64, CV_8UC1, cv::Scalar(255));

  TargetSpec spec;
  spec.type = TargetType::kChessboard;
  spec.cols = truth.board_cols;
  spec.rows = truth.board_rows;
  spec.square_size_mm = truth.square_size_mm;
  spec.detector = ChessboardDetector::kSectorBased;
  const auto board = BoardPoints(spec);

  CalibrationInput input;
  input.num_poses = num_poses;
  for (const auto& d : truth.devices) input.devices.push_back({d.name, d.model.width, d.model.height, false, std::nullopt, false, {}});
  for (int p = 0; p < num_poses; ++p) {
    BoardScene scene = MakeCheckerboardScene(spec.cols, spec.rows, spec.square_size_mm, poses.rig_from_board[static_cast<size_t>(p)]);
    scene.scene.layers.supersampling = supersampling;
    scene.scene.layers.ambient = 0.3;
    scene.scene.layers.noise_enabled = true;
    scene.scene.layers.seed = static_cast<uint64_t>(100 + p);
    scene.scene.radiometry.exposure = 0.6;
    const auto images = RenderScan(scene.scene, rig, {white});
    for (int d = 0; d < static_cast<int>(truth.devices.size()); ++d) {
      const TargetDetection det = DetectTarget(spec, images[static_cast<size_t>(d)][0]);
      EXPECT_TRUE(det.found) << "pose " << p << " camera " << d << ": " << det.reason;
      if (!det.found) continue;
      BoardView v;
      v.device = d;
      v.pose = p;
      v.label = "sim/" + std::to_string(d) + "/" + std::to_string(p);
      for (size_t i = 0; i < det.pixels_px.size(); ++i) {
        v.points_in_board_mm.push_back(board[static_cast<size_t>(det.point_ids[i])]);
        v.pixels_px.push_back(det.pixels_px[i]);
      }
      input.views.push_back(std::move(v));
    }
  }
  return Calibrate(input, {});
}

// The targets: focal length within 0.05 %, principal point within 0.3 px, baseline within
// 0.05 %, on the demo rig's 1920x1200 cameras (fx ~2730, 200 mm baseline, converging), 12 views
// with tilts up to 40 degrees, sensor noise on, one white frame per view, no supersampling.
TEST(CalibrateSimulated, DemoStereoRigFromRenderedBoards) {
  const Rig demo = LoadRig(testing::SourceDir() / "config/demo/rig.yaml");
  SyntheticRig truth;
  truth.devices = demo.cameras;
  truth.board_cols = 11;
  truth.board_rows = 8;
  truth.square_size_mm = 25;
  truth.distance_mm = 620;
  truth.max_tilt_rad = 0.7;
  truth.shift_fraction = 0.12;
  const int num_poses = 12;
  const CalibrationResult r = RenderAndCalibrate(truth, num_poses, 23, 1);
  std::printf("%s\n", r.summary.BriefReport().c_str());
  for (int d = 0; d < 2; ++d) {
    const auto& est = r.devices[static_cast<size_t>(d)].model;
    const auto& tru = truth.devices[static_cast<size_t>(d)].model;
    const auto& cov = r.intrinsics_covariance[static_cast<size_t>(d)];
    std::printf("camera %d: fx %+.4f %% fy %+.4f %% cx %+.3f px cy %+.3f px (sigma fx %.4f %% fy %.4f %% cx %.3f px cy %.3f px)\n", d,
                100 * (est.fx() / tru.fx() - 1), 100 * (est.fy() / tru.fy() - 1), est.cx() - tru.cx(), est.cy() - tru.cy(),
                100 * std::sqrt(cov(0, 0)) / tru.fx(), 100 * std::sqrt(cov(1, 1)) / tru.fy(), std::sqrt(cov(2, 2)),
                std::sqrt(cov(3, 3)));
    for (int i = 0; i < 4; ++i) {
      const double sigma = std::sqrt(cov(i, i));
      EXPECT_LT(std::abs(est.params[static_cast<size_t>(i)] - tru.params[static_cast<size_t>(i)]), 4 * sigma + 1e-9)
          << "camera " << d << " parameter " << i;
    }
    EXPECT_NEAR(est.fx() / tru.fx(), 1.0, 0.0005);
    EXPECT_NEAR(est.fy() / tru.fy(), 1.0, 0.0005);
    // The 0.3 px principal point is NOT reachable here: with a 38 degree field of view the
    // principal point trades off with the board rotations, and 12 views predict sigma ~0.9 px
    // (docs/benchmarks.md). Asserted: within 4 predicted sigma (above) and 3 px.
    EXPECT_NEAR(est.cx(), tru.cx(), 3.0);
    EXPECT_NEAR(est.cy(), tru.cy(), 3.0);
  }
  const Rigid3d t10 = truth.devices[1].cam_from_rig * truth.devices[0].cam_from_rig.Inverse();
  const Rigid3d r10 = r.devices[1].cam_from_rig * r.devices[0].cam_from_rig.Inverse();
  std::printf("baseline %+.4f %%, rotation %.5f deg, RMS %.4f px\n", 100 * (r10.translation.norm() / t10.translation.norm() - 1),
              r10.rotation.angularDistance(t10.rotation) * 180 / M_PI, r.summary.rms_px);
  EXPECT_NEAR(r10.translation.norm() / t10.translation.norm(), 1.0, 0.0005);
  EXPECT_LT(r.summary.rms_px, 0.3);
  EXPECT_EQ(r.summary.num_outlier_views, 0);
}

}  // namespace
}  // namespace slshadow
