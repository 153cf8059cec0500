// The V4L2 backend against an LD_PRELOAD shim (tests/capture/v4l2_shim.cc) that plays a UVC camera
// serving recorded frames: each format arrives bit-exact (GREY, Y16 little-endian, YUYV -> its
// luma bytes), frame ids and timestamps come from the driver, exposure and gain reach the device's
// controls and read back, settings the device cannot honour are refused by name, and a device that
// stops delivering gives timeouts, not stale frames. CTest sets LD_PRELOAD to the shim.
#include "capture/v4l2_camera.h"

#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <random>

#include <gtest/gtest.h>

#include "capture/factory.h"
#include "core/error.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::capture {
namespace {
using namespace std::chrono_literals;

constexpr const char* kDevice = "/dev/video-slshadow-shim";

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

bool ShimLoaded() {
  const char* preload = std::getenv("LD_PRELOAD");
  return preload != nullptr && std::strstr(preload, "v4l2_shim") != nullptr;
}

class V4l2CameraTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!ShimLoaded()) GTEST_SKIP() << "needs LD_PRELOAD of the v4l2 shim (run through ctest)";
    setenv("V4L2_SHIM_DEVICE", kDevice, 1);
    setenv("V4L2_SHIM_CONTROLS", "exposure,gain", 1);
  }
  // Writes `count` random frames of `bytes` each (seeded) and points the shim at them.
  std::vector<std::vector<uint8_t>> Record(const std::string& format, int width, int height,
                                           int bpp, int count) {
    std::mt19937 rng(1234);
    std::vector<std::vector<uint8_t>> frames(count,
                                             std::vector<uint8_t>(size_t(width) * height * bpp));
    std::ofstream out(dir_ / "frames.raw", std::ios::binary);
    for (auto& f : frames) {
      for (auto& v : f) v = static_cast<uint8_t>(rng());
      out.write(reinterpret_cast<const char*>(f.data()), static_cast<std::streamsize>(f.size()));
    }
    out.close();
    setenv("V4L2_SHIM_FORMAT", format.c_str(), 1);
    setenv("V4L2_SHIM_WIDTH", std::to_string(width).c_str(), 1);
    setenv("V4L2_SHIM_HEIGHT", std::to_string(height).c_str(), 1);
    setenv("V4L2_SHIM_FRAMES", (dir_ / "frames.raw").c_str(), 1);
    return frames;
  }
  testing::TempDir dir_;
};

TEST_F(V4l2CameraTest, GreyFramesAreBitExactThenTheDeviceStops) {
  const auto frames = Record("GREY", 64, 48, 1, 10);
  V4l2Camera camera(kDevice);
  const CameraInfo info = camera.Info();
  EXPECT_EQ(info.backend, "v4l2");
  EXPECT_EQ(info.model, "Shim UVC Camera");
  EXPECT_EQ(info.sensor_width, 64);
  EXPECT_EQ(info.pixel_formats, (std::vector<PixelFormat>{PixelFormat::kMono8}));
  CameraSettings s;
  s.trigger = TriggerMode::kFreeRun;
  camera.Configure(s);
  camera.Start();
  for (int i = 0; i < 10; ++i) {
    const Frame f = camera.Grab(1000ms);
    ASSERT_TRUE(f.ok()) << f.message;
    ASSERT_EQ(f.image.type(), CV_8UC1);
    ASSERT_EQ(f.image.cols, 64);
    ASSERT_EQ(f.image.rows, 48);
    EXPECT_EQ(std::memcmp(f.image.data, frames[i].data(), frames[i].size()), 0) << "frame " << i;
    EXPECT_EQ(f.frame_id, uint64_t(i));
    EXPECT_EQ(f.device_timestamp_ns, 1000000000000ull + uint64_t(i) * 33333000ull);
  }
  // No more frames: a timeout each time, never a repeated frame.
  for (int i = 0; i < 2; ++i) {
    const Frame f = camera.Grab(50ms);
    EXPECT_EQ(f.status, FrameStatus::kTimeout);
    EXPECT_NE(f.message.find("no frame within 50 ms"), std::string::npos);
    EXPECT_TRUE(f.image.empty());
  }
  EXPECT_EQ(camera.Statistics().completed_frames, 10u);
  EXPECT_EQ(camera.Statistics().timeouts, 2u);
  camera.Stop();
  EXPECT_EQ(camera.Grab(10ms).status, FrameStatus::kAborted);
}

