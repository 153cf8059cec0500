#include "calib/internal/initialization.h"

#include <algorithm>
#include <cmath>

#include <opencv2/calib3d.hpp>

#include "core/error.h"

namespace slshadow::calib::internal {

std::vector<cv::Point3f> ToCv(const std::vector<Eigen::Vector3d>& v) {
  std::vector<cv::Point3f> out;
  for (const auto& p : v)
    out.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()),
                     static_cast<float>(p.z()));
  return out;
}
std::vector<cv::Point2f> ToCv(const std::vector<Eigen::Vector2d>& v) {
  std::vector<cv::Point2f> out;
  for (const auto& p : v) out.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()));
  return out;
}

// Pose of the board in the device frame from one view, by PnP with the current intrinsics.
std::optional<Pose6> PoseByPnP(const Intr9& params, const BoardView& v) {
  using M = CameraModel;
  cv::Mat k = (cv::Mat_<double>(3, 3) << params[M::kFx], 0, params[M::kCx], 0, params[M::kFy],
               params[M::kCy], 0, 0, 1);
  cv::Mat dist = (cv::Mat_<double>(1, 5) << params[M::kK1], params[M::kK2], params[M::kP1],
                  params[M::kP2], params[M::kK3]);
  cv::Mat rvec, tvec;
  std::vector<cv::Point3d> obj;
  std::vector<cv::Point2d> img;
  for (size_t i = 0; i < v.pixels_px.size(); ++i) {
    obj.emplace_back(v.points_in_board_mm[i].x(), v.points_in_board_mm[i].y(),
                     v.points_in_board_mm[i].z());
    img.emplace_back(v.pixels_px[i].x(), v.pixels_px[i].y());
  }
  if (!cv::solvePnP(obj, img, k, dist, rvec, tvec, false, cv::SOLVEPNP_ITERATIVE))
    return std::nullopt;
  Pose6 p{rvec.at<double>(0), rvec.at<double>(1), rvec.at<double>(2),
          tvec.at<double>(0), tvec.at<double>(1), tvec.at<double>(2)};
  for (double x : p) {
    if (!std::isfinite(x)) return std::nullopt;
  }
  if (p[5] <= 0) return std::nullopt;
  return p;
}

// Single-device input made of the views of device d (device index remapped to 0).
CalibrationInput DeviceInput(const CalibrationInput& input, int d) {
  CalibrationInput sub;
  sub.devices = {input.devices[d]};
  sub.num_poses = input.num_poses;
  for (const auto& v : input.views) {
    if (v.device != d) continue;
    sub.views.push_back(v);
    sub.views.back().device = 0;
    sub.views.back().DropCarry();
  }
  return sub;
}

// Intrinsics and per-pose dev_from_board of one device alone.
State InitDevice(const CalibrationInput& sub, const CalibrationOptions& options) {
  const CalibrationDevice& dev = sub.devices[0];
  State s;
  s.extent = BoardExtent(sub);
  s.dev_from_rig = {Pose6{0, 0, 0, 0, 0, 0}};
  s.rig_from_board.assign(static_cast<size_t>(sub.num_poses), Pose6{0, 0, 0, 0, 0, 1000});
  s.pose_known.assign(static_cast<size_t>(sub.num_poses), false);
  Intr9 params{};
  if (dev.initial) {
    params = dev.initial->params;
  } else {
    std::vector<std::vector<cv::Point3f>> obj;
    std::vector<std::vector<cv::Point2f>> img;
    for (const auto& v : sub.views) {
      obj.push_back(ToCv(v.points_in_board_mm));
      img.push_back(ToCv(v.pixels_px));
    }
    // OpenCV's aspectRatio is fx / fy; 0 estimates both.
    const double cv_aspect = options.fix_aspect_ratio ? 1.0 / options.aspect_ratio : 0.0;
    cv::Mat k;
    try {
      k = cv::initCameraMatrix2D(obj, img, cv::Size(dev.width, dev.height), cv_aspect);
    } catch (const cv::Exception& e) {
      SLSHADOW_THROW("device '", dev.name,
                     "': cannot initialise the intrinsics from the board homographies (", e.what(),
                     ")");
    }
    params = {k.at<double>(0, 0),
              k.at<double>(1, 1),
              k.at<double>(0, 2),
              k.at<double>(1, 2),
              0,
              0,
              0,
              0,
              0};
    SLSHADOW_THROW_IF(
        !(params[CameraModel::kFx] > 0 && params[CameraModel::kFy] > 0 &&
          std::isfinite(params[CameraModel::kFx]) && std::isfinite(params[CameraModel::kFy])),
        "device '", dev.name, "': the board homographies give no valid focal length (fx ",
        params[CameraModel::kFx], ", fy ", params[CameraModel::kFy],
        "): the views are degenerate (all parallel to the image plane, or ",
        "too few); capture the board tilted by 20-40 degrees in several directions");
  }
  if (options.fix_principal_point && !dev.initial) {
    params[CameraModel::kCx] = (dev.width - 1) / 2.0;
    params[CameraModel::kCy] = (dev.height - 1) / 2.0;
  }
  s.intrinsics = {params};
  s.aspect = {options.fix_aspect_ratio ? params[CameraModel::kFy] / params[CameraModel::kFx] : 0.0};
  int posed = 0;
  for (const auto& v : sub.views) {
    const auto pose = PoseByPnP(params, v);
    if (!pose) continue;
    s.rig_from_board[v.pose] = *pose;
    s.pose_known[v.pose] = true;
    ++posed;
  }
  SLSHADOW_THROW_IF(posed == 0, "device '", dev.name,
                    "': no view could be posed (solvePnP failed on all views)");
  return s;
}

// The candidate transform closest (in translation, then rotation) to all others: robust average.
Rigid3d Medoid(const std::vector<Rigid3d>& candidates) {
  SLSHADOW_CHECK(!candidates.empty());
  size_t best = 0;
  double best_cost = 1e300;
  for (size_t i = 0; i < candidates.size(); ++i) {
    double cost = 0;
    for (const auto& c : candidates) {
      cost += (c.translation - candidates[i].translation).norm() +
              1000 * c.rotation.angularDistance(candidates[i].rotation);
    }
    if (cost < best_cost) {
      best_cost = cost;
      best = i;
    }
  }
  return candidates[best];
}

}  // namespace slshadow::calib::internal
