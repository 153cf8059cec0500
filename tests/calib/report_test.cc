#include "calib/report.h"

#include <gtest/gtest.h>

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
  for (size_t i = 0; i < bad.size(); ++i) bad[i] += Eigen::Vector2d(1.5, -1.0) * (static_cast<double>(i % 3) - 1.0);
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
  for (const char* f : {"summary.json", "report.txt", "per_view_rms.png", "residuals_cam0.png", "residuals_cam1.png",
                        "uncertainty_cam0.png", "uncertainty_cam1.png", "cross_validation_cam0.png", "cross_validation_cam1.png"}) {
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

}  // namespace
}  // namespace slshadow
