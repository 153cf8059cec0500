#include "calib/calibration_input.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

namespace fs = std::filesystem;

// A 9x6 chessboard with 40 px squares and a white margin of one square: inner corner (c, r) at
// ((c + 2) * 40 - 0.5, (r + 2) * 40 - 0.5), shifted by (dx, dy) inside a w x h image.
cv::Mat Board(int w, int h, int dx, int dy) {
  cv::Mat img(h, w, CV_8UC1, cv::Scalar(255));
  for (int r = 0; r < 7; ++r) {
    for (int c = 0; c < 10; ++c) {
      if ((r + c) % 2 == 0) img(cv::Rect(dx + (c + 1) * 40, dy + (r + 1) * 40, 40, 40)).setTo(0);
    }
  }
  cv::GaussianBlur(img, img, cv::Size(5, 5), 0.8);
  return img;
}

TargetSpec Chessboard() {
  TargetSpec s;
  s.type = TargetType::kChessboard;
  s.cols = 9;
  s.rows = 6;
  s.square_size_mm = 25;
  s.detector = ChessboardDetector::kClassic;
  s.subpix_half_window_px = 5;
  return s;
}

TEST(CalibrationInput, ImageFilesListsFoldersInNameOrderAndNamesBadArguments) {
  testing::TempDir dir;
  fs::create_directories(dir.path() / "imgs");
  fs::create_directories(dir.path() / "empty");
  for (const char* name : {"b.PNG", "a.jpg", "c.txt", "d.pgm"})
    std::ofstream(dir.path() / "imgs" / name) << "x";
  std::ofstream(dir.path() / "single.bmp") << "x";
  const auto files = ImageFiles(
      {(dir.path() / "imgs").string(), (dir.path() / "single.bmp").string()}, "--images");
  ASSERT_EQ(files.size(), 4u);
  EXPECT_EQ(files[0].filename(), "a.jpg");
  EXPECT_EQ(files[1].filename(), "b.PNG");
  EXPECT_EQ(files[2].filename(), "d.pgm");
  EXPECT_EQ(files[3].filename(), "single.bmp");
  try {
    ImageFiles({(dir.path() / "missing").string()}, "--left");
    FAIL() << "no error for a missing folder";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("--left"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("no such file or folder"), std::string::npos) << e.what();
  }
  EXPECT_THROW(ImageFiles({(dir.path() / "empty").string()}, "--images"), Error);
}

TEST(CalibrationInput, AddBoardViewsDetectsEachFileAsAPoseOfTheDevice) {
  testing::TempDir dir;
  const TargetSpec spec = Chessboard();
  std::vector<fs::path> files;
  for (int i = 0; i < 3; ++i) {
    files.push_back(dir.path() / ("view" + std::to_string(i) + ".png"));
    // The second image shows no board.
    cv::imwrite(files.back().string(), i == 1 ? cv::Mat(400, 600, CV_8UC1, cv::Scalar(128))
                                              : Board(600, 400, 10 * i, 5 * i));
  }
  CalibrationInput input;
  input.devices = {CalibrationDevice::Camera("cam")};
  std::vector<ImageCheck> checks;
  AddBoardViews(spec, files, 0, &input, &checks);
  EXPECT_EQ(input.devices[0].width, 600);
  EXPECT_EQ(input.devices[0].height, 400);
  ASSERT_EQ(checks.size(), 3u);
  EXPECT_TRUE(checks[0].found);
  EXPECT_FALSE(checks[1].found);
  EXPECT_FALSE(checks[1].reason.empty());
  EXPECT_TRUE(checks[2].found);
  ASSERT_EQ(input.views.size(), 2u);
  const auto board = BoardPoints(spec);
  for (const auto& v : input.views) {
    EXPECT_EQ(v.device, 0);
    const int shift =
        v.pose;  // pose = index in the list: the board is shifted by (10, 5) px per index
    ASSERT_EQ(v.pixels_px.size(), 54u);
    for (size_t i = 0; i < v.pixels_px.size(); ++i) {
      // Corners come in OpenCV's order; each pixel is its board point's position in the render.
      const Eigen::Vector3d& p = v.points_in_board_mm[i];
      const int c = static_cast<int>(std::lround(p.x() / 25)),
                r = static_cast<int>(std::lround(p.y() / 25));
      EXPECT_NEAR(v.pixels_px[i].x(), (c + 2) * 40 - 0.5 + 10 * shift, 0.1);
      EXPECT_NEAR(v.pixels_px[i].y(), (r + 2) * 40 - 0.5 + 5 * shift, 0.1);
      EXPECT_NE(std::find(board.begin(), board.end(), p), board.end());
    }
  }
  EXPECT_EQ(input.views[0].pose, 0);
  EXPECT_EQ(input.views[1].pose, 2);
  EXPECT_EQ(input.views[1].label, "view2.png");

  // Another size for the same device is an error naming the file.
  const fs::path other = dir.path() / "small.png";
  cv::imwrite(other.string(), Board(500, 400, 0, 0));
  try {
    AddBoardViews(spec, {other}, 0, &input, &checks);
    FAIL() << "no error for a mismatched size";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("small.png"), std::string::npos) << e.what();
  }
}

TEST(CalibrationInput, DevicesByNameKeepEveryOtherFieldAtItsDefault) {
  const CalibrationDevice cam = CalibrationDevice::Camera("left", 640, 480);
  EXPECT_EQ(cam.name, "left");
  EXPECT_EQ(cam.width, 640);
  EXPECT_EQ(cam.height, 480);
  EXPECT_FALSE(cam.is_projector);
  EXPECT_FALSE(cam.initial.has_value());
  EXPECT_FALSE(cam.hold_intrinsics);
  EXPECT_TRUE(cam.held_params.empty());
  const CalibrationDevice proj = CalibrationDevice::Projector("dlp", 1280, 800);
  EXPECT_TRUE(proj.is_projector);
  EXPECT_EQ(proj.width, 1280);
  EXPECT_EQ(proj.height, 800);
}

}  // namespace
}  // namespace slshadow
