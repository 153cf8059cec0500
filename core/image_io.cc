#include "core/image_io.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <sys/uio.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <csetjmp>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <memory>

// <cstdio> above: jpeglib.h needs FILE.
#include <jerror.h>
#include <jpeglib.h>
#include <png.h>
#include <tiffio.h>

#include "core/error.h"

namespace slshadow {
namespace fs = std::filesystem;

namespace {

// cv::imread's limits (CV_IO_MAX_IMAGE_WIDTH / HEIGHT / PIXELS), plus one on the decoded bytes so
// a forged header cannot ask for more memory than any camera image needs.
constexpr int64_t kMaxSide = int64_t{1} << 20;
constexpr int64_t kMaxPixels = int64_t{1} << 30;
constexpr int64_t kMaxBytes = int64_t{1} << 30;

void CheckSize(const std::string& name, const char* format, int64_t width, int64_t height,
               int64_t bytes_per_pixel) {
  SLSHADOW_THROW_IF(width <= 0 || height <= 0, name, ": ", format, ": invalid image size ", width,
                    " x ", height);
  SLSHADOW_THROW_IF(width > kMaxSide || height > kMaxSide || width * height > kMaxPixels ||
                        width * height * bytes_per_pixel > kMaxBytes,
                    name, ": ", format, ": image too large (", width, " x ", height, ")");
}

// OpenCV's fixed-point gray conversion (imgcodecs' icvCvt_BGR2Gray_*): 14-bit weights summing to
// 1, so a gray pixel stored as colour converts back exactly.
constexpr int kGrayB = 1868, kGrayG = 9617, kGrayR = 4899;
inline int Gray(int b, int g, int r) { return (b * kGrayB + g * kGrayG + r * kGrayR + 8192) >> 14; }

// How 16-bit samples become 8-bit ones outside kUnchanged mode: the high byte (PNM, gray TIFF), or
// rounded to 255 / 65535 (RGB TIFF, which OpenCV reads through libtiff's RGBA interface).
enum class Narrow { kHighByte, kRound };

// Converts a decoded image whose channel order is BGR(A) (or gray) to what `mode` asks for, the way
// cv::imread does for the PNM / BMP / TIFF decoders.
cv::Mat ToMode(cv::Mat image, ImageReadMode mode, Narrow narrow = Narrow::kHighByte) {
  if (mode == ImageReadMode::kUnchanged) return image;
  if (image.depth() == CV_16U) {
    cv::Mat bytes(image.size(), CV_MAKETYPE(CV_8U, image.channels()));
    const int n = image.cols * image.channels();
    for (int y = 0; y < image.rows; ++y) {
      const uint16_t* in = image.ptr<uint16_t>(y);
      uint8_t* out = bytes.ptr<uint8_t>(y);
      for (int x = 0; x < n; ++x) {
        out[x] = static_cast<uint8_t>(
            narrow == Narrow::kHighByte ? in[x] >> 8 : (in[x] * 255u + 32767u) / 65535u);
      }
    }
    image = bytes;
  }
  const int cn = image.channels();
  if (mode == ImageReadMode::kGrayscale) {
    if (cn == 1) return image;
    cv::Mat gray(image.size(), CV_8UC1);
    for (int y = 0; y < image.rows; ++y) {
      const uint8_t* in = image.ptr<uint8_t>(y);
      uint8_t* out = gray.ptr<uint8_t>(y);
      for (int x = 0; x < image.cols; ++x, in += cn) {
        out[x] = static_cast<uint8_t>(Gray(in[0], in[1], in[2]));
      }
    }
    return gray;
  }
  if (cn == 3) return image;
  cv::Mat bgr(image.size(), CV_8UC3);
  for (int y = 0; y < image.rows; ++y) {
    const uint8_t* in = image.ptr<uint8_t>(y);
    uint8_t* out = bgr.ptr<uint8_t>(y);
    for (int x = 0; x < image.cols; ++x, in += cn, out += 3) {
      out[0] = in[0];
      out[1] = cn == 1 ? in[0] : in[1];
      out[2] = cn == 1 ? in[0] : in[2];
    }
  }
  return bgr;
}

// ---- EXIF orientation (cv::imread applies it outside kUnchanged mode) ----

// The Orientation tag (0x0112) of IFD0 in a TIFF-structured EXIF block; 1 when absent or invalid.
int ExifOrientation(const uint8_t* p, size_t n) {
  if (n < 8) return 1;
  const bool le = p[0] == 'I' && p[1] == 'I';
  if (!le && !(p[0] == 'M' && p[1] == 'M')) return 1;
  auto u16 = [&](size_t at) -> uint32_t {
    return le ? uint32_t{p[at]} | (uint32_t{p[at + 1]} << 8)
              : (uint32_t{p[at]} << 8) | uint32_t{p[at + 1]};
  };
  auto u32 = [&](size_t at) -> uint32_t {
    return le ? u16(at) | (u16(at + 2) << 16) : (u16(at) << 16) | u16(at + 2);
  };
  if (u16(2) != 42) return 1;
  const size_t ifd = u32(4);
  if (ifd > n - 2) return 1;
  const size_t count = u16(ifd);
  for (size_t i = 0; i < count; ++i) {
    const size_t e = ifd + 2 + 12 * i;
    if (e + 12 > n) return 1;
    if (u16(e) == 0x0112) {
      const uint32_t v = u16(e + 8);
      return v >= 1 && v <= 8 ? static_cast<int>(v) : 1;
    }
  }
  return 1;
}

cv::Mat Orient(const cv::Mat& image, int orientation) {
  cv::Mat out;
  switch (orientation) {
    case 2:
      cv::flip(image, out, 1);
      return out;
    case 3:
      cv::flip(image, out, -1);
      return out;
    case 4:
      cv::flip(image, out, 0);
      return out;
    case 5:
      cv::transpose(image, out);
      return out;
    case 6:
      cv::transpose(image, out);
      cv::flip(out, out, 1);
      return out;
    case 7:
      cv::transpose(image, out);
      cv::flip(out, out, -1);
      return out;
    case 8:
      cv::transpose(image, out);
      cv::flip(out, out, 0);
      return out;
    default:
      return image;
  }
}

// ---- PNG ----

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

// ---- JPEG ----

struct JpegError {
  jpeg_error_mgr pub;
  std::jmp_buf jump;
  char message[JMSG_LENGTH_MAX];
};

void JpegErrorExit(j_common_ptr cinfo) {
  auto* e = reinterpret_cast<JpegError*>(cinfo->err);
  cinfo->err->format_message(cinfo, e->message);
  std::longjmp(e->jump, 1);
}

// Warnings are ignored as cv::imread ignores them (it prints them), except a premature end of
// the data: libjpeg would fill the rest with gray, we report a truncated file.
void JpegMessage(j_common_ptr cinfo, int level) {
  if (level < 0 && cinfo->err->msg_code == JWRN_JPEG_EOF) JpegErrorExit(cinfo);
}

struct JpegState {
  jpeg_decompress_struct cinfo;
  JpegError error;
  cv::Mat image;
  std::vector<uint8_t> row;
  int orientation = 1;
  bool too_large = false;
};

bool DecodeJpegInto(JpegState* s, const uint8_t* data, size_t size, ImageReadMode mode) {
  jpeg_decompress_struct* cinfo = &s->cinfo;
  cinfo->err = jpeg_std_error(&s->error.pub);
  s->error.pub.error_exit = JpegErrorExit;
  s->error.pub.emit_message = JpegMessage;
  jpeg_create_decompress(cinfo);
  if (setjmp(s->error.jump)) {
    jpeg_destroy_decompress(cinfo);
    return false;
  }
  cinfo->mem->max_memory_to_use = kMaxBytes;
  jpeg_mem_src(cinfo, data, static_cast<unsigned long>(size));
  jpeg_save_markers(cinfo, JPEG_APP0 + 1, 0xffff);
  jpeg_read_header(cinfo, TRUE);
  const bool color = mode == ImageReadMode::kColor ||
                     (mode == ImageReadMode::kUnchanged && cinfo->num_components > 1);
  const int64_t width = cinfo->image_width, height = cinfo->image_height;
  if (width <= 0 || height <= 0 || width > kMaxSide || height > kMaxSide ||
      width * height > kMaxPixels || width * height * 4 > kMaxBytes) {
    s->too_large = true;
    JpegErrorExit(reinterpret_cast<j_common_ptr>(cinfo));
  }
  const bool cmyk = cinfo->num_components == 4;
  if (cmyk) {
    cinfo->out_color_space = JCS_CMYK;
  } else {
    cinfo->out_color_space = color ? JCS_EXT_BGR : JCS_GRAYSCALE;
  }
  for (jpeg_saved_marker_ptr m = cinfo->marker_list; m != nullptr; m = m->next) {
    if (m->marker == JPEG_APP0 + 1) {
      if (m->data_length > 6) s->orientation = ExifOrientation(m->data + 6, m->data_length - 6);
      break;
    }
  }
  jpeg_start_decompress(cinfo);
  const int w = static_cast<int>(cinfo->output_width), h = static_cast<int>(cinfo->output_height);
  s->image.create(h, w, color ? CV_8UC3 : CV_8UC1);
  s->row.resize(static_cast<size_t>(w) * 4);
  for (int y = 0; y < h; ++y) {
    if (!cmyk) {
      JSAMPROW row = s->image.ptr<uint8_t>(y);
      jpeg_read_scanlines(cinfo, &row, 1);
      continue;
    }
    JSAMPROW row = s->row.data();
    jpeg_read_scanlines(cinfo, &row, 1);
    // opencv imgcodecs' icvCvt_CMYK2BGR_8u_C4C3R / icvCvt_CMYK2Gray_8u_C4C1R
    uint8_t* out = s->image.ptr<uint8_t>(y);
    for (int x = 0; x < w; ++x) {
      const uint8_t* p = s->row.data() + 4 * x;
      const int k = p[3];
      const int c = k - (((255 - p[0]) * k) >> 8), m = k - (((255 - p[1]) * k) >> 8),
                yy = k - (((255 - p[2]) * k) >> 8);
      if (color) {
        out[3 * x] = static_cast<uint8_t>(yy);
        out[3 * x + 1] = static_cast<uint8_t>(m);
        out[3 * x + 2] = static_cast<uint8_t>(c);
      } else {
        out[x] = static_cast<uint8_t>(Gray(yy, m, c));
      }
    }
  }
  jpeg_finish_decompress(cinfo);
  jpeg_destroy_decompress(cinfo);
  return true;
}

cv::Mat DecodeJpeg(const uint8_t* data, size_t size, ImageReadMode mode, const std::string& name) {
  auto s = std::make_unique<JpegState>();
  if (!DecodeJpegInto(s.get(), data, size, mode)) {
    SLSHADOW_THROW_IF(s->too_large, name, ": JPEG: image too large or empty");
    const bool truncated = s->error.pub.msg_code == JWRN_JPEG_EOF;
    SLSHADOW_THROW(name, ": cannot decode image: ", truncated ? "truncated" : "corrupt", " JPEG (",
                   s->error.message, ")");
  }
  return mode == ImageReadMode::kUnchanged ? s->image : Orient(s->image, s->orientation);
}

// ---- TIFF ----

struct TiffMemory {
  const uint8_t* data;
  size_t size;
  size_t pos;
};

tmsize_t TiffRead(thandle_t h, void* buf, tmsize_t n) {
  auto* m = static_cast<TiffMemory*>(h);
  if (n < 0) return -1;
  const size_t count = std::min(static_cast<size_t>(n), m->pos < m->size ? m->size - m->pos : 0);
  std::memcpy(buf, m->data + m->pos, count);
  m->pos += count;
  return static_cast<tmsize_t>(count);
}
tmsize_t TiffWriteNothing(thandle_t, void*, tmsize_t) { return -1; }
toff_t TiffSeek(thandle_t h, toff_t offset, int whence) {
  auto* m = static_cast<TiffMemory*>(h);
  uint64_t base = whence == SEEK_CUR ? m->pos : whence == SEEK_END ? m->size : 0;
  const uint64_t to = base + offset;
  if (to < base) return static_cast<toff_t>(-1);
  m->pos = static_cast<size_t>(std::min<uint64_t>(to, SIZE_MAX));
  return to;
}
int TiffClose(thandle_t) { return 0; }
toff_t TiffSize(thandle_t h) { return static_cast<TiffMemory*>(h)->size; }
int TiffMapNothing(thandle_t, void**, toff_t*) { return 0; }
void TiffUnmapNothing(thandle_t, void*, toff_t) {}

int TiffErrorHandler(TIFF*, void* user, const char* module, const char* fmt, va_list ap) {
  auto* message = static_cast<std::string*>(user);
  if (message->empty()) {
    char text[512];
    std::vsnprintf(text, sizeof(text), fmt, ap);
    *message = module != nullptr && *module != 0 ? std::string(module) + ": " + text : text;
  }
  return 1;
}
int TiffWarningHandler(TIFF*, void*, const char*, const char*, va_list) { return 1; }

struct TiffHandle {
  TIFF* tif = nullptr;
  TIFFOpenOptions* options = nullptr;
  std::string message;
  TiffHandle() {
    options = TIFFOpenOptionsAlloc();
    TIFFOpenOptionsSetErrorHandlerExtR(options, TiffErrorHandler, &message);
    TIFFOpenOptionsSetWarningHandlerExtR(options, TiffWarningHandler, nullptr);
    TIFFOpenOptionsSetMaxSingleMemAlloc(options, kMaxBytes);
  }
  ~TiffHandle() {
    if (tif != nullptr) TIFFClose(tif);
    TIFFOpenOptionsFree(options);
  }
  TiffHandle(const TiffHandle&) = delete;
  TiffHandle& operator=(const TiffHandle&) = delete;
};

cv::Mat DecodeTiff(const uint8_t* data, size_t size, ImageReadMode mode, const std::string& name) {
  TiffMemory memory{data, size, 0};
  TiffHandle h;
  h.tif = TIFFClientOpenExt(name.c_str(), "rm", &memory, TiffRead, TiffWriteNothing, TiffSeek,
                            TiffClose, TiffSize, TiffMapNothing, TiffUnmapNothing, h.options);
  SLSHADOW_THROW_IF(h.tif == nullptr, name, ": cannot decode image: corrupt TIFF (", h.message,
                    ")");
  TIFF* tif = h.tif;
  uint32_t width = 0, height = 0;
  uint16_t bits = 1, samples = 1, photometric = 0, planar = PLANARCONFIG_CONTIG,
           format = SAMPLEFORMAT_UINT;
  SLSHADOW_THROW_IF(!TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &width) ||
                        !TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &height),
                    name, ": TIFF: no image size");
  SLSHADOW_THROW_IF(!TIFFGetField(tif, TIFFTAG_PHOTOMETRIC, &photometric), name,
                    ": TIFF: no photometric interpretation");
  TIFFGetFieldDefaulted(tif, TIFFTAG_BITSPERSAMPLE, &bits);
  TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLESPERPIXEL, &samples);
  TIFFGetFieldDefaulted(tif, TIFFTAG_PLANARCONFIG, &planar);
  TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLEFORMAT, &format);
  const bool gray = photometric == PHOTOMETRIC_MINISBLACK && samples == 1;
  const bool rgb = photometric == PHOTOMETRIC_RGB && samples == 3;
  SLSHADOW_THROW_IF(!gray && !rgb, name, ": TIFF: unsupported layout (photometric ", photometric,
                    ", ", samples,
                    " samples per pixel; this reader takes min-is-black gray or 3-sample RGB)");
  SLSHADOW_THROW_IF((bits != 8 && bits != 16) || format != SAMPLEFORMAT_UINT, name,
                    ": TIFF: unsupported sample type (", bits, "-bit, sample format ", format,
                    "; this reader takes 8- or 16-bit unsigned)");
  SLSHADOW_THROW_IF(TIFFIsTiled(tif), name, ": TIFF: tiled images are not supported");
  SLSHADOW_THROW_IF(samples > 1 && planar != PLANARCONFIG_CONTIG, name,
                    ": TIFF: separate colour planes are not supported");
  const int bytes = bits / 8;
  CheckSize(name, "TIFF", width, height, int64_t{samples} * bytes);
  const int w = static_cast<int>(width), hgt = static_cast<int>(height);
  cv::Mat image(hgt, w, CV_MAKETYPE(bits == 16 ? CV_16U : CV_8U, samples));
  uint32_t rows_per_strip = height;
  TIFFGetFieldDefaulted(tif, TIFFTAG_ROWSPERSTRIP, &rows_per_strip);
  rows_per_strip = std::clamp<uint32_t>(rows_per_strip, 1, height);
  const size_t row_bytes = static_cast<size_t>(w) * samples * bytes;
  SLSHADOW_THROW_IF(static_cast<size_t>(TIFFScanlineSize64(tif)) != row_bytes, name,
                    ": TIFF: unexpected scanline size");
  std::vector<uint8_t> strip(row_bytes * rows_per_strip);
  for (uint32_t y0 = 0; y0 < height; y0 += rows_per_strip) {
    const uint32_t rows = std::min(rows_per_strip, height - y0);
    const tmsize_t want = static_cast<tmsize_t>(row_bytes * rows);
    const tmsize_t got =
        TIFFReadEncodedStrip(tif, TIFFComputeStrip(tif, y0, 0), strip.data(), want);
    SLSHADOW_THROW_IF(got != want, name, ": cannot decode image: corrupt or truncated TIFF (",
                      h.message.empty()
                          ? "strip " + std::to_string(y0 / rows_per_strip) + " is short"
                          : h.message,
                      ")");
    for (uint32_t r = 0; r < rows; ++r) {
      uint8_t* out = image.ptr<uint8_t>(static_cast<int>(y0 + r));
      std::memcpy(out, strip.data() + r * row_bytes, row_bytes);
      if (samples != 3) continue;
      if (bytes == 1) {
        for (int x = 0; x < w; ++x) std::swap(out[3 * x], out[3 * x + 2]);
      } else {
        auto* o = reinterpret_cast<uint16_t*>(out);
        for (int x = 0; x < w; ++x) std::swap(o[3 * x], o[3 * x + 2]);
      }
    }
  }
  return ToMode(image, mode, samples == 3 ? Narrow::kRound : Narrow::kHighByte);
}

