// Model-selection study on the kamino procam data (not a test; built with the benchmarks):
// projector intrinsics under different distortion models, decode thresholds, local homography
// windows and pixel conventions, with the predicted uncertainty and leave-one-pose-out
// cross-validation (the held-out pose is posed from the camera alone and its corners predicted in
// the projector). Usage: calib_kamino_study [SOURCE_DIR]
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include <opencv2/calib3d.hpp>

#include "calib/calibration.h"
#include "calib/calibration_io.h"
#include "calib/model_selection.h"
#include "calib/projector.h"
#include "calib/refine.h"
#include "calib/target.h"
#include "core/image_set.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"

using namespace slshadow;

namespace {

struct Variant {
  std::string name;
  std::vector<int> proj_held;
  std::vector<int> cam_held;
  bool joint = true;
};

std::vector<std::vector<cv::Mat>> g_images;

std::vector<ProcamPose> Poses(const PatternSpec& spec, const TargetSpec& target,
                              const DecodeOptions& d, const LocalHomographyOptions& lh) {
  std::vector<ProcamPose> out;
  for (int p = 0; p < 5; ++p)
    out.push_back(
        MakeProcamPose(spec, g_images[p], target, p, 0, 1, "capture_" + std::to_string(p), d, lh));
  return out;
}

CalibrationInput Input(const std::vector<ProcamPose>& poses, const Variant& v, int leave_out,
                       double shift) {
  CalibrationInput in;
  in.num_poses = 5;
  in.devices.resize(2);
  in.devices[0] = {"camera", 1280, 1024, false, std::nullopt, false, v.cam_held};
  in.devices[1] = {"projector", 1024, 768, true, std::nullopt, false, v.proj_held};
  for (const auto& p : poses) {
    if (p.camera_view.pose == leave_out) continue;
    in.views.push_back(p.camera_view);
    BoardView pv = p.projector_view;
    for (auto& x : pv.pixels_px) x += Eigen::Vector2d(shift, shift);
    in.views.push_back(pv);
  }
  return in;
}

// Calibrates the projector alone (its own board poses), as upstream's calibrateCamera step.
CalibrationResult ProjectorAlone(const std::vector<ProcamPose>& poses, const Variant& v) {
  CalibrationInput in;
  in.num_poses = 5;
  in.devices = {CalibrationDevice::Projector("projector", 1024, 768)};
  in.devices[0].held_params = v.proj_held;
  for (const auto& p : poses) {
    BoardView pv = p.projector_view;
    pv.device = 0;
    pv.DropCarry();
    in.views.push_back(pv);
  }
  return Calibrate(in, {});
}

// Held-out pose k's projector corners predicted by calibration `r` (camera device 0, projector
// device 1): the board posed from the camera's corners alone (camera intrinsics held), then
// projected into the projector. Adds the squared errors (corners shifted by `shift` px) and
// their count.
void PredictHeldOutProjectorCorners(const CalibrationResult& r, const ProcamPose& held_out,
                                    double shift, double* sq, int* n) {
  CalibrationInput cam;
  cam.num_poses = 1;
  cam.devices = {CalibrationDevice::Camera("camera", 1280, 1024)};
  cam.devices[0].initial = r.devices[0].model;
  cam.devices[0].hold_intrinsics = true;
  BoardView cv = held_out.camera_view;
  cv.pose = 0;
  cam.views = {cv};
  CalibrationOptions o;
  o.compute_covariance = false;
  const CalibrationResult pose = Calibrate(cam, o);
  const Rigid3d proj_from_board = r.devices[1].cam_from_rig * *pose.rig_from_board[0];
  const BoardView& pv = held_out.projector_view;
  for (size_t i = 0; i < pv.pixels_px.size(); ++i) {
    const auto px = r.devices[1].model.Project(proj_from_board * pv.points_in_board_mm[i]);
    if (!px) continue;
    *sq += (*px - (pv.pixels_px[i] + Eigen::Vector2d(shift, shift))).squaredNorm();
    ++*n;
  }
}

// Leave-one-pose-out: RMS of the held-out projector corners predicted through the camera.
double CrossValidate(const std::vector<ProcamPose>& poses, const Variant& v, double shift,
                     double* worst_cy) {
  double sq = 0;
  int n = 0;
  double lo = 1e9, hi = -1e9;
  for (int k = 0; k < 5; ++k) {
    const CalibrationResult r = Calibrate(Input(poses, v, k, shift), {});
    if (std::getenv("STUDY_VERBOSE")) {
      std::printf("  fold %d: %s\n    proj fx %.1f cx %.1f cy %.1f k1 %.3f; cam fx %.1f\n", k,
                  r.summary.BriefReport().c_str(), r.devices[1].model.fx(), r.devices[1].model.cx(),
                  r.devices[1].model.cy(), r.devices[1].model.params[4], r.devices[0].model.fx());
    }
    lo = std::min(lo, r.devices[1].model.cy());
    hi = std::max(hi, r.devices[1].model.cy());
    PredictHeldOutProjectorCorners(r, poses[k], shift, &sq, &n);
  }
  *worst_cy = hi - lo;
  return std::sqrt(sq / n);
}

void Row(const std::string& setting, const std::vector<ProcamPose>& poses, const Variant& v,
         double shift = 0) {
  CalibrationResult r;
  int dev = 1;
  if (v.joint) {
    r = Calibrate(Input(poses, v, -1, shift), {});
  } else {
    r = ProjectorAlone(poses, v);
    dev = 0;
  }
  const CameraModel& m = r.devices[dev].model;
  const auto& c =
      r.intrinsics_covariance.empty() ? Matrix9d::Zero().eval() : r.intrinsics_covariance[dev];
  double cy_spread = 0;
  const double cv = v.joint ? CrossValidate(poses, v, shift, &cy_spread) : std::nan("");
  const auto& t = r.devices[dev].cam_from_rig.translation;
  std::printf(
      "%-22s %-14s rms %.4f cam %.4f | fx %7.1f+-%5.1f fy %7.1f cx %6.1f+-%4.1f cy %6.1f+-%4.1f | "
      "k %+.3f %+.3f p %+.5f %+.5f "
      "k3 %+.2f | t %6.1f %6.1f %6.1f | camfx %.1f | LOO rms %.4f cy-range %.1f\n",
      setting.c_str(), v.name.c_str(), r.summary.devices[dev].rms_px,
      v.joint ? r.summary.devices[0].rms_px : 0.0, m.fx(), std::sqrt(c(0, 0)), m.fy(), m.cx(),
      std::sqrt(c(2, 2)), m.cy(), std::sqrt(c(3, 3)), m.params[4], m.params[5], m.params[6],
      m.params[7], m.params[8], t.x(), t.y(), t.z(), r.devices[0].model.fx(), cv, cy_spread);
  std::fflush(stdout);
}

// Upstream's calibrate.py with these corners: cv::calibrateCamera per device with the image sizes
// as upstream passes them (numpy shape order: (height, width) read as (width, height)), default
// flags, then cv::stereoCalibrate with its default CALIB_FIX_INTRINSIC.
void UpstreamReplica(const std::string& setting, const std::vector<ProcamPose>& poses,
                     bool swapped_sizes) {
  std::vector<std::vector<cv::Point3f>> obj, obj2;
  std::vector<std::vector<cv::Point2f>> cam, cam2, proj;
  for (const auto& p : poses) {
    std::vector<cv::Point3f> o, o2;
    std::vector<cv::Point2f> c, c2, q;
    for (size_t i = 0; i < p.camera_view.pixels_px.size(); ++i) {
      const auto& x = p.camera_view.points_in_board_mm[i];
      o.emplace_back(static_cast<float>(x.x()), static_cast<float>(x.y()), 0.f);
      c.emplace_back(static_cast<float>(p.camera_view.pixels_px[i].x()),
                     static_cast<float>(p.camera_view.pixels_px[i].y()));
    }
    for (const auto& pc : p.projector.corners) {
      const auto& x = p.camera_view.points_in_board_mm[static_cast<size_t>(pc.point_id)];
      o2.emplace_back(static_cast<float>(x.x()), static_cast<float>(x.y()), 0.f);
      c2.emplace_back(static_cast<float>(pc.camera_px.x()), static_cast<float>(pc.camera_px.y()));
      q.emplace_back(static_cast<float>(pc.projector_px.x()),
                     static_cast<float>(pc.projector_px.y()));
    }
    obj.push_back(o);
    cam.push_back(c);
    obj2.push_back(o2);
    cam2.push_back(c2);
    proj.push_back(q);
  }
  const cv::Size cam_size = swapped_sizes ? cv::Size(1024, 1280) : cv::Size(1280, 1024);
  const cv::Size proj_size = swapped_sizes ? cv::Size(768, 1024) : cv::Size(1024, 768);
  cv::Mat kc, dc, kp, dp, r, t, e, f;
  std::vector<cv::Mat> rv, tv;
  const double rc = cv::calibrateCamera(obj, cam, cam_size, kc, dc, rv, tv);
  const double rp = cv::calibrateCamera(obj2, proj, proj_size, kp, dp, rv, tv);
  const double rs = cv::stereoCalibrate(obj2, cam2, proj, kc, dc, kp, dp, cam_size, r, t, e, f);
  std::printf(
      "%-22s %-14s cam rms %.4f fx %.1f | proj alone rms %.4f fx %.1f fy %.1f cx %.1f cy %.1f k "
      "%+.3f %+.3f p %+.5f %+.5f k3 %+.2f | stereo rms %.4f t %.1f %.1f %.1f\n",
      setting.c_str(), swapped_sizes ? "upstream-swap" : "upstream-wh", rc, kc.at<double>(0, 0), rp,
      kp.at<double>(0, 0), kp.at<double>(1, 1), kp.at<double>(0, 2), kp.at<double>(1, 2),
      dp.at<double>(0), dp.at<double>(1), dp.at<double>(2), dp.at<double>(3), dp.at<double>(4), rs,
      t.at<double>(0), t.at<double>(1), t.at<double>(2));
  std::fflush(stdout);
}

// Are the residuals white within a pose? Per view: the camera residual r_c, the projector
// residual r_p and the projector's own part d = r_p - J r_c (the camera's error cancels). Printed:
// the correlation of neighbouring corners (one square apart; 0 for white noise) and the share of
// the residual energy a per-view affine field in the board coordinates explains (3/63 = 5 % per
// coordinate for white noise).
void ResidualStructure(const CalibrationInput& in, const CalibrationResult& r) {
  std::vector<std::vector<Eigen::Vector2d>> res(in.views.size());
  for (size_t vi = 0; vi < in.views.size(); ++vi) {
    const auto px = Reproject(r, in.views[vi]);
    for (size_t i = 0; i < px.size(); ++i) res[vi].push_back(px[i] - in.views[vi].pixels_px[i]);
  }
  auto stats = [&](const char* name, const std::vector<std::vector<Eigen::Vector2d>>& rr,
                   const std::vector<size_t>& views) {
    double nb = 0, nb_n = 0, e = 0, e_n = 0, fit = 0, tot = 0;
    double by_dist[6] = {0, 0, 0, 0, 0, 0}, by_dist_n[6] = {0, 0, 0, 0, 0, 0};
    for (size_t vi : views) {
      const auto& pts = in.views[vi].points_in_board_mm;
      const auto& x = rr[vi];
      double ss = 0;
      for (const auto& v : x) ss += v.squaredNorm();
      double spacing = 1e300;
      for (size_t i = 0; i < pts.size(); ++i) {
        for (size_t j = i + 1; j < pts.size(); ++j)
          spacing = std::min(spacing, (pts[i] - pts[j]).norm());
      }
      for (size_t i = 0; i < pts.size(); ++i) {
        for (size_t j = i + 1; j < pts.size(); ++j) {
          const double k = (pts[i] - pts[j]).norm() / spacing;
          if (k < 1.01) {
            nb += x[i].dot(x[j]);
            nb_n += 1;
          }
          const int bin = k < 1.01   ? 0
                          : k < 1.5  ? 1
                          : k < 2.01 ? 2
                          : k < 3.01 ? 3
                          : k < 5.01 ? 4
                                     : 5;
          if (k < 1.01 || std::abs(k - std::sqrt(2.0)) < 0.01 ||
              std::abs(k - std::round(k)) < 0.01 || bin >= 4) {
            by_dist[bin] += x[i].dot(x[j]);
            by_dist_n[bin] += 1;
          }
        }
      }
      e += ss;
      e_n += static_cast<double>(x.size());
      Eigen::MatrixXd a(static_cast<Eigen::Index>(pts.size()), 3);
      Eigen::MatrixXd b(static_cast<Eigen::Index>(pts.size()), 2);
      for (size_t i = 0; i < pts.size(); ++i) {
        a.row(static_cast<Eigen::Index>(i)) << pts[i].x(), pts[i].y(), 1;
        b.row(static_cast<Eigen::Index>(i)) << x[i].x(), x[i].y();
      }
      const Eigen::MatrixXd coef = a.colPivHouseholderQr().solve(b);
      fit += (a * coef).squaredNorm();
      tot += ss;
    }
    std::printf(
        "    %-6s rms %.4f px, neighbour correlation %+.2f, affine field explains %.0f %%; "
        "correlation at 1, 1.4, 2, 3, "
        "3.2-5, >5 squares:",
        name, std::sqrt(e / e_n), (nb / nb_n) / (e / e_n), 100 * fit / tot);
    for (int b = 0; b < 6; ++b) std::printf(" %+.2f", (by_dist[b] / by_dist_n[b]) / (e / e_n));
    std::printf("\n");
  };
  std::vector<size_t> cams, projs;
  std::vector<std::vector<Eigen::Vector2d>> own(in.views.size());
  for (size_t vi = 0; vi < in.views.size(); ++vi) {
    const BoardView& v = in.views[vi];
    if (!v.IsCarried()) {
      cams.push_back(vi);
      continue;
    }
    projs.push_back(vi);
    size_t si = 0;
    while (!(in.views[si].device == v.source_device && in.views[si].pose == v.pose)) ++si;
    for (size_t i = 0; i < v.pixels_px.size(); ++i) {
      own[vi].push_back(res[vi][i] -
                        v.source_jacobians[i] * res[si][static_cast<size_t>(v.source_points[i])]);
    }
  }
  stats("camera", res, cams);
  stats("proj", res, projs);
  stats("d", own, projs);
}

// Covariance sigma against the jackknife spread of the leave-one-pose-out folds, for the chosen
// models (camera k1k2p1p2, projector k1k2), under noise models and options.
void CovarianceVsJackknife(const std::vector<ProcamPose>& poses) {
  using M = CameraModel;
  const Variant v{"k1k2p/k1k2", {M::kP1, M::kP2, M::kK3}, {M::kK3}};
  const CalibrationInput in = Input(poses, v, -1, 0);
  struct Setting {
    std::string name;
    CalibrationOptions options;
  };
  std::vector<Setting> settings(4);
  settings[0].name = "independent";
  settings[0].options.correlated_carried_noise = false;
  settings[1].name = "joint";
  settings[1].options.correlated_carried_noise = true;
  settings[2].name = "independent+warp";
  settings[2].options.correlated_carried_noise = false;
  settings[2].options.estimate_board_warp = true;
  settings[3].name = "joint+warp";
  settings[3].options.correlated_carried_noise = true;
  settings[3].options.estimate_board_warp = true;
  for (const auto& st : settings) {
    const auto scores =
        ScoreModelsByLeaveOnePoseOut(in, st.options, {{v.name, {v.cam_held, v.proj_held}}}, 0, 1);
    const ModelScore& sc = scores[0];
    const CalibrationSummary& sum = sc.result.summary;
    const auto& c = sc.result.intrinsics_covariance[1];
    const CameraModel& m = sc.result.devices[1].model;
    std::printf(
        "%-18s cam rms %.4f proj rms %.4f predicted %.4f | fx %.1f sigma %.2f jack %.2f (x%.2f) | "
        "cx %.1f sigma %.2f "
        "jack %.2f (x%.2f) | cy %.1f sigma %.2f jack %.2f (x%.2f)",
        st.name.c_str(), sum.devices[0].rms_px, sum.devices[1].rms_px, sc.prediction_rms_px, m.fx(),
        std::sqrt(c(0, 0)), JackknifeSigma(sc, M::kFx),
        JackknifeSigma(sc, M::kFx) / std::sqrt(c(0, 0)), m.cx(), std::sqrt(c(2, 2)),
        JackknifeSigma(sc, M::kCx), JackknifeSigma(sc, M::kCx) / std::sqrt(c(2, 2)), m.cy(),
        std::sqrt(c(3, 3)), JackknifeSigma(sc, M::kCy),
        JackknifeSigma(sc, M::kCy) / std::sqrt(c(3, 3)));
    if (!sc.result.intrinsics_covariance_view_correlated.empty()) {
      const auto& vc = sc.result.intrinsics_covariance_view_correlated[1];
      std::printf(" | view-correlated sigma fx %.2f (x%.2f) cx %.2f (x%.2f) cy %.2f (x%.2f)",
                  std::sqrt(vc(0, 0)), JackknifeSigma(sc, M::kFx) / std::sqrt(vc(0, 0)),
                  std::sqrt(vc(2, 2)), JackknifeSigma(sc, M::kCx) / std::sqrt(vc(2, 2)),
                  std::sqrt(vc(3, 3)), JackknifeSigma(sc, M::kCy) / std::sqrt(vc(3, 3)));
      for (const auto& k : sum.view_noise)
        std::printf(" | kernel %.3f px %.2f %.2f sq", k.sigma_px, k.share, k.length_squares);
    }
    if (sum.joint_noise) {
      std::printf(" | noise cam %.4f proj %.4f carry x%.1f chi2/dof %.3f", sum.noise_sigma_px[0],
                  sum.noise_sigma_px[1], sum.carry_scale, sum.variance_factor);
    }
    if (st.options.estimate_board_warp) {
      std::printf(" | warp %.3f %.3f mm", sc.result.board_warp_mm.x(), sc.result.board_warp_mm.y());
    }
    std::printf("\n");
    ResidualStructure(in, sc.result);
    std::printf("\n  folds cy:");
    for (const auto& f : sc.fold_models) std::printf(" %.1f", f.cy());
    std::printf("  cx:");
    for (const auto& f : sc.fold_models) std::printf(" %.1f", f.cx());
    std::printf("\n");
    std::fflush(stdout);
  }
}

}  // namespace

