// plot/: the heat colour map against its control points, and charts drawn through each stream
// read back: a bar in a PNG (decoded by OpenCV) against the axes' range, a colour bar with a
// mark drawn over a caller's RGB buffer, an SVG. The oracle is where PLplot's viewport and window
// put a value: column = (vx0 + (vx1 - vx0) (x - wx0) / (wx1 - wx0)) width, likewise rows from
// the bottom.
#include "plot/plot.h"

#include <chrono>
#include <cmath>
#include <fstream>
#include <future>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "tests/testing/chart_readback.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::plot {
namespace {

using Rgb = std::array<uint8_t, 3>;

TEST(HeatColor, ControlPointsMidpointsAndClamping) {
  EXPECT_EQ(HeatColor(0.0), (Rgb{0, 0, 255}));
  EXPECT_EQ(HeatColor(0.25), (Rgb{0, 255, 255}));
  EXPECT_EQ(HeatColor(0.5), (Rgb{0, 255, 0}));
  EXPECT_EQ(HeatColor(0.75), (Rgb{255, 255, 0}));
  EXPECT_EQ(HeatColor(1.0), (Rgb{255, 0, 0}));
  // Linear between stops, rounded half away from zero (127.5 -> 128).
  EXPECT_EQ(HeatColor(0.125), (Rgb{0, 128, 255}));
  EXPECT_EQ(HeatColor(0.625), (Rgb{128, 255, 0}));
  EXPECT_EQ(HeatColor(0.9), (Rgb{255, 102, 0}));
  EXPECT_EQ(HeatColor(-3.0), HeatColor(0.0));
  EXPECT_EQ(HeatColor(7.0), HeatColor(1.0));
  EXPECT_EQ(HeatColor(std::numeric_limits<double>::quiet_NaN()), (Rgb{0, 255, 0}));
  // Infinities clamp like any value outside [0, 1] (they were drawn green, the NaN colour).
  EXPECT_EQ(HeatColor(std::numeric_limits<double>::infinity()), HeatColor(1.0));
  EXPECT_EQ(HeatColor(-std::numeric_limits<double>::infinity()), HeatColor(0.0));
}

// A filled bar x 2..4, y 0..60 in a window 0..10 x 0..100 on the viewport 0.1..0.9 of a 400 x
// 300 px page, framed by the box of the axes: frame and bar land on the columns and rows the
// window maps them to, in the palette's colour.
TEST(OpenPng, BarAndAxesLandWhereTheWindowMapsThem) {
  testing::TempDir dir;
  const auto file = dir / "bar.png";
  constexpr int kW = 400, kH = 300;
  const Rgb bar{200, 30, 40};
  {
    const auto lock = LockPlplot();
    auto pls = OpenPng(file, kW, kH, {{bar[0], bar[1], bar[2]}});
    pls->adv(0);
    pls->vpor(0.1, 0.9, 0.1, 0.9);
    pls->wind(0, 10, 0, 100);
    pls->box("bc", 0, 0, "bc", 0, 0);
    pls->col0(2);
    PLFLT xs[4] = {2, 4, 4, 2}, ys[4] = {0, 0, 60, 60};
    pls->fill(4, xs, ys);
  }
  const cv::Mat png = cv::imread(file.string(), cv::IMREAD_COLOR);
  ASSERT_FALSE(png.empty()) << file;
  EXPECT_EQ(png.cols, kW);
  EXPECT_EQ(png.rows, kH);
  const auto column = [](double x) { return (0.1 + 0.8 * x / 10) * kW; };
  const auto row = [](double y) { return (1 - (0.1 + 0.8 * y / 100)) * kH; };
  const auto frame = testing::FindChartFrame(png);
  ASSERT_TRUE(frame.has_value());
  EXPECT_NEAR(frame->left, column(0), 1.5);
  EXPECT_NEAR(frame->right, column(10), 1.5);
  EXPECT_NEAR(frame->top, row(100), 1.5);
  EXPECT_NEAR(frame->bottom, row(0), 1.5);
  // The bar: its colour at its centre, its edges (the run of that colour through the centre).
  const int cx = static_cast<int>(column(3)), cy = static_cast<int>(row(30));
  const testing::ColourRun run = testing::RunThrough(png, cx, cy, bar, 2);
  ASSERT_GE(run.top, 0) << "not the bar's colour at its centre: " << png.at<cv::Vec3b>(cy, cx);
  EXPECT_NEAR(run.top, row(60), 1.5);
  EXPECT_NEAR(run.bottom + 1, row(0), 1.5);
  EXPECT_NEAR(run.left, column(2), 1.5);
  EXPECT_NEAR(run.right + 1, column(4), 1.5);
  // Background white outside the bar and inside the frame.
  EXPECT_TRUE(
      testing::IsColour(png.at<cv::Vec3b>(static_cast<int>(row(80)), cx), {255, 255, 255}, 0));
}

// The heat colour bar with a mark, drawn over a caller's buffer filled beforehand: what was
// there stays where nothing is drawn, the bar's colour at a value is the heat map's colour of that
// value, the mark is a black line at its value.
TEST(OpenRgbMemory, ColourBarShowsTheHeatMapAndItsMarkOverTheCallersImage) {
  constexpr int kW = 500, kH = 400;
  std::vector<uint8_t> rgb(static_cast<size_t>(kW) * kH * 3);
  for (size_t i = 0; i < rgb.size(); i += 3) {
    rgb[i] = 10;
    rgb[i + 1] = 20;
    rgb[i + 2] = 30;
  }
  constexpr double kLo = 0, kHi = 10, kMark = 2.5;
  {
    const auto lock = LockPlplot();
    auto pls = OpenRgbMemory(rgb.data(), kW, kH, {});
    SetHeatColorMap(*pls);
    pls->adv(0);
    pls->vpor(0.1, 0.7, 0.1, 0.9);
    pls->wind(0, 1, 0, 1);
    HeatColorBar(*pls, kLo, kHi, "mm", 0.05, 0.05, {kMark});
  }
  const auto at = [&](double x_norm, double y_norm) {
    const size_t x = static_cast<size_t>(x_norm * kW), y = static_cast<size_t>((1 - y_norm) * kH);
    const size_t i = (y * kW + x) * 3;
    return Rgb{rgb[i], rgb[i + 1], rgb[i + 2]};
  };
  EXPECT_EQ(at(0.02, 0.98), (Rgb{10, 20, 30}));  // a corner: nothing drawn, nothing cleared
  // The bar spans x 0.75..0.80 and y 0.14..0.86 (5 % of the viewport's height in from each end).
  const auto y_of = [](double v) { return 0.14 + 0.72 * (v - kLo) / (kHi - kLo); };
  for (const double v : {1.3, 3.7, 5.3, 6.7, 8.3}) {  // off the axis ticks (every 0.5)
    const Rgb got = at(0.775, y_of(v)), want = HeatColor((v - kLo) / (kHi - kLo));
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(got[static_cast<size_t>(k)], want[static_cast<size_t>(k)], 6)
          << "value " << v << " channel " << k;
    }
  }
  // The mark: the darkest row of the bar's centre column within 8 px of its value (the ticks at
  // 2 and 3 are 14 px away) is black and at its value.
  int darkest_row = -1, darkest = 3 * 256;
  const size_t x = static_cast<size_t>(0.775 * kW);
  const double mark_row = (1 - y_of(kMark)) * kH;
  for (int y = static_cast<int>(mark_row) - 8; y <= static_cast<int>(mark_row) + 8; ++y) {
    const size_t i = (static_cast<size_t>(y) * kW + x) * 3;
    const int sum = rgb[i] + rgb[i + 1] + rgb[i + 2];
    if (sum < darkest) {
      darkest = sum;
      darkest_row = y;
    }
  }
  EXPECT_LT(darkest, 3 * 60);
  EXPECT_NEAR(darkest_row, mark_row, 2.0);
}

