// core/image_io against OpenCV's imgcodecs as the oracle: every image of ../shared/data and
// generated images of every type the reader takes decode to the same type and pixels as
// cv::imread in each mode; files our writer makes read back through cv::imread unchanged; cut or
// damaged files give one slshadow::Error naming the file, never a crash.
#include "core/image_io.h"

#include <png.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "core/error.h"
#include "tests/testing/error_of.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

namespace fs = std::filesystem;
using testing::ErrorOf;

constexpr ImageReadMode kModes[] = {ImageReadMode::kUnchanged, ImageReadMode::kGrayscale,
                                    ImageReadMode::kColor};
constexpr int kFlags[] = {cv::IMREAD_UNCHANGED, cv::IMREAD_GRAYSCALE, cv::IMREAD_COLOR};

// Ours equals cv::imread in all three modes: same size, type and every pixel.
void ExpectSameAsOpenCv(const fs::path& path) {
  for (int m = 0; m < 3; ++m) {
    SCOPED_TRACE(path.string() + " mode " + std::to_string(m));
    const cv::Mat theirs = cv::imread(path.string(), kFlags[m]);
    ASSERT_FALSE(theirs.empty());
    const cv::Mat ours = ReadImage(path, kModes[m]);
    ASSERT_EQ(ours.type(), theirs.type());
    ASSERT_EQ(ours.size(), theirs.size());
    EXPECT_EQ(cv::norm(ours, theirs, cv::NORM_INF), 0.0);
  }
}

cv::Mat Random(int rows, int cols, int type, uint64_t seed) {
  cv::Mat m(rows, cols, type);
  cv::RNG rng(seed);
  rng.fill(m, cv::RNG::UNIFORM, 0, CV_MAT_DEPTH(type) == CV_16U ? 65536 : 256);
  return m;
}

std::string Bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void WriteBytes(const fs::path& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary)
      .write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// A PNG written with libpng directly: the colour types, bit depths, palettes, tRNS, interlacing
