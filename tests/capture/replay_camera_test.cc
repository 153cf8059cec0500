// ReplayCamera: software trigger semantics (one frame per trigger, timeout without one), the
// pattern the sequencer announces, exhaustion, 16-bit frame ids that wrap 65535 -> 1, bit-exact
// pixels, and refused settings.
#include "capture/replay_camera.h"

#include <fstream>
#include <functional>

#include <gtest/gtest.h>

#include "capture/devices.h"
#include "capture/factory.h"
#include "core/config.h"
#include "core/error.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::capture {
namespace {
using std::chrono::milliseconds;

Rig OneCameraRig() {
  Rig rig;
  rig.name = "one";
  rig.cameras.push_back({"cam", CameraModel(40, 30, 50, 50, 19.5, 14.5), Rigid3d()});
  rig.projector = RigDevice{"projector", CameraModel(32, 20, 30, 30, 16, 10), Rigid3d()};
  return rig;
}

std::vector<cv::Mat> WriteSet(const std::filesystem::path& dir, int n) {
  std::vector<cv::Mat> images;
  ImageSetWriter writer(dir, OneCameraRig(), {{"kind", "gray_code"}},
                        {.encoding = ImageEncoding::kPgm});
  for (int i = 0; i < n; ++i) {
    cv::Mat m(30, 40, CV_8UC1);
    cv::RNG rng(static_cast<uint64_t>(i + 1));
    rng.fill(m, cv::RNG::UNIFORM, 0, 256);
    writer.Add("cam", i, m, 1000.0 + i, ImageSource::kDevice);
    images.push_back(m);
  }
  writer.Commit();
  return images;
}

TEST(ReplayCamera, OneFramePerSoftwareTriggerInPatternOrderBitExact) {
  testing::TempDir dir;
  const auto images = WriteSet(dir / "set", 5);
  ReplayCameraOptions options;
  options.first_frame_id = 65534;
  ReplayCamera cam(dir / "set", options);
  EXPECT_EQ(cam.size(), 5);
  EXPECT_EQ(cam.Info().sensor_width, 40);
  EXPECT_EQ(cam.Info().serial, "replay-cam");
  EXPECT_EQ(cam.Grab(milliseconds(10)).status, FrameStatus::kAborted);  // not started
  cam.Configure(CameraSettings{});
  cam.Start();
  EXPECT_EQ(cam.Grab(milliseconds(10)).status, FrameStatus::kTimeout);  // no trigger
  const uint64_t expected_ids[] = {65534, 65535, 1, 2, 3};
  for (int i = 0; i < 5; ++i) {
    cam.Trigger();
    const Frame f = cam.Grab(milliseconds(10));
    ASSERT_TRUE(f.ok()) << f.message;
    EXPECT_EQ(cv::norm(f.image, images[static_cast<size_t>(i)], cv::NORM_INF), 0.0);
    EXPECT_EQ(f.frame_id, expected_ids[i]);
    EXPECT_EQ(f.exposure_us, 1000.0 + i);
  }
  cam.Trigger();
  const Frame past = cam.Grab(milliseconds(10));
  EXPECT_EQ(past.status, FrameStatus::kTimeout);
  EXPECT_NE(past.message.find("replay exhausted"), std::string::npos);
  EXPECT_EQ(cam.Statistics().completed_frames, 5u);
  EXPECT_EQ(cam.Statistics().timeouts, 2u);
}

TEST(ReplayCamera, ServesThePatternTheSequencerAnnounces) {
  testing::TempDir dir;
  const auto images = WriteSet(dir / "set", 6);
  ReplayCamera cam(dir / "set");
  cam.Configure(CameraSettings{});
  cam.Start();
  cam.ExpectPattern(4);  // e.g. a resumed capture
  cam.Trigger();
  cam.Trigger();  // queued: pattern 5
  EXPECT_EQ(cv::norm(cam.Grab(milliseconds(1)).image, images[4], cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(cam.Grab(milliseconds(1)).image, images[5], cv::NORM_INF), 0.0);
  cam.ExpectPattern(2);  // a retry of pattern 2
  cam.Trigger();
  cam.Flush();  // the pending frame is dropped
  EXPECT_EQ(cam.Grab(milliseconds(1)).status, FrameStatus::kTimeout);
  cam.ExpectPattern(2);
  cam.Trigger();
  EXPECT_EQ(cv::norm(cam.Grab(milliseconds(1)).image, images[2], cv::NORM_INF), 0.0);
  // Free run: a frame per Grab, in order from the announced pattern.
  cam.Stop();
  CameraSettings free_run;
  free_run.trigger = TriggerMode::kFreeRun;
  cam.Configure(free_run);
  cam.Start();
  cam.ExpectPattern(0);
  EXPECT_EQ(cv::norm(cam.Grab(milliseconds(1)).image, images[0], cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(cam.Grab(milliseconds(1)).image, images[1], cv::NORM_INF), 0.0);
}

TEST(ReplayCamera, RefusesWhatARecordingCannotServe) {
  testing::TempDir dir;
  WriteSet(dir / "set", 2);
  const auto error_of = [](const std::function<void()>& f) -> std::string {
    try {
      f();
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  };
  ReplayCamera cam(dir / "set");
  CameraSettings s;
  s.pixel_format = PixelFormat::kMono16;
  EXPECT_NE(error_of([&] {
              cam.Configure(s);
            }).find("pixel_format: the recording is 8-bit, Mono16 cannot be served"),
            std::string::npos);
  s = {};
  s.roi = {0, 0, 20, 10};
  EXPECT_NE(error_of([&] {
              cam.Configure(s);
            }).find("roi: a replay serves the full recorded image (40x30)"),
            std::string::npos);
  EXPECT_NE(error_of([&] {
              ReplayCamera(dir / "set", ReplayCameraOptions{"left", 1, ""});
            }).find("no images of camera 'left'"),
            std::string::npos);
  EXPECT_NE(error_of([&] { ReplayCamera(dir / "nothing"); }).find("not an ImageSet folder"),
            std::string::npos);
}

TEST(ReplayCamera, TheFactoryOpensItFromADevicesEntry) {
  testing::TempDir dir;
  const auto images = WriteSet(dir / "set", 3);
  const std::string yaml =
      "format: slshadow-devices\nversion: 1\ncameras:\n  - name: left\n    backend: replay\n    "
      "imageset: set\n"
      "    imageset_camera: cam\n    first_frame_id: 7\n    serial: SN-7\n";
  { std::ofstream(dir / "devices.yaml") << yaml; }
  const DevicesConfig config = LoadDevices(dir / "devices.yaml");
  auto cam = OpenCamera(config.cameras[0]);
  EXPECT_EQ(cam->Info().backend, "replay");
  EXPECT_EQ(cam->Info().serial, "SN-7");
  cam->Configure(config.cameras[0].settings);
  cam->Start();
  cam->Trigger();
  const Frame f = cam->Grab(milliseconds(1));
  EXPECT_EQ(f.frame_id, 7u);
  EXPECT_EQ(cv::norm(f.image, images[0], cv::NORM_INF), 0.0);
}

}  // namespace
}  // namespace slshadow::capture
