#include "core/image_io.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>

#include "core/error.h"
#include "core/internal/image_codecs.h"

namespace slshadow::core::internal {

void CheckSize(const std::string& name, const char* format, int64_t width, int64_t height,
               int64_t bytes_per_pixel) {
  SLSHADOW_THROW_IF(width <= 0 || height <= 0, name, ": ", format, ": invalid image size ", width,
                    " x ", height);
  SLSHADOW_THROW_IF(width > kMaxSide || height > kMaxSide || width * height > kMaxPixels ||
                        width * height * bytes_per_pixel > kMaxBytes,
                    name, ": ", format, ": image too large (", width, " x ", height, ")");
}

// Converts a decoded image whose channel order is BGR(A) (or gray) to what `mode` asks for, the way
// cv::imread does for the PNM / BMP / TIFF decoders.
cv::Mat ToMode(cv::Mat image, ImageReadMode mode, Narrow narrow) {
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

}  // namespace slshadow::core::internal

namespace slshadow {
namespace fs = std::filesystem;
namespace {

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
  if (starts("\x89PNG\r\n\x1a\n", 8)) return core::internal::DecodePng(data, size, mode, name);
  if (starts("\xff\xd8\xff", 3)) return core::internal::DecodeJpeg(data, size, mode, name);
  if (starts("II*\0", 4) || starts("MM\0*", 4))
    return core::internal::DecodeTiff(data, size, mode, name);
  if (starts("BM", 2)) return core::internal::DecodeBmp(data, size, mode, name);
  if (size >= 2 && data[0] == 'P' && data[1] >= '1' && data[1] <= '7') {
    return core::internal::DecodePnm(data, size, mode, name);
  }
  SLSHADOW_THROW(name,
                 ": cannot decode image (corrupt or unsupported format; this reader takes PNG, "
                 "JPEG, TIFF, BMP, PGM and PPM)");
}

cv::Mat ReadImage(const fs::path& path, ImageReadMode mode) {
  const std::vector<uint8_t> bytes = ReadWholeFile(path);
  return DecodeImage(bytes.data(), bytes.size(), mode, path.string());
}

void WriteImage(const fs::path& path, const cv::Mat& image, const ImageWriteOptions& options) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext == ".pgm" || ext == ".ppm") {
    core::internal::WritePnm(path, image);
    return;
  }
  if (ext == ".tif" || ext == ".tiff") {
    core::internal::EncodeTiff(path, image);
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
