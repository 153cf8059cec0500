// Projector calibration by local homographies (Moreno & Taubin, "Simple, Accurate, and Robust
// Projector-Camera Calibration", 3DIMPVT 2012).
//
// The projector cannot see the board, so each board corner found in the camera is carried into
// projector pixels: around the corner's camera position c, the decoded structured light gives
// pairs (camera pixel q, projector coordinate P(q)); on a plane they are related by a homography
// H (projector_from_camera), fitted to the window by least squares, and the corner's projector
// position is H c. The board is locally planar and H absorbs the lens distortion to first order,
// so only the window's size limits the fit. The projector is then calibrated as an inverse camera
// together with the camera (calib/calibration.h), the projector being a device with
// is_projector set.
//
// Robustness beyond the paper: wrongly decoded pixels (a flipped Gray bit moves P(q) by powers of
// two) are removed by refitting after dropping pairs farther than inlier_threshold_px from the
// first fit (repeated until none is dropped), and corners whose fit stays poor are skipped with a
// reason.
#pragma once

#include <array>
#include <string>
#include <vector>

#include <Eigen/Core>

#include <opencv2/core.hpp>

#include "calib/calibration.h"
#include "calib/target.h"
#include "core/projector_map.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"

namespace slshadow {

struct LocalHomographyOptions {
  int half_window_px = 20;           // camera pixels each side of the corner: window (2n+1)^2
  int min_valid_pixels = 100;        // fewer decoded pixels in the window: corner skipped
  double inlier_threshold_px = 1.5;  // projector px; pairs farther from the fit are dropped, refit
  double max_fit_rms_px = 0.8;  // projector px; a corner whose inlier RMS exceeds this is skipped
  // Sets half_window_px = n and min_valid_pixels = min(100, n^2), so a small window (below 10 px)
  // asks for no more decoded pixels than it can hold (`calibrate projector|rig --window`).
  void SetHalfWindow(int n);
  // Throws slshadow::Error naming the first violated constraint.
  void Check() const;
};

struct ProjectorCorner {
  int point_id = 0;  // board point index (TargetDetection::point_ids)
  Eigen::Vector2d camera_px = Eigen::Vector2d::Zero();
  Eigen::Vector2d projector_px = Eigen::Vector2d::Zero();
  int num_pixels = 0;     // decoded pixel pairs used (inliers)
  double fit_rms_px = 0;  // RMS distance of the inliers to the homography, projector px
  // d projector_px / d camera_px: how an error of the camera corner moves the projector corner.
  Eigen::Matrix2d jacobian = Eigen::Matrix2d::Identity();
  // Covariance of H c from the fit alone (projector px^2): the inliers' residual variance per
  // coordinate propagated through the least-squares fit (8 homography entries) to the corner,
  // as if the decoded pixels' errors were independent. They are not (Gray-code stripes and
  // phase errors are shared by neighbouring pixels), so the calibration uses its shape and
  // relative size and estimates its scale (CalibrationSummary::carry_scale).
  Eigen::Matrix2d fit_covariance_px2 = Eigen::Matrix2d::Zero();
};

struct ProjectorCorners {
  std::vector<ProjectorCorner> corners;
  std::vector<std::string> skipped;  // one line per skipped corner: id and why
};

// Maps every detected corner into projector pixels. `map` must have both axes coded and the
// camera image's size (throws slshadow::Error otherwise).
ProjectorCorners ProjectorCornersByLocalHomography(const ProjectorMap& map,
                                                   const TargetDetection& detection,
                                                   const LocalHomographyOptions& options = {});

// One board pose of a camera-projector capture, ready for Calibrate(): the camera's view (board
// found in the sequence's white frame) and the projector's view (the corners carried into
// projector pixels, a carried view: BoardView::source_device is the camera, with each corner's
// Jacobian and fit covariance), plus what was found along the way.
struct ProcamPose {
  TargetDetection detection;   // in the white frame
  ProjectorCorners projector;  // corners in projector pixels, and skipped ones
  BoardView camera_view;       // device camera_device, pose `pose`
  BoardView projector_view;    // device projector_device, pose `pose`
  std::array<int64_t, kNumPixelStatus> decode_counts{};  // decoded pixels by status
};

// Decodes `images` (one camera's images of `patterns`, in sequence order), finds the board in the
// white frame and maps its corners into the projector. Throws slshadow::Error when the sequence
// has no white frame or does not code both axes; a board not found is a result (detection.found
// false, empty views).
ProcamPose MakeProcamPose(const PatternSpec& patterns, const std::vector<cv::Mat>& images,
                          const TargetSpec& target, int pose, int camera_device,
                          int projector_device, const std::string& label,
                          const DecodeOptions& decode = {},
                          const LocalHomographyOptions& local = {});

}  // namespace slshadow
