#include <cstring>
#include <string>

#include "core/error.h"
#include "core/internal/image_codecs.h"

namespace slshadow::core::internal {

namespace fs = std::filesystem;

namespace {

uint32_t Le32(const uint8_t* p) {
  return uint32_t{p[0]} | (uint32_t{p[1]} << 8) | (uint32_t{p[2]} << 16) | (uint32_t{p[3]} << 24);
}
uint16_t Le16(const uint8_t* p) { return static_cast<uint16_t>(p[0] | (p[1] << 8)); }

// Uncompressed Windows bitmaps, decoded as opencv imgcodecs' grfmt_bmp.cpp does: a palette of
// grays gives one channel, any other palette three (BGR); 24-bit gives BGR; 32-bit BI_RGB gives
// BGR (the fourth byte dropped). Rows are bottom-up unless the height is negative.

}  // namespace

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

}  // namespace slshadow::core::internal
