#include "core/point_cloud.h"

#include <cstring>
#include <fstream>
#include <random>

#include <gtest/gtest.h>

#include "core/error.h"
#include "tests/testing/error_of.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

using testing::ErrorOf;

PointCloud RandomCloud(size_t n, bool normals, bool colors, int seed = 3) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0, 100);
  std::uniform_int_distribution<int> byte(0, 255);
  PointCloud c;
  std::vector<float> quality, u;
  for (size_t i = 0; i < n; ++i) {
    c.points.emplace_back(g(rng), g(rng), 500 + g(rng));
    if (normals) c.normals.push_back(Eigen::Vector3f(g(rng), g(rng), g(rng)).normalized());
    if (colors)
      c.colors.push_back({static_cast<uint8_t>(byte(rng)), static_cast<uint8_t>(byte(rng)),
                          static_cast<uint8_t>(byte(rng))});
    quality.push_back(static_cast<float>(g(rng)));
    u.push_back(static_cast<float>(i) + 0.5f);
  }
  c.SetScalar("quality", quality);
  c.SetScalar("pixel_u", u);
  return c;
}

void ExpectBitExact(const PointCloud& a, const PointCloud& b) {
  ASSERT_EQ(a.size(), b.size());
  // memcmp only over non-empty arrays (an empty vector's data() may be null: UB for memcmp, UBSan).
  if (!a.points.empty()) {
    EXPECT_EQ(0, std::memcmp(a.points.data(), b.points.data(), a.size() * sizeof(Eigen::Vector3d)));
  }
  ASSERT_EQ(a.normals.size(), b.normals.size());
  if (!a.normals.empty()) {
    EXPECT_EQ(0, std::memcmp(a.normals.data(), b.normals.data(),
                             a.normals.size() * sizeof(Eigen::Vector3f)));
  }
  EXPECT_EQ(a.colors, b.colors);
  ASSERT_EQ(a.scalars.size(), b.scalars.size());
  for (size_t k = 0; k < a.scalars.size(); ++k) {
    EXPECT_EQ(a.scalars[k].name, b.scalars[k].name);
    EXPECT_EQ(0, std::memcmp(a.scalars[k].values.data(), b.scalars[k].values.data(),
                             a.size() * sizeof(float)));
  }
}

TEST(PointCloud, BinaryAndAsciiRoundTripsAreBitExact) {
  testing::TempDir dir;
  for (bool normals : {false, true}) {
    for (bool colors : {false, true}) {
      const PointCloud c = RandomCloud(1000, normals, colors);
      WritePly(dir / "b.ply", c);
      ExpectBitExact(c, ReadPly(dir / "b.ply"));
      WritePly(dir / "a.ply", c, {.binary = false});
      ExpectBitExact(c, ReadPly(dir / "a.ply"));
    }
  }
}

// Binary records are written in chunks of 16 384: a cloud of several chunks and a partial one
// round-trips bit for bit, with double positions and (rounded once to float) with float ones.
TEST(PointCloud, ChunkedBinaryWritesRoundTrip) {
  testing::TempDir dir;
  const PointCloud c = RandomCloud(40000, true, true, 5);
  WritePly(dir / "d.ply", c);
  ExpectBitExact(c, ReadPly(dir / "d.ply"));
  WritePly(dir / "f.ply", c, {.binary = true, .double_positions = false});
  const PointCloud f = ReadPly(dir / "f.ply");
  PointCloud rounded = c;
  for (auto& p : rounded.points) p = p.cast<float>().cast<double>();
  ExpectBitExact(rounded, f);
  // 12 bytes less per point, and "float" is one letter shorter than "double" in 3 header lines.
  EXPECT_EQ(std::filesystem::file_size(dir / "d.ply") - std::filesystem::file_size(dir / "f.ply"),
            40000u * 12u + 3u);
}