void EncodeTiff(const fs::path& path, const cv::Mat& image) {
  const int channels = image.channels();
  SLSHADOW_THROW_IF(
      (channels != 1 && channels != 3) || (image.depth() != CV_8U && image.depth() != CV_16U),
      path.string(), ": cannot write image: TIFF takes 8- or 16-bit images of 1 or 3 channels");
  TiffHandle h;
  h.tif = TIFFOpenExt(path.c_str(), "w", h.options);
  SLSHADOW_THROW_IF(h.tif == nullptr, path.string(), ": cannot write image: ", h.message);
  TIFF* tif = h.tif;
  const int bits = image.depth() == CV_16U ? 16 : 8;
  TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, static_cast<uint32_t>(image.cols));
  TIFFSetField(tif, TIFFTAG_IMAGELENGTH, static_cast<uint32_t>(image.rows));
  TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, bits);
  TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, channels);
  TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, channels == 1 ? PHOTOMETRIC_MINISBLACK : PHOTOMETRIC_RGB);
  TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
  TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_NONE);
  TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, SAMPLEFORMAT_UINT);
  TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, TIFFDefaultStripSize(tif, 0));
  const size_t row_bytes = static_cast<size_t>(image.cols) * image.elemSize();
  std::vector<uint8_t> row(row_bytes);
  for (int y = 0; y < image.rows; ++y) {
    std::memcpy(row.data(), image.ptr(y), row_bytes);
    if (channels == 3 && bits == 8) {
      for (int x = 0; x < image.cols; ++x) std::swap(row[3 * x], row[3 * x + 2]);
    } else if (channels == 3) {
      auto* o = reinterpret_cast<uint16_t*>(row.data());
      for (int x = 0; x < image.cols; ++x) std::swap(o[3 * x], o[3 * x + 2]);
    }
    SLSHADOW_THROW_IF(TIFFWriteScanline(tif, row.data(), static_cast<uint32_t>(y), 0) < 0,
                      path.string(), ": cannot write image: ", h.message);
  }
  const bool ok = TIFFFlush(tif) == 1;
  TIFFClose(tif);
  h.tif = nullptr;
  SLSHADOW_THROW_IF(!ok, path.string(), ": cannot write image: ", h.message);
}

