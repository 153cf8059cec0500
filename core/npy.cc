#include "core/npy.h"

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/file_util.h"

namespace slshadow {

void WriteNpy(const std::filesystem::path& path, const cv::Mat& m) {
  SLSHADOW_CHECK(m.depth() == CV_32F && (m.channels() == 1 || m.channels() == 3) &&
                 m.isContinuous());
  std::string header = "{'descr': '<f4', 'fortran_order': False, 'shape': (" +
                       std::to_string(m.rows) + ", " + std::to_string(m.cols) +
                       (m.channels() == 3 ? ", 3), }" : "), }");
  const size_t total = 10 + header.size() + 1;
  header.append((64 - total % 64) % 64, ' ');
  header += '\n';
  WriteFileAtomically(path, [&](const std::filesystem::path& tmp) {
    std::FILE* f = std::fopen(tmp.c_str(), "wb");
    SLSHADOW_THROW_IF(!f, path.string(), ": cannot write");
    const char magic[8] = {'\x93', 'N', 'U', 'M', 'P', 'Y', 1, 0};
    const uint16_t len = static_cast<uint16_t>(header.size());
    const unsigned char len_le[2] = {static_cast<unsigned char>(len & 0xff),
                                     static_cast<unsigned char>(len >> 8)};
    const size_t bytes = m.total() * m.elemSize();
    bool ok = std::fwrite(magic, 1, 8, f) == 8 && std::fwrite(len_le, 1, 2, f) == 2 &&
              std::fwrite(header.data(), 1, header.size(), f) == header.size() &&
              std::fwrite(m.data, 1, bytes, f) == bytes;
    ok = std::fclose(f) == 0 && ok;
    SLSHADOW_THROW_IF(!ok, path.string(), ": write failed (disk full?)");
  });
}

cv::Mat ReadNpy(const std::filesystem::path& path, int channels) {
  const std::string file = path.string();
  const std::string data = ReadTextFile(path);
  SLSHADOW_THROW_IF(data.size() < 10 || data.compare(0, 6, "\x93NUMPY") != 0, file,
                    ": not a .npy file");
  const size_t len = static_cast<unsigned char>(data[8]) |
                     (static_cast<size_t>(static_cast<unsigned char>(data[9])) << 8);
  SLSHADOW_THROW_IF(data.size() < 10 + len, file, ": truncated header");
  const std::string header = data.substr(10, len);
  SLSHADOW_THROW_IF(
      header.find("'<f4'") == std::string::npos || header.find("False") == std::string::npos, file,
      ": descr/fortran_order: expected little-endian float32 in C order (header ", header, ")");
  const size_t open = header.find("'shape': (");
  SLSHADOW_THROW_IF(open == std::string::npos, file, ": shape: missing in header");
  // Up to three non-negative integers separated by ", " and closed by ')'.
  std::vector<uint64_t> shape;
  size_t pos = open + 10;
  while (pos < header.size() && header[pos] != ')') {
    if (header[pos] == ' ' || header[pos] == ',') {
      ++pos;
      continue;
    }
    uint64_t v = 0;
    size_t digits = 0;
    for (; pos < header.size() && header[pos] >= '0' && header[pos] <= '9' && digits < 12;
         ++pos, ++digits) {
      v = v * 10 + static_cast<uint64_t>(header[pos] - '0');
    }
    SLSHADOW_THROW_IF(digits == 0 || digits == 12 || shape.size() == 3, file,
                      ": shape: malformed in header ", header);
    shape.push_back(v);
  }
  SLSHADOW_THROW_IF(pos >= header.size() || shape.size() < 2, file, ": shape: malformed in header ",
                    header);
  const uint64_t ch = shape.size() == 3 ? shape[2] : 1;
  SLSHADOW_THROW_IF(ch != static_cast<uint64_t>(channels), file, ": shape: expected ", channels,
                    " channels (got ", ch, ")");
  // Dimensions have at most 11 digits, so the product below cannot overflow 64 bits before the
  // per-dimension limit stops it.
  constexpr uint64_t kMaxSide = 1u << 20;
  SLSHADOW_THROW_IF(shape[0] == 0 || shape[1] == 0 || shape[0] > kMaxSide || shape[1] > kMaxSide,
                    file, ": shape: ", shape[0], " x ", shape[1], " is outside 1..", kMaxSide,
                    " per side");
  const uint64_t bytes = shape[0] * shape[1] * ch * sizeof(float);
  SLSHADOW_THROW_IF(data.size() - 10 - len != bytes, file, ": shape ", shape[0], " x ", shape[1],
                    " x ", ch, " needs ", bytes, " data bytes, the file has ",
                    data.size() - 10 - len);
  cv::Mat m(static_cast<int>(shape[0]), static_cast<int>(shape[1]), CV_32FC(channels));
  std::memcpy(m.data, data.data() + 10 + len, bytes);
  return m;
}

}  // namespace slshadow
