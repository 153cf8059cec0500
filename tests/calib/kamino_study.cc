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
#include "calib/projector.h"
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

std::vector<ProcamPose> Poses(const PatternSpec& spec, const TargetSpec& target, const DecodeOptions& d,
                              const LocalHomographyOptions& lh) {
  std::vector<ProcamPose> out;
  for (int p = 0; p < 5; ++p) out.push_back(MakeProcamPose(spec, g_images[p], target, p, 0, 1, "capture_" + std::to_string(p), d, lh));
  return out;
}

CalibrationInput Input(const std::vector<ProcamPose>& poses, const Variant& v, int leave_out, double shift) {
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
  in.devices = {{"projector", 1024, 768, true, std::nullopt, false, v.proj_held}};
  for (const auto& p : poses) {
    BoardView pv = p.projector_view;
    pv.device = 0;
    in.views.push_back(pv);
  }
  return Calibrate(in, {});
}

// Leave-one-pose-out: RMS of the held-out projector corners predicted through the camera.
double CrossValidate(const std::vector<ProcamPose>& poses, const Variant& v, double shift, double* worst_cy) {
  double sq = 0;
  int n = 0;
  double lo = 1e9, hi = -1e9;
  for (int k = 0; k < 5; ++k) {
    const CalibrationResult r = Calibrate(Input(poses, v, k, shift), {});
    if (std::getenv("STUDY_VERBOSE")) {
      std::printf("  fold %d: %s\n    proj fx %.1f cx %.1f cy %.1f k1 %.3f; cam fx %.1f\n", k, r.summary.BriefReport().c_str(),
                  r.devices[1].model.fx(), r.devices[1].model.cx(), r.devices[1].model.cy(), r.devices[1].model.params[4],
                  r.devices[0].model.fx());
    }
    lo = std::min(lo, r.devices[1].model.cy());
    hi = std::max(hi, r.devices[1].model.cy());
    CalibrationInput cam;
    cam.num_poses = 1;
    cam.devices = {{"camera", 1280, 1024, false, r.devices[0].model, true, {}}};
    BoardView cv = poses[k].camera_view;
    cv.pose = 0;
    cam.views = {cv};
    CalibrationOptions o;
    o.compute_covariance = false;
    const CalibrationResult pose = Calibrate(cam, o);
    const Rigid3d proj_from_board = r.devices[1].cam_from_rig * *pose.rig_from_board[0];
    const BoardView& pv = poses[k].projector_view;
    for (size_t i = 0; i < pv.pixels_px.size(); ++i) {
      const auto px = r.devices[1].model.Project(proj_from_board * pv.points_in_board_mm[i]);
      if (!px) continue;
      sq += (*px - (pv.pixels_px[i] + Eigen::Vector2d(shift, shift))).squaredNorm();
      ++n;
    }
  }
  *worst_cy = hi - lo;
  return std::sqrt(sq / n);
}

void Row(const std::string& setting, const std::vector<ProcamPose>& poses, const Variant& v, double shift = 0) {
  CalibrationResult r;
  int dev = 1;
  if (v.joint) {
    r = Calibrate(Input(poses, v, -1, shift), {});
  } else {
    r = ProjectorAlone(poses, v);
    dev = 0;
  }
  const CameraModel& m = r.devices[dev].model;
  const auto& c = r.intrinsics_covariance.empty() ? Matrix9d::Zero().eval() : r.intrinsics_covariance[dev];
  double cy_spread = 0;
  const double cv = v.joint ? CrossValidate(poses, v, shift, &cy_spread) : std::nan("");
  const auto& t = r.devices[dev].cam_from_rig.translation;
  std::printf("%-22s %-14s rms %.4f cam %.4f | fx %7.1f+-%5.1f fy %7.1f cx %6.1f+-%4.1f cy %6.1f+-%4.1f | k %+.3f %+.3f p %+.5f %+.5f "
              "k3 %+.2f | t %6.1f %6.1f %6.1f | camfx %.1f | LOO rms %.4f cy-range %.1f\n",
              setting.c_str(), v.name.c_str(), r.summary.devices[dev].rms_px, v.joint ? r.summary.devices[0].rms_px : 0.0,
              m.fx(), std::sqrt(c(0, 0)), m.fy(), m.cx(), std::sqrt(c(2, 2)), m.cy(), std::sqrt(c(3, 3)), m.params[4],
              m.params[5], m.params[6], m.params[7], m.params[8], t.x(), t.y(), t.z(), r.devices[0].model.fx(), cv, cy_spread);
  std::fflush(stdout);
}

// Upstream's calibrate.py with these corners: cv::calibrateCamera per device with the image sizes
// as upstream passes them (numpy shape order: (height, width) read as (width, height)), default
// flags, then cv::stereoCalibrate with its default CALIB_FIX_INTRINSIC.
void UpstreamReplica(const std::string& setting, const std::vector<ProcamPose>& poses, bool swapped_sizes) {
  std::vector<std::vector<cv::Point3f>> obj, obj2;
  std::vector<std::vector<cv::Point2f>> cam, cam2, proj;
  for (const auto& p : poses) {
    std::vector<cv::Point3f> o, o2;
    std::vector<cv::Point2f> c, c2, q;
    for (size_t i = 0; i < p.camera_view.pixels_px.size(); ++i) {
      const auto& x = p.camera_view.points_in_board_mm[i];
      o.emplace_back(static_cast<float>(x.x()), static_cast<float>(x.y()), 0.f);
      c.emplace_back(static_cast<float>(p.camera_view.pixels_px[i].x()), static_cast<float>(p.camera_view.pixels_px[i].y()));
    }
    for (const auto& pc : p.projector.corners) {
      const auto& x = p.camera_view.points_in_board_mm[static_cast<size_t>(pc.point_id)];
      o2.emplace_back(static_cast<float>(x.x()), static_cast<float>(x.y()), 0.f);
      c2.emplace_back(static_cast<float>(pc.camera_px.x()), static_cast<float>(pc.camera_px.y()));
      q.emplace_back(static_cast<float>(pc.projector_px.x()), static_cast<float>(pc.projector_px.y()));
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
  std::printf("%-22s %-14s cam rms %.4f fx %.1f | proj alone rms %.4f fx %.1f fy %.1f cx %.1f cy %.1f k %+.3f %+.3f p %+.5f %+.5f k3 %+.2f | stereo rms %.4f t %.1f %.1f %.1f\n",
              setting.c_str(), swapped_sizes ? "upstream-swap" : "upstream-wh", rc, kc.at<double>(0, 0), rp, kp.at<double>(0, 0),
              kp.at<double>(1, 1), kp.at<double>(0, 2), kp.at<double>(1, 2), dp.at<double>(0), dp.at<double>(1), dp.at<double>(2),
              dp.at<double>(3), dp.at<double>(4), rs, t.at<double>(0), t.at<double>(1), t.at<double>(2));
  std::fflush(stdout);
}

}  // namespace

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
  const std::vector<std::pair<std::string, DecodeOptions>> decodes = {{"default thr", DecodeOptions{}}, {"thr40/5 no-mid", [] {
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
