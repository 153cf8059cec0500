// Simulated validation (the simulator as the fixture factory): sim/ renders a printed checkerboard
// in known poses for a known stereo rig with sensor noise on; the images go through the same
// detection and calibration as real ones, and the result is compared with the truth.
//
// The rig is the demo's (1920x1200 cameras, 200 mm baseline, converging 23 degrees, their
// distortion including p1, p2 != 0) with 6 mm lenses (fx 1000, 88 degrees wide) instead of
// 16 mm (fx 2730, 38 degrees). Why: the principal point trades off with the tangential
// distortion p1, p2, and the trade-off is broken only by the image's periphery. With this test's
// view plan and its measured corner noise (0.23 px RMS), the predicted sigma(cx) is 1.08 px at
// fx 2730 (62 poses), 0.56 px at 2000, 0.23 px at 1400 and 0.10 px at 1000 (SIM_FX=...
// SIM_DESIGN=0.163, docs/benchmarks.md "Calibration"); holding p1 = p2 = 0 instead cuts sigma ~3x
// but biases the principal point by 1-2 px, since the true p1, p2 are not zero. So the 0.3
// px is reachable with a wide lens, not with the demo's 16 mm.
//
// The view set is what a careful user captures: for each camera, the board near, middle and far
// at nine places covering the image up to its corners, tilted 30-45 degrees in varied directions
// facing the camera; plus poses both cameras see, which tie the cameras together. Each camera
// image is rendered alone, lit by a light beside the camera, and all renders and detections are
// made once for the test suite.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>

#include "calib/calibration.h"
#include "calib/target.h"
#include "core/rig.h"
#include "sim/shapes.h"
#include "sim/simulate.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

constexpr double kDeg = M_PI / 180;

struct PlannedView {
  std::vector<int> cameras;  // rig camera indices that see the pose
  Rigid3d rig_from_board;
};

TargetSpec Board() {
  TargetSpec spec;
  spec.type = TargetType::kChessboard;
  spec.cols = 17;
  spec.rows = 12;
  spec.square_size_mm = 10;
  // findChessboardCorners + cornerSubPix: 0.02 s per view here against 2.7 s for the
  // sector-based detector (exhaustive, accuracy flags), whose corners are better (0.13 against
  // 0.23 px RMS) but would make this test take minutes.
  spec.detector = ChessboardDetector::kClassic;
  return spec;
}

bool AllInside(const RigDevice& cam, const Rigid3d& rig_from_board,
               const std::vector<Eigen::Vector3d>& board, double margin) {
  for (const auto& x : board) {
    const auto px = cam.model.Project(cam.cam_from_rig * (rig_from_board * x));
    if (!px || px->x() < margin || px->y() < margin || px->x() > cam.model.width - 1 - margin ||
        px->y() > cam.model.height - 1 - margin) {
      return false;
    }
  }
  return true;
}

// A board rotation tilted by `tilt` about a random in-plane axis, with a small in-plane turn.
Eigen::Quaterniond Tilt(double tilt, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  const double phi = M_PI * u(rng);
  return Eigen::Quaterniond(
             Eigen::AngleAxisd(tilt, Eigen::Vector3d(std::cos(phi), std::sin(phi), 0))) *
         Eigen::Quaterniond(Eigen::AngleAxisd(0.3 * u(rng), Eigen::Vector3d::UnitZ()));
}

