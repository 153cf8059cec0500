#include "calib/guidance.h"

#include <gtest/gtest.h>

#include <cmath>

#include "calib/synthetic.h"

namespace slshadow {
namespace {

bool Has(const std::vector<Finding>& f, const std::string& needle) {
  for (const auto& x : f) {
    if (x.Text().find(needle) != std::string::npos) return true;
  }
  return false;
}

std::string All(const std::vector<Finding>& f) {
  std::string s;
  for (const auto& x : f) s += x.Text() + "\n";
  return s;
}

TEST(Guidance, GoodDataGivesNoWarnings) {
  const SyntheticData data = MakeSyntheticData(SyntheticRig::OneCamera(), 15, 0.1, 2);
  const CalibrationResult r = Calibrate(data.input, {});
  const auto f = ReviewCalibration(data.input, r, {});
  EXPECT_TRUE(f.empty()) << All(f);
  EXPECT_GT(ImageCoverage(data.input, 0), 0.55);
}

// Corner errors shared across each view (0.5 px waves across the board): the review says the
// standard covariance is optimistic and by how much.
TEST(Guidance, CorrelatedCornerErrors) {
  SyntheticData data = MakeSyntheticData(SyntheticRig::OneCamera(), 15, 0.1, 2);
  for (auto& v : data.input.views) {
    for (size_t i = 0; i < v.pixels_px.size(); ++i) {
      const double s = 0.02 * v.points_in_board_mm[i].x() + 0.7 * v.pose,
                   t = 0.025 * v.points_in_board_mm[i].y() - 0.4 * v.pose;
      v.pixels_px[i] += 0.5 * Eigen::Vector2d(std::sin(s + t), std::cos(s - t));
    }
  }
  const auto f = ReviewCalibration(data.input, Calibrate(data.input, {}), {});
  EXPECT_TRUE(Has(f, "corner errors are correlated across each view")) << All(f);
}

TEST(Guidance, TooFewViews) {
  const SyntheticData data = MakeSyntheticData(SyntheticRig::OneCamera(), 5, 0.1, 2);
  const auto f = ReviewCalibration(data.input, Calibrate(data.input, {}), {});
  EXPECT_TRUE(Has(f, "too few views")) << All(f);
  EXPECT_TRUE(Has(f, "capture at least 10")) << All(f);
}

TEST(Guidance, FrontoParallelBoards) {
  SyntheticRig rig = SyntheticRig::OneCamera();
  rig.max_tilt_rad = 0.12;
  const SyntheticData data = MakeSyntheticData(rig, 12, 0.1, 4);
  const CalibrationResult r = Calibrate(data.input, {});
  const auto tilts = BoardTiltsDeg(data.input, r, 0);
  ASSERT_EQ(tilts.size(), 12u);
  EXPECT_LT(*std::max_element(tilts.begin(), tilts.end()), 15.0);
  const auto f = ReviewCalibration(data.input, r, {});
  EXPECT_TRUE(Has(f, "fronto-parallel")) << All(f);
  EXPECT_TRUE(Has(f, "tilted 20-40 deg")) << All(f);
}

TEST(Guidance, CornersOnlyInTheCentre) {
  SyntheticRig rig = SyntheticRig::OneCamera();
  rig.distance_mm = 1500;  // a 300 mm board at 1.5 m covers the middle of the image only
  rig.shift_fraction = 0.03;
  const SyntheticData data = MakeSyntheticData(rig, 12, 0.1, 6);
  const CalibrationResult r = Calibrate(data.input, {});
  EXPECT_LT(ImageCoverage(data.input, 0), 0.4);
  const auto f = ReviewCalibration(data.input, r, {});
  EXPECT_TRUE(Has(f, "corners only in the centre")) << All(f);
  EXPECT_TRUE(Has(f, "near each image corner")) << All(f);
}

TEST(Guidance, SaturatedAndMissingImagesAndOutliers) {
  SyntheticData data = MakeSyntheticData(SyntheticRig::OneCamera(), 12, 0.1, 8);
  for (auto& px : data.input.views[3].pixels_px)
    px += Eigen::Vector2d(1.5, -1.0) * ((&px - &data.input.views[3].pixels_px[0]) % 3 - 1);
  const CalibrationResult r = Calibrate(data.input, {});
  std::vector<ImageCheck> images = {{"a.png", 0, true, "", 0.15},
                                    {"b.png", 0, false, "9x6 chessboard not found", 0.0}};
  const auto f = ReviewCalibration(data.input, r, images);
  EXPECT_TRUE(Has(f, "saturated image")) << All(f);
  EXPECT_TRUE(Has(f, "a.png")) << All(f);
  EXPECT_TRUE(Has(f, "lower the exposure")) << All(f);
  EXPECT_TRUE(Has(f, "board not found in b.png")) << All(f);
  EXPECT_TRUE(Has(f, "outlier view cam0/pose3")) << All(f);
  // Warnings come before infos.
  EXPECT_EQ(f.back().severity, Severity::kInfo);
}

}  // namespace
}  // namespace slshadow
