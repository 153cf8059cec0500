#include <png.h>

#include <algorithm>
#include <csetjmp>
#include <cstdio>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/image_io.h"
#include "core/internal/image_codecs.h"

namespace slshadow::core::internal {

namespace fs = std::filesystem;

namespace {

// A PNG's chunk structure (lengths and types, not CRCs) up to IEND, so a truncated file is named
// as such instead of failing somewhere inside libpng.
void CheckPngStructure(const uint8_t* data, size_t size, const std::string& name) {
  for (uint64_t pos = 8;;) {
    SLSHADOW_THROW_IF(pos + 8 > size, name,
                      ": truncated PNG: no IEND chunk (the file ends at byte ", size, ")");
    const uint8_t* chunk = data + pos;
    const uint64_t length = (uint64_t{chunk[0]} << 24) | (uint64_t{chunk[1]} << 16) |
                            (uint64_t{chunk[2]} << 8) | chunk[3];
    const std::string type(reinterpret_cast<const char*>(chunk + 4), 4);
    SLSHADOW_THROW_IF(pos + 12 + length > size, name, ": truncated PNG: chunk '", type,
                      "' at byte ", pos, " needs ", 12 + length, " bytes, the file ends at byte ",
                      size);
    if (type == "IEND") return;
    pos += 12 + length;
  }
}

// State shared with libpng's callbacks, owned by the caller of the setjmp frames below so that a
// longjmp leaves no C++ object of those frames half-built.
struct PngState {
  const uint8_t* data = nullptr;
  size_t size = 0, pos = 0;
  std::vector<uint8_t>* out = nullptr;  // encoder output
  std::vector<png_bytep> rows;
  cv::Mat image;
  int orientation = 1;
  std::string name;
  char message[256] = {};
  bool too_large = false;
};

void PngError(png_structp png, png_const_charp message) {
  auto* s = static_cast<PngState*>(png_get_error_ptr(png));
  std::snprintf(s->message, sizeof(s->message), "%s", message);
  png_longjmp(png, 1);
}

void PngWarning(png_structp, png_const_charp) {}

void PngRead(png_structp png, png_bytep out, size_t n) {
  auto* s = static_cast<PngState*>(png_get_io_ptr(png));
  if (n > s->size - s->pos) png_error(png, "unexpected end of file");
  std::memcpy(out, s->data + s->pos, n);
  s->pos += n;
}

// Decodes with cv::imread's libpng transforms (opencv imgcodecs grfmt_png.cpp): 16 bits kept or
// stripped, alpha stripped below four channels else tRNS expanded to alpha, palette to RGB, low
// gray depths to 8 bits, BGR order, gray <-> RGB as the mode asks. False on a libpng error.
bool DecodePngInto(PngState* s, ImageReadMode mode) {
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, s, PngError, PngWarning);
  if (png == nullptr) return false;
  png_infop info = png_create_info_struct(png);
  png_infop end = png_create_info_struct(png);
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_read_struct(&png, &info, &end);
    return false;
  }
  if (info == nullptr || end == nullptr) png_error(png, "out of memory");
  png_set_read_fn(png, s, PngRead);
  png_read_info(png, info);
  png_uint_32 width = 0, height = 0;
  int bit_depth = 0, color_type = 0;
  png_get_IHDR(png, info, &width, &height, &bit_depth, &color_type, nullptr, nullptr, nullptr);
  int channels = 1;
  if (color_type == PNG_COLOR_TYPE_RGB || color_type == PNG_COLOR_TYPE_PALETTE) {
    png_bytep trans = nullptr;
    int num_trans = 0;
    png_color_16p trans_values = nullptr;
    png_get_tRNS(png, info, &trans, &num_trans, &trans_values);
    channels = num_trans > 0 ? 4 : 3;
  } else if (color_type == PNG_COLOR_TYPE_GRAY_ALPHA || color_type == PNG_COLOR_TYPE_RGB_ALPHA) {
    channels = 4;
  }
  int depth = bit_depth == 16 ? CV_16U : CV_8U;
  if (mode != ImageReadMode::kUnchanged) {
    depth = CV_8U;
    channels = mode == ImageReadMode::kColor ? 3 : 1;
  }
  const int64_t elem = (depth == CV_16U ? 2 : 1) * channels;
  if (width == 0 || height == 0 || width > kMaxSide || height > kMaxSide ||
      int64_t{width} * height > kMaxPixels || int64_t{width} * height * elem > kMaxBytes) {
    s->too_large = true;
    png_error(png, "image too large");
  }
  const bool color = channels > 1;
  if (depth == CV_8U && bit_depth == 16) {
    png_set_strip_16(png);
  } else {
    png_set_swap(png);
  }
  if (channels < 4) {
    png_set_strip_alpha(png);
  } else {
    png_set_tRNS_to_alpha(png);
  }
  if (color_type == PNG_COLOR_TYPE_PALETTE) png_set_palette_to_rgb(png);
  if ((color_type & PNG_COLOR_MASK_COLOR) == 0 && bit_depth < 8) {
    png_set_expand_gray_1_2_4_to_8(png);
  }
  if ((color_type & PNG_COLOR_MASK_COLOR) && color) {
    png_set_bgr(png);
  } else if (color) {
    png_set_gray_to_rgb(png);
  } else {
    png_set_rgb_to_gray(png, 1, 0.299, 0.587);
  }
  png_set_interlace_handling(png);
  png_read_update_info(png, info);
  if (png_get_rowbytes(png, info) != static_cast<size_t>(width) * static_cast<size_t>(elem)) {
    png_error(png, "unexpected row size after the transforms");
  }
  s->image.create(static_cast<int>(height), static_cast<int>(width), CV_MAKETYPE(depth, channels));
  s->rows.resize(height);
  for (png_uint_32 y = 0; y < height; ++y) s->rows[y] = s->image.ptr(static_cast<int>(y));
  png_read_image(png, s->rows.data());
  png_read_end(png, end);
  png_uint_32 exif_size = 0;
  png_bytep exif = nullptr;
  if (png_get_valid(png, info, PNG_INFO_eXIf)) {
    png_get_eXIf_1(png, info, &exif_size, &exif);
  } else if (png_get_valid(png, end, PNG_INFO_eXIf)) {
    png_get_eXIf_1(png, end, &exif_size, &exif);
  }
  if (exif != nullptr) s->orientation = ExifOrientation(exif, exif_size);
  png_destroy_read_struct(&png, &info, &end);
  return true;
}

}  // namespace