// and eXIf chunks cv::imwrite cannot make. `samples` are the raw values, row-major, `channels`
// per pixel (1 for palette indices).
void WriteRawPng(const fs::path& path, int width, int height, int color_type, int bit_depth,
                 const std::vector<uint16_t>& samples, int channels, bool interlace,
                 int palette_size, bool trns, int orientation) {
  FILE* f = std::fopen(path.c_str(), "wb");
  ASSERT_NE(f, nullptr);
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png_create_info_struct(png);
  ASSERT_EQ(setjmp(png_jmpbuf(png)), 0);
  png_init_io(png, f);
  png_set_IHDR(png, info, static_cast<png_uint_32>(width), static_cast<png_uint_32>(height),
               bit_depth, color_type, interlace ? PNG_INTERLACE_ADAM7 : PNG_INTERLACE_NONE,
               PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  std::vector<png_color> palette(static_cast<size_t>(palette_size));
  for (int i = 0; i < palette_size; ++i) {
    palette[static_cast<size_t>(i)] = {static_cast<png_byte>(i * 37),
                                       static_cast<png_byte>(255 - i * 11),
                                       static_cast<png_byte>(i * 5 + 3)};
  }
  if (palette_size > 0) png_set_PLTE(png, info, palette.data(), palette_size);
  std::vector<png_byte> alpha(static_cast<size_t>(std::max(palette_size, 1)));
  for (size_t i = 0; i < alpha.size(); ++i) alpha[i] = static_cast<png_byte>(255 - 29 * i);
  png_color_16 trans_value{};
  trans_value.gray = 1;
  trans_value.red = 10;
  trans_value.green = 20;
  trans_value.blue = 30;
  if (trns) png_set_tRNS(png, info, alpha.data(), static_cast<int>(alpha.size()), &trans_value);
  std::vector<png_byte> exif;
  if (orientation > 0) {
    exif = {'M',  'M',  0, 42, 0, 0, 0, 8, 0, 1,
            0x01, 0x12, 0, 3,  0, 0, 0, 1, 0, static_cast<png_byte>(orientation),
            0,    0,    0, 0,  0, 0};
    png_set_eXIf_1(png, info, static_cast<png_uint_32>(exif.size()), exif.data());
  }
  png_write_info(png, info);
  // Pack the rows at the bit depth.
  const int row_bits = width * channels * bit_depth;
  std::vector<std::vector<png_byte>> rows(
      static_cast<size_t>(height), std::vector<png_byte>(static_cast<size_t>((row_bits + 7) / 8)));
  for (int y = 0; y < height; ++y) {
    auto& row = rows[static_cast<size_t>(y)];
    for (int i = 0; i < width * channels; ++i) {
      const uint16_t v = samples[static_cast<size_t>(y * width * channels + i)];
      if (bit_depth == 16) {
        row[2 * static_cast<size_t>(i)] = static_cast<png_byte>(v >> 8);
        row[2 * static_cast<size_t>(i) + 1] = static_cast<png_byte>(v & 255);
      } else if (bit_depth == 8) {
        row[static_cast<size_t>(i)] = static_cast<png_byte>(v);
      } else {
        const int bit = i * bit_depth;
        row[static_cast<size_t>(bit / 8)] |= static_cast<png_byte>(v << (8 - bit_depth - bit % 8));
      }
    }
  }
  std::vector<png_bytep> pointers;
  for (auto& r : rows) pointers.push_back(r.data());
  png_write_image(png, pointers.data());
  png_write_end(png, info);
  png_destroy_write_struct(&png, &info);
  std::fclose(f);
}

TEST(ImageIo, EveryImageOfTheSharedDataMatchesOpenCv) {
  size_t png = 0, jpg = 0;
  for (const auto& entry : fs::recursive_directory_iterator(testing::SharedDataDir())) {
    const std::string ext = entry.path().extension().string();
    if (ext != ".png" && ext != ".jpg") continue;
    ExpectSameAsOpenCv(entry.path());
    ++(ext == ".png" ? png : jpg);
  }
  EXPECT_GE(png, 252u);
  EXPECT_GE(jpg, 30u);
}

TEST(ImageIo, ImagesWrittenByOpenCvMatchOpenCv) {
  testing::TempDir dir;
  int n = 0;
  for (const int depth : {CV_8U, CV_16U}) {
    for (const int channels : {1, 3, 4}) {
      const cv::Mat image = Random(37, 53, CV_MAKETYPE(depth, channels), 7 + n);
      std::vector<std::string> exts = {".png", ".tif"};
      if (channels != 4) exts.push_back(channels == 1 ? ".pgm" : ".ppm");
      if (depth == CV_8U) exts.push_back(".bmp");
      if (depth == CV_8U && channels != 4) exts.push_back(".jpg");
      for (const std::string& ext : exts) {
        if (ext == ".tif" && channels == 4) continue;  // RGBA TIFF: not taken (a clear error)
        const fs::path path = dir / ("image" + std::to_string(n++) + ext);
        ASSERT_TRUE(cv::imwrite(path.string(), image));
        ExpectSameAsOpenCv(path);
      }
    }
  }
  // Uncompressed TIFF (the ImageSet writer's choice) and a 1-bit PNG.
  for (const int type : {CV_8UC1, CV_16UC1, CV_8UC3, CV_16UC3}) {
    const fs::path path = dir / ("plain" + std::to_string(type) + ".tif");
    ASSERT_TRUE(
        cv::imwrite(path.string(), Random(20, 31, type, 3), {cv::IMWRITE_TIFF_COMPRESSION, 1}));
    ExpectSameAsOpenCv(path);
  }
  cv::Mat bilevel = Random(19, 23, CV_8UC1, 5) > 128;
  ASSERT_TRUE(cv::imwrite((dir / "bilevel.png").string(), bilevel, {cv::IMWRITE_PNG_BILEVEL, 1}));
  ExpectSameAsOpenCv(dir / "bilevel.png");
}

TEST(ImageIo, PngColourTypesDepthsPalettesAndTransparencyMatchOpenCv) {
  testing::TempDir dir;
  const int w = 13, h = 9;
  cv::RNG rng(11);
  int n = 0;
  struct Case {
    int color_type, bit_depth, channels, palette;
    bool trns;
  };
  const std::vector<Case> cases = {
      {PNG_COLOR_TYPE_GRAY, 1, 1, 0, false},        {PNG_COLOR_TYPE_GRAY, 2, 1, 0, false},
      {PNG_COLOR_TYPE_GRAY, 4, 1, 0, true},         {PNG_COLOR_TYPE_GRAY, 8, 1, 0, true},
      {PNG_COLOR_TYPE_GRAY, 16, 1, 0, false},       {PNG_COLOR_TYPE_GRAY_ALPHA, 8, 2, 0, false},
      {PNG_COLOR_TYPE_GRAY_ALPHA, 16, 2, 0, false}, {PNG_COLOR_TYPE_RGB, 8, 3, 0, true},
      {PNG_COLOR_TYPE_RGB, 16, 3, 0, true},         {PNG_COLOR_TYPE_RGB_ALPHA, 16, 4, 0, false},
      {PNG_COLOR_TYPE_PALETTE, 1, 1, 2, false},     {PNG_COLOR_TYPE_PALETTE, 2, 1, 4, true},
      {PNG_COLOR_TYPE_PALETTE, 4, 1, 16, false},    {PNG_COLOR_TYPE_PALETTE, 8, 1, 200, true}};
  for (const Case& c : cases) {
    for (const bool interlace : {false, true}) {
      for (const int orientation : {0, 6}) {
        std::vector<uint16_t> samples(static_cast<size_t>(w * h * c.channels));
        const int limit = c.palette > 0 ? c.palette : 1 << c.bit_depth;
        for (auto& s : samples) s = static_cast<uint16_t>(rng.uniform(0, limit));
        const fs::path path = dir / ("raw" + std::to_string(n++) + ".png");
        WriteRawPng(path, w, h, c.color_type, c.bit_depth, samples, c.channels, interlace,
                    c.palette, c.trns, orientation);
        ExpectSameAsOpenCv(path);
      }
    }
  }
}

TEST(ImageIo, PnmMaxvalsAndJpegOrientationMatchOpenCv) {
  testing::TempDir dir;
  // maxval below 255 (scaled to 0..255) and between 256 and 65535 (kept as stored).
  for (const int maxval : {1, 15, 200, 1000, 65535}) {
    for (const char* magic : {"P5", "P6"}) {
      const int channels = magic[1] == '6' ? 3 : 1, bytes = maxval > 255 ? 2 : 1;
      std::string data = std::string(magic) + "\n# comment\n7 5\n" + std::to_string(maxval) + "\n";
      cv::RNG rng(static_cast<uint64_t>(maxval));
      for (int i = 0; i < 7 * 5 * channels; ++i) {
        const int v = rng.uniform(0, maxval + 1);
        if (bytes == 2) data += static_cast<char>(v >> 8);
        data += static_cast<char>(v & 255);
      }
      const fs::path path = dir / ("max" + std::to_string(maxval) + magic + ".pnm");
      WriteBytes(path, data);
      ExpectSameAsOpenCv(path);
    }
  }
  // A JPEG with an EXIF orientation: rotated in the gray and colour modes, as stored unchanged.
  for (const int channels : {1, 3}) {
    std::vector<uchar> jpeg;
    ASSERT_TRUE(cv::imencode(".jpg", Random(24, 40, CV_MAKETYPE(CV_8U, channels), 2), jpeg));
    const std::string exif(
        "\xff\xe1\x00\x22"
        "Exif\0\0MM\0\x2a\0\0\0\x08\0\x01\x01\x12\0\x03\0\0\0\x01\0\x06\0\0\0\0\0\0",
        36);
    std::string bytes(jpeg.begin(), jpeg.end());
    bytes = bytes.substr(0, 2) + exif + bytes.substr(2);
    const fs::path path = dir / ("oriented" + std::to_string(channels) + ".jpg");
    WriteBytes(path, bytes);
    ExpectSameAsOpenCv(path);
    EXPECT_EQ(ReadImage(path, ImageReadMode::kGrayscale).size(), cv::Size(24, 40));
  }
}

TEST(ImageIo, WrittenImagesReadBackThroughOpenCvUnchanged) {
  testing::TempDir dir;
  int n = 0;
  for (const int depth : {CV_8U, CV_16U}) {
    for (const int channels : {1, 3, 4}) {
      const cv::Mat full = Random(33, 47, CV_MAKETYPE(depth, channels), 100 + n);
      const cv::Mat roi = full(cv::Rect(2, 3, 40, 25));  // rows not contiguous
      std::vector<std::string> exts = {".png"};
      if (channels != 4) exts.insert(exts.end(), {channels == 1 ? ".pgm" : ".ppm", ".tif"});
      for (const cv::Mat& image : {full, roi}) {
        for (const std::string& ext : exts) {
          for (const int level : {-1, 0, 6}) {
            if (ext != ".png" && level != -1) continue;
            const fs::path path = dir / (std::to_string(n++) + "w" + ext);
            WriteImage(path, image, ImageWriteOptions{level});
            const cv::Mat back = cv::imread(path.string(), cv::IMREAD_UNCHANGED);
            SCOPED_TRACE(path.string());
            ASSERT_EQ(back.type(), image.type());
            EXPECT_EQ(cv::norm(back, image, cv::NORM_INF), 0.0);
            const cv::Mat ours = ReadImage(path);
            EXPECT_EQ(cv::norm(ours, image, cv::NORM_INF), 0.0);
          }
        }
      }
    }
  }
  const std::vector<uint8_t> png = EncodePng(Random(5, 6, CV_8UC3, 1), "x.png");
  const cv::Mat decoded = cv::imdecode(png, cv::IMREAD_UNCHANGED);
  EXPECT_EQ(cv::norm(decoded, Random(5, 6, CV_8UC3, 1), cv::NORM_INF), 0.0);
  EXPECT_NE(ErrorOf([&] {
              WriteImage(dir / "x.jpg", Random(4, 4, CV_8UC1, 1));
            }).find("x.jpg: cannot write image: unknown extension"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              WriteImage(dir / "x.png", cv::Mat(4, 4, CV_32FC1));
            }).find("x.png: cannot write image: PNG takes"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              WriteImage(dir / "no_folder" / "x.tif", Random(4, 4, CV_8UC1, 1));
            }).find("no_folder/x.tif: cannot write image"),
            std::string::npos);
}

