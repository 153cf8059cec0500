// The codecs behind core/image_io.h, one file each (image_io_png.cc, image_io_jpeg.cc,
// image_io_tiff.cc, image_io_bmp.cc, image_io_pnm.cc), and what they share (image_io.cc): the size
// limits, the conversion to a read mode and the EXIF orientation. Included only by those files.
// Every function throws slshadow::Error naming the file (`name`, `path`) as core/image_io.h says.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>

#include <opencv2/core.hpp>

#include "core/image_io.h"

namespace slshadow::core::internal {

// cv::imread's limits (CV_IO_MAX_IMAGE_WIDTH / HEIGHT / PIXELS), plus one on the decoded bytes so
// a forged header cannot ask for more memory than any camera image needs.
constexpr int64_t kMaxSide = int64_t{1} << 20;
constexpr int64_t kMaxPixels = int64_t{1} << 30;
constexpr int64_t kMaxBytes = int64_t{1} << 30;

// Throws unless width x height (both > 0) at bytes_per_pixel stays within the limits above.
void CheckSize(const std::string& name, const char* format, int64_t width, int64_t height,
               int64_t bytes_per_pixel);

// OpenCV's fixed-point gray conversion (imgcodecs' icvCvt_BGR2Gray_*): 14-bit weights summing to
// 1, so a gray pixel stored as colour converts back exactly.
constexpr int kGrayB = 1868, kGrayG = 9617, kGrayR = 4899;
inline int Gray(int b, int g, int r) { return (b * kGrayB + g * kGrayG + r * kGrayR + 8192) >> 14; }

// How 16-bit samples become 8-bit ones outside kUnchanged mode: the high byte (PNM, gray TIFF), or
// rounded to 255 / 65535 (RGB TIFF, which OpenCV reads through libtiff's RGBA interface).
enum class Narrow { kHighByte, kRound };

// Converts a decoded image whose channel order is BGR(A) (or gray) to what `mode` asks for, the way
// cv::imread does for the PNM / BMP / TIFF decoders.
cv::Mat ToMode(cv::Mat image, ImageReadMode mode, Narrow narrow = Narrow::kHighByte);

// The Orientation tag (0x0112) of IFD0 in a TIFF-structured EXIF block; 1 when absent or invalid.
int ExifOrientation(const uint8_t* p, size_t n);
// `image` turned as EXIF orientation 1..8 says (cv::imread applies it outside kUnchanged mode).
cv::Mat Orient(const cv::Mat& image, int orientation);

// The codecs. Decoders take the file's bytes; `name` stands for the file in messages.
cv::Mat DecodePng(const uint8_t* data, size_t size, ImageReadMode mode, const std::string& name);
cv::Mat DecodeJpeg(const uint8_t* data, size_t size, ImageReadMode mode, const std::string& name);
cv::Mat DecodeTiff(const uint8_t* data, size_t size, ImageReadMode mode, const std::string& name);
void EncodeTiff(const std::filesystem::path& path, const cv::Mat& image);
cv::Mat DecodeBmp(const uint8_t* data, size_t size, ImageReadMode mode, const std::string& name);
cv::Mat DecodePnm(const uint8_t* data, size_t size, ImageReadMode mode, const std::string& name);
void WritePnm(const std::filesystem::path& path, const cv::Mat& image);

}  // namespace slshadow::core::internal