cv::Mat DecodePng(const uint8_t* data, size_t size, ImageReadMode mode, const std::string& name) {
  CheckPngStructure(data, size, name);
  PngState s;
  s.data = data;
  s.size = size;
  if (!DecodePngInto(&s, mode)) {
    SLSHADOW_THROW_IF(s.too_large, name, ": PNG: image too large or empty");
    SLSHADOW_THROW(name, ": cannot decode image: corrupt PNG (", s.message, ")");
  }
  return mode == ImageReadMode::kUnchanged ? s.image : Orient(s.image, s.orientation);
}

namespace {

void PngWrite(png_structp png, png_bytep data, size_t n) {
  auto* s = static_cast<PngState*>(png_get_io_ptr(png));
  s->out->insert(s->out->end(), data, data + n);
}

void PngFlush(png_structp) {}

bool EncodePngInto(PngState* s, const cv::Mat& image, int level) {
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, s, PngError, PngWarning);
  if (png == nullptr) return false;
  png_infop info = png_create_info_struct(png);
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return false;
  }
  if (info == nullptr) png_error(png, "out of memory");
  png_set_write_fn(png, s, PngWrite, PngFlush);
  if (level >= 0) {
    png_set_compression_level(png, std::min(level, 9));
    png_set_compression_strategy(png, 0);  // Z_DEFAULT_STRATEGY
  } else {
    png_set_filter(png, PNG_FILTER_TYPE_BASE, PNG_FILTER_SUB);
    png_set_compression_level(png, 1);
    png_set_compression_strategy(png, 3);  // Z_RLE
  }
  const int channels = image.channels();
  png_set_IHDR(png, info, static_cast<png_uint_32>(image.cols),
               static_cast<png_uint_32>(image.rows), image.depth() == CV_16U ? 16 : 8,
               channels == 1   ? PNG_COLOR_TYPE_GRAY
               : channels == 3 ? PNG_COLOR_TYPE_RGB
                               : PNG_COLOR_TYPE_RGB_ALPHA,
               PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  png_set_bgr(png);
  png_set_swap(png);
  s->rows.resize(static_cast<size_t>(image.rows));
  for (int y = 0; y < image.rows; ++y) {
    s->rows[static_cast<size_t>(y)] = const_cast<png_bytep>(image.ptr(y));
  }
  png_write_image(png, s->rows.data());
  png_write_end(png, info);
  png_destroy_write_struct(&png, &info);
  return true;
}

}  // namespace

}  // namespace slshadow::core::internal

namespace slshadow {

std::vector<uint8_t> EncodePng(const cv::Mat& image, const std::string& name,
                               const ImageWriteOptions& options) {
  const int channels = image.channels();
  SLSHADOW_THROW_IF(image.empty() || (channels != 1 && channels != 3 && channels != 4) ||
                        (image.depth() != CV_8U && image.depth() != CV_16U),
                    name,
                    ": cannot write image: PNG takes non-empty 8- or 16-bit images of 1, 3 or 4 "
                    "channels");
  std::vector<uint8_t> bytes;
  core::internal::PngState s;
  s.out = &bytes;
  s.name = name;
  SLSHADOW_THROW_IF(!core::internal::EncodePngInto(&s, image, options.png_compression), name,
                    ": cannot write image: PNG encoding failed (", s.message, ")");
  return bytes;
}

}  // namespace slshadow
