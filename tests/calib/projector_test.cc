#include "calib/projector.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>

#include <opencv2/calib3d.hpp>

#include "calib/calibration.h"
#include "calib/calibration_io.h"
#include "calib/model_selection.h"
#include "calib/uncertainty.h"
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
  // Each corner's Jacobian is the mapping's derivative there, and its fit covariance is that of
  // a least-squares fit over ~1600 pixels: well under the decoded pixels' own scatter.
  for (const auto& c : pc.corners) {
    const cv::Vec3d t = proj_from_cam * cv::Vec3d(c.camera_px.x(), c.camera_px.y(), 1);
    Eigen::Matrix2d j;
    for (int r = 0; r < 2; ++r) {
      for (int k = 0; k < 2; ++k)
        j(r, k) = (proj_from_cam(r, k) - t[r] / t[2] * proj_from_cam(2, k)) / t[2];
    }
    EXPECT_LT((c.jacobian - j).norm(), 0.01 * j.norm());
    const double trace = c.fit_covariance_px2.trace();
    EXPECT_GT(trace, 0);
    EXPECT_LT(std::sqrt(trace / 2), 0.5 * c.fit_rms_px);
    EXPECT_NEAR(c.fit_covariance_px2(0, 1), c.fit_covariance_px2(1, 0), 1e-15);
  }
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

struct KaminoData {
  CalibrationInput input;
  std::vector<ProcamPose> poses;
};

KaminoData LoadKamino(const DecodeOptions& decode, const LocalHomographyOptions& lh) {
  const PatternSpec spec = KaminoSpec();
  const TargetSpec target =
      LoadTargetSpec(testing::SourceDir() / "config/targets/kamino-procam-graycode.yaml");
  KaminoData run;
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
    const auto dir =
        testing::SharedDataDir() / "kamino-procam-graycode" / ("capture_" + std::to_string(p));
    std::vector<cv::Mat> images;
    for (int i = 0; i < spec.NumImages(); ++i) {
      char name[32];
      std::snprintf(name, sizeof(name), "graycode_%02d.png", i);
      images.push_back(ReadGrayImage(dir / name));
    }
    ProcamPose pose =
        MakeProcamPose(spec, images, target, p, 0, 1, "capture_" + std::to_string(p), decode, lh);
    EXPECT_TRUE(pose.detection.found) << pose.detection.reason;
    EXPECT_EQ(pose.projector.corners.size(), 63u);
    run.input.views.push_back(pose.camera_view);
    run.input.views.push_back(pose.projector_view);
    run.poses.push_back(std::move(pose));
  }
  return run;
}

// The projector calibrated alone from its corners by OpenCV as upstream's calibrate.py does
// (cv::calibrateCamera, default flags, image size given as numpy's (rows, cols): 768 x 1024).
double UpstreamProjectorAloneRms(const std::vector<ProcamPose>& poses, cv::Mat* k) {
  std::vector<std::vector<cv::Point3f>> obj;
  std::vector<std::vector<cv::Point2f>> img;
  for (const auto& p : poses) {
    obj.emplace_back();
    img.emplace_back();
    for (size_t i = 0; i < p.projector_view.pixels_px.size(); ++i) {
      const auto& x = p.projector_view.points_in_board_mm[i];
      obj.back().emplace_back(static_cast<float>(x.x()), static_cast<float>(x.y()), 0.f);
      img.back().emplace_back(static_cast<float>(p.projector_view.pixels_px[i].x()),
                              static_cast<float>(p.projector_view.pixels_px[i].y()));
    }
  }
  cv::Mat dist;
  std::vector<cv::Mat> rvecs, tvecs;
  return cv::calibrateCamera(obj, img, cv::Size(768, 1024), *k, dist, rvecs, tvecs);
}

