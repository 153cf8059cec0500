// Internal to calib/ (calib/internal/: not part of the public API; include only from calib/*.cc).
// Initialisation of Calibrate(): each device alone from its board homographies and PnP, then the
// devices placed in the rig by a robust average of their per-pose relative poses.
#pragma once

#include <optional>
#include <vector>

#include <opencv2/core.hpp>

#include "calib/internal/calibration_problem.h"

namespace slshadow::calib::internal {

std::vector<cv::Point3f> ToCv(const std::vector<Eigen::Vector3d>& v);
std::vector<cv::Point2f> ToCv(const std::vector<Eigen::Vector2d>& v);

// Pose of the board in the device frame from one view, by PnP with the current intrinsics.
std::optional<Pose6> PoseByPnP(const Intr9& params, const BoardView& v);

// Single-device input made of the views of device d (device index remapped to 0).
CalibrationInput DeviceInput(const CalibrationInput& input, int d);

// Intrinsics and per-pose dev_from_board of one device alone.
State InitDevice(const CalibrationInput& sub, const CalibrationOptions& options);

// The candidate transform closest (in translation, then rotation) to all others: robust average.
Rigid3d Medoid(const std::vector<Rigid3d>& candidates);

}  // namespace slshadow::calib::internal
