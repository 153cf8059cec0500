#include "core/projector_map.h"

#include <limits>

namespace slshadow {

std::string ToString(PixelStatus status) {
  switch (status) {
    case PixelStatus::kValid:
      return "valid";
    case PixelStatus::kShadow:
      return "shadow";
    case PixelStatus::kLowContrast:
      return "low_contrast";
    case PixelStatus::kSaturated:
      return "saturated";
    case PixelStatus::kCodeError:
      return "code_error";
    case PixelStatus::kFiltered:
      return "filtered";
  }
  return "unknown";
}

void ProjectorMap::Allocate(int width, int height, bool code_x, bool code_y, PixelStatus initial) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  proj_x = cv::Mat(height, width, CV_32FC1, cv::Scalar(nan));
  proj_y = cv::Mat(height, width, CV_32FC1, cv::Scalar(nan));
  status = cv::Mat(height, width, CV_8UC1, cv::Scalar(static_cast<int>(initial)));
  quality = cv::Mat(height, width, CV_32FC1, cv::Scalar(0));
  has_x = code_x;
  has_y = code_y;
}

std::array<int64_t, kNumPixelStatus> ProjectorMap::CountByStatus() const {
  std::array<int64_t, kNumPixelStatus> counts{};
  for (int y = 0; y < status.rows; ++y) {
    const uint8_t* row = status.ptr<uint8_t>(y);
    for (int x = 0; x < status.cols; ++x) {
      if (row[x] < kNumPixelStatus) ++counts[row[x]];
    }
  }
  return counts;
}

}  // namespace slshadow