// ---- BMP ----

uint32_t Le32(const uint8_t* p) {
  return uint32_t{p[0]} | (uint32_t{p[1]} << 8) | (uint32_t{p[2]} << 16) | (uint32_t{p[3]} << 24);
}
uint16_t Le16(const uint8_t* p) { return static_cast<uint16_t>(p[0] | (p[1] << 8)); }

// Uncompressed Windows bitmaps, decoded as opencv imgcodecs' grfmt_bmp.cpp does: a palette of
// grays gives one channel, any other palette three (BGR); 24-bit gives BGR; 32-bit BI_RGB gives
// BGR (the fourth byte dropped). Rows are bottom-up unless the height is negative.
cv::Mat DecodeBmp(const uint8_t* data, size_t size, ImageReadMode mode, const std::string& name) {
  SLSHADOW_THROW_IF(size < 14 + 16, name, ": truncated BMP header");
  const uint32_t offset = Le32(data + 10);
  const uint32_t header = Le32(data + 14);
  SLSHADOW_THROW_IF(header != 40 && header != 52 && header != 56 && header != 108 && header != 124,
                    name, ": BMP: unsupported header size ", header);
  SLSHADOW_THROW_IF(size < 14 + header, name, ": truncated BMP header");
  const uint8_t* h = data + 14;
  const int64_t width = static_cast<int32_t>(Le32(h + 4));
  const int64_t signed_height = static_cast<int32_t>(Le32(h + 8));
  const int bpp = Le16(h + 14);
  const uint32_t compression = Le32(h + 16);
  uint32_t colors = Le32(h + 32);
  const bool top_down = signed_height < 0;
  const int64_t height = top_down ? -signed_height : signed_height;
  SLSHADOW_THROW_IF(bpp != 8 && bpp != 24 && bpp != 32, name, ": BMP: unsupported bit depth ", bpp,
                    " (this reader takes 8, 24 and 32 bits per pixel)");
  SLSHADOW_THROW_IF(compression != 0, name,
                    ": BMP: compressed or bit-field bitmaps are not supported (compression ",
                    compression, "; this reader takes BI_RGB)");
  CheckSize(name, "BMP", width, height, 4);
  std::vector<uint8_t> palette(256 * 4, 0);
  bool color = bpp > 8;
  if (bpp == 8) {
    if (colors == 0 || colors > 256) colors = 256;
    const size_t at = 14 + header;
    SLSHADOW_THROW_IF(at + colors * 4 > size, name, ": truncated BMP palette");
    std::memcpy(palette.data(), data + at, colors * 4);
    for (int i = 0; i < 256; ++i) {
      const uint8_t* p = palette.data() + 4 * i;
      if (p[0] != p[1] || p[0] != p[2]) color = true;
    }
  }
  const size_t pitch = (static_cast<size_t>(width) * (bpp / 8) + 3) & ~size_t{3};
  SLSHADOW_THROW_IF(offset > size || pitch * static_cast<size_t>(height) > size - offset, name,
                    ": truncated BMP: ", pitch * static_cast<size_t>(height),
                    " bytes of pixels expected at byte ", offset, ", the file has ", size);
  const int w = static_cast<int>(width), hgt = static_cast<int>(height);
  cv::Mat image(hgt, w, color ? CV_8UC3 : CV_8UC1);
  for (int y = 0; y < hgt; ++y) {
    const uint8_t* in = data + offset + pitch * static_cast<size_t>(top_down ? y : hgt - 1 - y);
    uint8_t* out = image.ptr<uint8_t>(y);
    for (int x = 0; x < w; ++x) {
      const uint8_t* p = bpp == 8 ? palette.data() + 4 * in[x] : in + x * (bpp / 8);
      if (color) {
        out[3 * x] = p[0];
        out[3 * x + 1] = p[1];
        out[3 * x + 2] = p[2];
      } else {
        out[x] = p[0];
      }
    }
  }
  return ToMode(image, mode);
}