// Every file cut short, at many lengths, or with bytes overwritten: one slshadow::Error naming the
// file, or (damaged pixel data) an image; never a crash. Cut files fail, except a TIFF cut in its
// last bytes (tag data the decoder does not need).
TEST(ImageIo, CutOrDamagedFilesGiveOneClearError) {
  testing::TempDir dir;
  std::vector<fs::path> files;
  int n = 0;
  for (const int type : {CV_8UC1, CV_16UC1, CV_8UC3}) {
    for (const std::string ext : {".png", ".tif", ".bmp", ".pgm", ".ppm", ".jpg"}) {
      const int channels = CV_MAT_CN(type);
      if ((ext == ".pgm" && channels != 1) || (ext == ".ppm" && channels != 3)) continue;
      if ((ext == ".bmp" || ext == ".jpg") && CV_MAT_DEPTH(type) != CV_8U) continue;
      files.push_back(dir / ("good" + std::to_string(n++) + ext));
      ASSERT_TRUE(cv::imwrite(files.back().string(), Random(30, 41, type, 9)));
    }
  }
  cv::RNG rng(3);
  for (const fs::path& good : files) {
    const std::string bytes = Bytes(good);
    const fs::path bad = dir / ("bad" + good.extension().string());
    std::vector<size_t> cuts = {
        0, 1, 2, 7, 8, 20, bytes.size() / 3, bytes.size() / 2, bytes.size() - 2, bytes.size() - 1};
    for (const size_t cut : cuts) {
      SCOPED_TRACE(good.string() + " cut at " + std::to_string(cut));
      WriteBytes(bad, bytes.substr(0, cut));
      const bool may_decode = good.extension() == ".tif" && cut + 2 >= bytes.size();
      for (const ImageReadMode mode : kModes) {
        const std::string message = ErrorOf([&] { (void)ReadImage(bad, mode); });
        if (may_decode && message.empty()) continue;
        EXPECT_NE(message.find(bad.string()), std::string::npos) << message;
        EXPECT_EQ(message.find('\n'), std::string::npos) << message;
      }
    }
    for (int trial = 0; trial < 40; ++trial) {
      std::string damaged = bytes;
      for (int k = 0; k < 1 + trial % 4; ++k) {
        damaged[static_cast<size_t>(rng.uniform(0, static_cast<int>(damaged.size())))] =
            static_cast<char>(rng.uniform(0, 256));
      }
      WriteBytes(bad, damaged);
      for (const ImageReadMode mode : kModes) {
        try {
          (void)ReadImage(bad, mode);
        } catch (const Error& e) {
          EXPECT_NE(std::string(e.what()).find(bad.string()), std::string::npos) << e.what();
        }
      }
    }
  }
  EXPECT_NE(
      ErrorOf([&] { (void)ReadImage(dir / "none.png"); }).find("none.png: image file not found"),
      std::string::npos);
  WriteBytes(dir / "text.png", "not an image");
  EXPECT_NE(ErrorOf([&] { (void)ReadImage(dir / "text.png"); }).find("cannot decode image"),
            std::string::npos);
}

