// devices.yaml: the examples in config/devices/ load; every kind of bad input is one error naming
// the file, the field and the value; the factory opens replay and none, and says clearly which
// backends this build lacks.
#include "capture/devices.h"

#include <functional>

#include <gtest/gtest.h>

#include "capture/factory.h"
#include "core/config.h"
#include "core/error.h"
#include "core/rig.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::capture {
namespace {

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

DevicesConfig Parse(const std::string& yaml) {
  return DevicesFromConfig(ConfigNode::ParseYaml(yaml, "dev.yaml"));
}

const std::string kHead = "format: slshadow-devices\nversion: 1\n";

TEST(Devices, ExamplesLoad) {
  const auto dir = testing::SourceDir() / "config/devices";
  const DevicesConfig gige = LoadDevices(dir / "stereo_gige_hdmi.yaml");
  ASSERT_EQ(gige.cameras.size(), 2u);
  EXPECT_EQ(gige.cameras[0].name, "left");
  EXPECT_EQ(gige.cameras[0].backend, "aravis");
  EXPECT_EQ(gige.cameras[0].address, "192.168.10.21");
  EXPECT_EQ(gige.cameras[0].settings.exposure_us, 8000.0);
  EXPECT_EQ(gige.cameras[0].settings.packet_size_bytes, 8192);
  EXPECT_EQ(gige.cameras[0].settings.socket_buffer_bytes, 8388608);
  EXPECT_EQ(gige.cameras[0].settings.trigger, TriggerMode::kSoftware);
  EXPECT_EQ(gige.projector.backend, "window");
  EXPECT_EQ(gige.projector.display, "1");
  EXPECT_EQ(gige.projector.latency_us, 35000);
  EXPECT_EQ(gige.projector.settle_us, 2000);

  const DevicesConfig hw = LoadDevices(dir / "hardware_trigger_roi.yaml");
  EXPECT_EQ(hw.cameras[0].serial, "22416789");
  EXPECT_EQ(hw.cameras[0].settings.pixel_format, PixelFormat::kMono12);
  EXPECT_EQ(hw.cameras[0].settings.trigger, TriggerMode::kHardware);
  EXPECT_EQ(hw.cameras[0].settings.roi.x, 320);
  EXPECT_EQ(hw.cameras[0].settings.roi.height, 800);
  EXPECT_EQ(hw.cameras[0].grab_timeout_ms, 2000);
  EXPECT_EQ(hw.projector.display, "1920,0,1280,800");

  const DevicesConfig replay = LoadDevices(dir / "replay.yaml");
  EXPECT_EQ(replay.cameras[0].imageset, dir / "../../scan_virtual");
  EXPECT_EQ(replay.cameras[1].imageset_camera, "right");
  EXPECT_EQ(replay.cameras[1].first_frame_id, 65400);
  EXPECT_EQ(replay.projector.backend, "none");
  const Rig demo = LoadRig(testing::SourceDir() / "config/demo/rig.yaml");
  replay.CheckAgainst(demo);
  gige.CheckAgainst(demo);

  const DevicesConfig seq = LoadDevices(dir / "gige_lightcrafter_pattern_sequence.yaml");
  EXPECT_EQ(seq.cameras[1].settings.trigger, TriggerMode::kHardware);
  EXPECT_EQ(seq.cameras[1].settings.trigger_line, "Line1");
  EXPECT_EQ(seq.projector.backend, "lightcrafter");
  EXPECT_EQ(seq.projector.mode, "pattern-sequence");
  EXPECT_EQ(seq.projector.usb, "1:7");
  EXPECT_EQ(seq.projector.frame_period_us, 16667);
  EXPECT_EQ(seq.projector.exposure_us, 16667);
  EXPECT_EQ(seq.projector.bit_depth, 0);
  EXPECT_FALSE(seq.projector.trigger_inverted);
  EXPECT_EQ(seq.projector.settle_us, 100000);
  EXPECT_TRUE(RunsSequenceItself(seq.projector));
  EXPECT_FALSE(RunsSequenceItself(LoadDevices(dir / "uvc_lightcrafter.yaml").projector));
  seq.CheckAgainst(demo);
}

// The LightCrafter's pattern-sequence fields: only where they mean something, in range.
TEST(Devices, LightCrafterPatternSequenceFields) {
  const std::string cam = "cameras:\n  - name: left\n    backend: replay\n    imageset: x\n";
  const std::string lc = "projector:\n  backend: lightcrafter\n  mode: pattern-sequence\n";
  EXPECT_EQ(Parse(kHead + cam + lc + "  frame_period_us: 8333\n").projector.frame_period_us, 8333);
  EXPECT_EQ(Parse(kHead + cam + "projector: {backend: lightcrafter}\n").projector.mode, "video");
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + cam + "projector: {backend: lightcrafter, mode: pattern}\n");
            }).find("dev.yaml: projector.mode: expected video or pattern-sequence"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + cam + "projector: {backend: window, mode: video}\n");
            }).find("projector.mode: only for backend lightcrafter"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + cam + "projector: {backend: lightcrafter, frame_period_us: 8333}\n");
            }).find("projector.frame_period_us: only for a lightcrafter in mode pattern-sequence"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + cam + lc + "  frame_period_us: 100\n");
            }).find("projector.frame_period_us: must be in [235, 10000000] us (got 100)"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + cam + lc + "  exposure_us: 20000\n");
            }).find("projector.exposure_us: must be at most frame_period_us (got 20000)"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + cam + lc + "  bit_depth: 9\n");
            }).find("projector.bit_depth: must be 1..8"),
            std::string::npos);
  // Opened as a projector shown pattern by pattern, it says why not (no USB needed to see that).
  EXPECT_NE(ErrorOf([&] { OpenProjector(Parse(kHead + cam + lc).projector); })
                .find("dev.yaml: projector.mode: pattern-sequence: the LightCrafter runs the "
                      "sequence itself"),
            std::string::npos);
}