// An independent reader for the binary layout we promise in docs/formats.md: header lines, then
// per vertex double x y z, float nx ny nz, uchar r g b, one float per scalar field.
TEST(PointCloud, BinaryLayoutMatchesDocumentedHeader) {
  testing::TempDir dir;
  const PointCloud c = RandomCloud(50, true, true);
  WritePly(dir / "c.ply", c);
  std::ifstream f(dir / "c.ply", std::ios::binary);
  std::string line;
  std::vector<std::string> header;
  while (std::getline(f, line) && line != "end_header") header.push_back(line);
  const std::vector<std::string> expected = {"ply",
                                             "format binary_little_endian 1.0",
                                             "comment written by slshadow",
                                             "element vertex 50",
                                             "property double x",
                                             "property double y",
                                             "property double z",
                                             "property float nx",
                                             "property float ny",
                                             "property float nz",
                                             "property uchar red",
                                             "property uchar green",
                                             "property uchar blue",
                                             "property float quality",
                                             "property float pixel_u"};
  EXPECT_EQ(header, expected);
  const std::streampos body = f.tellg();
  f.seekg(0, std::ios::end);
  EXPECT_EQ(static_cast<size_t>(f.tellg() - body), 50u * (24 + 12 + 3 + 8));
  f.seekg(body + std::streamoff(17 * 49));  // not used: layout checked per record below
  f.seekg(body);
  for (size_t i = 0; i < c.size(); ++i) {
    double xyz[3];
    float n[3];
    uint8_t rgb[3];
    float s[2];
    f.read(reinterpret_cast<char*>(xyz), 24);
    f.read(reinterpret_cast<char*>(n), 12);
    f.read(reinterpret_cast<char*>(rgb), 3);
    f.read(reinterpret_cast<char*>(s), 8);
    EXPECT_EQ(xyz[2], c.points[i].z());
    EXPECT_EQ(n[1], c.normals[i].y());
    EXPECT_EQ(rgb[2], c.colors[i][2]);
    EXPECT_EQ(s[1], (*c.Scalar("pixel_u"))[i]);
  }
}

TEST(PointCloud, ReadsForeignPlyWithFloatPositionsAndFaces) {
  testing::TempDir dir;
  {
    std::ofstream f(dir / "foreign.ply");
    f << "ply\nformat ascii 1.0\ncomment made by hand\nelement vertex 3\nproperty float32 "
         "x\nproperty float32 y\n"
         "property float32 z\nproperty uchar intensity\nelement face 1\nproperty list uchar int "
         "vertex_indices\n"
         "end_header\n0 0 0 10\n1 0 0 20\n0 1 0 30\n3 0 1 2\n";
  }
  const PointCloud c = ReadPly(dir / "foreign.ply");
  ASSERT_EQ(c.size(), 3u);
  EXPECT_EQ(c.points[1], Eigen::Vector3d(1, 0, 0));
  ASSERT_NE(c.Scalar("intensity"), nullptr);
  EXPECT_EQ((*c.Scalar("intensity"))[2], 30.0f);
}

TEST(PointCloud, BadPlyFilesGiveClearErrors) {
  testing::TempDir dir;
  const PointCloud c = RandomCloud(100, true, false);
  WritePly(dir / "full.ply", c);
  std::ifstream in(dir / "full.ply", std::ios::binary);
  std::string data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  {
    std::ofstream out(dir / "truncated.ply", std::ios::binary);
    out.write(data.data(), static_cast<std::streamsize>(data.size() - 100));
  }
  try {
    ReadPly(dir / "truncated.ply");
    FAIL();
  } catch (const Error& e) {
    // Fixed-size rows: the header's count is checked against the data before reading.
    EXPECT_NE(std::string(e.what()).find(
                  "PLY header: element 'vertex' claims 100 rows, but the file has only"),
              std::string::npos)
        << e.what();
  }
  // Lists have no fixed size: data ending inside a list is found while reading.
  {
    std::ofstream out(dir / "truncated_list.ply", std::ios::binary);
    out << "ply\nformat binary_little_endian 1.0\nelement face 1\nproperty list uchar int "
           "vertex_indices\nend_header\n";
    out.put(3);
    out.write("\0\0\0\0\1\0\0\0", 8);
  }
  try {
    ReadPlyData(dir / "truncated_list.ply");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("truncated binary PLY: data ends in element 'face' row 0"),
              std::string::npos)
        << e.what();
  }
  {
    std::ofstream out(dir / "nomagic.ply");
    out << "hello\n";
  }
  EXPECT_THROW(ReadPly(dir / "nomagic.ply"), Error);
  {
    std::ofstream out(dir / "noxyz.ply");
    out << "ply\nformat ascii 1.0\nelement vertex 1\nproperty float a\nend_header\n1\n";
  }
  EXPECT_THROW(ReadPly(dir / "noxyz.ply"), Error);
  {
    std::ofstream out(dir / "nan.ply");
    out << "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty "
           "float z\nend_header\n1 nan 2\n";
  }
  EXPECT_THROW(ReadPly(dir / "nan.ply"), Error);
  {
    std::ofstream out(dir / "word.ply");
    out << "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty "
           "float z\nend_header\n1 two 2\n";
  }
  try {
    ReadPly(dir / "word.ply");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("property 'y': not a number (got \"two\")"),
              std::string::npos)
        << e.what();
  }
  EXPECT_THROW(ReadPly(dir / "missing.ply"), Error);
  PointCloud bad = RandomCloud(10, false, false);
  bad.scalars[0].values.pop_back();
  EXPECT_THROW(WritePly(dir / "bad.ply", bad), Error);
  EXPECT_FALSE(std::filesystem::exists(dir / "bad.ply"));
  PointCloud badname = RandomCloud(10, false, false);
  badname.scalars[0].name = "has space";
  EXPECT_THROW(WritePly(dir / "bad.ply", badname), Error);
}