TEST_F(V4l2CameraTest, DamagedFramesAreReportedAndTheStreamGoesOn) {
  const auto frames = Record("GREY", 16, 8, 1, 5);
  setenv("V4L2_SHIM_ERROR_FRAME", "1", 1);
  setenv("V4L2_SHIM_SHORT_FRAME", "3", 1);
  V4l2Camera camera(kDevice, V4l2CameraOptions{2});
  camera.Configure(CameraSettings{});
  camera.Start();
  std::vector<FrameStatus> statuses;
  for (int i = 0; i < 5; ++i) {
    const Frame f = camera.Grab(1000ms);
    statuses.push_back(f.status);
    if (f.ok()) {
      EXPECT_EQ(std::memcmp(f.image.data, frames[i].data(), frames[i].size()), 0) << i;
    }
    if (i == 1) {
      EXPECT_NE(f.message.find("flagged frame 1 as damaged"), std::string::npos) << f.message;
    }
    if (i == 3) {
      EXPECT_NE(f.message.find("frame of 64 bytes, expected 128"), std::string::npos) << f.message;
    }
  }
  unsetenv("V4L2_SHIM_ERROR_FRAME");
  unsetenv("V4L2_SHIM_SHORT_FRAME");
  EXPECT_EQ(statuses,
            (std::vector<FrameStatus>{FrameStatus::kOk, FrameStatus::kOtherError, FrameStatus::kOk,
                                      FrameStatus::kSizeMismatch, FrameStatus::kOk}));
  EXPECT_EQ(camera.Statistics().failed_frames, 2u);
  EXPECT_EQ(camera.Statistics().completed_frames, 3u);
}

TEST_F(V4l2CameraTest, Y16IsLittleEndianSixteenBit) {
  const auto frames = Record("Y16", 32, 24, 2, 3);
  V4l2Camera camera(kDevice);
  CameraSettings s;
  s.pixel_format = PixelFormat::kMono16;
  camera.Configure(s);
  camera.Start();
  for (int i = 0; i < 3; ++i) {
    const Frame f = camera.Grab(1000ms);
    ASSERT_TRUE(f.ok()) << f.message;
    ASSERT_EQ(f.image.type(), CV_16UC1);
    for (int y = 0; y < 24; ++y) {
      for (int x = 0; x < 32; ++x) {
        const size_t at = 2 * (size_t(y) * 32 + x);
        ASSERT_EQ(f.image.at<uint16_t>(y, x), frames[i][at] | frames[i][at + 1] << 8)
            << i << " " << x << "," << y;
      }
    }
  }
  // Mono8 is not offered by a Y16-only device: refused by name.
  CameraSettings mono8;
  camera.Stop();
  EXPECT_NE(ErrorOf([&] { camera.Configure(mono8); })
                .find("/dev/video-slshadow-shim: settings.pixel_format: Mono8 needs GREY or YUYV "
                      "but the device offers Y16"),
            std::string::npos);
}

TEST_F(V4l2CameraTest, YuyvGivesTheLumaBytes) {
  const auto frames = Record("YUYV", 40, 30, 2, 4);
  V4l2Camera camera(kDevice);
  camera.Configure(CameraSettings{});
  camera.Start();
  for (int i = 0; i < 4; ++i) {
    const Frame f = camera.Grab(1000ms);
    ASSERT_TRUE(f.ok()) << f.message;
    ASSERT_EQ(f.image.type(), CV_8UC1);
    for (int y = 0; y < 30; ++y) {
      for (int x = 0; x < 40; ++x)
        ASSERT_EQ(f.image.at<uint8_t>(y, x), frames[i][2 * (size_t(y) * 40 + x)]);
    }
  }
}

TEST_F(V4l2CameraTest, ControlsReachTheDeviceOrAreRefusedByName) {
  Record("GREY", 16, 16, 1, 2);
  {
    V4l2Camera camera(kDevice);
    CameraSettings s;
    s.exposure_us = 5000;
    s.gain_db = 12;
    camera.Configure(s);
    const CameraSettings back = camera.Settings();  // read back through VIDIOC_G_CTRL
    EXPECT_EQ(back.exposure_us, 5000.0);
    EXPECT_EQ(back.gain_db, 12.0);
    s.exposure_us = 5050;  // not a multiple of 100 us: rounded with a warning
    camera.Configure(s);
    EXPECT_EQ(camera.Settings().exposure_us, 5100.0);
    EXPECT_FALSE(camera.Warnings().empty());
    s.gain_db = 300;  // the device's range is 0..255
    EXPECT_NE(ErrorOf([&] {
                camera.Configure(s);
              }).find("settings.gain_db: the device refused value 300"),
              std::string::npos);
    CameraSettings hw;
    hw.trigger = TriggerMode::kHardware;
    EXPECT_NE(ErrorOf([&] {
                camera.Configure(hw);
              }).find("settings.trigger: UVC cameras have no trigger input"),
              std::string::npos);
    CameraSettings roi;
    roi.roi = Roi{0, 0, 8, 8};
    EXPECT_NE(ErrorOf([&] {
                camera.Configure(roi);
              }).find("settings.roi: asked for 8x8, the device offers 16x16"),
              std::string::npos);
  }
  setenv("V4L2_SHIM_CONTROLS", "", 1);
  V4l2Camera bare(kDevice);
  CameraSettings s;
  s.exposure_us = 1000;
  EXPECT_NE(ErrorOf([&] {
              bare.Configure(s);
            }).find("settings.exposure_us: the device has no exposure control"),
            std::string::npos);
  s.exposure_us.reset();
  s.gain_db = 1;
  EXPECT_NE(
      ErrorOf([&] { bare.Configure(s); }).find("settings.gain_db: the device has no gain control"),
      std::string::npos);
  EXPECT_NE(ErrorOf([] {
              V4l2Camera("/dev/video-none-such");
            }).find("/dev/video-none-such: cannot open the V4L2 device"),
            std::string::npos);
}