// ---- PNM ----

// Binary PGM (P5) and PPM (P6); maxval 1..65535 (above 255: 16-bit big-endian samples). As
// cv::imread, samples are kept as stored whatever the maxval (not scaled to 255 or 65535).
cv::Mat DecodePnm(const uint8_t* data, size_t size, ImageReadMode mode, const std::string& name) {
  SLSHADOW_THROW_IF(size < 2 || data[0] != 'P' || (data[1] != '5' && data[1] != '6'), name,
                    ": PNM: only binary P5 (PGM) and P6 (PPM) are supported");
  const int channels = data[1] == '6' ? 3 : 1;
  size_t pos = 2;
  auto number = [&](const char* what) -> int64_t {
    while (pos < size) {
      if (data[pos] == '#') {
        while (pos < size && data[pos] != '\n' && data[pos] != '\r') ++pos;
      } else if (std::isspace(data[pos])) {
        ++pos;
      } else {
        break;
      }
    }
    SLSHADOW_THROW_IF(pos >= size || !std::isdigit(data[pos]), name, ": PNM header: no ", what);
    int64_t v = 0;
    while (pos < size && std::isdigit(data[pos])) {
      v = v * 10 + (data[pos++] - '0');
      SLSHADOW_THROW_IF(v > (int64_t{1} << 31), name, ": PNM header: ", what, " too large");
    }
    return v;
  };
  const int64_t width = number("width"), height = number("height"), maxval = number("maxval");
  SLSHADOW_THROW_IF(maxval < 1 || maxval > 65535, name, ": PNM header: maxval ", maxval,
                    " out of range 1..65535");
  SLSHADOW_THROW_IF(pos >= size || !std::isspace(data[pos]), name,
                    ": PNM header: no white space after maxval");
  ++pos;
  const int bytes = maxval > 255 ? 2 : 1;
  CheckSize(name, "PNM", width, height, int64_t{channels} * bytes);
  const size_t need = static_cast<size_t>(width * height) * channels * bytes;
  SLSHADOW_THROW_IF(need > size - pos, name, ": truncated PNM: ", need,
                    " bytes of pixels expected at byte ", pos, ", the file has ", size);
  const int w = static_cast<int>(width), hgt = static_cast<int>(height);
  cv::Mat image(hgt, w, CV_MAKETYPE(bytes == 2 ? CV_16U : CV_8U, channels));
  const uint8_t* in = data + pos;
  const int n = w * channels;
  for (int y = 0; y < hgt; ++y) {
    if (bytes == 2) {
      auto* out = image.ptr<uint16_t>(y);
      for (int x = 0; x < n; ++x, in += 2) out[x] = static_cast<uint16_t>((in[0] << 8) | in[1]);
      if (channels == 3) {
        for (int x = 0; x < w; ++x) std::swap(out[3 * x], out[3 * x + 2]);
      }
    } else {
      auto* out = image.ptr<uint8_t>(y);
      std::memcpy(out, in, static_cast<size_t>(n));
      in += n;
      if (channels == 3) {
        for (int x = 0; x < w; ++x) std::swap(out[3 * x], out[3 * x + 2]);
      }
    }
  }
  return ToMode(image, mode);
}

