// Real data: ../shared/data/kamino-procam-graycode (see its README): a printed 9x7 chessboard in
// 5 poses under OpenCV's GrayCodePattern for a 1024x768 projector, 1280x1024 camera. The board is
// planar, so on it the camera-to-projector map is a homography (up to lens distortion): the decoded
// maps must be monotone along the board, close to one homography, and valid over the board.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/image_set.h"
#include "patterns/codec.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

std::filesystem::path KaminoDir() { return testing::SharedDataDir() / "kamino-procam-graycode"; }

struct PoseStats {
  int corners = 0;
  double board_px = 0;       // camera pixels inside the board's corner hull
  double valid_share = 0;    // share of them decoded valid
  double fit_rms_px = 0;     // RMS residual of a homography fitted to the valid board pixels
  double outlier_share = 0;  // share of valid board pixels more than 2 px off that homography
  double monotone_share_x =
      0;  // share of neighbour pairs along the board's x that follow its direction
  double monotone_share_y = 0;
  int white_cells = 0, black_cells = 0;
  double white_cell_min_valid = 0;  // smallest share of valid pixels in a white cell
  double black_cell_shadow = 0;     // mean share of shadow pixels in black cells
};

PoseStats Measure(int pose, const DecodeOptions& options) {
  PoseStats s;
  const std::filesystem::path dir = KaminoDir() / ("capture_" + std::to_string(pose));
  const PatternSpec spec =
      LoadPatternSpec(testing::SourceDir() / "config/patterns/kamino_opencv_graycode.yaml");
  std::vector<cv::Mat> images;
  for (int i = 0; i < spec.NumImages(); ++i) {
    char name[32];
    std::snprintf(name, sizeof(name), "graycode_%02d.png", i);
    images.push_back(ReadGrayImage(dir / name));
  }
  const ProjectorMap map = DecodePatterns(spec, images, options);
  EXPECT_EQ(map.width(), 1280);
  EXPECT_EQ(map.height(), 1024);

  std::vector<cv::Point2f> corners;
  const cv::Mat& white = images[static_cast<size_t>(spec.WhiteFrameIndex())];
  if (!cv::findChessboardCornersSB(white, cv::Size(9, 7), corners)) return s;
  s.corners = static_cast<int>(corners.size());
  std::vector<cv::Point> hull;
  std::vector<cv::Point> pts;
  for (const auto& c : corners) pts.emplace_back(cvRound(c.x), cvRound(c.y));
  cv::convexHull(pts, hull);
  cv::Mat board(map.height(), map.width(), CV_8UC1, cv::Scalar(0));
  cv::fillConvexPoly(board, hull, cv::Scalar(255));
  s.board_px = cv::countNonZero(board);
  // Per chessboard cell (between 4 neighbouring corners, shrunk to 70% about its centre): white
  // cells (lit range white - black > 40) must decode; black ink returns too little light.
  const cv::Mat& black = images[static_cast<size_t>(spec.BlackFrameIndex())];
  s.white_cell_min_valid = 1;
  for (int j = 0; j < 6; ++j) {
    for (int i = 0; i < 8; ++i) {
      const std::vector<cv::Point2f> quad = {corners[j * 9 + i], corners[j * 9 + i + 1],
                                             corners[(j + 1) * 9 + i + 1],
                                             corners[(j + 1) * 9 + i]};
      const cv::Point2f centre = (quad[0] + quad[1] + quad[2] + quad[3]) / 4;
      std::vector<cv::Point> shrunk;
      for (const auto& q : quad) {
        shrunk.emplace_back(cvRound(centre.x + 0.7 * (q.x - centre.x)),
                            cvRound(centre.y + 0.7 * (q.y - centre.y)));
      }
      const cv::Rect roi = cv::boundingRect(shrunk);
      cv::Mat cell(roi.size(), CV_8UC1, cv::Scalar(0));
      for (auto& p : shrunk) p -= roi.tl();
      cv::fillConvexPoly(cell, shrunk, cv::Scalar(255));
      const double area = cv::countNonZero(cell);
      cv::Mat lit;
      cv::subtract(white(roi), black(roi), lit, cell, CV_16S);
      const double mean_lit = cv::sum(lit)[0] / area;
      if (mean_lit > 40) {
        ++s.white_cells;
        const double valid = cv::countNonZero((map.status(roi) == 0) & cell) / area;
        s.white_cell_min_valid = std::min(s.white_cell_min_valid, valid);
      } else {
        ++s.black_cells;
        s.black_cell_shadow +=
            cv::countNonZero((map.status(roi) == static_cast<int>(PixelStatus::kShadow)) & cell) /
            area;
      }
    }
  }
  s.black_cell_shadow /= std::max(s.black_cells, 1);

  std::vector<cv::Point2f> cam, proj;
  for (int v = 0; v < map.height(); ++v) {
    for (int u = 0; u < map.width(); ++u) {
      if (!board.at<uint8_t>(v, u) || map.status.at<uint8_t>(v, u) != 0) continue;
      cam.emplace_back(static_cast<float>(u), static_cast<float>(v));
      proj.emplace_back(map.proj_x.at<float>(v, u), map.proj_y.at<float>(v, u));
    }
  }
  s.valid_share = static_cast<double>(cam.size()) / s.board_px;
  if (cam.size() < 100) return s;
  // Robust fit (a few code errors must not drag it), then residuals of all valid board pixels.
  const cv::Mat h = cv::findHomography(cam, proj, cv::RANSAC, 2.0);
  std::vector<cv::Point2f> predicted;
  cv::perspectiveTransform(cam, predicted, h);
  double sum2 = 0;
  int64_t inliers = 0, outliers = 0;
  for (size_t i = 0; i < cam.size(); ++i) {
    const double e = cv::norm(predicted[i] - proj[i]);
    if (e > 2.0) {
      ++outliers;
      continue;
    }
    sum2 += e * e;
    ++inliers;
  }
  s.fit_rms_px = std::sqrt(sum2 / static_cast<double>(std::max<int64_t>(inliers, 1)));
  s.outlier_share = static_cast<double>(outliers) / static_cast<double>(cam.size());

  // Monotonicity along the board axes: step one camera pixel along the board's x (corner 0 -> 8)
  // and y (corner 0 -> 9) directions; the projector coordinate must not move against the
  // direction the homography predicts for the board as a whole.
  for (int axis = 0; axis < 2; ++axis) {
    const cv::Point2f dir = axis == 0 ? corners[8] - corners[0] : corners[9 * 6] - corners[0];
    const cv::Point2f step = dir / static_cast<float>(cv::norm(dir));
    std::vector<cv::Point2f> ends = {corners[0], corners[0] + dir};
    std::vector<cv::Point2f> proj_ends;
    cv::perspectiveTransform(ends, proj_ends, h);
    const cv::Point2f expected = proj_ends[1] - proj_ends[0];
    int64_t agree = 0, total = 0;
    for (int v = 0; v < map.height(); v += 2) {
      for (int u = 0; u < map.width(); u += 2) {
        const int u2 = cvRound(u + 3 * step.x), v2 = cvRound(v + 3 * step.y);
        if (u2 < 0 || v2 < 0 || u2 >= map.width() || v2 >= map.height()) continue;
        if (!board.at<uint8_t>(v, u) || !board.at<uint8_t>(v2, u2)) continue;
        if (map.status.at<uint8_t>(v, u) != 0 || map.status.at<uint8_t>(v2, u2) != 0) continue;
        const cv::Point2f d(map.proj_x.at<float>(v2, u2) - map.proj_x.at<float>(v, u),
                            map.proj_y.at<float>(v2, u2) - map.proj_y.at<float>(v, u));
        ++total;
        agree += d.dot(expected) >= 0;
      }
    }
    (axis == 0 ? s.monotone_share_x : s.monotone_share_y) =
        static_cast<double>(agree) / static_cast<double>(total);
  }
  return s;
}