TEST(OpenSvg, WritesAVectorDrawingOfThePageSize) {
  testing::TempDir dir;
  const auto file = dir / "chart.svg";
  {
    const auto lock = LockPlplot();
    auto pls = OpenSvg(file, 320, 240, {{0, 128, 0}});
    pls->adv(0);
    pls->vpor(0.1, 0.9, 0.1, 0.9);
    pls->wind(0, 1, 0, 1);
    pls->box("bc", 0, 0, "bc", 0, 0);
  }
  std::ifstream in(file);
  std::stringstream text;
  text << in.rdbuf();
  EXPECT_NE(text.str().find("<svg"), std::string::npos);
  EXPECT_NE(text.str().find("width=\"320pt\""), std::string::npos) << text.str().substr(0, 400);
  EXPECT_NE(text.str().find("<path"), std::string::npos);
}

TEST(LockPlplot, HoldsOffOtherThreadsUntilReleased) {
  auto lock = LockPlplot();
  auto other = std::async(std::launch::async, [] { return LockPlplot().owns_lock(); });
  EXPECT_EQ(other.wait_for(std::chrono::milliseconds(100)), std::future_status::timeout);
  lock.unlock();
  EXPECT_TRUE(other.get());
}

}  // namespace
}  // namespace slshadow::plot