TEST(Devices, BadInputIsNamedWithFileFieldAndValue) {
  const std::string cam = "cameras:\n  - name: left\n    backend: replay\n    imageset: x\n";
  EXPECT_NO_THROW(Parse(kHead + cam));
  EXPECT_EQ(ErrorOf([&] { Parse(kHead + cam + "    exposure_us: 10\n"); }),
            "dev.yaml: cameras[0].exposure_us: unknown field (known fields here: name, backend, "
            "id, address, serial, "
            "settings, grab_timeout_ms, imageset, imageset_camera, first_frame_id)");
  EXPECT_NE(ErrorOf([&] { Parse(kHead + "cameras:\n  - name: left\n    backend: gige\n"); })
                .find("dev.yaml: cameras[0].backend: unknown backend (expected aravis, replay, sim "
                      "or v4l2)"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] { Parse(kHead + cam + "    settings: {exposure_us: -3}\n"); })
                .find("dev.yaml: cameras[0].settings.exposure_us: must be a positive number of "
                      "microseconds (got -3)"),
            std::string::npos);
  EXPECT_NE(
      ErrorOf([&] {
        Parse(kHead + cam + "    settings: {pixel_format: RGB8}\n");
      }).find("cameras[0].settings.pixel_format: unknown name (expected Mono8, Mono12 or Mono16)"),
      std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + cam + "    settings: {trigger: line}\n");
            }).find("settings.trigger: unknown name (expected free-run, software or hardware)"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + cam + "    settings: {roi: [0, 0, 640]}\n");
            }).find("settings.roi: expected [x, y, width, height]"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + cam + "    settings: {exposure: 5}\n");
            }).find("cameras[0].settings.exposure: unknown field"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + cam + "    grab_timeout_ms: 0\n");
            }).find("cameras[0].grab_timeout_ms: must be in (0, 3600000]"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + cam + "    first_frame_id: 0\n");
            }).find("first_frame_id: must be in [1, 65535]"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + "cameras:\n  - name: left\n    backend: aravis\n    imageset: x\n");
            }).find("cameras[0].imageset: only for backend replay"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + cam + cam.substr(9));
            }).find("cameras[1].name: a second entry for the same camera"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + cam + "projector: {backend: window, latency_us: -1}\n");
            }).find("dev.yaml: projector.latency_us: must be >= 0 (got -1)"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + cam + "projector: {backend: hdmi}\n");
            }).find("projector.backend: unknown backend"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse("format: slshadow-devices\nversion: 2\n" + cam);
            }).find("dev.yaml: version: unsupported"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              Parse(kHead + "cameras: []\n");
            }).find("cameras: expected a list of at least one camera"),
            std::string::npos);
  const Rig demo = LoadRig(testing::SourceDir() / "config/demo/rig.yaml");
  const DevicesConfig wrong =
      Parse(kHead + "cameras:\n  - name: centre\n    backend: replay\n    imageset: x\n");
  EXPECT_NE(ErrorOf([&] {
              wrong.CheckAgainst(demo);
            }).find("dev.yaml: cameras[0].name: the rig 'demo' has no camera 'centre'"),
            std::string::npos);
}

TEST(Factory, OpensNoneAndNamesABackendNotBuiltIn) {
  const DevicesConfig config =
      Parse(kHead +
            "cameras:\n  - name: left\n    backend: aravis\n    address: 127.0.0.1\n"
            "projector: {backend: none, latency_us: 1500}\n");
  const auto projector = OpenProjector(config.projector);
  EXPECT_EQ(projector->Info().backend, "none");
  EXPECT_EQ(projector->Latency(), std::chrono::microseconds(1500));
  projector->Load(std::vector<cv::Mat>(3));
  EXPECT_EQ(projector->size(), 3);
  // The simulator camera lives in the workflow layer (capture/ may not depend on sim/).
  CameraEntry sim = config.cameras[0];
  sim.backend = "sim";
  EXPECT_NE(ErrorOf([&] {
              OpenCamera(sim);
            }).find("dev.yaml: cameras[0].backend: backend 'sim' is not built into this slshadow"),
            std::string::npos);
}

}  // namespace
}  // namespace slshadow::capture
