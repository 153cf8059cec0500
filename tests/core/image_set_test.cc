#include "core/image_set.h"

#include <fstream>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "tests/testing/error_of.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

Rig SmallRig() {
  Rig rig;
  rig.name = "small";
  rig.cameras.push_back({"left", CameraModel(64, 48, 60, 60, 31.5, 23.5, -0.1), Rigid3d()});
  rig.cameras.push_back(
      {"right", CameraModel(64, 48, 61, 61, 32, 24),
       Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitY())),
               {-100, 0, 10})});
  rig.projector = RigDevice{"projector", CameraModel(32, 20, 30, 30, 16, 10), Rigid3d()};
  return rig;
}

nlohmann::json Spec() { return {{"kind", "gray_code"}}; }

cv::Mat RandomImage(int depth, int seed) {
  cv::Mat m(48, 64, depth == 8 ? CV_8UC1 : CV_16UC1);
  cv::RNG rng(seed);
  rng.fill(m, cv::RNG::UNIFORM, 0, depth == 8 ? 256 : 65536);
  return m;
}

using testing::ErrorOf;

TEST(ImageSet, WriteReadRoundTripIsBitExact) {
  testing::TempDir dir;
  const nlohmann::json spec = {{"kind", "gray_code"}, {"projector_width", 32}};
  for (const ImageEncoding encoding :
       {ImageEncoding::kPng, ImageEncoding::kPgm, ImageEncoding::kTiff}) {
    const auto out = dir / ("set" + std::to_string(static_cast<int>(encoding)));
    std::vector<cv::Mat> images;
    {
      ImageSetWriter writer(out, SmallRig(), spec, {.encoding = encoding});
      for (int i = 0; i < 6; ++i) {
        images.push_back(RandomImage(i < 3 ? 8 : 16, i));
        writer.Add(i % 2 ? "right" : "left", i / 2, images.back(), 1000.0 + i,
                   ImageSource::kVirtual);
      }
      writer.SetExtra({{"scene", "test"}});
      EXPECT_FALSE(std::filesystem::exists(out));  // nothing visible before Commit
      writer.Commit();
    }
    const ImageSet set = ImageSet::Open(out);
    EXPECT_EQ(set.patterns(), spec);
    EXPECT_EQ(set.extra()["scene"], "test");
    EXPECT_EQ(RigToJson(set.rig()), RigToJson(SmallRig()));
    EXPECT_EQ(set.PatternCount(), 3);
    EXPECT_EQ(set.CameraNames(), (std::vector<std::string>{"left", "right"}));
    for (int i = 0; i < 6; ++i) {
      const cv::Mat back = set.Load(i % 2 ? "right" : "left", i / 2);
      ASSERT_EQ(back.type(), images[i].type());
      EXPECT_EQ(cv::norm(back, images[i], cv::NORM_INF), 0.0) << "image " << i;
      const ImageRecord* r = set.Find(i % 2 ? "right" : "left", i / 2);
      EXPECT_EQ(r->exposure_us, 1000.0 + i);
      EXPECT_EQ(r->source, ImageSource::kVirtual);
      EXPECT_EQ(r->bit_depth, i < 3 ? 8 : 16);
    }
    EXPECT_EQ(set.LoadCamera("left").size(), 3u);
  }
}

// slshadow writes PGM itself (one writev); OpenCV's reader must read back every pixel, also of a
// sub-image (rows not contiguous) and of 16-bit images (big-endian samples).
TEST(ImageSet, PgmWriterRoundTripsThroughOpenCv) {
  testing::TempDir dir;
  for (const int depth : {8, 16}) {
    const cv::Mat full = RandomImage(depth, 40 + depth);
    const cv::Mat roi = full(cv::Rect(3, 2, full.cols - 7, full.rows - 5));
    ASSERT_FALSE(roi.isContinuous());
    for (const cv::Mat& image : {full, roi}) {
      const auto path =
          dir / ("image" + std::to_string(depth) + "_" + std::to_string(image.cols) + ".pgm");
      WriteGrayImage(path, image);
      const cv::Mat back = cv::imread(path.string(), cv::IMREAD_UNCHANGED);
      ASSERT_EQ(back.type(), image.type()) << path;
      EXPECT_EQ(cv::norm(back, image, cv::NORM_INF), 0.0) << path;
    }
  }
  const auto missing = dir / "no_such_folder" / "image.pgm";
  const std::string message = ErrorOf([&] { WriteGrayImage(missing, RandomImage(8, 1)); });
  EXPECT_NE(message.find(missing.string()), std::string::npos) << message;
  EXPECT_NE(message.find("No such file"), std::string::npos) << message;
  EXPECT_NE(ErrorOf([&] {
              WriteGrayImage(dir / "color.pgm", cv::Mat(4, 4, CV_8UC3));
            }).find("single-channel"),
            std::string::npos);
}