TEST(PointCloud, FailedWriteKeepsExistingFile) {
  testing::TempDir dir;
  const PointCloud good = RandomCloud(10, false, false);
  WritePly(dir / "out.ply", good);
  PointCloud bad = good;
  bad.normals.resize(3);
  EXPECT_THROW(WritePly(dir / "out.ply", bad), Error);
  ExpectBitExact(good, ReadPly(dir / "out.ply"));
}

// Element counts in a PLY header are bounded by the data that follows before anything is
// allocated: a header claiming 10^12 vertices is a clear error naming the file and the count.
TEST(PointCloud, HugeHeaderCountsAreRefusedBeforeAllocation) {
  testing::TempDir dir;
  const auto write = [&](const std::string& name, const std::string& text) {
    std::ofstream(dir / name, std::ios::binary) << text;
    return (dir / name).string();
  };
  const std::string bin =
      write("huge.ply",
            "ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\n"
            "property double x\nproperty double y\nproperty double z\nend_header\n" +
                std::string(48, '\0'));
  EXPECT_EQ(ErrorOf([&] { ReadPly(bin); }),
            bin +
                ": PLY header: element 'vertex' claims 1000000000000 rows, but the "
                "file has only 48 bytes of data (at least 24 bytes per row)");
  const std::string ascii =
      write("huge_ascii.ply",
            "ply\nformat ascii 1.0\nelement vertex 1000000000000\nproperty float x\n"
            "property float y\nproperty float z\nend_header\n1 2 3\n");
  EXPECT_NE(ErrorOf([&] {
              ReadPly(ascii);
            }).find(ascii + ": PLY header: element 'vertex' claims 1000000000000 rows"),
            std::string::npos);
  // A count that does not fit in 64 bits is a bad element line, not LLONG_MAX rows.
  const std::string overflow =
      write("overflow.ply",
            "ply\nformat ascii 1.0\nelement vertex 99999999999999999999\nproperty float x\n"
            "end_header\n");
  EXPECT_THROW(ReadPly(overflow), Error);
  // Lists: a NaN vertex index (a float list type allows it) and x given as a list.
  const std::string nan_index =
      write("nan_index.ply",
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            "property float z\nelement face 1\nproperty list uchar float vertex_indices\n"
            "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 nan\n");
  EXPECT_EQ(
      ErrorOf([&] { ReadPlyData(nan_index); }),
      nan_index +
          ": element 'face' row 0 property 'vertex_indices': list value nan is not an integer");
  const std::string x_list =
      write("x_list.ply",
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar int x\n"
            "property float y\nproperty float z\nend_header\n1 5 0 0\n");
  EXPECT_EQ(ErrorOf([&] { ReadPly(x_list); }),
            x_list + ": PLY vertex property 'x' is a list, expected a number");
}

}  // namespace
}  // namespace slshadow
