// Self-calibration on simulated scans: sim/ traces the demo scene for the demo rig (true
// projector coordinates per camera pixel, as a perfect decoder would give them, plus Gaussian
// decoding noise); the rig is then bumped, and the calibration check must flag it and the
// refinement must bring the truth back.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>

#include "calib/refine.h"
#include "core/error.h"
#include "core/rig.h"
#include "sim/scene.h"
#include "sim/simulate.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

constexpr double kDeg = M_PI / 180;
constexpr double kDecodeNoisePx = 0.1;  // projector px, per axis

class RefineSim : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    truth_ = new Rig(LoadRig(testing::SourceDir() / "config/demo/rig.yaml"));
    Scene scene = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
    scene.layers.supersampling = 1;
    const Simulator sim(scene, *truth_);
    maps_ = new std::vector<ProjectorMap>();
    std::mt19937 rng(7);
    std::normal_distribution<float> g(0.0f, static_cast<float>(kDecodeNoisePx));
    for (int c = 0; c < sim.num_cameras(); ++c) {
      ProjectorMap m = sim.geometry(c).projector;
      for (int y = 0; y < m.height(); ++y) {
        for (int x = 0; x < m.width(); ++x) {
          m.proj_x.at<float>(y, x) += g(rng);
          m.proj_y.at<float>(y, x) += g(rng);
        }
      }
      maps_->push_back(std::move(m));
    }
  }
  static void TearDownTestSuite() {
    delete truth_;
    delete maps_;
  }
  static Rig* truth_;
  static std::vector<ProjectorMap>* maps_;
};
Rig* RefineSim::truth_ = nullptr;
std::vector<ProjectorMap>* RefineSim::maps_ = nullptr;

// A bumped device: 0.2 degree about a skew axis and a 1 mm shift (in its own frame).
Rigid3d Bump(const Rigid3d& cam_from_rig) {
  const Eigen::Quaterniond r(
      Eigen::AngleAxisd(0.2 * kDeg, Eigen::Vector3d(0.3, 1.0, 0.2).normalized()));
  return Rigid3d(r, Eigen::Vector3d(0.6, -0.8, 0.0)) * cam_from_rig;
}

double DirectionError(const Rigid3d& a, const Rigid3d& b) {
  return std::acos(
      std::clamp(a.translation.normalized().dot(b.translation.normalized()), -1.0, 1.0));
}

TEST_F(RefineSim, BumpedStereoCameraIsDetectedAndRecovered) {
  const Rig& truth = *truth_;
  const auto corr = StereoCorrespondences((*maps_)[0], (*maps_)[1], 6000);
  ASSERT_GT(corr.size(), 3000u);
  const EpipolarStats ok = StereoEpipolarResiduals(truth, 0, 1, corr);
  Rig bumped = truth;
  bumped.cameras[1].cam_from_rig = Bump(truth.cameras[1].cam_from_rig);
  const EpipolarStats bad = StereoEpipolarResiduals(bumped, 0, 1, corr);
  const RefineResult r = RefineStereoPose(bumped, 0, 1, corr);
  const Rigid3d t10 = truth.cameras[1].cam_from_rig * truth.cameras[0].cam_from_rig.Inverse();
  const Rigid3d r10 = r.rig.cameras[1].cam_from_rig * r.rig.cameras[0].cam_from_rig.Inverse();
  const Rigid3d b10 = bumped.cameras[1].cam_from_rig * bumped.cameras[0].cam_from_rig.Inverse();
  std::printf(
      "stereo: %zu correspondences; truth median %.4f px p95 %.4f; bumped median %.3f; %s\n"
      "  rotation error %.5f deg, baseline direction error %.5f deg\n",
      corr.size(), ok.median_px, ok.p95_px, bad.median_px, r.message.c_str(),
      r10.rotation.angularDistance(t10.rotation) / kDeg, DirectionError(r10, t10) / kDeg);
  // 0.1 px decoding noise, averaged by the 5x5 affine match: the truth fits to ~0.05 px.
  EXPECT_LT(ok.median_px, 0.1);
  EXPECT_GT(bad.median_px, 10 * ok.median_px);
  EXPECT_NE(r.message.find("WARNING"), std::string::npos) << r.message;
  EXPECT_EQ(r.message.find("far larger than a bump"), std::string::npos) << r.message;
  EXPECT_LT(r.after.median_px, 1.1 * ok.median_px);
  EXPECT_LT(r10.rotation.angularDistance(t10.rotation), 0.01 * kDeg);
  EXPECT_LT(DirectionError(r10, t10), 0.02 * kDeg);
  EXPECT_NEAR(r10.translation.norm(), b10.translation.norm(),
              1e-9);  // scale kept from the rig file
  EXPECT_EQ(r.rig.cameras[0].cam_from_rig.translation, truth.cameras[0].cam_from_rig.translation);
}