TEST(DecodeKamino, AllPosesDecodeSmoothMonotoneMapsOverTheBoard) {
  // The shared data is part of a prepared machine (scripts/run-tests.sh checks it): absent fails.
  ASSERT_TRUE(std::filesystem::exists(KaminoDir())) << "real data not present: " << KaminoDir();
  for (int pose = 0; pose < 5; ++pose) {
    const PoseStats s = Measure(pose, {});
    std::printf(
        "pose %d: corners %d, board %.0f px, valid %.4f, homography rms %.3f px, outliers %.5f, "
        "monotone x %.5f y %.5f, white cells %d min valid %.4f, black cells %d shadow %.4f\n",
        pose, s.corners, s.board_px, s.valid_share, s.fit_rms_px, s.outlier_share,
        s.monotone_share_x, s.monotone_share_y, s.white_cells, s.white_cell_min_valid,
        s.black_cells, s.black_cell_shadow);
    SCOPED_TRACE(::testing::Message() << "pose " << pose);
    ASSERT_EQ(s.corners, 63);
    // Measured (2026-11, default DecodeOptions): every white cell fully valid; black ink returns
    // 5-17 grey levels and is mostly shadow; valid share of the corner hull 0.525-0.750.
    EXPECT_EQ(s.white_cells, 24);
    EXPECT_GE(s.white_cell_min_valid, 0.99);
    EXPECT_GE(s.black_cell_shadow, 0.45);
    EXPECT_GE(s.valid_share, 0.50);
    // Smooth: one homography explains the map to 0.37-0.44 px RMS (integer Gray code alone gives
    // sqrt(2/12) = 0.41 px), with at most 3e-5 of the pixels more than 2 px off.
    EXPECT_LE(s.fit_rms_px, 0.5);
    EXPECT_LE(s.outlier_share, 1e-4);
    // Monotone along both board axes (measured >= 0.99987 of neighbour pairs).
    EXPECT_GE(s.monotone_share_x, 0.9995);
    EXPECT_GE(s.monotone_share_y, 0.9995);
  }
}

}  // namespace
}  // namespace slshadow