// The principal point bounded to the image (CalibrationOptions::principal_point_inside) against
// the data-driven fit, chosen models (camera k1 k2 p1 p2, projector k1 k2): fit RMS, leave-one-
// pose-out prediction per fold, the cost increase and its significance under the standard and the
// view-correlated covariance, and the dense epipolar check of each capture (STUDY_PP=1).
void PrincipalPointStudy(const PatternSpec& spec, const std::vector<ProcamPose>& poses,
                         const DecodeOptions& decode) {
  using M = CameraModel;
  const Variant v{"chosen", {M::kP1, M::kP2, M::kK3}, {M::kK3}};
  std::vector<std::vector<Correspondence>> dense;
  for (int p = 0; p < 5; ++p)
    dense.push_back(SampleCorrespondences(DecodePatterns(spec, g_images[p], decode)));
  CalibrationResult results[2];
  std::vector<double> fold_rms[2];
  for (int inside = 0; inside < 2; ++inside) {
    CalibrationOptions o;
    o.principal_point_inside = inside == 1;
    const CalibrationInput in = Input(poses, v, -1, 0);
    const CalibrationResult r = Calibrate(in, o);
    results[inside] = r;
    double sq = 0;
    int n = 0;
    for (int k = 0; k < 5; ++k) {
      CalibrationOptions fo = o;
      fo.compute_covariance = false;
      const CalibrationResult f = Calibrate(Input(poses, v, k, 0), fo);
      double fsq = 0;
      int fn = 0;
      PredictHeldOutProjectorCorners(f, poses[static_cast<size_t>(k)], 0, &fsq, &fn);
      fold_rms[inside].push_back(std::sqrt(fsq / fn));
      sq += fsq;
      n += fn;
      std::printf("  %s fold %d: held-out %.4f px, projector fx %.1f cx %.1f cy %.1f\n",
                  inside ? "inside" : "free  ", k, fold_rms[inside].back(), f.devices[1].model.fx(),
                  f.devices[1].model.cx(), f.devices[1].model.cy());
    }
    const Rig rig = RigFromCalibration(in, r, "kamino");
    std::printf(
        "%s: %s\n  projector fit RMS %.4f px, camera %.4f px, held-out %.4f px; cost %.4f\n",
        inside ? "INSIDE" : "FREE", r.summary.BriefReport().c_str(), r.summary.devices[1].rms_px,
        r.summary.devices[0].rms_px, std::sqrt(sq / n), r.summary.final_cost);
    const auto& m = r.devices[1].model;
    const auto& c = r.intrinsics_covariance[1];
    const auto& vc = r.intrinsics_covariance_view_correlated[1];
    std::printf(
        "  projector fx %.2f fy %.2f cx %.2f cy %.2f k1 %.4f k2 %.4f; sigma standard fx %.2f cx "
        "%.2f cy %.2f, "
        "view-correlated fx %.2f cx %.2f cy %.2f; camera fx %.2f cx %.2f cy %.2f\n",
        m.fx(), m.fy(), m.cx(), m.cy(), m.params[4], m.params[5], std::sqrt(c(0, 0)),
        std::sqrt(c(2, 2)), std::sqrt(c(3, 3)), std::sqrt(vc(0, 0)), std::sqrt(vc(2, 2)),
        std::sqrt(vc(3, 3)), r.devices[0].model.fx(), r.devices[0].model.cx(),
        r.devices[0].model.cy());
    for (const auto& b : r.summary.bounds_active) std::printf("  bound active: %s\n", b.c_str());
    std::printf("  dense epipolar median (p95) per capture, projector px:");
    for (int p = 0; p < 5; ++p) {
      const EpipolarStats e = EpipolarResiduals(rig, 0, dense[static_cast<size_t>(p)]);
      std::printf(" %.3f (%.2f)", e.median_px, e.p95_px);
    }
    std::printf("\n");
  }
  const CalibrationResult& u = results[0];
  const CalibrationResult& b = results[1];
  const double sigma2 = u.summary.residual_sigma_px * u.summary.residual_sigma_px;
  const double lr_iid = 2 * (b.summary.final_cost - u.summary.final_cost) / sigma2;
  const double var_std = u.intrinsics_covariance[1](M::kCy, M::kCy),
               var_vc = u.intrinsics_covariance_view_correlated[1](M::kCy, M::kCy);
  const double shift = u.devices[1].model.cy() - b.devices[1].model.cy();
  const double lr_vc =
      lr_iid * var_std / var_vc;  // the same cost rise measured in the correlated model's units
  auto p_of = [](double chi2) {
    return std::erfc(std::sqrt(std::max(chi2, 0.0) / 2));
  };  // chi^2, 1 dof
  std::printf(
      "cost %.4f -> %.4f (+%.4f, residual sigma %.4f px): LR (independent errors) %.1f, p %.2g; "
      "Wald standard "
      "(%.1f px / %.2f)^2 = %.1f; view-correlated: LR x var_std/var_vc %.1f, p %.2g; Wald (%.1f / "
      "%.2f)^2 = %.1f, p %.2g\n",
      u.summary.final_cost, b.summary.final_cost, b.summary.final_cost - u.summary.final_cost,
      u.summary.residual_sigma_px, lr_iid, p_of(lr_iid), shift, std::sqrt(var_std),
      std::pow(shift, 2) / var_std, lr_vc, p_of(lr_vc), shift, std::sqrt(var_vc),
      std::pow(shift, 2) / var_vc, p_of(std::pow(shift, 2) / var_vc));
  double mean = 0, ss = 0;
  for (int k = 0; k < 5; ++k)
    mean += (fold_rms[1][static_cast<size_t>(k)] - fold_rms[0][static_cast<size_t>(k)]) / 5;
  for (int k = 0; k < 5; ++k)
    ss += std::pow(fold_rms[1][static_cast<size_t>(k)] - fold_rms[0][static_cast<size_t>(k)] - mean,
                   2);
  const double sd = std::sqrt(ss / 4);
  std::printf("held-out per fold, inside - free: mean %+.4f px, sd %.4f, se %.4f, t %.2f (4 dof)\n",
              mean, sd, sd / std::sqrt(5.0), mean / (sd / std::sqrt(5.0)));
}

