// Calibration check: does the rig file fit the captures it reconstructs? Judged on the epipolar
// error of the dense correspondences (one figure, one name in text and JSON):
//   projector mode, both projector axes coded: the signed distance of the decoded projector
//     coordinate from the epipolar line of its camera pixel, projector px;
//   stereo, both axes coded: the decoded projector row of the left camera minus that of the right
//     camera at the matched position, projector px (rectification matched the columns; the rows
//     must then agree).
// With one coded axis the triangulation leaves no such residual. Stereo then checks the projector
// error instead when the rig has a (calibrated) projector, a third view: the left camera's decoded
// projector column minus the column the stereo point projects to, projector px. Otherwise the check
// says it is not available, and why.
//
// The error is split into a systematic part and noise. A smooth field is fitted to it over the
// reference camera's image, robustly (Huber IRLS), in nested groups of terms
//   offset 1 | linear x, y | quadratic x^2, x y, y^2 | radial x r^2, y r^2
// (x, y: normalised camera coordinates scaled to +-1 across the image width). The noise is the
// robust scatter (1.4826 MAD) about the field: the decoding noise of this very capture. The
// systematic part is the field's RMS over the correspondences. It is significant when it exceeds
//   threshold = max(noise_factor x noise, 5 x noise x sqrt(8 / n), min_warning_px)
// (the second term: five standard errors of a field fitted to pure noise, for small n; the third:
// exact, noise-free maps leave no noise to judge by), or a user's fixed threshold. Each group's
// share (RMS of what it adds to the field) names what is likely wrong: offset -> a principal point
// or a rotation of the pose (both shift whole epipolar lines), linear -> a focal length or a
// rotation, quadratic -> the pose, radial -> the distortion; a field above 1 px -> a bumped rig,
// swapped camera names or a wrong rig file. The epipolar error cannot see errors that move points
// along epipolar lines (e.g. a camera principal point shifted along the baseline): those stay
// invisible to any such check.
//
// The default noise_factor 1 warns when the calibration's systematic error exceeds the per-point
// decode noise, i.e. when the calibration, not the decoding, dominates a point's error.
//
// The threshold is also given in mm: the depth error a disparity error of that size causes at
// the working distance, threshold_px x Z^2 / (f B), f the focal length of the device whose
// pixels the error is in (the projector), B the baseline of the triangulating pair, Z the scan's
// median range (reconstruct.cc).
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace slshadow {

// The residual checked: its name in text and its key in JSON.
enum class CalibrationResidual { kEpipolarError, kProjectorError };
std::string ToString(CalibrationResidual residual);     // "epipolar error", "projector error"
const char* ResidualKey(CalibrationResidual residual);  // "epipolar_error_px", "projector_error_px"

struct CalibrationCheckSetup {
  CalibrationResidual residual = CalibrationResidual::kEpipolarError;
  std::string pair;     // "<camera>-<other device>", for messages
  bool stereo = false;  // wording of the likely causes
  // Fixed threshold on the systematic part, px; 0: automatic (noise_factor x noise); infinity:
  // the check runs and reports but never warns.
  double warning_px = 0;
  double noise_factor = 1.0;       // automatic threshold in units of the noise (> 0)
  double min_warning_px = 0.01;    // floor of the automatic threshold, px
  double working_distance_mm = 0;  // Z
  // Depth error per px of epipolar error at the working distance, Z^2 / (f B); 0: not known.
  double mm_per_px = 0;
};

struct CalibrationCheck {
  static constexpr int kNumGroups = 4;
  static std::string GroupName(int group);  // "offset", "linear", "quadratic", "radial"

  bool available = false;
  std::string unavailable_reason;  // when !available: why (one clause, "because ...")
  std::string pair;
  CalibrationResidual residual = CalibrationResidual::kEpipolarError;
  int64_t count = 0;             // correspondences used
  double median_px = 0;          // signed median of the residual, projector px
  double noise_px = 0;           // robust scatter about the fitted field, projector px
  double systematic_px = 0;      // RMS of the fitted field over the correspondences, projector px
  double threshold_px = 0;       // what systematic_px is judged against
  std::string threshold_source;  // "noise" (automatic), "floor" (min_warning_px) or "user"
  double threshold_mm = 0;       // threshold_px as depth error at the working distance (0: unknown)
  double working_distance_mm = 0;
  std::array<double, kNumGroups> group_rms_px{};  // what each nested group adds to the field
  std::vector<std::string> likely_causes;         // named from the dominant groups
  bool warn = false;

  // One line: the warning (warn), the passed verdict, or "not available, because ...".
  std::string Message() const;
  nlohmann::json ToJson() const;
};

// The check of signed epipolar errors `error_px` at normalised camera coordinates (x, y) (the
// reference camera's undistorted image plane, scaled so that the image's half width is ~1).
// Non-finite entries are ignored; fewer than 100 finite ones make the check unavailable.
CalibrationCheck FitCalibrationCheck(const std::vector<float>& x, const std::vector<float>& y,
                                     const std::vector<float>& error_px,
                                     const CalibrationCheckSetup& setup);

// The check that cannot run, with its reason ("only projector columns are coded: ...").
CalibrationCheck UnavailableCalibrationCheck(const std::string& pair, const std::string& reason);

}  // namespace slshadow
