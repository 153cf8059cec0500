#include "calib/target.h"

#include <gtest/gtest.h>

#include <opencv2/aruco/charuco.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/config.h"
#include "core/error.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

TargetSpec Chessboard(int cols, int rows, double square_mm, ChessboardDetector det) {
  TargetSpec s;
  s.type = TargetType::kChessboard;
  s.cols = cols;
  s.rows = rows;
  s.square_size_mm = square_mm;
  s.detector = det;
  s.subpix_half_window_px = 5;
  return s;
}

// Renders a chessboard with (cols+1)x(rows+1) squares of `px` pixels, 8-bit, white margin of one
// square, so inner corner (c, r) lies at ((c + 2) * px - 0.5, (r + 2) * px - 0.5) in pixel centres.
cv::Mat RenderChessboard(int cols, int rows, int px) {
  cv::Mat img((rows + 3) * px, (cols + 3) * px, CV_8UC1, cv::Scalar(255));
  for (int r = 0; r < rows + 1; ++r) {
    for (int c = 0; c < cols + 1; ++c) {
      if ((r + c) % 2 == 0) img(cv::Rect((c + 1) * px, (r + 1) * px, px, px)).setTo(0);
    }
  }
  return img;
}

// Warps `board` by homography h into a w x h image, blurred a little like a lens.
cv::Mat Warp(const cv::Mat& board, const cv::Matx33d& hom, cv::Size size) {
  cv::Mat out;
  cv::warpPerspective(board, out, cv::Mat(hom), size, cv::INTER_AREA, cv::BORDER_CONSTANT,
                      cv::Scalar(255));
  cv::GaussianBlur(out, out, cv::Size(5, 5), 0.8);
  return out;
}

Eigen::Vector2d Apply(const cv::Matx33d& h, double x, double y) {
  const cv::Vec3d p = h * cv::Vec3d(x, y, 1);
  return {p[0] / p[2], p[1] / p[2]};
}

const cv::Matx33d kHom(0.9, 0.12, 60, -0.05, 0.85, 50, 0.0001, 0.00015, 1);

TEST(Target, ChessboardBothDetectorsFindWarpedCornersSubPixel) {
  const int px = 40;
  const cv::Mat board = RenderChessboard(9, 6, px);
  const cv::Mat image = Warp(board, kHom, cv::Size(640, 480));
  for (auto det : {ChessboardDetector::kSectorBased, ChessboardDetector::kClassic}) {
    const TargetSpec spec = Chessboard(9, 6, 25, det);
    const TargetDetection d = DetectTarget(spec, image);
    ASSERT_TRUE(d.found) << d.reason;
    ASSERT_EQ(d.pixels_px.size(), 54u);
    const auto board_points = BoardPoints(spec);
    // The corner order may start at either end of the board; it must follow the board points.
    const Eigen::Vector2d first = Apply(kHom, 2 * px - 0.5, 2 * px - 0.5);
    const Eigen::Vector2d last = Apply(kHom, 10 * px - 0.5, 7 * px - 0.5);
    const bool reversed =
        (d.pixels_px.front() - last).norm() < (d.pixels_px.front() - first).norm();
    double worst = 0;
    for (size_t i = 0; i < d.pixels_px.size(); ++i) {
      const int id = reversed ? 53 - d.point_ids[i] : d.point_ids[i];
      const Eigen::Vector3d& b = board_points[static_cast<size_t>(id)];
      const Eigen::Vector2d truth =
          Apply(kHom, (b.x() / 25 + 2) * px - 0.5, (b.y() / 25 + 2) * px - 0.5);
      worst = std::max(worst, (d.pixels_px[i] - truth).norm());
    }
    // The sector-based detector is the more accurate one on hard-edged renders.
    EXPECT_LT(worst, det == ChessboardDetector::kClassic ? 0.25 : 0.15)
        << (det == ChessboardDetector::kClassic ? "classic" : "sb");
  }
}

TEST(Target, SaturationIsMeasuredInsideTheBoard) {
  const cv::Mat bright =
      Warp(RenderChessboard(9, 6, 40), kHom, cv::Size(640, 480));  // white squares at 255
  cv::Mat dim;
  bright.convertTo(dim, CV_8U, 0.7, 20);  // 20..198: nothing saturated
  const TargetSpec spec = Chessboard(9, 6, 25, ChessboardDetector::kSectorBased);
  const TargetDetection b = DetectTarget(spec, bright);
  const TargetDetection d = DetectTarget(spec, dim);
  ASSERT_TRUE(b.found && d.found);
  EXPECT_GT(b.saturated_fraction, 0.3);  // about half the board is white paper at full scale
  EXPECT_LT(b.saturated_fraction, 0.7);
  EXPECT_EQ(d.saturated_fraction, 0.0);
}

