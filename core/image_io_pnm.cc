#include <fcntl.h>
#include <sys/uio.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <cstring>
#include <string>

#include "core/error.h"
#include "core/internal/image_codecs.h"

namespace slshadow::core::internal {

namespace fs = std::filesystem;

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

}  // namespace slshadow::core::internal
