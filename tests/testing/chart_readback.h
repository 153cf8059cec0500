// Reading a drawn chart back from its PNG (decoded by OpenCV's imgcodecs, not by our code): the
// axes box (the long dark lines PLplot draws around the viewport) and the extent and colour of a
// filled area, so a test can check where a bar landed against the axes' range and what colour
// it has.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdlib>
#include <optional>

#include <opencv2/core.hpp>

namespace slshadow::testing {

// Pixel rows and columns of the axes box: its sides are the outermost columns at least
// `min_fraction` of whose pixels are dark (every channel below 200: black or grey lines,
// antialiased over two pixels; the heat colours and white always have a channel at 255), its top
// and bottom the ends of the dark run down the left side (bars standing on the bottom line blend
// with it, so rows are not counted across).
struct ChartFrame {
  int left = 0, right = 0, top = 0, bottom = 0;
};

inline bool IsDark(const cv::Vec3b& bgr) { return bgr[0] < 200 && bgr[1] < 200 && bgr[2] < 200; }

inline std::optional<ChartFrame> FindChartFrame(const cv::Mat& bgr, double min_fraction = 0.5) {
  ChartFrame f{-1, -1, -1, -1};
  for (int x = 0; x < bgr.cols; ++x) {
    int dark = 0;
    for (int y = 0; y < bgr.rows; ++y) dark += IsDark(bgr.at<cv::Vec3b>(y, x));
    if (dark >= min_fraction * bgr.rows) {
      if (f.left < 0) f.left = x;
      f.right = x;
    }
  }
  if (f.left < 0 || f.right - f.left < 10) return {};
  // The longest dark run down the left side.
  int best = 0;
  for (int y = 0; y < bgr.rows;) {
    if (!IsDark(bgr.at<cv::Vec3b>(y, f.left))) {
      ++y;
      continue;
    }
    int end = y;
    while (end + 1 < bgr.rows && IsDark(bgr.at<cv::Vec3b>(end + 1, f.left))) ++end;
    if (end - y + 1 > best) {
      best = end - y + 1;
      f.top = y;
      f.bottom = end;
    }
    y = end + 1;
  }
  if (best < 10) return {};
  return f;
}

// Whether a pixel is within `tolerance` of an RGB colour in every channel.
inline bool IsColour(const cv::Vec3b& bgr, const std::array<uint8_t, 3>& rgb, int tolerance) {
  return std::abs(bgr[2] - rgb[0]) <= tolerance && std::abs(bgr[1] - rgb[1]) <= tolerance &&
         std::abs(bgr[0] - rgb[2]) <= tolerance;
}

// The run of pixels of colour `rgb` through (x, y): along the column, the topmost and bottommost
// rows of the run; along the row, its leftmost and rightmost columns. -1 when (x, y) is not that
// colour.
struct ColourRun {
  int top = -1, bottom = -1, left = -1, right = -1;
};

inline ColourRun RunThrough(const cv::Mat& bgr, int x, int y, const std::array<uint8_t, 3>& rgb,
                            int tolerance) {
  ColourRun r;
  if (!IsColour(bgr.at<cv::Vec3b>(y, x), rgb, tolerance)) return r;
  r.top = r.bottom = y;
  while (r.top > 0 && IsColour(bgr.at<cv::Vec3b>(r.top - 1, x), rgb, tolerance)) --r.top;
  while (r.bottom + 1 < bgr.rows && IsColour(bgr.at<cv::Vec3b>(r.bottom + 1, x), rgb, tolerance))
    ++r.bottom;
  r.left = r.right = x;
  while (r.left > 0 && IsColour(bgr.at<cv::Vec3b>(y, r.left - 1), rgb, tolerance)) --r.left;
  while (r.right + 1 < bgr.cols && IsColour(bgr.at<cv::Vec3b>(y, r.right + 1), rgb, tolerance))
    ++r.right;
  return r;
}

}  // namespace slshadow::testing
