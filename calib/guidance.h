// What a user needs to hear about a calibration data set beyond the numbers: problems named in
// words, each with what to capture next. Checked after calibrating (tilts come from the board
// poses) and on the images themselves (saturation, boards not found).
//
// Checks, per device:
//   too few views        fewer than min_views (default 10) views         -> capture more poses
//   fronto-parallel      largest board tilt below min_tilt_deg (15)       -> tilt the board 20-40
//   deg centre-only corners  fewer than min_coverage (55 %) of the image's
//                        8 x 6 cells contain a corner                     -> put the board near
//                        edges/corners
//   saturated images     a view's image with > max_saturated (2 %) pixels
//                        at the saturation level                         -> lower exposure / light
//   board not found      an image where the target was not found         -> the detector's reason
//   outlier views        flagged by Calibrate                            -> recapture or drop them
//   high RMS             device RMS above max_rms_px (1 px)              -> check target size /
//   focus edge uncertainty     projection uncertainty p95 above max_uncertainty_px (0.5 px)
//                                                                         -> more views near the
//                                                                         edges
//   correlated errors    corner errors shared across views make fx's sigma more than
//                        max_correlated_sigma_ratio (1.5) x the standard covariance's
//                        (CalibrationResult::intrinsics_covariance_view_correlated)
//                                                                         -> quote that covariance;
//                                                                         check focus, print
#pragma once

#include <string>
#include <vector>

#include "calib/calibration.h"

namespace slshadow {

enum class Severity { kInfo, kWarning, kError };
std::string ToString(Severity s);  // "info", "warning", "error"

struct Finding {
  Severity severity = Severity::kWarning;
  std::string device;        // device name, or empty for the whole data set
  std::string problem;       // what is wrong, with the measured value
  std::string advice;        // what to capture or change next
  std::string Text() const;  // "warning: left: problem; advice"
};

// What is known about one captured image before calibration.
struct ImageCheck {
  std::string label;  // image file
  int device = 0;
  bool found = true;
  std::string reason;  // why not found
  double saturated_fraction = 0;
};

struct GuidanceOptions {
  int min_views = 10;
  double min_tilt_deg = 15;
  double min_coverage = 0.55;
  double max_saturated = 0.02;
  double max_rms_px = 1.0;
  double max_uncertainty_px = 0.5;
  double max_correlated_sigma_ratio = 1.5;
};

// Reviews a calibration (input, result and the per-image checks). Findings are ordered by
// severity (errors first).
std::vector<Finding> ReviewCalibration(const CalibrationInput& input,
                                       const CalibrationResult& result,
                                       const std::vector<ImageCheck>& images,
                                       const GuidanceOptions& options = {});

// Share (0..1) of the device's image cells (an 8 x 6 grid) holding at least one observed point.
double ImageCoverage(const CalibrationInput& input, int device);

// Angle between the board's normal and the device's optical axis for each of the device's
// views with a pose, degrees.
std::vector<double> BoardTiltsDeg(const CalibrationInput& input, const CalibrationResult& result,
                                  int device);

}  // namespace slshadow
