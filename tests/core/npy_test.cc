#include "core/npy.h"

#include <cstring>
#include <fstream>
#include <limits>

#include <gtest/gtest.h>

#include "core/error.h"
#include "tests/testing/error_of.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

using testing::ErrorOf;

// A header as NumPy writes it: magic, version 1.0, little-endian length, dict padded to 64.
std::string Npy(const std::string& shape, const std::string& payload) {
  std::string header = "{'descr': '<f4', 'fortran_order': False, 'shape': (" + shape + "), }";
  header.append((64 - (10 + header.size() + 1) % 64) % 64, ' ');
  header += '\n';
  std::string out = std::string("\x93NUMPY\x01\x00", 8);
  out.push_back(static_cast<char>(header.size() & 0xff));
  out.push_back(static_cast<char>(header.size() >> 8));
  return out + header + payload;
}

TEST(Npy, RoundTripIsBitExactForOneAndThreeChannels) {
  testing::TempDir dir;
  for (const int channels : {1, 3}) {
    cv::Mat m(5, 7, CV_32FC(channels));
    cv::RNG rng(channels);
    rng.fill(m, cv::RNG::NORMAL, 0, 100);
    m.at<float>(2, 3) = std::numeric_limits<float>::quiet_NaN();
    WriteNpy(dir / "m.npy", m);
    const cv::Mat back = ReadNpy(dir / "m.npy", channels);
    ASSERT_EQ(back.type(), m.type());
    ASSERT_EQ(back.size(), m.size());
    EXPECT_EQ(0, std::memcmp(back.data, m.data, m.total() * m.elemSize()));
  }
}

// The shape is checked against the data before anything is allocated: a header that claims
// 10^12 floats is a clear error naming the file and the shape (it used to allocate first).
TEST(Npy, HugeOrMalformedShapesAreRefusedBeforeAllocation) {
  testing::TempDir dir;
  const auto write = [&](const std::string& name, const std::string& bytes) {
    std::ofstream(dir / name, std::ios::binary) << bytes;
    return (dir / name).string();
  };
  const std::string huge = write("huge.npy", Npy("1000000, 1000000", std::string(16, '\0')));
  EXPECT_EQ(ErrorOf([&] { ReadNpy(huge, 1); }),
            huge + ": shape 1000000 x 1000000 x 1 needs 4000000000000 data bytes, the file has 16");
  const std::string wide = write("wide.npy", Npy("4294967297, 1", std::string(16, '\0')));
  EXPECT_EQ(ErrorOf([&] { ReadNpy(wide, 1); }),
            wide + ": shape: 4294967297 x 1 is outside 1..1048576 per side");
  const std::string digits = write("digits.npy", Npy("999999999999999999999, 1", ""));
  EXPECT_NE(ErrorOf([&] { ReadNpy(digits, 1); }).find(digits + ": shape: malformed"),
            std::string::npos);
  const std::string channels = write("channels.npy", Npy("2, 2, 3", std::string(48, '\0')));
  EXPECT_EQ(ErrorOf([&] { ReadNpy(channels, 1); }),
            channels + ": shape: expected 1 channels (got 3)");
  const std::string truncated = write("truncated.npy", Npy("2, 2", std::string(15, '\0')));
  EXPECT_EQ(ErrorOf([&] { ReadNpy(truncated, 1); }),
            truncated + ": shape 2 x 2 x 1 needs 16 data bytes, the file has 15");
  const std::string not_npy = write("text.npy", "hello world");
  EXPECT_EQ(ErrorOf([&] { ReadNpy(not_npy, 1); }), not_npy + ": not a .npy file");
}

}  // namespace
}  // namespace slshadow
