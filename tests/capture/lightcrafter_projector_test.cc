// The LightCrafter as the sequencer's projector in video mode, over the emulated DLPC350: opening
// it reads the firmware, stops any running sequence and switches to video mode (read back);
// showing delegates to the HDMI output; a device that refuses video mode is one error naming it.
// In pattern-sequence mode: the LUTs programmed for the images, start / stop, the alive check.
#include "capture/lightcrafter_projector.h"

#include <gtest/gtest.h>

#include "capture/none_projector.h"
#include "core/error.h"
#include "tests/capture/dlpc350_emulator.h"

namespace slshadow::capture {
namespace {

TEST(LightCrafterProjector, SwitchesToVideoModeAndDelegatesToTheHdmiOutput) {
  testing::Dlpc350Emulator device;
  device.display_mode = 1;
  device.sequence_control = 2;
  device.version = {2, 0, 1, 3, 0, 0, 0, 2, 0, 0, 0, 1, 0, 0, 0, 1};
  LightCrafterProjector projector(std::make_unique<testing::MemoryTransport>(device),
                                  std::make_unique<NoneProjector>(std::chrono::microseconds(1234)));
  EXPECT_EQ(device.display_mode, 0);
  EXPECT_EQ(device.sequence_control, 0);
  std::vector<uint16_t> commands;
  for (const auto& q : device.log) commands.push_back(q.command);
  EXPECT_EQ(commands, (std::vector<uint16_t>{dlpc350::kVersion, dlpc350::kSequenceControl,
                                             dlpc350::kDisplayMode, dlpc350::kDisplayMode}));
  const ProjectorInfo info = projector.Info();
  EXPECT_EQ(info.backend, "lightcrafter");
  EXPECT_NE(info.id.find("emulated LightCrafter 4500, video mode, firmware application 3.1.2"),
            std::string::npos)
      << info.id;
  EXPECT_EQ(projector.Latency(), std::chrono::microseconds(1234));
  projector.SetLatency(std::chrono::microseconds(50));
  EXPECT_EQ(projector.Latency(), std::chrono::microseconds(50));
  // The USB side stays usable for programming (e.g. `projector validate`).
  device.validation_status = 0x04;
  EXPECT_EQ(projector.client().Validate().warnings.size(), 1u);
}

TEST(LightCrafterProjector, RefusedVideoModeIsOneErrorNamingTheDevice) {
  testing::Dlpc350Emulator device;
  device.nack_command = dlpc350::kDisplayMode;
  try {
    LightCrafterProjector projector(std::make_unique<testing::MemoryTransport>(device),
                                    std::make_unique<NoneProjector>(std::chrono::microseconds(0)));
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("emulated LightCrafter 4500: display mode (0x1A1B) with "
                                         "data [00]: the device refused it"),
              std::string::npos)
        << e.what();
  }
}

// Pattern-sequence mode: Load programs the LUTs for the images (bit depth from their values),
// no repeat, TRIG_OUT1 as configured; the emulator decodes the LUTs back to the pattern order.
TEST(LightCrafterSequenceProjector, ProgramsTheSequenceStartsStopsAndChecks) {
  testing::Dlpc350Emulator device;
  device.sequence_control = 2;
  LightCrafterSequenceOptions options;
  options.frame_period_us = 8333;
  options.trig_out1.invert = true;
  LightCrafterSequenceProjector projector(std::make_unique<testing::MemoryTransport>(device),
                                          options);
  EXPECT_EQ(device.sequence_control, 0);  // a running sequence is stopped on opening
  std::vector<cv::Mat> binary;
  for (int i = 0; i < 30; ++i)
    binary.push_back(cv::Mat(40, 64, CV_8UC1, cv::Scalar(i % 2 ? 255 : 0)));
  projector.Load(binary);
  EXPECT_EQ(projector.bit_depth(), 1);
  EXPECT_EQ(device.display_mode, 1);
  EXPECT_EQ(device.pattern_config,
            (std::vector<uint8_t>{29, 0, 29, 1}));  // 30 entries, no repeat, 2 images
  EXPECT_EQ(device.trig_out1, (std::vector<uint8_t>{1, 0xBB, 0xBB}));
  EXPECT_EQ(device.frame_period_us, 8333u);
  EXPECT_EQ(device.exposure_us, 8333u);
  std::vector<int> in_order(30);
  for (int i = 0; i < 30; ++i) in_order[static_cast<size_t>(i)] = i;
  EXPECT_EQ(device.LutPatterns(), in_order);
  EXPECT_EQ(projector.Info().width, 64);
  EXPECT_NEAR(projector.Info().refresh_hz, 120.0, 0.01);

  std::vector<cv::Mat> grey = binary;
  grey[3].setTo(128);
  projector.Load(grey);
  EXPECT_EQ(projector.bit_depth(), 8);  // 3 patterns per 24-bit flash image
  EXPECT_EQ(device.pattern_config, (std::vector<uint8_t>{29, 0, 29, 9}));
  EXPECT_EQ(device.LutPatterns(), in_order);

  std::vector<uint8_t> controls;
  device.on_sequence_control = [&](uint8_t c) { controls.push_back(c); };
  projector.Start();
  projector.CheckAlive();
  projector.Stop();
  EXPECT_EQ(controls, (std::vector<uint8_t>{2, 0}));
  device.display_mode = 0;  // someone switched it to video mode
  try {
    projector.CheckAlive();
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(
                  "emulated LightCrafter 4500: the display mode reads back as video"),
              std::string::npos)
        << e.what();
  }
  device.validation_status = 0x01;
  try {
    projector.Load(grey);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(
        std::string(e.what()).find(
            "refused the pattern sequence at validation: bit 0: exposure or frame period invalid"),
        std::string::npos)
        << e.what();
  }
  LightCrafterSequenceOptions bad;
  bad.frame_period_us = 1000;
  bad.exposure_us = 900;  // must equal the period or leave 230 us
  EXPECT_THROW(
      LightCrafterSequenceProjector(std::make_unique<testing::MemoryTransport>(device), bad),
      Error);
}

}  // namespace
}  // namespace slshadow::capture