// Moreno-Taubin on the kamino capture, camera and projector in one bundle adjustment with shared
// board poses, the distortion models chosen by leave-one-pose-out prediction of the projector's
// corners (calib/model_selection.h). docs/benchmarks.md ("Calibration") has the study behind it
// (build-*/bench/calib/calib_kamino_study: thresholds, windows, pixel convention, models).
TEST(ProjectorCalibrationRealData, KaminoProcamGraycode) {
  DecodeOptions decode;  // upstream's thresholds: black 40 (shadow), white 5 (bit contrast)
  decode.shadow_threshold = 40;
  decode.contrast_threshold = 5;
  const KaminoData data = LoadKamino(decode, {});
  using M = CameraModel;
  const std::vector<int> full = {}, no_k3 = {M::kK3}, k1k2 = {M::kP1, M::kP2, M::kK3},
                         k1 = {M::kK2, M::kP1, M::kP2, M::kK3},
                         none = {M::kK1, M::kK2, M::kP1, M::kP2, M::kK3};
  const std::vector<ModelCandidate> candidates = {{"camera full / projector full", {full, full}},
                                                  {"camera k1k2p / projector full", {no_k3, full}},
                                                  {"camera k1k2p / projector k1k2", {no_k3, k1k2}},
                                                  {"camera k1k2p / projector k1", {no_k3, k1}},
                                                  {"camera k1k2p / projector none", {no_k3, none}}};
  const auto scores = ScoreModelsByLeaveOnePoseOut(data.input, {}, candidates, 0, 1);
  size_t best = 0;
  for (size_t i = 0; i < scores.size(); ++i) {
    const auto& r = scores[i].result;
    const CameraModel& p = r.devices[1].model;
    const auto& c = r.intrinsics_covariance[1];
    std::printf(
        "%-32s fit %.4f px, predicted %.4f px | fx %.1f +- %.1f (jackknife %.1f) cx %.1f +- %.1f "
        "(%.1f) cy %.1f +- %.1f "
        "(%.1f)\n",
        scores[i].name.c_str(), scores[i].fit_rms_px, scores[i].prediction_rms_px, p.fx(),
        std::sqrt(c(0, 0)), JackknifeSigma(scores[i], M::kFx), p.cx(), std::sqrt(c(2, 2)),
        JackknifeSigma(scores[i], M::kCx), p.cy(), std::sqrt(c(3, 3)),
        JackknifeSigma(scores[i], M::kCy));
    EXPECT_EQ(scores[i].num_predicted, 5 * 63);
    if (scores[i].prediction_rms_px < scores[best].prediction_rms_px) best = i;
  }
  const ModelScore& chosen = scores[best];
  const CalibrationResult& result = chosen.result;
  std::printf("chosen: %s\n%s\n", chosen.name.c_str(), result.summary.FullReport().c_str());
  if (std::getenv("KAMINO_DUMP")) {
    std::ofstream(std::getenv("KAMINO_DUMP"))
        << CalibrationEvidenceToJson(data.input, {}, result).dump();
  }
  EXPECT_TRUE(result.summary.converged);
  // Fewer parameters predict the held-out poses better than the full models (the full models fit
  // noise with 5 poses); a projector without distortion predicts far worse: the data need k1, k2.
  EXPECT_LT(chosen.prediction_rms_px, 0.95 * scores[0].prediction_rms_px);
  EXPECT_GT(scores.back().prediction_rms_px, 1.5 * chosen.prediction_rms_px);
  EXPECT_LE(result.summary.devices[1].rms_px, 0.43);  // the bound (upstream's best, 0.4254)
  EXPECT_LE(chosen.prediction_rms_px, 0.43);          // even on poses the calibration has not seen
  const CameraModel& proj = result.devices[1].model;
  const auto& cov = result.intrinsics_covariance[1];
  // How far the covariance's sigma can be trusted: the jackknife sigma of the five leave-one-out
  // models measures the real spread. Measured here 2.0x (fx), 3.8x (cx), 1.9x (cy) the
  // covariance's (five folds estimate a sigma to only +-35 %). Asserted: the same order (factor
  // 0.5..5), and each fold within 3 jackknife sigma of the full-data estimate.
  for (int i : {M::kFx, M::kCx, M::kCy}) {
    const double sigma = std::sqrt(cov(i, i)), jack = JackknifeSigma(chosen, i);
    EXPECT_GT(jack, sigma / 2) << "parameter " << i;
    EXPECT_LT(jack, sigma * 5) << "parameter " << i;
    for (const auto& m : chosen.fold_models)
      EXPECT_LT(std::abs(m.params[i] - proj.params[i]), 3 * jack) << "parameter " << i;
  }
  // Why: the covariance assumes independent corner errors, and they are not. Neighbouring
  // corners' residuals correlate (measured +0.38 camera, +0.41 projector; independent errors give
  // ~0, calib_uncertainty_test), errors shared across each pose that the covariance cannot see.
  const double camera_corr = NeighbourResidualCorrelation(data.input, result, 0);
  const double projector_corr = NeighbourResidualCorrelation(data.input, result, 1);
  std::printf("neighbour residual correlation: camera %+.3f, projector %+.3f\n", camera_corr,
              projector_corr);
  EXPECT_GT(camera_corr, 0.2);
  EXPECT_GT(projector_corr, 0.2);
  // The covariance under a noise model with corner errors correlated across each pose
  // (intrinsics_covariance_view_correlated; kernel fitted to the residual moments, measured:
  // camera sigma 0.28 px, share 0.70 over 1.7 squares; projector's own part 0.065 px, 0.59 over
  // 2.4 squares) agrees with the jackknife for fx (measured 6.93 vs 6.21 px) and cy (17.7 vs
  // 15.2 px), not yet for cx (5.82 vs 11.0, 1.9x). Asserted with margin (five folds estimate a
  // sigma to about +-35 %): jackknife / sigma in 0.6..1.5 for fx and cy, < 2.5 for cx, and the
  // sigma wider than the standard covariance's.
  ASSERT_EQ(result.intrinsics_covariance_view_correlated.size(), 2u);
  const auto& vcov = result.intrinsics_covariance_view_correlated[1];
  for (const auto& k : result.summary.view_noise) {
    std::printf("view noise: sigma %.4f px, share %.3f, length %.2f squares\n", k.sigma_px, k.share,
                k.length_squares);
  }
  for (int i : {M::kFx, M::kCx, M::kCy}) {
    const double sigma = std::sqrt(cov(i, i)), view = std::sqrt(vcov(i, i)),
                 jack = JackknifeSigma(chosen, i);
    std::printf("parameter %d: sigma %.2f, view-correlated %.2f, jackknife %.2f (x%.2f)\n", i,
                sigma, view, jack, jack / view);
    EXPECT_GT(view, 1.2 * sigma) << "parameter " << i;
    EXPECT_LT(jack / view, i == M::kCx ? 2.5 : 1.5) << "parameter " << i;
    EXPECT_GT(jack / view, 0.6) << "parameter " << i;
  }
  // The joint noise model (CalibrationOptions::correlated_carried_noise: each projector corner
  // whitened with its camera corner through the local homography's Jacobian) does not make the
  // covariance trustworthy here: it removes the camera's share of the projector error, trusts the
  // remainder (0.09 px, even more correlated across a pose: +0.5) as independent, and its sigma
  // shrinks while the folds spread more. Measured: cx 1.7 px against a jackknife of 13.5 (8.1x,
  // independent weighting 3.8x), cy 6.2 against 26.5 (4.3x, independent 1.9x). Asserted: the joint
  // model is the more optimistic for cx and cy, and still predicts held-out poses within 0.43 px.
  CalibrationOptions joint_options;
  joint_options.correlated_carried_noise = true;
  const ModelScore joint =
      ScoreModelsByLeaveOnePoseOut(data.input, joint_options, {candidates[best]}, 0, 1).front();
  ASSERT_TRUE(joint.result.summary.joint_noise);
  const CalibrationSummary& js = joint.result.summary;
  std::printf(
      "joint noise model: %s\n  corner noise camera %.4f projector %.4f px, carry scale %.1f, "
      "chi2/dof %.3f; predicted %.4f px\n",
      js.BriefReport().c_str(), js.noise_sigma_px[0], js.noise_sigma_px[1], js.carry_scale,
      js.variance_factor, joint.prediction_rms_px);
  for (int i : {M::kFx, M::kCx, M::kCy}) {
    const double sigma_i = std::sqrt(cov(i, i)),
                 sigma_j = std::sqrt(joint.result.intrinsics_covariance[1](i, i));
    std::printf(
        "parameter %d: independent %.1f sigma %.2f jackknife %.2f (x%.2f) | joint %.1f sigma %.2f "
        "jackknife %.2f (x%.2f)\n",
        i, proj.params[i], sigma_i, JackknifeSigma(chosen, i), JackknifeSigma(chosen, i) / sigma_i,
        joint.result.devices[1].model.params[i], sigma_j, JackknifeSigma(joint, i),
        JackknifeSigma(joint, i) / sigma_j);
    EXPECT_LT(sigma_j, sigma_i) << "parameter " << i;
    if (i != M::kFx) {
      EXPECT_GT(JackknifeSigma(joint, i) / sigma_j, 1.5 * JackknifeSigma(chosen, i) / sigma_i)
          << "parameter " << i;
    }
  }
  EXPECT_LE(joint.prediction_rms_px, 0.43);
  EXPECT_NEAR(joint.result.summary.variance_factor, 1.0, 0.2);
  EXPECT_GT(proj.cx(), 0);
  EXPECT_LT(proj.cx(), 1024);
  // The principal point's row is NOT inside the 768-row image: the data put it ~90 px below
  // (cy ~855 px, jackknife sigma ~15 px; every model the data support, every fold, decode
  // threshold, window size and pixel convention agree), as for a table projector throwing upwards
  // with ~110 % lens offset. Only a distortion-free projector model (rejected above) or OpenCV's
  // local minimum (below) give cy ~720-740. Checked: not beyond 1.5 image heights.
  EXPECT_GT(proj.cy(), 0);
  EXPECT_LT(proj.cy(), 1.5 * 768);
  // The wish, the principal point inside the 1024x768 image, as a constraint
  // (CalibrationOptions::principal_point_inside, the chosen models): it holds with the projector
  // RMS still under 0.43 px, but the data reject it. Measured (docs/benchmarks.md): cy on the
  // bound 767.5, fit RMS 0.206 -> 0.234 px, held-out 0.285 -> 0.389 px, cost +2.28, i.e. a
  // likelihood ratio of 124 under independent errors and 25 (p 6e-7) once scaled by the
  // view-correlated covariance's variance of cy. Asserted: the bound holds and is reported, the RMS
  // bound, and that the data reject it: significant at 5 % (chi^2 1 dof > 3.84) under the
  // view-correlated covariance, and worse on held-out poses.
  CalibrationOptions inside;
  inside.principal_point_inside = true;
  const ModelScore bounded =
      ScoreModelsByLeaveOnePoseOut(data.input, inside, {candidates[best]}, 0, 1).front();
  const CalibrationResult& br = bounded.result;
  const double var_std = cov(M::kCy, M::kCy), var_vc = vcov(M::kCy, M::kCy);
  const double lr_iid = 2 * (br.summary.final_cost - result.summary.final_cost) /
                        (result.summary.residual_sigma_px * result.summary.residual_sigma_px);
  std::printf(
      "principal point inside: projector fx %.2f cx %.2f cy %.2f, fit RMS %.4f px (free %.4f), "
      "held-out %.4f px (free %.4f), "
      "cost %.4f -> %.4f: LR %.1f independent, %.1f view-correlated; %s\n",
      br.devices[1].model.fx(), br.devices[1].model.cx(), br.devices[1].model.cy(),
      br.summary.devices[1].rms_px, result.summary.devices[1].rms_px, bounded.prediction_rms_px,
      chosen.prediction_rms_px, result.summary.final_cost, br.summary.final_cost, lr_iid,
      lr_iid * var_std / var_vc,
      br.summary.bounds_active.empty() ? "no bound active" : br.summary.bounds_active[0].c_str());
  EXPECT_TRUE(br.summary.converged) << br.summary.termination;
  EXPECT_LE(br.devices[1].model.cy(), 767.5);
  EXPECT_GE(br.devices[1].model.cy(), -0.5);
  EXPECT_GE(br.devices[1].model.cx(), -0.5);
  EXPECT_LE(br.devices[1].model.cx(), 1023.5);
  EXPECT_LE(br.summary.devices[1].rms_px, 0.43);
  ASSERT_EQ(br.summary.bounds_active.size(), 1u);
  EXPECT_EQ(br.summary.bounds_active[0], "projector cy = 767.5 (upper bound)");
  EXPECT_GT(lr_iid * var_std / var_vc, 3.84);
  EXPECT_GT(bounded.prediction_rms_px, chosen.prediction_rms_px);
  EXPECT_NEAR(br.devices[0].model.fx() / 3452.39, 1.0, 0.005);
  // Upstream's projector step (OpenCV calibrateCamera on the projector corners alone, full model,
  // image size transposed) on OUR corners: it stops at a worse minimum than our solver reaches on
  // the same objective (the projector alone, full model).
  cv::Mat k_upstream;
  const double upstream_rms = UpstreamProjectorAloneRms(data.poses, &k_upstream);
  CalibrationInput alone;
  alone.num_poses = 5;
  alone.devices = {data.input.devices[1]};
  for (const auto& p : data.poses) {
    alone.views.push_back(p.projector_view);
    alone.views.back().device = 0;
    alone.views.back().DropCarry();  // its source, the camera, is not in this problem
  }
  const CalibrationResult ours_alone = Calibrate(alone, {});
  std::printf(
      "projector alone, full model: OpenCV (upstream's call) RMS %.4f px fx %.1f cx %.1f cy %.1f; "
      "ours RMS %.4f px fx %.1f "
      "cx %.1f cy %.1f\n",
      upstream_rms, k_upstream.at<double>(0, 0), k_upstream.at<double>(0, 2),
      k_upstream.at<double>(1, 2), ours_alone.summary.rms_px, ours_alone.devices[0].model.fx(),
      ours_alone.devices[0].model.cx(), ours_alone.devices[0].model.cy());
  EXPECT_LT(ours_alone.summary.rms_px, 0.9 * upstream_rms);
  // The camera's focal length moves by < 0.5 % from the camera-only value (3452.39) when the
  // projector joins (5 poses).
  EXPECT_NEAR(result.devices[0].model.fx() / 3452.39, 1.0, 0.005);
  // The first upstream result (0.43 px) has the same order of focal length.
  EXPECT_NEAR(proj.fx() / 1947.16, 1.0, 0.1);
}

}  // namespace
}  // namespace slshadow
