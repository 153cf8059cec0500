// OpenCV's own stereo calibration of the same board detections slshadow calibrated from: the
// independent figure for a stereo rig's baseline and pose (cv::calibrateCamera per camera, then
// cv::stereoCalibrate refining both cameras and the pose jointly, as samples/cpp/stereo_calib.cpp
// does). Only poses where both cameras saw the board are used (OpenCV needs pairs).
#pragma once

#include <cmath>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

#include "calib/calibration.h"

namespace slshadow::testing {

struct OpenCvStereo {
  double rms_px = 0;      // cv::stereoCalibrate's RMS over both cameras
  Eigen::Matrix3d R;      // right_from_left rotation: x_right = R x_left + T
  Eigen::Vector3d T_mm;   // board units are mm, so T is too
  cv::Mat K[2], dist[2];  // refined intrinsics (fx fy cx cy) and k1 k2 p1 p2 k3
  int pairs = 0;
};

// Devices 0 and 1 of `input` (plain views, no carried ones). `flags` go to both calls (e.g.
// cv::CALIB_FIX_ASPECT_RATIO, aspect ratio 1 as slshadow's fix_aspect_ratio starts from).
inline OpenCvStereo OpenCvStereoCalibrate(const CalibrationInput& input, int flags) {
  std::vector<std::vector<cv::Point3f>> object;
  std::vector<std::vector<cv::Point2f>> pixels[2];
  for (int pose = 0; pose < input.num_poses; ++pose) {
    const BoardView* v[2] = {nullptr, nullptr};
    for (const BoardView& view : input.views) {
      if (view.pose == pose && view.device < 2) v[view.device] = &view;
    }
    if (!v[0] || !v[1] || v[0]->points_in_board_mm.size() != v[1]->points_in_board_mm.size())
      continue;
    std::vector<cv::Point3f> obj;
    for (const auto& p : v[0]->points_in_board_mm)
      obj.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()),
                       static_cast<float>(p.z()));
    object.push_back(obj);
    for (int d = 0; d < 2; ++d) {
      std::vector<cv::Point2f> px;
      for (const auto& p : v[d]->pixels_px)
        px.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()));
      pixels[d].push_back(px);
    }
  }
  OpenCvStereo out;
  out.pairs = static_cast<int>(object.size());
  for (int d = 0; d < 2; ++d) {
    const cv::Size size(input.devices[static_cast<size_t>(d)].width,
                        input.devices[static_cast<size_t>(d)].height);
    out.K[d] = cv::Mat::eye(3, 3, CV_64F);
    out.dist[d] = cv::Mat::zeros(5, 1, CV_64F);
    std::vector<cv::Mat> rvecs, tvecs;
    cv::calibrateCamera(object, pixels[d], size, out.K[d], out.dist[d], rvecs, tvecs, flags);
  }
  cv::Mat R, T, E, F;
  out.rms_px = cv::stereoCalibrate(
      object, pixels[0], pixels[1], out.K[0], out.dist[0], out.K[1], out.dist[1],
      cv::Size(input.devices[0].width, input.devices[0].height), R, T, E, F,
      flags | cv::CALIB_USE_INTRINSIC_GUESS,
      cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 200, 1e-10));
  cv::cv2eigen(R, out.R);
  cv::cv2eigen(T, out.T_mm);
  return out;
}

// Angle of the rotation between two rotation matrices, degrees.
inline double RotationAngleDeg(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  return Eigen::AngleAxisd(a.transpose() * b).angle() * 180 / M_PI;
}

}  // namespace slshadow::testing
