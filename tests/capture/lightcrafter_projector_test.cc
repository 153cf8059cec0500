// The LightCrafter as the sequencer's projector in video mode, over the emulated DLPC350: opening
// it reads the firmware, stops any running sequence and switches to video mode (read back);
// showing delegates to the HDMI output; a device that refuses video mode is one error naming it.
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
  EXPECT_EQ(commands, (std::vector<uint16_t>{dlpc350::kVersion, dlpc350::kSequenceControl, dlpc350::kDisplayMode,
                                             dlpc350::kDisplayMode}));
  const ProjectorInfo info = projector.Info();
  EXPECT_EQ(info.backend, "lightcrafter");
  EXPECT_NE(info.id.find("emulated LightCrafter 4500, video mode, firmware application 3.1.2"), std::string::npos) << info.id;
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
    EXPECT_NE(std::string(e.what()).find("emulated LightCrafter 4500: display mode (0x1A1B) with data [00]: the device refused it"),
              std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace slshadow::capture