// Binary PGM / PPM in one writev of header and pixels: no encoder buffer, no row copies of 8-bit
// gray images (the simulator writes ~100 MB of these per scan). 16-bit samples are big-endian,
// colour samples RGB, as the format requires.
void WritePnm(const fs::path& path, const cv::Mat& image) {
  const int channels = image.channels();
  SLSHADOW_THROW_IF(
      (channels != 1 && channels != 3) || (image.depth() != CV_8U && image.depth() != CV_16U),
      path.string(),
      channels == 1 || path.extension() == ".pgm"
          ? ": cannot write image: PGM takes 8- or 16-bit single-channel images"
          : ": cannot write image: PPM takes 8- or 16-bit three-channel images");
  SLSHADOW_THROW_IF(path.extension() == ".pgm" && channels != 1, path.string(),
                    ": cannot write image: PGM takes 8- or 16-bit single-channel images");
  SLSHADOW_THROW_IF(path.extension() == ".ppm" && channels != 3, path.string(),
                    ": cannot write image: PPM takes 8- or 16-bit three-channel images");
  const bool wide = image.depth() == CV_16U;
  const std::string header = std::string(channels == 1 ? "P5\n" : "P6\n") +
                             std::to_string(image.cols) + " " + std::to_string(image.rows) + "\n" +
                             (wide ? "65535" : "255") + "\n";
  cv::Mat data = image.isContinuous() ? image : image.clone();
  if (wide || channels == 3) {
    cv::Mat converted(data.size(), data.type());
    const size_t n = data.total();
    if (wide) {
      const uint16_t* in = data.ptr<uint16_t>();
      uint16_t* out = converted.ptr<uint16_t>();
      for (size_t i = 0; i < n; ++i, in += channels, out += channels) {
        for (int c = 0; c < channels; ++c) {
          const uint16_t v = in[channels == 3 ? 2 - c : c];
          out[c] = static_cast<uint16_t>((v >> 8) | (v << 8));
        }
      }
    } else {
      const uint8_t* in = data.ptr<uint8_t>();
      uint8_t* out = converted.ptr<uint8_t>();
      for (size_t i = 0; i < n; ++i, in += 3, out += 3) {
        out[0] = in[2];
        out[1] = in[1];
        out[2] = in[0];
      }
    }
    data = converted;
  }
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  SLSHADOW_THROW_IF(fd < 0, path.string(), ": cannot write image: ", std::strerror(errno));
  char* const pixels = reinterpret_cast<char*>(data.data);
  const size_t pixel_bytes = data.total() * data.elemSize(), total = header.size() + pixel_bytes;
  for (size_t done = 0; done < total;) {
    iovec parts[2];
    int n = 0;
    if (done < header.size()) {
      parts[n++] = {const_cast<char*>(header.data()) + done, header.size() - done};
      parts[n++] = {pixels, pixel_bytes};
    } else {
      parts[n++] = {pixels + (done - header.size()), total - done};
    }
    const ssize_t written = ::writev(fd, parts, n);
    if (written < 0 && errno == EINTR) continue;
    if (written <= 0) {
      const int error = errno;
      ::close(fd);
      SLSHADOW_THROW(path.string(), ": cannot write image: ",
                     written < 0 ? std::strerror(error) : "nothing written");
    }
    done += static_cast<size_t>(written);
  }
  SLSHADOW_THROW_IF(::close(fd) != 0, path.string(),
                    ": cannot write image: ", std::strerror(errno));
}