// Sets made by other tools: the reader finds each file's format from its first bytes, as
// docs/formats.md "ImageSet" says, so a grey BMP or JPEG under any name reads (BMP bit-exact,
// JPEG within its loss); a colour file is refused naming the file.
TEST(ImageSet, ReadsGreyBmpAndJpegFromTheirBytesAndRefusesColour) {
  testing::TempDir dir;
  const auto out = dir / "set";
  std::vector<cv::Mat> images;
  {
    ImageSetWriter writer(out, SmallRig(), Spec(), {.encoding = ImageEncoding::kPng});
    for (int i = 0; i < 3; ++i) {
      images.push_back(RandomImage(8, 70 + i));
      cv::GaussianBlur(images.back(), images.back(), cv::Size(5, 5), 1.5);  // JPEG-friendly
      writer.Add("left", i, images.back(), 0, ImageSource::kDevice);
    }
    writer.Commit();
  }
  const ImageSet written = ImageSet::Open(out);
  const auto file = [&](int k) { return out / written.Find("left", k)->file; };
  std::vector<uchar> bytes;
  ASSERT_TRUE(cv::imencode(".bmp", images[0], bytes));
  std::ofstream(file(0), std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()),
             static_cast<std::streamsize>(bytes.size()));
  ASSERT_TRUE(cv::imencode(".jpg", images[1], bytes, {cv::IMWRITE_JPEG_QUALITY, 98}));
  std::ofstream(file(1), std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()),
             static_cast<std::streamsize>(bytes.size()));
  const ImageSet set = ImageSet::Open(out);
  EXPECT_EQ(cv::norm(set.Load("left", 0), images[0], cv::NORM_INF), 0.0);  // BMP: lossless
  const cv::Mat jpeg = set.Load("left", 1);
  ASSERT_EQ(jpeg.type(), CV_8UC1);
  EXPECT_LE(cv::norm(jpeg, images[1], cv::NORM_INF), 12.0);  // JPEG: lossy, but the same image
  EXPECT_GT(cv::norm(jpeg, images[1], cv::NORM_INF), 0.0);

  cv::Mat colour;
  cv::cvtColor(images[2], colour, cv::COLOR_GRAY2BGR);
  colour.col(5).setTo(cv::Scalar(0, 0, 255));
  ASSERT_TRUE(cv::imencode(".jpg", colour, bytes));
  std::ofstream(file(2), std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()),
             static_cast<std::streamsize>(bytes.size()));
  const std::string message = ErrorOf([&] { set.Load("left", 2); });
  EXPECT_NE(message.find(file(2).filename().string()), std::string::npos) << message;
  EXPECT_NE(message.find("expected a single-channel (grey) image, got 3 channels"),
            std::string::npos)
      << message;
}

TEST(ImageSet, AbandonedWriterLeavesNothing) {
  testing::TempDir dir;
  {
    ImageSetWriter writer(dir / "set", SmallRig(), Spec());
    writer.Add("left", 0, RandomImage(8, 1), 0, ImageSource::kDevice);
  }
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
}