TEST_F(V4l2CameraTest, SoftwareTriggerDropsFramesAlreadyDelivered) {
  const auto frames = Record("GREY", 16, 8, 1, 6);
  V4l2Camera camera(kDevice, V4l2CameraOptions{2});
  camera.Configure(CameraSettings{});  // software trigger by default
  camera.Start();
  const Frame first = camera.Grab(1000ms);
  ASSERT_TRUE(first.ok());
  EXPECT_EQ(first.frame_id, 0u);
  camera.Trigger();  // the shim delivers at once: frames 1 and 2 (two buffers) are dropped
  const Frame next = camera.Grab(1000ms);
  ASSERT_TRUE(next.ok());
  EXPECT_EQ(next.frame_id, 3u);
  EXPECT_EQ(std::memcmp(next.image.data, frames[3].data(), frames[3].size()), 0);
}

// The devices.yaml example's v4l2 entries open through the factory (its node swapped for the
// shim's).
TEST_F(V4l2CameraTest, FactoryOpensTheExampleEntry) {
  const auto frames = Record("GREY", 16, 8, 1, 1);
  DevicesConfig devices =
      LoadDevices(::slshadow::testing::SourceDir() / "config/devices/uvc_lightcrafter.yaml");
  ASSERT_EQ(devices.cameras.size(), 2u);
  EXPECT_EQ(devices.cameras[0].id, "/dev/video0");
  EXPECT_EQ(devices.projector.backend, "lightcrafter");
  CameraEntry entry = devices.cameras[0];
  entry.id = kDevice;
  auto camera = OpenCamera(entry);
  EXPECT_EQ(camera->Info().backend, "v4l2");
  camera->Configure(entry.settings);
  EXPECT_EQ(camera->Settings().exposure_us, 10000.0);
  camera->Start();
  const Frame f = camera->Grab(1000ms);
  ASSERT_TRUE(f.ok()) << f.message;
  EXPECT_EQ(std::memcmp(f.image.data, frames[0].data(), frames[0].size()), 0);
  entry.id = "/dev/video-none-such";
  try {
    OpenCamera(entry);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(
                  "uvc_lightcrafter.yaml: cameras[0]: /dev/video-none-such: cannot open"),
              std::string::npos)
        << e.what();
  }
}

TEST(V4l2Nodes, ListsVideoNodesInNumericOrder) {
  ::slshadow::testing::TempDir dir;
  for (const char* name : {"video10", "video2", "video", "videoX", "media0", "video0"})
    std::ofstream(dir / name) << "";
  EXPECT_EQ(ListV4l2Nodes(dir.path().string()),
            (std::vector<std::string>{(dir / "video0").string(), (dir / "video2").string(),
                                      (dir / "video10").string()}));
  EXPECT_TRUE(ListV4l2Nodes((dir / "missing").string()).empty());
}

// Frames per second through the shim (printed for docs/benchmarks.md; asserted only for
// correctness).
TEST_F(V4l2CameraTest, Throughput) {
  constexpr int kN = 300;
  const auto frames = Record("GREY", 640, 480, 1, kN);
  V4l2Camera camera(kDevice);
  CameraSettings s;
  s.trigger = TriggerMode::kFreeRun;
  camera.Configure(s);
  camera.Start();
  const auto start = std::chrono::steady_clock::now();
  int ok = 0;
  for (int i = 0; i < kN; ++i) ok += camera.Grab(1000ms).ok();
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("[ MEASURE  ] %d GREY 640x480 frames: %.0f frames/s\n", kN, kN / seconds);
  EXPECT_EQ(ok, kN);
}

}  // namespace
}  // namespace slshadow::capture
