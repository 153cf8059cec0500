#include <csetjmp>
#include <cstdio>
#include <memory>
#include <string>

#include <jerror.h>
#include <jpeglib.h>

#include "core/error.h"
#include "core/internal/image_codecs.h"

namespace slshadow::core::internal {

namespace fs = std::filesystem;

namespace {

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

}  // namespace

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

}  // namespace slshadow::core::internal