TEST(Target, NotFoundSaysWhy) {
  const TargetSpec spec = Chessboard(9, 6, 25, ChessboardDetector::kSectorBased);
  const TargetDetection blank = DetectTarget(spec, cv::Mat(480, 640, CV_8UC1, cv::Scalar(128)));
  EXPECT_FALSE(blank.found);
  EXPECT_NE(blank.reason.find("9x6"), std::string::npos) << blank.reason;
  const TargetDetection white = DetectTarget(spec, cv::Mat(480, 640, CV_8UC1, cv::Scalar(255)));
  EXPECT_FALSE(white.found);
  EXPECT_NE(white.reason.find("saturated"), std::string::npos) << white.reason;
  EXPECT_NEAR(white.saturated_fraction, 1.0, 1e-12);
  const TargetDetection dark = DetectTarget(spec, cv::Mat(480, 640, CV_8UC1, cv::Scalar(3)));
  EXPECT_NE(dark.reason.find("dark"), std::string::npos) << dark.reason;
  // Wrong size configured: a 9x6 board looked for as 8x6 is not found.
  const cv::Mat image = Warp(RenderChessboard(9, 6, 40), kHom, cv::Size(640, 480));
  EXPECT_FALSE(DetectTarget(Chessboard(7, 5, 25, ChessboardDetector::kClassic), image).found);
  EXPECT_THROW(DetectTarget(spec, cv::Mat()), Error);
}

TEST(Target, CharucoDetectsIdsAtTheRightPlaces) {
  TargetSpec spec;
  spec.type = TargetType::kCharuco;
  spec.cols = 5;
  spec.rows = 7;
  spec.square_size_mm = 40;
  spec.marker_size_mm = 20;
  spec.dictionary = "DICT_6X6_250";
  spec.Check("test");
  const int px = 60;  // pixels per square in the drawn board
  auto board = cv::aruco::CharucoBoard::create(
      5, 7, 40.f, 20.f, cv::aruco::getPredefinedDictionary(cv::aruco::DICT_6X6_250));
  cv::Mat drawn;
  board->draw(cv::Size(5 * px, 7 * px), drawn, 0, 1);
  cv::Mat padded(7 * px + 2 * px, 5 * px + 2 * px, CV_8UC1, cv::Scalar(255));
  drawn.copyTo(padded(cv::Rect(px, px, 5 * px, 7 * px)));
  const cv::Matx33d h(0.8, 0.05, 120, -0.03, 0.8, 20, 0.00005, 0.0001, 1);
  const cv::Mat image = Warp(padded, h, cv::Size(640, 520));
  const TargetDetection d = DetectTarget(spec, image);
  ASSERT_TRUE(d.found) << d.reason;
  EXPECT_GE(d.pixels_px.size(), 18u);
  const auto pts = BoardPoints(spec);
  ASSERT_EQ(pts.size(), 24u);
  // Ids and sub-pixel positions are consistent: one homography maps the board points (mm) of the
  // reported ids onto the detections to well under a pixel.
  std::vector<cv::Point2f> src, dst;
  for (size_t i = 0; i < d.pixels_px.size(); ++i) {
    const auto& b = pts[static_cast<size_t>(d.point_ids[i])];
    src.emplace_back(static_cast<float>(b.x()), static_cast<float>(b.y()));
    dst.emplace_back(static_cast<float>(d.pixels_px[i].x()),
                     static_cast<float>(d.pixels_px[i].y()));
  }
  const cv::Mat fit = cv::findHomography(src, dst, 0);
  std::vector<cv::Point2f> mapped;
  cv::perspectiveTransform(src, mapped, fit);
  double sq = 0;
  for (size_t i = 0; i < dst.size(); ++i) sq += std::pow(cv::norm(mapped[i] - dst[i]), 2);
  EXPECT_LT(std::sqrt(sq / static_cast<double>(dst.size())), 0.15);
  for (size_t i = 0; i < d.pixels_px.size(); ++i) {
    // Board point in mm -> drawn pixel (40 mm = 60 px) -> padded -> warped. The board frame's y
    // runs either down or up the drawing depending on the OpenCV version: accept the one that fits.
    const Eigen::Vector3d b = pts[static_cast<size_t>(d.point_ids[i])];
    const double x = b.x() / 40 * px + px - 0.5;
    const Eigen::Vector2d down = Apply(h, x, b.y() / 40 * px + px - 0.5);
    const Eigen::Vector2d up = Apply(h, x, (7 - b.y() / 40) * px + px - 0.5);
    // Within a pixel of the rendered truth (the drawing's edge convention costs ~0.5 px).
    EXPECT_LT(std::min((d.pixels_px[i] - down).norm(), (d.pixels_px[i] - up).norm()), 1.0)
        << d.point_ids[i];
  }
  // An image without markers: reason names the dictionary.
  const TargetDetection none = DetectTarget(spec, cv::Mat(480, 640, CV_8UC1, cv::Scalar(128)));
  EXPECT_FALSE(none.found);
  EXPECT_NE(none.reason.find("DICT_6X6_250"), std::string::npos) << none.reason;
}