// What the reader does not take is refused with what the file holds, not misread.
TEST(ImageIo, UnsupportedVariantsAreNamed) {
  testing::TempDir dir;
  ASSERT_TRUE(cv::imwrite((dir / "rgba.tif").string(), Random(4, 5, CV_8UC4, 1)));
  EXPECT_NE(ErrorOf([&] {
              (void)ReadImage(dir / "rgba.tif");
            }).find("rgba.tif: TIFF: unsupported layout (photometric 2, 4 samples per pixel"),
            std::string::npos);
  ASSERT_TRUE(cv::imwrite((dir / "float.tif").string(), cv::Mat(4, 5, CV_32FC1, cv::Scalar(0.5))));
  EXPECT_NE(ErrorOf([&] {
              (void)ReadImage(dir / "float.tif");
            }).find("float.tif: TIFF: unsupported sample type (32-bit, sample format 3"),
            std::string::npos);
  ASSERT_TRUE(cv::imwrite((dir / "a.bmp").string(), Random(4, 5, CV_8UC3, 1)));
  std::string bmp = Bytes(dir / "a.bmp");
  bmp[30] = 3;  // BI_BITFIELDS
  WriteBytes(dir / "bitfields.bmp", bmp);
  EXPECT_NE(ErrorOf([&] {
              (void)ReadImage(dir / "bitfields.bmp");
            }).find("bitfields.bmp: BMP: compressed or bit-field bitmaps are not supported"),
            std::string::npos);
  WriteBytes(dir / "ascii.pgm", "P2\n2 1\n255\n0 255\n");
  EXPECT_NE(ErrorOf([&] {
              (void)ReadImage(dir / "ascii.pgm");
            }).find("ascii.pgm: PNM: only binary P5 (PGM) and P6 (PPM) are supported"),
            std::string::npos);
}

}  // namespace
}  // namespace slshadow
