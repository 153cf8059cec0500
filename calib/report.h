// The report folder of a calibration (what `slshadow calibrate ... --report DIR` writes), in the
// spirit of mrcal's "interpreting the results": not just the RMS, but where the residuals are,
// which views disagree, how uncertain the projection is across each image, and how two halves of
// the data agree. Layout (docs/formats.md, "Calibration report"):
//   summary.json                 summary, per device and per view statistics, findings,
//                                uncertainty and cross-validation statistics, options, inputs
//   report.txt                   FullReport() and the findings, as printed
//   per_view_rms.png             bar chart: RMS per view and device, outliers in red
//   residuals_<device>.png       residual vectors at the observed points, magnified
//   uncertainty_<device>.png     projection uncertainty map (px), rotation-compensated, from the
//                                covariance PreferredCovariance (calib/uncertainty.h) picks: the
//                                view-correlated one when corner errors correlate across views,
//                                else the standard one; summary.json and report.txt say which and
//                                why
//   cross_validation_<device>.png  projection difference of the two halves (px)
// The folder is written to a temporary sibling and renamed into place.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "calib/calibration.h"
#include "calib/guidance.h"
#include "calib/uncertainty.h"

namespace slshadow {

struct CalibrationReport {
  const CalibrationInput* input = nullptr;
  const CalibrationOptions* options = nullptr;
  const CalibrationResult* result = nullptr;
  std::optional<CrossValidation> cross_validation;
  std::vector<Finding> findings;
  nlohmann::json extra;  // free-form (command line, target, pattern spec), stored in summary.json
};

// The JSON summary alone (what summary.json holds).
nlohmann::json CalibrationReportJson(const CalibrationReport& report);

// Writes the whole folder; replaces an existing folder when `overwrite` (else throws).
void WriteCalibrationReport(const std::filesystem::path& dir, const CalibrationReport& report,
                            bool overwrite = true);

}  // namespace slshadow