TEST(Target, CircleGridsSymmetricAndAsymmetric) {
  for (bool asym : {false, true}) {
    TargetSpec spec;
    spec.type = asym ? TargetType::kCirclesAsymmetric : TargetType::kCirclesSymmetric;
    spec.cols = asym ? 4 : 7;
    spec.rows = asym ? 11 : 5;
    spec.square_size_mm = 10;
    const auto pts = BoardPoints(spec);
    const double px_per_mm = 2.5, margin = 40;
    cv::Mat board(600, 600, CV_8UC1, cv::Scalar(255));
    for (const auto& p : pts) {
      cv::circle(board,
                 cv::Point(static_cast<int>(margin + p.x() * px_per_mm),
                           static_cast<int>(margin + p.y() * px_per_mm)),
                 7, cv::Scalar(0), cv::FILLED, cv::LINE_AA);
    }
    const cv::Matx33d h(0.9, 0.05, 80, -0.02, 0.9, 30, 0.00005, 0.00005, 1);
    const cv::Mat image = Warp(board, h, cv::Size(640, 480));
    const TargetDetection d = DetectTarget(spec, image);
    ASSERT_TRUE(d.found) << d.reason;
    ASSERT_EQ(d.pixels_px.size(), pts.size());
    // Order may be reversed for the symmetric grid (180 degree ambiguity): accept either.
    double fwd = 0, rev = 0;
    for (size_t i = 0; i < pts.size(); ++i) {
      const auto& a = pts[i];
      const auto& b = pts[pts.size() - 1 - i];
      fwd = std::max(
          fwd, (d.pixels_px[i] - Apply(h, margin + a.x() * px_per_mm, margin + a.y() * px_per_mm))
                   .norm());
      rev = std::max(
          rev, (d.pixels_px[i] - Apply(h, margin + b.x() * px_per_mm, margin + b.y() * px_per_mm))
                   .norm());
    }
    EXPECT_LT(std::min(fwd, rev), 0.5) << (asym ? "asymmetric" : "symmetric");
  }
}

TEST(Target, YamlReadingAndErrorsNameTheField) {
  const TargetSpec spec =
      LoadTargetSpec(testing::SourceDir() / "config/targets/opencv-charuco-tutorial.yaml");
  EXPECT_EQ(spec.type, TargetType::kCharuco);
  EXPECT_EQ(spec.dictionary, "DICT_6X6_250");
  EXPECT_EQ(spec.NumPoints(), 24);
  const TargetSpec chess =
      LoadTargetSpec(testing::SourceDir() / "config/targets/opencv-stereo-chessboard.yaml");
  EXPECT_EQ(chess.detector, ChessboardDetector::kClassic);
  EXPECT_EQ(BoardPoints(chess)[10], Eigen::Vector3d(25, 25, 0));
  const TargetSpec acircles =
      LoadTargetSpec(testing::SourceDir() / "config/targets/circles-asymmetric-4x11.yaml");
  EXPECT_EQ(BoardPoints(acircles)[5], Eigen::Vector3d(60, 20, 0));  // row 1, col 1: (2*1+1)*20

  auto expect_error = [](const std::string& yaml, const std::string& needle) {
    try {
      TargetSpecFromConfig(ConfigNode::ParseYaml(yaml, "t.yaml"));
      ADD_FAILURE() << "no error for " << yaml;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  expect_error("type: hexagons\ncols: 3\nrows: 3\nsquare_size_mm: 1\n", "type");
  expect_error("type: chessboard\ncols: 9\nrows: 6\nsquare_size_mm: -2\n", "square_size_mm");
  expect_error("type: chessboard\ncols: 9\nrows: 6\n", "square_size_mm");
  expect_error(
      "type: charuco\ncols: 5\nrows: 7\nsquare_size_mm: 40\nmarker_size_mm: 20\ndictionary: "
      "DICT_9X9\n",
      "dictionary");
  expect_error(
      "type: charuco\ncols: 5\nrows: 7\nsquare_size_mm: 40\nmarker_size_mm: 50\ndictionary: "
      "DICT_6X6_250\n",
      "marker_size_mm");
  expect_error("type: chessboard\ncols: 9\nrows: 6\nsquare_size_mm: 2\ndetecter: sb\n", "detecter");
  expect_error("type: chessboard\ncols: 9\nrows: 6\nsquare_size_mm: 2\ndetector: fast\n",
               "detector");
  EXPECT_THROW(DetectTargetInFile(spec, "/nonexistent/image.png"), Error);
}

}  // namespace
}  // namespace slshadow
