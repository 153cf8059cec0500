#include <algorithm>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include <tiffio.h>

#include "core/error.h"
#include "core/internal/image_codecs.h"

namespace slshadow::core::internal {

namespace fs = std::filesystem;

namespace {

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

}  // namespace

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

}  // namespace slshadow::core::internal
