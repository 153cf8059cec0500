#include "compare/report.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <limits>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "tests/compare/test_shapes.h"
#include "tests/testing/chart_readback.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::compare {
namespace {

using testing::IcoSphere;

bool IsPng(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  char sig[8] = {};
  in.read(sig, 8);
  return in && std::string(sig + 1, 3) == "PNG";
}

CompareResult SmallResult() {
  const TriangleMesh mesh = IcoSphere(20.0, 3);
  const Reference ref = ReferenceFromMesh(mesh, "sphere.stl", 20000);
  PointCloud cloud;
  std::mt19937 rng(51);
  std::normal_distribution<double> noise(0.0, 0.1);
  for (const auto& p : ReferenceFromMesh(mesh, "s", 30000).cloud.points) {
    if (p.z() > -5) cloud.points.push_back(p * (1.0 + noise(rng) / 20.0));
  }
  return Compare(cloud, ref, CompareOptions{}, "noisy.ply");
}

TEST(WriteReport, WritesEveryFileAndTheJsonSchema) {
  slshadow::testing::TempDir tmp;
  const CompareResult r = SmallResult();
  WriteReport(tmp / "report", r);
  for (const char* f :
       {"report.json", "compared.ply", "histogram.png", "deviation_map.png", "summary.txt"}) {
    EXPECT_TRUE(std::filesystem::exists(tmp / "report" / f)) << f;
  }
  EXPECT_TRUE(IsPng(tmp / "report" / "histogram.png"));
  EXPECT_TRUE(IsPng(tmp / "report" / "deviation_map.png"));
  const auto j = nlohmann::json::parse(ReadTextFile(tmp / "report" / "report.json"));
  for (const char* k : {"count", "mean_mm", "std_mm", "rms_mm", "median_mm", "p95_mm", "max_mm",
                        "threshold_mm", "inliers", "outliers", "coverage"}) {
    EXPECT_TRUE(j["c2c"].contains(k)) << k;
  }
  EXPECT_EQ(j["c2c"]["count"].get<size_t>(), r.c2c.count);
  EXPECT_DOUBLE_EQ(j["c2c"]["rms_mm"].get<double>(), r.c2c.rms_mm);
  EXPECT_EQ(j["registration"]["method"], "none");
  EXPECT_EQ(j["registration"]["transform"].size(), 4u);
  EXPECT_TRUE(j["registration"].contains("rmse_mm"));
  EXPECT_TRUE(j.contains("c2m"));
  // The PLY carries the deviation field bit-for-bit (as float) and colours.
  const PointCloud back = ReadPly(tmp / "report" / "compared.ply");
  ASSERT_EQ(back.size(), r.compared.size());
  ASSERT_NE(back.Scalar("deviation"), nullptr);
  for (size_t i = 0; i < back.size(); i += 97) {
    EXPECT_EQ((*back.Scalar("deviation"))[i], static_cast<float>(r.deviations_mm[i]));
  }
  EXPECT_TRUE(back.HasColors());
  // Positions as float (the sphere is far below 8192 mm): within 2^-11 mm, i.e. 1 um fidelity.
  for (size_t i = 0; i < back.size(); ++i) {
    ASSERT_EQ(back.points[i], r.compared.points[i].cast<float>().cast<double>());
    ASSERT_LE((back.points[i] - r.compared.points[i]).cwiseAbs().maxCoeff(), std::ldexp(1.0, -11));
  }
}

// Coordinates of 8192 mm or more keep double positions (float would round them by > 0.49 um).
TEST(WriteReport, FarCoordinatesKeepDoublePositions) {
  slshadow::testing::TempDir tmp;
  CompareResult r = SmallResult();
  r.compared.points[7].x() += 9000.0;
  WriteReport(tmp / "report", r);
  const PointCloud back = ReadPly(tmp / "report" / "compared.ply");
  ASSERT_EQ(back.size(), r.compared.size());
  for (size_t i = 0; i < back.size(); ++i) ASSERT_EQ(back.points[i], r.compared.points[i]);
}

TEST(WriteReport, RefusesToOverwriteWhenAskedAndLeavesTheOldReport) {
  slshadow::testing::TempDir tmp;
  const CompareResult r = SmallResult();
  WriteReport(tmp / "out", r);
  const std::string before = ReadTextFile(tmp / "out" / "summary.txt");
  ReportOptions o;
  o.overwrite = false;
  EXPECT_THROW(WriteReport(tmp / "out", r, o), Error);
  EXPECT_EQ(ReadTextFile(tmp / "out" / "summary.txt"), before);
  // No staging folders left behind.
  size_t entries = 0;
  for ([[maybe_unused]] const auto& e : std::filesystem::directory_iterator(tmp.path())) ++entries;
  EXPECT_EQ(entries, 1u);
}

TEST(FitView, EveryPointProjectsInsideTheImage) {
  const CompareResult r = SmallResult();
  const ViewCamera v = FitView(r.compared, 800);
  for (const auto& p : r.compared.points) {
    const auto px = v.camera.Project(v.cam_from_reference * p);
    ASSERT_TRUE(px.has_value());
    EXPECT_TRUE(v.camera.IsInImage(*px));
  }
}

TEST(RenderValues, APointLandsOnItsPixelWithItsValue) {
  ViewCamera v;
  v.camera = CameraModel(64, 48, 50, 50, 31.5, 23.5);
  const std::vector<Eigen::Vector3d> pts = {{0, 0, 100}, {0.0, 0.0, 50}, {20, 10, 100}};
  const std::vector<double> vals = {1.0, 2.0, 3.0};
  const ValueImage img = RenderValues(pts, vals, v, 1);
  auto at = [&](int x, int y) { return img.values[static_cast<size_t>(y * 64 + x)]; };
  EXPECT_EQ(at(32, 24), 2.0f);  // the nearer point wins the z-buffer
  EXPECT_EQ(at(41, 28), 3.0f);  // (20, 10, 100) -> (31.5 + 10, 23.5 + 5)
  EXPECT_TRUE(std::isnan(at(5, 5)));
}

// The colour map: its five stops exactly, and in between the linear interpolation rounded half
// away from zero (std::lround), on a dense sweep of t.
TEST(DeviationColor, StopsAndRoundedInterpolation) {
  EXPECT_EQ(DeviationColor(0.0), (std::array<uint8_t, 3>{0, 0, 255}));
  EXPECT_EQ(DeviationColor(0.25), (std::array<uint8_t, 3>{0, 255, 255}));
  EXPECT_EQ(DeviationColor(0.5), (std::array<uint8_t, 3>{0, 255, 0}));
  EXPECT_EQ(DeviationColor(0.75), (std::array<uint8_t, 3>{255, 255, 0}));
  EXPECT_EQ(DeviationColor(1.0), (std::array<uint8_t, 3>{255, 0, 0}));
  EXPECT_EQ(DeviationColor(-3.0), DeviationColor(0.0));
  EXPECT_EQ(DeviationColor(7.0), DeviationColor(1.0));
  EXPECT_EQ(DeviationColor(std::numeric_limits<double>::quiet_NaN()), DeviationColor(0.5));
  const double stops[5][4] = {{0.00, 0, 0, 255},
                              {0.25, 0, 255, 255},
                              {0.50, 0, 255, 0},
                              {0.75, 255, 255, 0},
                              {1.00, 255, 0, 0}};
  for (int j = 0; j <= 400000; ++j) {
    // Includes the t whose channel values land exactly on .5 (t = (k + 0.5) / 1020).
    const double t = j % 2 == 0 ? j / 400000.0 : (j % 1020 + 0.5) / 1020.0;
    int i = 0;
    while (i < 3 && t > stops[i + 1][0]) ++i;
    const double f = (t - stops[i][0]) / (stops[i + 1][0] - stops[i][0]);
    const std::array<uint8_t, 3> c = DeviationColor(t);
    for (int k = 0; k < 3; ++k) {
      const auto expected = static_cast<uint8_t>(
          std::lround(stops[i][k + 1] + f * (stops[i + 1][k + 1] - stops[i][k + 1])));
      ASSERT_EQ(c[static_cast<size_t>(k)], expected) << "t " << t << " channel " << k;
    }
  }
}

// The map's pixels are drawn one per image pixel in the heat colours, row 0 at the top (where the
// y axis has its 0), NaN pixels white. Image 400 x 200: the top-left quarter at the low end of the
// range (blue), the top-right above the range (clamped: red), the bottom-right in the middle
// (green), the bottom-left empty.
TEST(WriteDeviationMapPng, DrawsEachPixelInItsPlaceAndColour) {
  ValueImage img;
  img.width = 400;
  img.height = 200;
  img.values.assign(400 * 200, std::numeric_limits<float>::quiet_NaN());
  for (int y = 0; y < 200; ++y) {
    for (int x = 0; x < 400; ++x) {
      float& v = img.values[static_cast<size_t>(y * 400 + x)];
      if (y < 100) v = x < 200 ? -0.5f : 7.0f;
      if (y >= 100 && x >= 200) v = 0.0f;
    }
  }
  MapChart chart;
  chart.lo = -0.5;
  chart.hi = 0.5;
  chart.notes = {"a note"};
  const slshadow::testing::TempDir tmp;
  const auto path = tmp / "map.png";
  WriteDeviationMapPng(path, img, chart);
  const cv::Mat png = cv::imread(path.string(), cv::IMREAD_COLOR);  // BGR
  ASSERT_FALSE(png.empty());
  EXPECT_GT(png.cols, 400);
  EXPECT_GT(png.rows, 200);
  // Pixels of exactly one colour: their count and median position (the colour bar holds a few
  // of each too, far fewer than a 200 x 100 block).
  struct Found {
    size_t count = 0;
    int x = 0, y = 0;
  };
  const auto find = [&](int r, int g, int b) {
    std::vector<int> xs, ys;
    for (int y = 0; y < png.rows; ++y) {
      for (int x = 0; x < png.cols; ++x) {
        const cv::Vec3b c = png.at<cv::Vec3b>(y, x);
        if (c[2] == r && c[1] == g && c[0] == b) {
          xs.push_back(x);
          ys.push_back(y);
        }
      }
    }
    Found f;
    f.count = xs.size();
    if (xs.empty()) return f;
    std::nth_element(xs.begin(), xs.begin() + static_cast<long>(xs.size() / 2), xs.end());
    std::nth_element(ys.begin(), ys.begin() + static_cast<long>(ys.size() / 2), ys.end());
    f.x = xs[xs.size() / 2];
    f.y = ys[ys.size() / 2];
    return f;
  };
  const Found blue = find(0, 0, 255), red = find(255, 0, 0), green = find(0, 255, 0);
  const size_t block = 200 * 100;
  EXPECT_GE(blue.count, block * 95 / 100);
  EXPECT_LE(blue.count, block * 105 / 100);
  EXPECT_GE(red.count, block * 95 / 100);
  EXPECT_LE(red.count, block * 105 / 100);
  EXPECT_GE(green.count, block * 95 / 100);
  EXPECT_LE(green.count, block * 105 / 100);
  // Blue and red side by side on the top half, 200 px apart; green 100 px below red.
  EXPECT_NEAR(red.x - blue.x, 200, 2);
  EXPECT_NEAR(red.y, blue.y, 2);
  EXPECT_NEAR(green.x, red.x, 2);
  EXPECT_NEAR(green.y - red.y, 100, 2);
  // The empty quarter is white (left of green, level with it).
  const cv::Vec3b empty = png.at<cv::Vec3b>(green.y, blue.x);
  EXPECT_EQ(empty, cv::Vec3b(255, 255, 255));
}

// The histogram read back from its PNG: the axes box spans the bins' range (lo..hi) and 0..1.12
// times the peak count, so each bar stands on its bin's columns, reaches the row of its count
// and has the heat colour of its bin centre (unsigned: centre / hi); an empty bin draws nothing.
TEST(WriteHistogramPng, BarsStandOnTheirBinsAtTheirCountsInTheirColours) {
  Histogram h;
  h.lo_mm = 0;
  h.hi_mm = 1;
  h.counts = {0, 5, 20, 50, 100, 60, 30, 10, 0, 2};
  HistogramChart chart;
  chart.title = "deviation";
  chart.threshold_mm = 0.83;  // a dashed line in the empty bin 8, 15 px off its centre
  chart.notes = {"a note"};
  const slshadow::testing::TempDir tmp;
  const auto path = tmp / "histogram.png";
  WriteHistogramPng(path, h, chart);
  const cv::Mat png = cv::imread(path.string(), cv::IMREAD_COLOR);
  ASSERT_FALSE(png.empty());
  EXPECT_EQ(png.cols, chart.width_px);
  EXPECT_EQ(png.rows, chart.height_px);
  const auto frame = slshadow::testing::FindChartFrame(png);
  ASSERT_TRUE(frame.has_value());
  const double ymax = 100 * 1.12;
  const auto column = [&](double x) {
    return frame->left + (frame->right - frame->left) * (x - h.lo_mm) / (h.hi_mm - h.lo_mm);
  };
  const auto row = [&](double count) {
    return frame->bottom - (frame->bottom - frame->top) * count / ymax;
  };
  for (size_t i = 0; i < h.counts.size(); ++i) {
    SCOPED_TRACE("bin " + std::to_string(i));
    const double x0 = 0.1 * static_cast<double>(i), xc = x0 + 0.05;
    const int cx = static_cast<int>(std::lround(column(xc)));
    const int cy = static_cast<int>(std::lround(row(h.counts[i] / 2.0)));
    if (h.counts[i] == 0) {  // white halfway up (the axis' ticks stand at its foot)
      EXPECT_TRUE(slshadow::testing::IsColour(
          png.at<cv::Vec3b>(static_cast<int>(std::lround(row(ymax / 2))), cx), {255, 255, 255}, 0));
      continue;
    }
    if (h.counts[i] < 10) continue;  // a bar a few pixels high: too short to read a colour run
    const std::array<uint8_t, 3> colour = DeviationColor(xc / h.hi_mm);
    const slshadow::testing::ColourRun run = slshadow::testing::RunThrough(png, cx, cy, colour, 6);
    ASSERT_GE(run.top, 0) << "colour at the bar's centre " << png.at<cv::Vec3b>(cy, cx)
                          << ", expected RGB " << int{colour[0]} << " " << int{colour[1]} << " "
                          << int{colour[2]};
    // Inside its grey outline (one pixel, antialiased) and the axis.
    EXPECT_NEAR(run.top, row(static_cast<double>(h.counts[i])), 2.5);
    EXPECT_NEAR(run.bottom, frame->bottom, 2.5);
    EXPECT_NEAR(run.left, column(x0), 2.5);
    EXPECT_NEAR(run.right, column(x0 + 0.1), 2.5);
  }
}

}  // namespace
}  // namespace slshadow::compare
