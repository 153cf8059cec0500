// Simulated validation (the simulator as the fixture factory): sim/ renders a printed checkerboard
// in known poses for a known stereo rig with sensor noise on; the images go through the same
// detection and calibration as real ones, and the result is compared with the truth.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "calib/calibration.h"
#include "calib/synthetic.h"
#include "calib/target.h"
#include "sim/shapes.h"
#include "sim/simulate.h"

namespace slshadow {
namespace {

TEST(CalibrateSimulated, StereoRigFromRenderedBoards) {
  // A 640x512 stereo pair (fx ~700) and a projector lighting the board; 11x8 inner corners, 30 mm.
  SyntheticRig truth = SyntheticRig::Stereo();
  truth.devices[0].model = CameraModel(640, 512, 700, 702, 322, 253, -0.12, 0.08, 0.0004, -0.0002, 0.0);
  truth.devices[1].model = CameraModel(640, 512, 695, 696, 318, 258, -0.10, 0.06, -0.0002, 0.0003, 0.0);
  const int num_poses = 12;
  const SyntheticData poses = MakeSyntheticData(truth, num_poses, 0.0, 17);
  Rig rig;
  rig.name = "sim";
  rig.working_distance_mm = 650;
  rig.cameras = truth.devices;
  RigDevice projector;
  projector.name = "projector";
  projector.model = CameraModel(800, 600, 600, 600, 400, 300);
  projector.cam_from_rig = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(-75, 0, 0));
  rig.projector = projector;
  const cv::Mat white(600, 800, CV_8UC1, cv::Scalar(255));

  TargetSpec spec;
  spec.type = TargetType::kChessboard;
  spec.cols = truth.board_cols;
  spec.rows = truth.board_rows;
  spec.square_size_mm = truth.square_size_mm;
  spec.detector = ChessboardDetector::kSectorBased;
  const auto board = BoardPoints(spec);

  CalibrationInput input;
  input.num_poses = num_poses;
  for (const auto& d : truth.devices) input.devices.push_back({d.name, d.model.width, d.model.height, false, std::nullopt, false});
  for (int p = 0; p < num_poses; ++p) {
    BoardScene scene = MakeCheckerboardScene(spec.cols, spec.rows, spec.square_size_mm, poses.rig_from_board[static_cast<size_t>(p)]);
    scene.scene.layers.supersampling = 2;
    scene.scene.layers.ambient = 0.3;
    scene.scene.layers.noise_enabled = true;
    scene.scene.layers.seed = static_cast<uint64_t>(100 + p);
    scene.scene.radiometry.exposure = 0.6;
    const auto images = RenderScan(scene.scene, rig, {white});
    for (int d = 0; d < 2; ++d) {
      const TargetDetection det = DetectTarget(spec, images[static_cast<size_t>(d)][0]);
      ASSERT_TRUE(det.found) << "pose " << p << " camera " << d << ": " << det.reason;
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
  const CalibrationResult r = Calibrate(input, {});
  std::printf("%s\n", r.summary.BriefReport().c_str());
  for (int d = 0; d < 2; ++d) {
    const auto& est = r.devices[static_cast<size_t>(d)].model;
    const auto& tru = truth.devices[static_cast<size_t>(d)].model;
    std::printf("camera %d: fx %+.4f %% fy %+.4f %% cx %+.3f px cy %+.3f px (sigma fx %.4f %%, cx %.3f px)\n", d,
                100 * (est.fx() / tru.fx() - 1), 100 * (est.fy() / tru.fy() - 1), est.cx() - tru.cx(), est.cy() - tru.cy(),
                100 * std::sqrt(r.intrinsics_covariance[static_cast<size_t>(d)](0, 0)) / tru.fx(),
                std::sqrt(r.intrinsics_covariance[static_cast<size_t>(d)](2, 2)));
    // Within 4 predicted sigma of the truth, and the prediction itself small.
    for (int i = 0; i < 4; ++i) {
      const double sigma = std::sqrt(r.intrinsics_covariance[static_cast<size_t>(d)](i, i));
      EXPECT_LT(std::abs(est.params[static_cast<size_t>(i)] - tru.params[static_cast<size_t>(i)]), 4 * sigma + 1e-9)
          << "camera " << d << " parameter " << i;
    }
    EXPECT_NEAR(est.fx() / tru.fx(), 1.0, 0.002);
    EXPECT_NEAR(est.cx(), tru.cx(), 1.0);
  }
  const double baseline_true = truth.devices[1].cam_from_rig.translation.norm();
  const double baseline = r.devices[1].cam_from_rig.translation.norm();
  std::printf("baseline %+.4f %%, rotation %.5f rad\n", 100 * (baseline / baseline_true - 1),
              r.devices[1].cam_from_rig.rotation.angularDistance(truth.devices[1].cam_from_rig.rotation));
  EXPECT_NEAR(baseline / baseline_true, 1.0, 0.002);
  EXPECT_LT(r.summary.rms_px, 0.3);
  EXPECT_EQ(r.summary.num_outlier_views, 0);
}

}  // namespace
}  // namespace slshadow