std::vector<uint8_t> ReadWholeFile(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  SLSHADOW_THROW_IF(fd < 0, path.string(),
                    errno == ENOENT ? ": image file not found" : ": cannot open image: ",
                    errno == ENOENT ? "" : std::strerror(errno));
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    SLSHADOW_THROW(path.string(), ": not a regular file");
  }
  std::vector<uint8_t> bytes(static_cast<size_t>(st.st_size));
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::read(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    done += static_cast<size_t>(n);
  }
  ::close(fd);
  bytes.resize(done);
  return bytes;
}

}  // namespace

cv::Mat DecodeImage(const uint8_t* data, size_t size, ImageReadMode mode, const std::string& name) {
  SLSHADOW_THROW_IF(size == 0, name, ": cannot decode image: the file is empty");
  auto starts = [&](const char* magic, size_t n) {
    return size >= n && std::memcmp(data, magic, n) == 0;
  };
  if (starts("\x89PNG\r\n\x1a\n", 8)) return DecodePng(data, size, mode, name);
  if (starts("\xff\xd8\xff", 3)) return DecodeJpeg(data, size, mode, name);
  if (starts("II*\0", 4) || starts("MM\0*", 4)) return DecodeTiff(data, size, mode, name);
  if (starts("BM", 2)) return DecodeBmp(data, size, mode, name);
  if (size >= 2 && data[0] == 'P' && data[1] >= '1' && data[1] <= '7') {
    return DecodePnm(data, size, mode, name);
  }
  SLSHADOW_THROW(name,
                 ": cannot decode image (corrupt or unsupported format; this reader takes PNG, "
                 "JPEG, TIFF, BMP, PGM and PPM)");
}

