#include "tests/testing/sim_camera.h"

#include <cstring>

#include <gtest/gtest.h>

#include "core/error.h"
#include "patterns/codec.h"
#include "sim/simulate.h"
#include "workflows/pipeline/scan_pipeline.h"

namespace slshadow::testing {
namespace {

using pipeline::LoadPatternSpecOrDemo;
using pipeline::LoadRigOrDemo;
using pipeline::LoadSceneOrDemo;

bool SameBytes(const cv::Mat& a, const cv::Mat& b) {
  if (a.type() != b.type() || a.size() != b.size()) return false;
  for (int y = 0; y < a.rows; ++y) {
    if (std::memcmp(a.ptr(y), b.ptr(y), a.cols * a.elemSize()) != 0) return false;
  }
  return true;
}

constexpr std::chrono::milliseconds kTimeout{100};

// Oracle: RenderScan. The embedded demo, with sensor noise on (its seed depends on the pattern
// index, so a frame rendered for the wrong pattern or with the wrong seed differs), scanned frame
// by frame through the capture seams (the projector shows pattern i, each camera is triggered and
// grabbed) gives RenderScan's images, pixel for pixel, for both cameras.
TEST(SimCamera, CapturingFrameByFrameEqualsRenderScan) {
  const Rig rig = LoadRigOrDemo("");
  Scene scene = LoadSceneOrDemo("");
  scene.layers.noise_enabled = true;
  scene.layers.full_well_e = 10000;
  scene.layers.read_noise_e = 10;
  scene.layers.seed = 5;
  const PatternSpec spec = LoadPatternSpecOrDemo("");
  const std::vector<cv::Mat> patterns = GeneratePatterns(spec);
  std::vector<GeometryBuffer> geometry;
  const auto reference = RenderScan(scene, rig, patterns, &geometry);
  ASSERT_FALSE(SameBytes(reference[0][0], RenderScan(scene, rig, {patterns[1], patterns[0]})[0][1]))
      << "the noise does not depend on the pattern index: the test would not see a wrong index";

  auto shown = std::make_shared<ShownPattern>();
  SimProjector projector(rig, shown);
  EXPECT_EQ(projector.Info().backend, "sim");
  EXPECT_EQ(projector.Info().width, rig.projector->model.width);
  projector.Load(patterns);
  EXPECT_EQ(projector.size(), spec.NumImages());
  std::vector<std::unique_ptr<SimCamera>> cameras;
  capture::CameraSettings settings;
  settings.trigger = capture::TriggerMode::kSoftware;
  for (const auto& c : rig.cameras) {
    cameras.push_back(std::make_unique<SimCamera>(scene, rig, c.name, shown));
    EXPECT_EQ(cameras.back()->Info().sensor_width, c.model.width);
    cameras.back()->Configure(settings);
    cameras.back()->Start();
  }
  for (int i = 0; i < spec.NumImages(); ++i) {
    projector.Show(i);
    for (size_t c = 0; c < cameras.size(); ++c) {
      cameras[c]->Trigger();
      const capture::Frame frame = cameras[c]->Grab(kTimeout);
      ASSERT_TRUE(frame.ok()) << frame.message;
      EXPECT_EQ(frame.frame_id, static_cast<uint64_t>(i + 1));
      EXPECT_EQ(frame.exposure_us, scene.radiometry.exposure_us);
      ASSERT_TRUE(SameBytes(frame.image, reference[c][static_cast<size_t>(i)]))
          << "camera " << c << " pattern " << i;
    }
  }
  EXPECT_EQ(cameras[0]->Statistics().completed_frames, static_cast<uint64_t>(spec.NumImages()));

  // The frame is taken when triggered: showing the next pattern before grabbing changes nothing.
  projector.Show(3);
  cameras[0]->Trigger();
  projector.Show(4);
  ASSERT_TRUE(SameBytes(cameras[0]->Grab(kTimeout).image, reference[0][3]));
  // No trigger, no frame; stopped, aborted.
  EXPECT_EQ(cameras[0]->Grab(kTimeout).status, capture::FrameStatus::kTimeout);
  cameras[0]->Stop();
  EXPECT_EQ(cameras[0]->Grab(kTimeout).status, capture::FrameStatus::kAborted);

  // Black: what RenderScan gives for an all-zero projector image.
  const std::vector<cv::Mat> black = {cv::Mat::zeros(patterns[0].size(), CV_8UC1)};
  projector.ShowBlack();
  cameras[1]->Trigger();
  const capture::Frame dark = cameras[1]->Grab(kTimeout);
  ASSERT_TRUE(dark.ok());
  ASSERT_TRUE(SameBytes(
      dark.image,
      PatternRenderer(scene, rig, 1, geometry[1]).Render(black[0], ShownPattern::kBlack)));

  // Free-run: each Grab renders what is shown then.
  settings.trigger = capture::TriggerMode::kFreeRun;
  cameras[1]->Stop();
  cameras[1]->Configure(settings);
  cameras[1]->Start();
  projector.Show(7);
  ASSERT_TRUE(SameBytes(cameras[1]->Grab(kTimeout).image, reference[1][7]));
}

// Oracle: the scene with a longer exposure. Twice the exposure time and +6.02 dB of gain
// (x 2) render what RenderScan renders for the scene with 4 x its exposure.
TEST(SimCamera, ExposureAndGainScaleTheScenesExposure) {
  const Rig rig = LoadRigOrDemo("");
  Scene scene = LoadSceneOrDemo("");
  scene.radiometry.exposure_fraction = 0.2;
  const std::vector<cv::Mat> patterns = GeneratePatterns(LoadPatternSpecOrDemo(""));
  auto shown = std::make_shared<ShownPattern>();
  SimProjector projector(rig, shown);
  projector.Load(patterns);
  SimCamera camera(scene, rig, "left", shown);
  capture::CameraSettings settings;
  settings.exposure_us = 2 * scene.radiometry.exposure_us;
  settings.gain_db = 20 * std::log10(2.0);
  camera.Configure(settings);
  EXPECT_EQ(*camera.Settings().exposure_us, 2 * scene.radiometry.exposure_us);
  camera.Start();
  projector.Show(36);  // white
  camera.Trigger();
  const capture::Frame frame = camera.Grab(kTimeout);
  ASSERT_TRUE(frame.ok());
  EXPECT_EQ(frame.exposure_us, 2 * scene.radiometry.exposure_us);
  Scene brighter = scene;
  brighter.radiometry.exposure_fraction =
      scene.radiometry.exposure_fraction * 2 * std::pow(10.0, settings.gain_db.value() / 20);
  const std::vector<cv::Mat> one = {patterns[36]};
  ASSERT_TRUE(SameBytes(frame.image, RenderScan(brighter, rig, one)[0][0]));
  EXPECT_GT(cv::mean(frame.image)[0], 2 * cv::mean(RenderScan(scene, rig, one)[0][0])[0]);
}

TEST(SimCamera, RefusedSettingsAndImagesAreNamed) {
  const Rig rig = LoadRigOrDemo("");
  const Scene scene = LoadSceneOrDemo("");
  auto shown = std::make_shared<ShownPattern>();
  SimProjector projector(rig, shown);
  const auto message = [](const std::function<void()>& f) -> std::string {
    try {
      f();
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  };
  EXPECT_NE(message([&] { projector.Load({cv::Mat::zeros(10, 10, CV_8UC1)}); }).find("image 0"),
            std::string::npos);
  EXPECT_NE(message([&] { projector.Show(0); }).find("not loaded"), std::string::npos);
  EXPECT_NE(message([&] { SimCamera(scene, rig, "middle", shown); }).find("'middle'"),
            std::string::npos);
  SimCamera camera(scene, rig, "right", shown);
  EXPECT_EQ(camera.Info().pixel_formats,
            std::vector<capture::PixelFormat>{capture::PixelFormat::kMono8});
  capture::CameraSettings settings;
  settings.pixel_format = capture::PixelFormat::kMono16;
  EXPECT_NE(message([&] { camera.Configure(settings); }).find("pixel_format"), std::string::npos);
  settings = {};
  settings.roi = {0, 0, 640, 480};
  EXPECT_NE(message([&] { camera.Configure(settings); }).find("roi"), std::string::npos);
  settings = {};
  settings.trigger = capture::TriggerMode::kHardware;
  EXPECT_NE(message([&] { camera.Configure(settings); }).find("trigger"), std::string::npos);
  // Nothing loaded: the frame says so instead of throwing.
  camera.Start();
  camera.Trigger();
  const capture::Frame frame = camera.Grab(kTimeout);
  EXPECT_EQ(frame.status, capture::FrameStatus::kOtherError);
  EXPECT_NE(frame.message.find("nothing loaded"), std::string::npos);
}

}  // namespace
}  // namespace slshadow::testing