TEST_F(RefineSim, BumpedProjectorAndFocalLengthAreRecovered) {
  const Rig& truth = *truth_;
  const auto corr = SampleCorrespondences((*maps_)[0], 6000);
  const EpipolarStats ok = EpipolarResiduals(truth, 0, corr);
  Rig bumped = truth;
  bumped.projector->cam_from_rig = Bump(truth.projector->cam_from_rig);
  bumped.projector->model.params[CameraModel::kFx] *= 1.003;
  bumped.projector->model.params[CameraModel::kFy] *= 1.003;
  RefineOptions with_focal;
  with_focal.refine_focal = true;
  const RefineResult r = RefineProjectorPose(bumped, 0, corr, with_focal);
  const RefineResult pose_only = RefineProjectorPose(bumped, 0, corr);
  const Rigid3d tp = truth.projector->cam_from_rig * truth.cameras[0].cam_from_rig.Inverse();
  const Rigid3d rp = r.rig.projector->cam_from_rig * truth.cameras[0].cam_from_rig.Inverse();
  const double f_err = r.rig.projector->model.fx() / truth.projector->model.fx() - 1;
  std::printf(
      "procam: truth median %.4f px; %s\n  focal error %+.4f %%, rotation error %.5f deg, "
      "direction error %.5f "
      "deg; pose only: after median %.4f px\n",
      ok.median_px, r.message.c_str(), 100 * f_err, rp.rotation.angularDistance(tp.rotation) / kDeg,
      DirectionError(rp, tp) / kDeg, pose_only.after.median_px);
  EXPECT_NE(r.message.find("WARNING"), std::string::npos);
  EXPECT_LT(r.after.median_px, 1.1 * ok.median_px + 0.01);
  EXPECT_LT(std::abs(f_err), 0.0005);
  EXPECT_NEAR(r.rig.projector->model.fy() / r.rig.projector->model.fx(), 1.0, 1e-12);
  EXPECT_LT(rp.rotation.angularDistance(tp.rotation), 0.02 * kDeg);
  EXPECT_LT(DirectionError(rp, tp), 0.05 * kDeg);
}

// Stereo self-calibration with the optional focal length: the right camera bumped (0.2 degree,
// 1 mm) and its focal length 0.5 % too long. The demo scene (a part on a plate, ~100 mm of depth
// at 500 mm) makes the focal length observable: a focal-length scale on one camera moves its
// pixels radially by an amount independent of depth, while the pose change that could mimic it
// (the baseline turning towards the optical axis) moves them by baseline/depth; with depth varying
// across the scene the two differ. On a fronto-parallel plane they would trade off.
TEST_F(RefineSim, BumpedStereoCameraAndFocalLengthAreRecovered) {
  const Rig& truth = *truth_;
  const auto corr = StereoCorrespondences((*maps_)[0], (*maps_)[1], 6000);
  const EpipolarStats ok = StereoEpipolarResiduals(truth, 0, 1, corr);
  Rig bumped = truth;
  bumped.cameras[1].cam_from_rig = Bump(truth.cameras[1].cam_from_rig);
  bumped.cameras[1].model.params[CameraModel::kFx] *= 1.005;
  bumped.cameras[1].model.params[CameraModel::kFy] *= 1.005;
  RefineOptions with_focal;
  with_focal.refine_focal = true;
  const RefineResult r = RefineStereoPose(bumped, 0, 1, corr, with_focal);
  const RefineResult pose_only = RefineStereoPose(bumped, 0, 1, corr);
  const Rigid3d t10 = truth.cameras[1].cam_from_rig * truth.cameras[0].cam_from_rig.Inverse();
  const Rigid3d r10 = r.rig.cameras[1].cam_from_rig * r.rig.cameras[0].cam_from_rig.Inverse();
  const Rigid3d b10 = bumped.cameras[1].cam_from_rig * bumped.cameras[0].cam_from_rig.Inverse();
  const double f_err = r.rig.cameras[1].model.fx() / truth.cameras[1].model.fx() - 1;
  std::printf(
      "stereo + focal: truth median %.4f px; %s\n  focal error %+.4f %%, rotation error %.5f deg, "
      "direction error "
      "%.5f deg; pose only: after median %.4f px\n",
      ok.median_px, r.message.c_str(), 100 * f_err,
      r10.rotation.angularDistance(t10.rotation) / kDeg, DirectionError(r10, t10) / kDeg,
      pose_only.after.median_px);
  EXPECT_NE(r.message.find("WARNING"), std::string::npos);
  EXPECT_LT(r.after.median_px, 1.1 * ok.median_px + 0.01);
  // Without the focal length the pose absorbs most of the residual of a 0.5 % focal error (the
  // two are weakly separable in epipolar residuals), at the cost of a wrong pose.
  const Rigid3d p10 =
      pose_only.rig.cameras[1].cam_from_rig * pose_only.rig.cameras[0].cam_from_rig.Inverse();
  std::printf("  pose only: rotation error %.5f deg, direction error %.5f deg\n",
              p10.rotation.angularDistance(t10.rotation) / kDeg, DirectionError(p10, t10) / kDeg);
  EXPECT_GT(DirectionError(p10, t10), 10 * DirectionError(r10, t10));
  EXPECT_LT(std::abs(f_err), 0.0005);  // 0.5 % error recovered to 0.05 %
  EXPECT_NEAR(r.rig.cameras[1].model.fy() / r.rig.cameras[1].model.fx(),
              truth.cameras[1].model.fy() / truth.cameras[1].model.fx(), 1e-12);
  EXPECT_LT(r10.rotation.angularDistance(t10.rotation), 0.02 * kDeg);
  EXPECT_LT(DirectionError(r10, t10), 0.05 * kDeg);
  EXPECT_NEAR(r10.translation.norm(), b10.translation.norm(),
              1e-9);  // scale kept from the rig file
  // The first camera and the other intrinsics are untouched.
  EXPECT_EQ(r.rig.cameras[0].model.params, truth.cameras[0].model.params);
  EXPECT_EQ(r.rig.cameras[1].model.cx(), bumped.cameras[1].model.cx());
  EXPECT_EQ(r.rig.cameras[1].model.params[CameraModel::kK1],
            bumped.cameras[1].model.params[CameraModel::kK1]);
}

