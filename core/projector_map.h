// ProjectorMap: what decoding one camera's fringe images yields, per camera pixel: the projector
// coordinate seen there, whether it is valid and why not, and a quality value. Produced by
// patterns/ (decoding), by sim/ (ground truth), consumed by reconstruct/ and calib/.
#pragma once

#include <array>
#include <cstdint>
#include <string>

#include <opencv2/core.hpp>

namespace slshadow {

// Why a camera pixel has no projector coordinate. Stored as CV_8U in ProjectorMap::status.
enum class PixelStatus : uint8_t {
  kValid = 0,
  kShadow = 1,       // not lit by the projector: white - black below the shadow threshold
  kLowContrast = 2,  // lit, but a bit or fringe could not be told apart from noise
  kSaturated = 3,    // at the sensor's maximum in a frame that matters
  kCodeError = 4,    // the code read is impossible (out of range, inconsistent unwrapping)
  kFiltered = 5,     // removed by a later filter (e.g. reconstruction gates)
};
constexpr int kNumPixelStatus = 6;
std::string ToString(PixelStatus status);  // "valid", "shadow", ...

struct ProjectorMap {
  // Projector column / row coordinate in projector pixels (OpenCV convention: integer values are
  // projector pixel centres). CV_32FC1, NaN where invalid or where that axis is not coded.
  cv::Mat proj_x;
  cv::Mat proj_y;
  cv::Mat status;      // CV_8UC1 of PixelStatus
  cv::Mat quality;     // CV_32FC1: modulation (phase codecs) or contrast (Gray code), grey levels
  bool has_x = false;  // the pattern codes projector columns
  bool has_y = false;  // the pattern codes projector rows

  int width() const { return status.cols; }
  int height() const { return status.rows; }
  // Allocates all maps at the given size, every pixel invalid with status `initial`.
  void Allocate(int width, int height, bool code_x, bool code_y,
                PixelStatus initial = PixelStatus::kShadow);
  // Number of pixels per status, indexed by PixelStatus.
  std::array<int64_t, kNumPixelStatus> CountByStatus() const;
};

}  // namespace slshadow