std::vector<PlannedView> PlanViews(const Rig& rig, const std::vector<Eigen::Vector3d>& board,
                                   const Eigen::Vector3d& centre, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<PlannedView> views;
  for (int c = 0; c < 2; ++c) {
    const RigDevice& cam = rig.cameras[static_cast<size_t>(c)];
    for (double depth_demo : {400.0, 480.0, 560.0}) {
      const double depth =
          1.3 * depth_demo * cam.model.fx() / 2730;  // the board ~1/3 to 1/2 of the image wide
      for (int gy = -1; gy <= 1; ++gy) {
        for (int gx = -1; gx <= 1; ++gx) {
          const double tilt = (30 + 15 * u(rng)) * kDeg;
          // Tilt direction redrawn until the board faces the camera within 55 degrees at this
          // place of the image (a user sees a grazing board as too dark and foreshortened).
          const Eigen::Vector2d aim_px(cam.model.cx() + 0.7 * gx * cam.model.width / 2,
                                       cam.model.cy() + 0.7 * gy * cam.model.height / 2);
          const Eigen::Vector3d aim_ray =
              cam.model.UndistortToNormalized(aim_px)->homogeneous().normalized();
          Eigen::Quaterniond rot = Tilt(tilt, rng);
          for (int attempt = 0;
               attempt < 100 && (rot * Eigen::Vector3d::UnitZ()).dot(aim_ray) < std::cos(55 * kDeg);
               ++attempt) {
            rot = Tilt(tilt, rng);
          }
          // Push the board towards this place of the image as far as it stays inside.
          for (double reach = 0.95; reach > 0; reach -= 0.05) {
            const Eigen::Vector2d px(cam.model.cx() + reach * gx * cam.model.width / 2,
                                     cam.model.cy() + reach * gy * cam.model.height / 2);
            const Eigen::Vector3d ray = cam.model.UndistortToNormalized(px)->homogeneous();
            const Rigid3d cam_from_board(rot, depth * ray - rot * centre);
            const Rigid3d rig_from_board = cam.cam_from_rig.Inverse() * cam_from_board;
            if (AllInside(cam, rig_from_board, board, 4)) {
              views.push_back({{c}, rig_from_board});
              break;
            }
          }
        }
      }
    }
  }
  // Poses both cameras see, around the rig's convergence point.
  const double stereo_depth = std::max(250.0, 500 * rig.cameras[0].model.fx() / 2730);
  const Eigen::Vector3d aim = (rig.cameras[0].CenterInRig() + rig.cameras[1].CenterInRig()) / 2 +
                              Eigen::Vector3d(0, 0, stereo_depth);
  for (int n = 0, attempt = 0; n < 8 && attempt < 100000; ++attempt) {
    // Tilted about the cameras' mean viewing direction, facing each camera within 50 degrees.
    const Eigen::Quaterniond rig_from_cam1 = rig.cameras[1].cam_from_rig.Inverse().rotation;
    const Eigen::Quaterniond rot = Eigen::Quaterniond::Identity().slerp(0.5, rig_from_cam1) *
                                   Tilt((20 + 15 * u(rng)) * kDeg, rng);
    bool facing = true;
    for (const auto& cam : rig.cameras) {
      const Eigen::Vector3d normal = cam.cam_from_rig.rotation * (rot * Eigen::Vector3d::UnitZ());
      const Eigen::Vector3d view = (cam.cam_from_rig * (aim)).normalized();
      facing = facing && normal.dot(view) > std::cos(50 * kDeg);
    }
    if (!facing) continue;
    const Eigen::Vector3d at =
        aim + stereo_depth / 500 *
                  Eigen::Vector3d(80 * (u(rng) - 0.5), 60 * (u(rng) - 0.5), 120 * (u(rng) - 0.5));
    const Rigid3d rig_from_board(rot, at - rot * centre);
    if (AllInside(rig.cameras[0], rig_from_board, board, 4) &&
        AllInside(rig.cameras[1], rig_from_board, board, 4)) {
      views.push_back({{0, 1}, rig_from_board});
      ++n;
    }
  }
  return views;
}

