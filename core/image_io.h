// Image files through the system codecs (libpng, libjpeg-turbo, libtiff) and our own PNM / BMP
// code, without OpenCV's imgcodecs (which loads ~100 libraries at start-up on Debian). Pixels,
// types and channel order are those of cv::imread / cv::imwrite (BGR, 8- or 16-bit), checked
// pixel for pixel against them in tests/core/image_io_test.cc.
//
// Read (the format is found from the content, not the extension):
//   PNG   every colour type and bit depth; palette, low bit depths and tRNS expanded as
//         cv::imread does (tRNS gives an alpha channel in kUnchanged mode)
//   JPEG  baseline and progressive, grayscale, colour (YCbCr / RGB) and CMYK
//   TIFF  8- or 16-bit unsigned, gray (min-is-black) or RGB, strips, any compression libtiff
//         decodes
//   BMP   uncompressed 8-bit (palette), 24-bit and 32-bit
//   PNM   binary P5 (PGM) and P6 (PPM), 8- or 16-bit (maxval up to 65535)
// Write (the format is taken from the extension): .png (8/16-bit, 1/3/4 channels), .pgm / .ppm
// (binary, 8/16-bit, 1 / 3 channels), .tif / .tiff (uncompressed, 8/16-bit, 1 / 3 channels).
// Every failure throws slshadow::Error naming the file and what is wrong.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace slshadow {

enum class ImageReadMode {
  kUnchanged,  // depth and channels as stored (cv::IMREAD_UNCHANGED)
  kGrayscale,  // 8-bit, one channel (cv::IMREAD_GRAYSCALE)
  kColor,      // 8-bit, three channels, BGR (cv::IMREAD_COLOR)
};

// Reads one image file. In kGrayscale and kColor mode an EXIF orientation (JPEG, PNG) is applied,
// as cv::imread does; kUnchanged returns the pixels as stored.
cv::Mat ReadImage(const std::filesystem::path& path,
                  ImageReadMode mode = ImageReadMode::kUnchanged);
// The same from bytes in memory; `name` stands for the file in error messages.
cv::Mat DecodeImage(const uint8_t* data, size_t size, ImageReadMode mode, const std::string& name);

struct ImageWriteOptions {
  // PNG: zlib level 0..9 with libpng's adaptive filters; -1: the fast setting cv::imwrite uses
  // when given no level (the "sub" filter, level 1, run-length strategy).
  int png_compression = -1;
};

// Writes one image, the format from the extension (.png, .pgm, .ppm, .tif, .tiff). Colour images
// are BGR(A), as in OpenCV.
void WriteImage(const std::filesystem::path& path, const cv::Mat& image,
                const ImageWriteOptions& options = {});
// A PNG file's bytes; `name` stands for the file in error messages.
std::vector<uint8_t> EncodePng(const cv::Mat& image, const std::string& name,
                               const ImageWriteOptions& options = {});

}  // namespace slshadow