cv::Mat ReadImage(const fs::path& path, ImageReadMode mode) {
  const std::vector<uint8_t> bytes = ReadWholeFile(path);
  return DecodeImage(bytes.data(), bytes.size(), mode, path.string());
}

std::vector<uint8_t> EncodePng(const cv::Mat& image, const std::string& name,
                               const ImageWriteOptions& options) {
  const int channels = image.channels();
  SLSHADOW_THROW_IF(image.empty() || (channels != 1 && channels != 3 && channels != 4) ||
                        (image.depth() != CV_8U && image.depth() != CV_16U),
                    name,
                    ": cannot write image: PNG takes non-empty 8- or 16-bit images of 1, 3 or 4 "
                    "channels");
  std::vector<uint8_t> bytes;
  PngState s;
  s.out = &bytes;
  s.name = name;
  SLSHADOW_THROW_IF(!EncodePngInto(&s, image, options.png_compression), name,
                    ": cannot write image: PNG encoding failed (", s.message, ")");
  return bytes;
}

void WriteImage(const fs::path& path, const cv::Mat& image, const ImageWriteOptions& options) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext == ".pgm" || ext == ".ppm") {
    WritePnm(path, image);
    return;
  }
  if (ext == ".tif" || ext == ".tiff") {
    EncodeTiff(path, image);
    return;
  }
  SLSHADOW_THROW_IF(ext != ".png", path.string(),
                    ": cannot write image: unknown extension (use .png, .pgm, .ppm, .tif or "
                    ".tiff)");
  const std::vector<uint8_t> bytes = EncodePng(image, path.string(), options);
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  SLSHADOW_THROW_IF(fd < 0, path.string(), ": cannot write image: ", std::strerror(errno));
  for (size_t done = 0; done < bytes.size();) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int error = errno;
      ::close(fd);
      SLSHADOW_THROW(path.string(),
                     ": cannot write image: ", n < 0 ? std::strerror(error) : "nothing written");
    }
    done += static_cast<size_t>(n);
  }
  SLSHADOW_THROW_IF(::close(fd) != 0, path.string(),
                    ": cannot write image: ", std::strerror(errno));
}

}  // namespace slshadow