class CalibrateSimulated : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    truth_ = new Rig(LoadRig(testing::SourceDir() / "config/demo/rig.yaml"));
    // 6 mm lenses instead of the demo's 16 mm: fx 1000 px, 88 x 62 degrees (see the file comment).
    // SIM_FX=2730 gives the demo's own cameras (with SIM_DESIGN, their predicted sigma).
    const double fx = std::getenv("SIM_FX") ? std::atof(std::getenv("SIM_FX")) : 1000.0;
    for (auto& c : truth_->cameras) {
      const double f = fx / c.model.fx();
      c.model.params[CameraModel::kFx] *= f;
      c.model.params[CameraModel::kFy] *= f;
    }
    input_ = new CalibrationInput();
    const TargetSpec spec = Board();
    const auto board = BoardPoints(spec);
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    for (const auto& x : board) centre += x;
    centre /= static_cast<double>(board.size());
    // The detectors need the outer squares and a white border in the image: plan with the inner
    // corner grid grown by 1.5 squares on every side.
    std::vector<Eigen::Vector3d> outline;
    for (int y = -3; y <= 2 * spec.rows + 1; ++y) {
      for (int x = -3; x <= 2 * spec.cols + 1; ++x)
        outline.emplace_back(x * spec.square_size_mm / 2, y * spec.square_size_mm / 2, 0);
    }
    const auto plan = PlanViews(*truth_, outline, centre, 23);
    RigDevice projector;  // a wide light next to the (first) camera rendered: one white frame
    projector.name = "projector";
    projector.model = CameraModel(64, 48, 16, 16, 32, 24);
    const cv::Mat white(48, 64, CV_8UC1, cv::Scalar(255));
    input_->num_poses = static_cast<int>(plan.size());
    for (const auto& c : truth_->cameras)
      input_->devices.push_back(CalibrationDevice::Camera(c.name, c.model.width, c.model.height));
    double render_s = 0, detect_s = 0, sq = 0;
    int n = 0;
    // Planning aid (docs/benchmarks.md): SIM_DESIGN=NOISE replaces renders and detections by the
    // true corners plus Gaussian noise of NOISE px per coordinate, to read the predicted sigma of
    // a view set in a second.
    if (std::getenv("SIM_DESIGN")) {
      const double noise = std::atof(std::getenv("SIM_DESIGN"));
      std::mt19937 rng(5);
      std::normal_distribution<double> g(0, noise);
      for (size_t p = 0; p < plan.size(); ++p) {
        for (int c : plan[p].cameras) {
          BoardView v;
          v.device = c;
          v.pose = static_cast<int>(p);
          const RigDevice& cam = truth_->cameras[static_cast<size_t>(c)];
          for (const auto& x : board) {
            v.points_in_board_mm.push_back(x);
            v.pixels_px.push_back(
                *cam.model.Project(cam.cam_from_rig * (plan[p].rig_from_board * x)) +
                Eigen::Vector2d(g(rng), g(rng)));
          }
          input_->views.push_back(std::move(v));
        }
      }
      corner_rms_px_ = noise * std::sqrt(2.0);
      std::printf("%zu poses, %zu views\n", plan.size(), input_->views.size());
      return;
    }
    for (size_t p = 0; p < plan.size(); ++p) {
      for (size_t k = 0; k < plan[p].cameras.size(); ++k) {
        // Each camera rendered alone, lit by a wide light 30 mm above it.
        const int c = plan[p].cameras[k];
        Rig rig;
        rig.name = "sim";
        rig.cameras = {truth_->cameras[static_cast<size_t>(c)]};
        projector.cam_from_rig =
            Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 30, 0)) *
            rig.cameras[0].cam_from_rig;
        rig.projector = projector;
        BoardScene scene = MakeCheckerboardScene(spec.cols, spec.rows, spec.square_size_mm,
                                                 plan[p].rig_from_board);
        scene.scene.layers.supersampling = 1;
        scene.scene.layers.ambient = 0.3;
        scene.scene.layers.noise_enabled = true;
        scene.scene.layers.seed = 100 + 2 * p + k;
        // Exposure set for the board's distance from the light (irradiance falls as 1/d^2).
        const double d = (plan[p].rig_from_board * centre - projector.CenterInRig()).norm();
        scene.scene.radiometry.exposure_fraction = 0.6 * (d / 500) * (d / 500);
        const auto t0 = std::chrono::steady_clock::now();
        const auto images = RenderScan(scene.scene, rig, {white});
        const auto t1 = std::chrono::steady_clock::now();
        const TargetDetection det = DetectTarget(spec, images[0][0]);
        detect_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
        render_s += std::chrono::duration<double>(t1 - t0).count();
        ASSERT_TRUE(det.found) << "pose " << p << " camera " << c << ": " << det.reason;
        BoardView v;
        v.device = c;
        v.pose = static_cast<int>(p);
        v.label = "sim/" + std::to_string(c) + "/" + std::to_string(p);
        const RigDevice& cam = truth_->cameras[static_cast<size_t>(c)];
        // Corner error against the truth; the board's labelling is symmetric under a half turn,
        // so the detector may number the corners from the other end.
        double sq_same = 0, sq_turned = 0;
        for (size_t i = 0; i < det.pixels_px.size(); ++i) {
          const size_t id = static_cast<size_t>(det.point_ids[i]);
          const Eigen::Vector3d& x = board[id];
          v.points_in_board_mm.push_back(x);
          v.pixels_px.push_back(det.pixels_px[i]);
          auto truth_px = [&](size_t j) {
            return *cam.model.Project(cam.cam_from_rig * (plan[p].rig_from_board * board[j]));
          };
          sq_same += (det.pixels_px[i] - truth_px(id)).squaredNorm();
          sq_turned += (det.pixels_px[i] - truth_px(board.size() - 1 - id)).squaredNorm();
          ++n;
        }
        sq += std::min(sq_same, sq_turned);
        input_->views.push_back(std::move(v));
      }
    }
    corner_rms_px_ = std::sqrt(sq / n);
    std::printf(
        "%zu poses, %zu views: render %.1f s, detection %.1f s (wall); corner error vs truth RMS "
        "%.4f px\n",
        plan.size(), input_->views.size(), render_s, detect_s, corner_rms_px_);
  }
  static void TearDownTestSuite() {
    delete truth_;
    delete input_;
  }
  static Rig* truth_;
  static CalibrationInput* input_;
  static double corner_rms_px_;
};
Rig* CalibrateSimulated::truth_ = nullptr;
CalibrationInput* CalibrateSimulated::input_ = nullptr;
double CalibrateSimulated::corner_rms_px_ = 0;