TEST(ImageSet, WriterRejectsBadImages) {
  testing::TempDir dir;
  ImageSetWriter writer(dir / "set", SmallRig(), Spec());
  EXPECT_NE(ErrorOf([&] {
              writer.Add("left", 0, cv::Mat(47, 64, CV_8UC1), 0, ImageSource::kDevice);
            }).find("wrong image size 64x47, camera 'left' is 64x48"),
            std::string::npos);
  EXPECT_THROW(writer.Add("middle", 0, RandomImage(8, 0), 0, ImageSource::kDevice), Error);
  EXPECT_THROW(writer.Add("left", 0, cv::Mat(48, 64, CV_8UC3), 0, ImageSource::kDevice), Error);
  EXPECT_THROW(writer.Add("left", 0, cv::Mat(48, 64, CV_32FC1), 0, ImageSource::kDevice), Error);
  writer.Add("left", 0, RandomImage(8, 0), 0, ImageSource::kDevice);
  EXPECT_THROW(writer.Add("left", 0, RandomImage(8, 0), 0, ImageSource::kDevice), Error);
  EXPECT_THROW(ImageSetWriter(dir / "x", SmallRig(), Spec(), {.png_compression = 12}), Error);
  EXPECT_THROW(ImageSetWriter(dir / "y", SmallRig(), nlohmann::json()), Error);
}

TEST(ImageSet, ExistingFolderIsNotOverwrittenUnlessAsked) {
  testing::TempDir dir;
  std::filesystem::create_directories(dir / "set");
  { std::ofstream(dir / "set" / "keep.txt") << "precious"; }
  EXPECT_THROW(ImageSetWriter(dir / "set", SmallRig(), Spec()), Error);
  EXPECT_TRUE(std::filesystem::exists(dir / "set" / "keep.txt"));
  ImageSetWriter writer(dir / "set", SmallRig(), Spec(), {.overwrite = true});
  writer.Add("left", 0, RandomImage(8, 0), 0, ImageSource::kDevice);
  writer.Commit();
  EXPECT_FALSE(std::filesystem::exists(dir / "set" / "keep.txt"));
  EXPECT_NO_THROW(ImageSet::Open(dir / "set"));
}

class BadManifest : public ::testing::Test {
 protected:
  void SetUp() override {
    ImageSetWriter writer(dir_ / "set", SmallRig(), {{"kind", "gray_code"}});
    writer.Add("left", 0, RandomImage(8, 0), 0, ImageSource::kDevice);
    writer.Add("right", 0, RandomImage(8, 1), 0, ImageSource::kDevice);
    writer.Commit();
    std::ifstream in(dir_ / "set" / "manifest.json");
    manifest_ = nlohmann::json::parse(in);
  }
  std::string OpenWith(const nlohmann::json& m) {
    { std::ofstream(dir_ / "set" / "manifest.json") << m.dump(); }
    return ErrorOf([&] { ImageSet::Open(dir_ / "set").Load("left", 0); });
  }
  testing::TempDir dir_;
  nlohmann::json manifest_;
};

TEST_F(BadManifest, EachDefectIsNamed) {
  const std::string m = (dir_ / "set" / "manifest.json").string();
  nlohmann::json j = manifest_;
  j.erase("rig");
  EXPECT_EQ(OpenWith(j), m + ": rig: missing required field");
  j = manifest_;
  j["version"] = 7;
  EXPECT_NE(OpenWith(j).find("version: unsupported ImageSet version"), std::string::npos);
  j = manifest_;
  j["images"][0]["camera"] = "center";
  EXPECT_EQ(
      OpenWith(j),
      m + ": images[0].camera: no camera of this name in the manifest's rig (got \"center\")");
  j = manifest_;
  j["images"][1]["bit_depth"] = "eight";
  EXPECT_EQ(OpenWith(j), m + ": images[1].bit_depth: expected a whole number (got \"eight\")");
  j = manifest_;
  j["images"][0]["file"] = "left/none.png";
  EXPECT_NE(OpenWith(j).find("images[0].file: image file not found"), std::string::npos);
  j = manifest_;
  j["images"][0]["file"] = "../escape.png";
  EXPECT_NE(OpenWith(j).find("without '..'"), std::string::npos);
  j = manifest_;
  j["images"][1]["camera"] = "left";
  EXPECT_NE(OpenWith(j).find("duplicate image for camera 'left', pattern 0"), std::string::npos);
  j = manifest_;
  j["rig"]["cameras"][0]["intrinsics"]["fx"] = -60;
  EXPECT_EQ(OpenWith(j),
            m + ": rig.cameras[0].intrinsics.fx: focal length must be positive (got -60)");
  j = manifest_;
  j["images"][0]["bit_depth"] = 16;
  EXPECT_NE(OpenWith(j).find("bit depth is 8, the manifest says 16"), std::string::npos);
}

