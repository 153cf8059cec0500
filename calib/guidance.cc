#include "calib/guidance.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "calib/uncertainty.h"
#include "core/string_printf.h"

namespace slshadow {
std::string ToString(Severity s) {
  switch (s) {
    case Severity::kInfo:
      return "info";
    case Severity::kWarning:
      return "warning";
    case Severity::kError:
      return "error";
  }
  return "?";
}

std::string Finding::Text() const {
  return ToString(severity) + ": " + (device.empty() ? "" : device + ": ") + problem + "; " +
         advice;
}

double ImageCoverage(const CalibrationInput& input, int device) {
  const auto& dev = input.devices[static_cast<size_t>(device)];
  constexpr int kCols = 8, kRows = 6;
  bool cell[kRows][kCols] = {};
  for (const auto& v : input.views) {
    if (v.device != device) continue;
    for (const auto& p : v.pixels_px) {
      const int c = std::clamp(static_cast<int>((p.x() + 0.5) / dev.width * kCols), 0, kCols - 1);
      const int r = std::clamp(static_cast<int>((p.y() + 0.5) / dev.height * kRows), 0, kRows - 1);
      cell[r][c] = true;
    }
  }
  int n = 0;
  for (const auto& row : cell) {
    for (bool b : row) n += b;
  }
  return static_cast<double>(n) / (kCols * kRows);
}

std::vector<double> BoardTiltsDeg(const CalibrationInput& input, const CalibrationResult& result,
                                  int device) {
  std::vector<double> tilts;
  for (const auto& v : input.views) {
    if (v.device != device || !result.rig_from_board[static_cast<size_t>(v.pose)]) continue;
    const Rigid3d dev_from_board = result.devices[static_cast<size_t>(device)].cam_from_rig *
                                   *result.rig_from_board[static_cast<size_t>(v.pose)];
    const Eigen::Vector3d normal = dev_from_board.rotation * Eigen::Vector3d::UnitZ();
    tilts.push_back(std::acos(std::min(1.0, std::abs(normal.z()))) * 180.0 / M_PI);
  }
  return tilts;
}

std::vector<Finding> ReviewCalibration(const CalibrationInput& input,
                                       const CalibrationResult& result,
                                       const std::vector<ImageCheck>& images,
                                       const GuidanceOptions& o) {
  std::vector<Finding> out;
  for (size_t d = 0; d < input.devices.size(); ++d) {
    const std::string& name = input.devices[d].name;
    const int di = static_cast<int>(d);
    int views = 0;
    for (const auto& v : input.views) views += v.device == di;
    if (views < o.min_views) {
      out.push_back(
          {views < 4 ? Severity::kError : Severity::kWarning, name,
           std::to_string(views) +
               " views (too few views: intrinsics and distortion are poorly determined)",
           "capture at least " + std::to_string(o.min_views) +
               " poses of the board, tilted in different directions and spread over the image"});
    }
    const auto tilts = BoardTiltsDeg(input, result, di);
    if (!tilts.empty()) {
      const double max_tilt = *std::max_element(tilts.begin(), tilts.end());
      if (max_tilt < o.min_tilt_deg) {
        out.push_back(
            {Severity::kWarning, name,
             StringPrintf("all boards nearly fronto-parallel (largest tilt %.1f deg): focal "
                          "length and distance trade "
                          "off, the focal length is poorly determined",
                          max_tilt),
             "capture views with the board tilted 20-40 deg about its horizontal and its "
             "vertical axis"});
      }
    }
    const double coverage = ImageCoverage(input, di);
    if (coverage < o.min_coverage) {
      out.push_back(
          {Severity::kWarning, name,
           StringPrintf(
               "corners cover only %.0f%% of the image (corners only in the centre): distortion "
               "towards the "
               "edges is extrapolated",
               100 * coverage),
           "capture views with the board near each image corner and edge, filling the image"});
    }
    if (d < result.summary.devices.size() && result.summary.devices[d].rms_px > o.max_rms_px) {
      out.push_back(
          {Severity::kWarning, name,
           StringPrintf("RMS reprojection error %.2f px is high", result.summary.devices[d].rms_px),
           "check the target's square size, focus and motion blur, and the outlier views"});
    }
    // Corner errors shared across a view: how much wider is the focal length's sigma? The same
    // criterion picks the covariance the report's sigmas and uncertainty maps use.
    const QuotedCovariance quoted =
        PreferredCovariance(result, static_cast<int>(d), o.max_correlated_sigma_ratio);
    if (quoted.view_correlated) {
      const auto& k = result.summary.view_noise[d];
      out.push_back(
          {Severity::kWarning, name,
           StringPrintf(
               "corner errors are correlated across each view (share %.2f over %.1f board squares)",
               k.share, k.length_squares) +
               StringPrintf(": with them the focal length's sigma is %.1fx the independent-error "
                            "covariance's",
                            quoted.fx_sigma_ratio),
           "the report's sigmas and uncertainty maps use the view-correlated covariance (rig file: "
           "calibration.intrinsics_covariance_view_correlated); quote it or the cross-validation; "
           "check focus, motion blur, the board's print and flatness"});
    }
    if (quoted.available && quoted.covariance.norm() > 0) {
      const PixelMap u = ProjectionUncertaintyMap(result.devices[d].model, quoted.covariance, 32);
      if (u.p95 > o.max_uncertainty_px) {
        out.push_back(
            {Severity::kWarning, name,
             StringPrintf(
                 "projection uncertainty reaches %.2f px (95th percentile over the image, median "
                 "%.2f px; ",
                 u.p95, u.median) +
                 (quoted.view_correlated ? "view-correlated covariance)" : "standard covariance)"),
             "capture more views, especially with the board near the image edges where it is "
             "largest"});
      }
    }
  }
  for (const auto& v : result.summary.views) {
    if (!v.outlier) continue;
    out.push_back(
        {Severity::kWarning, input.devices[static_cast<size_t>(v.device)].name,
         "outlier view " + v.label +
             StringPrintf(" (RMS %.2f px, worst point %.2f px)", v.rms_px, v.max_px),
         "look at that image (blur, mis-detected corner, board moved during the capture); "
         "recapture or drop it"});
  }
  for (const auto& im : images) {
    const std::string dev = im.device < static_cast<int>(input.devices.size())
                                ? input.devices[static_cast<size_t>(im.device)].name
                                : "";
    if (!im.found) {
      out.push_back({Severity::kInfo, dev, "board not found in " + im.label + ": " + im.reason,
                     "the image is not used"});
    }
    if (im.saturated_fraction > o.max_saturated) {
      out.push_back({Severity::kWarning, dev,
                     StringPrintf("saturated image: %.1f%% of the pixels at the sensor maximum in ",
                                  100 * im.saturated_fraction) +
                         im.label,
                     "lower the exposure time or the light; saturated corners are biased"});
    }
  }
  std::stable_sort(out.begin(), out.end(), [](const Finding& a, const Finding& b) {
    return static_cast<int>(a.severity) > static_cast<int>(b.severity);
  });
  return out;
}

}  // namespace slshadow
