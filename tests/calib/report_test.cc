#include "calib/report.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "calib/synthetic.h"
#include "core/file_util.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

TEST(CalibrationReport, WritesSummaryTextAndCharts) {
  testing::TempDir tmp;
  SyntheticData data = MakeSyntheticData(SyntheticRig::Stereo(), 10, 0.2, 9);
  auto& bad = data.input.views[5].pixels_px;  // an outlier view: corners jittered by 1.8 px
  for (size_t i = 0; i < bad.size(); ++i)
    bad[i] += Eigen::Vector2d(1.5, -1.0) * (static_cast<double>(i % 3) - 1.0);
  const CalibrationOptions options;
  const CalibrationResult result = Calibrate(data.input, options);
  CalibrationReport report;
  report.input = &data.input;
  report.options = &options;
  report.result = &result;
  report.cross_validation = CrossValidate(data.input, options);
  report.findings = ReviewCalibration(data.input, result, {});
  report.extra = {{"command", "test"}};
  const auto dir = tmp / "report";
  WriteCalibrationReport(dir, report);
  for (const char* f : {"summary.json", "report.txt", "per_view_rms.png", "residuals_cam0.png",
                        "residuals_cam1.png", "uncertainty_cam0.png", "uncertainty_cam1.png",
                        "cross_validation_cam0.png", "cross_validation_cam1.png"}) {
    EXPECT_TRUE(std::filesystem::exists(dir / f)) << f;
  }
  const cv::Mat png = cv::imread((dir / "uncertainty_cam0.png").string());
  ASSERT_FALSE(png.empty());
  EXPECT_GT(png.cols, 500);
  // Not a blank page: the heat map has many colours.
  cv::Mat hsv;
  cv::cvtColor(png, hsv, cv::COLOR_BGR2HSV);
  std::vector<cv::Mat> ch;
  cv::split(hsv, ch);
  double sat_max = 0;
  cv::minMaxLoc(ch[1], nullptr, &sat_max);
  EXPECT_GT(sat_max, 100);
  const nlohmann::json j = nlohmann::json::parse(ReadTextFile(dir / "summary.json"));
  EXPECT_EQ(j["summary"]["views"].size(), data.input.views.size());
  EXPECT_TRUE(j["summary"]["views"][5]["outlier"].get<bool>());
  EXPECT_EQ(j["cross_validation"].size(), 2u);
  EXPECT_EQ(j["devices_result"][1]["params_sigma"].size(), 9u);
  EXPECT_EQ(j["extra"]["command"], "test");
  const std::string text = ReadTextFile(dir / "report.txt");
  EXPECT_NE(text.find("OUTLIER"), std::string::npos);
  EXPECT_NE(text.find("baseline"), std::string::npos);
  // Rewriting replaces the folder; refusing to overwrite throws and keeps it.
  WriteCalibrationReport(dir, report);
  EXPECT_THROW(WriteCalibrationReport(dir, report, false), std::exception);
  EXPECT_TRUE(std::filesystem::exists(dir / "summary.json"));
}

// Which covariance the report quotes (PreferredCovariance): with independent corner errors the
// standard one, unchanged; with errors shared across each view (0.5 px waves across the board,
// as in guidance_test) the view-correlated one, and the uncertainty map widens accordingly.
TEST(CalibrationReport, QuotesTheViewCorrelatedCovarianceOnlyWhenErrorsCorrelate) {
  const CalibrationOptions options;
  for (const bool waves : {false, true}) {
    SyntheticData data = MakeSyntheticData(SyntheticRig::OneCamera(), 15, 0.1, 2);
    for (auto& v : data.input.views) {
      for (size_t i = 0; waves && i < v.pixels_px.size(); ++i) {
        const double s = 0.02 * v.points_in_board_mm[i].x() + 0.7 * v.pose,
                     t = 0.025 * v.points_in_board_mm[i].y() - 0.4 * v.pose;
        v.pixels_px[i] += 0.5 * Eigen::Vector2d(std::sin(s + t), std::cos(s - t));
      }
    }
    const CalibrationResult result = Calibrate(data.input, options);
    CalibrationReport report;
    report.input = &data.input;
    report.options = &options;
    report.result = &result;
    const nlohmann::json j = CalibrationReportJson(report);
    const auto& dev = j["devices_result"][0];
    const QuotedCovariance q = PreferredCovariance(result, 0);
    ASSERT_TRUE(q.available);
    EXPECT_EQ(q.view_correlated, waves) << q.reason;
    EXPECT_EQ(dev["covariance_used"], waves ? "view-correlated" : "standard");
    EXPECT_EQ(dev["covariance_reason"], q.reason);
    const Matrix9d& standard = result.intrinsics_covariance[0];
    const PixelMap standard_map = ProjectionUncertaintyMap(result.devices[0].model, standard, 16);
    const double used_median = dev["projection_uncertainty"]["median_px"].get<double>();
    std::printf(
        "%s: %s; uncertainty median %.4f px (standard %.4f px, x%.2f), fx sigma %.4f (standard "
        "%.4f)\n",
        waves ? "waves" : "independent", q.reason.c_str(), used_median, standard_map.median,
        used_median / standard_map.median, dev["params_sigma"][0].get<double>(),
        dev["params_sigma_standard"][0].get<double>());
    for (int i = 0; i < CameraModel::kNumParams; ++i) {
      EXPECT_EQ(dev["params_sigma_standard"][i].get<double>(), std::sqrt(standard(i, i)));
      if (!waves) {
        EXPECT_EQ(dev["params_sigma"][i].get<double>(), std::sqrt(standard(i, i)));  // unchanged
      }
    }
    if (!waves) {
      EXPECT_EQ(used_median, standard_map.median);
    } else {
      const Matrix9d& vc = result.intrinsics_covariance_view_correlated.at(0);
      EXPECT_EQ(dev["params_sigma"][0].get<double>(), std::sqrt(vc(0, 0)));
      EXPECT_GT(q.fx_sigma_ratio, 1.5);
      EXPECT_GT(used_median, 1.5 * standard_map.median);
      EXPECT_EQ(used_median, ProjectionUncertaintyMap(result.devices[0].model, vc, 16).median);
    }
  }
}

}  // namespace
}  // namespace slshadow