TEST_F(BadManifest, WrongImageSizeOrCorruptFileIsNamed) {
  cv::imwrite((dir_ / "set" / "left" / "0000.png").string(),
              cv::Mat(10, 10, CV_8UC1, cv::Scalar(3)));
  EXPECT_NE(ErrorOf([&] {
              ImageSet::Open(dir_ / "set").Load("left", 0);
            }).find("left/0000.png: wrong image size 10x10"),
            std::string::npos);
  { std::ofstream(dir_ / "set" / "right" / "0000.png") << "not a png"; }
  EXPECT_NE(
      ErrorOf([&] { ImageSet::Open(dir_ / "set").Load("right", 0); }).find("cannot decode image"),
      std::string::npos);
  { std::ofstream(dir_ / "set" / "manifest.json") << "{ broken"; }
  EXPECT_NE(ErrorOf([&] { ImageSet::Open(dir_ / "set"); }).find("not valid JSON"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] { ImageSet::Open(dir_ / "nothing"); }).find("not an ImageSet folder"),
            std::string::npos);
}

// Sizes from a manifest or an image header are bounded before anything is allocated for them.
TEST_F(BadManifest, HugePatternIndexAndHugeImageHeaderAreRefusedBeforeAllocation) {
  const std::string m = (dir_ / "set" / "manifest.json").string();
  nlohmann::json j = manifest_;
  j["images"][0]["pattern"] = 4294967296LL;  // would truncate to 0 as an int
  EXPECT_EQ(OpenWith(j),
            m + ": images[0].pattern: pattern index must be 0..999999 (got 4294967296)");
  // A gap: LoadCamera would allocate for 1000000 patterns; it names the first missing one instead.
  j = manifest_;
  j["images"][0]["pattern"] = 999999;
  { std::ofstream(dir_ / "set" / "manifest.json") << j.dump(); }
  EXPECT_EQ(ErrorOf([&] { ImageSet::Open(dir_ / "set").LoadCamera("left"); }),
            m + ": no image for camera 'left', pattern 0 (the manifest has patterns up to 999999)");
  // A PNG whose IHDR claims 100000 x 100000 pixels (10^10, 10 GB at 8 bits): refused from its
  // header, before the decoder allocates, naming the file and the claimed size.
  { std::ofstream(dir_ / "set" / "manifest.json") << manifest_.dump(); }
  const auto png = dir_ / "set" / "left" / "0000.png";
  std::string bytes;
  {
    std::ifstream in(png, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  ASSERT_EQ(bytes.substr(12, 4), "IHDR");
  const unsigned char big[4] = {0x00, 0x01, 0x86, 0xA0};  // 100000, big-endian
  bytes.replace(16, 4, reinterpret_cast<const char*>(big), 4);
  bytes.replace(20, 4, reinterpret_cast<const char*>(big), 4);
  { std::ofstream(png, std::ios::binary) << bytes; }
  EXPECT_EQ(
      ErrorOf([&] { ImageSet::Open(dir_ / "set").Load("left", 0); }),
      png.string() + ": wrong image size 100000x100000 in its header, camera 'left' is 64x48");
  // The same for a binary PGM header.
  const auto pgm = dir_ / "set" / "right" / "0000.png";
  {
    std::ofstream(pgm, std::ios::binary) << "P5\n# comment\n1000000 1000000\n255\n"
                                         << std::string(16, '\0');
  }
  EXPECT_EQ(
      ErrorOf([&] { ImageSet::Open(dir_ / "set").Load("right", 0); }),
      pgm.string() + ": wrong image size 1000000x1000000 in its header, camera 'right' is 64x48");
}

}  // namespace
}  // namespace slshadow