int main(int argc, char** argv) {
  const std::string src = argc > 1 ? argv[1] : SLSHADOW_SOURCE_DIR;
  const std::string data = src + "/../shared/data/kamino-procam-graycode";
  const PatternSpec spec = LoadPatternSpec(src + "/config/patterns/kamino_opencv_graycode.yaml");
  const TargetSpec target = LoadTargetSpec(src + "/config/targets/kamino-procam-graycode.yaml");
  for (int p = 0; p < 5; ++p) {
    std::vector<cv::Mat> images;
    for (int i = 0; i < spec.NumImages(); ++i) {
      char name[64];
      std::snprintf(name, sizeof(name), "/capture_%d/graycode_%02d.png", p, i);
      images.push_back(ReadGrayImage(data + name));
    }
    g_images.push_back(std::move(images));
  }
  using M = CameraModel;
  const std::vector<Variant> models = {
      {"full", {}, {}},
      {"no-k3", {M::kK3}, {}},
      {"no-p", {M::kP1, M::kP2}, {}},
      {"no-p-k3", {M::kP1, M::kP2, M::kK3}, {}},
      {"k1-only", {M::kK2, M::kP1, M::kP2, M::kK3}, {}},
      {"none", {M::kK1, M::kK2, M::kP1, M::kP2, M::kK3}, {}},
      {"both-no-p-k3", {M::kP1, M::kP2, M::kK3}, {M::kP1, M::kP2, M::kK3}},
      {"both-no-k3", {M::kK3}, {M::kK3}},
      {"cam-no-k3/no-p", {M::kP1, M::kP2}, {M::kK3}},
      {"cam-no-k3/k1k2", {M::kP1, M::kP2, M::kK3}, {M::kK3}},
      {"cam-no-k3/k1", {M::kK2, M::kP1, M::kP2, M::kK3}, {M::kK3}},
      {"cam-no-p-k3/full", {}, {M::kP1, M::kP2, M::kK3}},
      {"alone-full", {}, {}, false},
      {"alone-no-p-k3", {M::kP1, M::kP2, M::kK3}, {}, false},
  };
  DecodeOptions upstream;
  upstream.shadow_threshold = 40;
  upstream.contrast_threshold = 5;
  const auto base = Poses(spec, target, upstream, {});
  if (std::getenv("STUDY_PP")) {
    PrincipalPointStudy(spec, base, upstream);
    return 0;
  }
  if (std::getenv("STUDY_COVARIANCE")) {
    CovarianceVsJackknife(base);
    return 0;
  }
  if (std::getenv("STUDY_QUICK")) {
    Row("thr40/5 w20", base, models[3]);
    return 0;
  }
  {
    LocalHomographyOptions lh;  // upstream's 17x17 patch
    lh.half_window_px = 8;
    lh.min_valid_pixels = 64;
    const auto w8 = Poses(spec, target, upstream, lh);
    UpstreamReplica("thr40/5 w8", w8, true);
    UpstreamReplica("thr40/5 w8", w8, false);
    UpstreamReplica("thr40/5 w20", base, true);
    UpstreamReplica("thr40/5 w20", base, false);
  }
  if (std::getenv("STUDY_UPSTREAM")) return 0;
  for (const auto& v : models) Row("thr40/5 w20", base, v);
  Row("thr40/5 w20 +0.5", base, models[0], 0.5);
  Row("thr40/5 w20 +0.5", base, models[3], 0.5);
  const std::vector<std::pair<std::string, DecodeOptions>> decodes = {
      {"default thr", DecodeOptions{}}, {"thr40/5 no-mid", [] {
                                           DecodeOptions d;
                                           d.shadow_threshold = 40;
                                           d.contrast_threshold = 5;
                                           d.gray_edge_midpoint = false;
                                           return d;
                                         }()}};
  for (const auto& [name, d] : decodes) {
    const auto poses = Poses(spec, target, d, {});
    Row(name + " w20", poses, models[0]);
    Row(name + " w20", poses, models[3]);
  }
  for (int w : {8, 12, 30, 47}) {
    LocalHomographyOptions lh;
    lh.half_window_px = w;
    lh.min_valid_pixels = std::min(100, (2 * w + 1) * (2 * w + 1) / 3);
    const auto poses = Poses(spec, target, upstream, lh);
    Row("thr40/5 w" + std::to_string(w), poses, models[0]);
    Row("thr40/5 w" + std::to_string(w), poses, models[3]);
  }
  return 0;
}