TEST_F(RefineSim, SwappedCamerasAndWrongRigFileAreFlagged) {
  const Rig& truth = *truth_;
  const auto corr = StereoCorrespondences((*maps_)[0], (*maps_)[1], 3000);
  const EpipolarStats ok = StereoEpipolarResiduals(truth, 0, 1, corr);
  // The rig file names the cameras the other way round: its "left" entry describes the right one.
  Rig swapped = truth;
  std::swap(swapped.cameras[0].model, swapped.cameras[1].model);
  std::swap(swapped.cameras[0].cam_from_rig, swapped.cameras[1].cam_from_rig);
  const EpipolarStats s = StereoEpipolarResiduals(swapped, 0, 1, corr);
  const RefineResult rs = RefineStereoPose(swapped, 0, 1, corr);
  // A wrong file: another rig of similar build (cameras 250 mm apart, toed in 15 degrees).
  Rig wrong = truth;
  const Eigen::Quaterniond toe(Eigen::AngleAxisd(15 * kDeg, Eigen::Vector3d::UnitY()));
  wrong.cameras[1].cam_from_rig = Rigid3d(toe, toe * -Eigen::Vector3d(250, 0, 0));
  const EpipolarStats w = StereoEpipolarResiduals(wrong, 0, 1, corr);
  const RefineResult rw = RefineStereoPose(wrong, 0, 1, corr);
  // Swapped camera and projector check: the projector map of camera 1 against camera 0's entry.
  const EpipolarStats pw = EpipolarResiduals(truth, 0, SampleCorrespondences((*maps_)[1], 3000));
  std::printf(
      "truth median %.4f px; swapped %.2f px (p95 %.2f); wrong file %.2f px; camera 1's scan "
      "checked as camera "
      "0: %.2f px\n  %s\n  %s\n",
      ok.median_px, s.median_px, s.p95_px, w.median_px, pw.median_px, rs.message.c_str(),
      rw.message.c_str());
  EXPECT_GT(s.median_px, 50 * ok.median_px);
  EXPECT_GT(w.median_px, 20 * ok.median_px);
  EXPECT_GT(pw.median_px, 5.0);
  EXPECT_NE(rs.message.find("WARNING"), std::string::npos);
  EXPECT_NE(rw.message.find("WARNING"), std::string::npos);
  // Refinement can make even a swapped rig fit (epipolar geometry alone), so it says the
  // correction is no bump.
  EXPECT_NE(rs.message.find("far larger than a bump"), std::string::npos) << rs.message;
  EXPECT_NE(rw.message.find("far larger than a bump"), std::string::npos) << rw.message;
  EXPECT_THROW(RefineStereoPose(truth, 0, 0, corr), Error);
  EXPECT_THROW(RefineStereoPose(truth, 0, 2, corr), Error);
  EXPECT_THROW(StereoEpipolarResiduals(truth, -1, 1, corr), Error);
}

}  // namespace
}  // namespace slshadow