// The targets: focal length within 0.05 %, principal point within 0.3 px, baseline within
// 0.05 %, RMS ~ the corner noise.
TEST_F(CalibrateSimulated, DemoStereoRigFromRenderedBoards) {
  const Rig& truth = *truth_;
  const CalibrationResult r = Calibrate(*input_, {});
  std::printf("%s\n", r.summary.BriefReport().c_str());
  for (int d = 0; d < 2; ++d) {
    const auto& est = r.devices[static_cast<size_t>(d)].model;
    const auto& tru = truth.cameras[static_cast<size_t>(d)].model;
    const auto& cov = r.intrinsics_covariance[static_cast<size_t>(d)];
    std::printf(
        "camera %d: fx %+.4f %% fy %+.4f %% cx %+.3f px cy %+.3f px (sigma fx %.4f %% fy %.4f %% "
        "cx %.3f px cy %.3f px)\n",
        d, 100 * (est.fx() / tru.fx() - 1), 100 * (est.fy() / tru.fy() - 1), est.cx() - tru.cx(),
        est.cy() - tru.cy(), 100 * std::sqrt(cov(0, 0)) / tru.fx(),
        100 * std::sqrt(cov(1, 1)) / tru.fy(), std::sqrt(cov(2, 2)), std::sqrt(cov(3, 3)));
    // The view set is good enough for the targets: predicted sigma well inside them.
    EXPECT_LT(std::sqrt(cov(2, 2)), 0.15) << "camera " << d;
    EXPECT_LT(std::sqrt(cov(3, 3)), 0.15) << "camera " << d;
    // Each of fx fy cx cy within 4 predicted sigma (8 checks: at 3 sigma one seed in ~50 would
    // fail by chance; plan seeds 24-26 gave at most 3.0 sigma, fy of camera 1 with seed 24).
    for (int i = 0; i < 4; ++i) {
      const double sigma = std::sqrt(cov(i, i));
      EXPECT_LT(std::abs(est.params[static_cast<size_t>(i)] - tru.params[static_cast<size_t>(i)]),
                4 * sigma)
          << "camera " << d << " parameter " << i;
    }
    EXPECT_NEAR(est.fx() / tru.fx(), 1.0, 0.0005);
    EXPECT_NEAR(est.fy() / tru.fy(), 1.0, 0.0005);
    EXPECT_NEAR(est.cx(), tru.cx(), 0.3);
    EXPECT_NEAR(est.cy(), tru.cy(), 0.3);
  }
  const Rigid3d t10 = truth.cameras[1].cam_from_rig * truth.cameras[0].cam_from_rig.Inverse();
  const Rigid3d r10 = r.devices[1].cam_from_rig * r.devices[0].cam_from_rig.Inverse();
  std::printf("baseline %+.4f %%, rotation %.5f deg, RMS %.4f px, corner error vs truth %.4f px\n",
              100 * (r10.translation.norm() / t10.translation.norm() - 1),
              r10.rotation.angularDistance(t10.rotation) / kDeg, r.summary.rms_px, corner_rms_px_);
  EXPECT_NEAR(r10.translation.norm() / t10.translation.norm(), 1.0, 0.0005);
  // RMS ~ the corner noise: the fit absorbs a fraction free_parameters / (2 points) of the
  // variance, so RMS ~ corner error * sqrt(1 - p / 2N); within 15 % of it.
  const double expected = corner_rms_px_ * std::sqrt(1.0 - r.summary.num_free_parameters /
                                                               (2.0 * r.summary.num_points));
  EXPECT_NEAR(r.summary.rms_px / expected, 1.0, 0.15);
  EXPECT_EQ(r.summary.num_outlier_views, 0);
}

}  // namespace
}  // namespace slshadow
