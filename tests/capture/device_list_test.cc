// capture/device_list.cc (`slshadow devices` without the command line) against a GigE Vision fake
// camera on loopback inside a private network namespace (tests/capture/fake_gv_camera.h): the line
// per device handed to `print` one at a time, the notes for what was not looked for, and bad
// addresses refused by Check() before anything is sent. (An address without a camera:
// tests/apps/cmd_devices_test.cc.)
#include "capture/device_list.h"

#include <cstdlib>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/error.h"
#include "tests/capture/fake_gv_camera.h"

namespace slshadow::capture {
namespace {

std::vector<std::string> Listed(const DeviceListOptions& options) {
  std::vector<std::string> lines;
  ListDevices(options, [&](const std::string& line) { lines.push_back(line); });
  return lines;
}

TEST(DeviceListOptions, CheckRefusesAnAddressThatIsNotIpv4) {
  DeviceListOptions options;
  EXPECT_NO_THROW(options.Check());
  options.addresses = {"127.0.0.2", "10.1.2.3"};
  EXPECT_NO_THROW(options.Check());
  for (const char* bad : {"camera-7", "256.1.1.1", "1.2.3", ""}) {
    options.addresses = {"127.0.0.2", bad};
    try {
      options.Check();
      ADD_FAILURE() << "accepted '" << bad << "'";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(std::string("'") + bad + "'"), std::string::npos)
          << e.what();
    }
  }
}

class ListDevicesTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::string reason = testing::SkipReasonWithoutPrivateNetwork();
    if (!reason.empty()) GTEST_SKIP() << reason;
    // No X display in these cases: the displays' note is the last line.
    if (const char* d = std::getenv("DISPLAY")) display_ = d;
    unsetenv("DISPLAY");
  }
  void TearDown() override {
    if (!display_.empty()) setenv("DISPLAY", display_.c_str(), 1);
  }
  std::string display_;
};

// By address: exactly the camera's line (its GenICam information), then the displays' note; no
// USB or V4L2 enumeration, no discovery note.
TEST_F(ListDevicesTest, AddressListsThatCameraAlone) {
  testing::FakeGvCamera fake({.address = "127.0.0.2", .serial = "GV91"});
  DeviceListOptions options;
  options.addresses = {"127.0.0.2"};
  const std::vector<std::string> lines = Listed(options);
  ASSERT_EQ(lines.size(), 2u) << ::testing::PrintToString(lines);
  EXPECT_EQ(lines[0].rfind("camera  GigEVision 127.0.0.2", 0), 0u) << lines[0];
  EXPECT_NE(
      lines[0].find("vendor=Aravis model=Fake serial=GV91 sensor=2048x2048 formats=Mono8,Mono16"),
      std::string::npos)
      << lines[0];
  EXPECT_EQ(lines[1], "(displays: $DISPLAY is not set, no X display to list)\n");
  for (const auto& l : lines) EXPECT_EQ(l.back(), '\n') << l;
}

// Without addresses or discovery no GigE Vision camera is sought (the fake one is not listed) and a
// note says how to find one; with discovery the broadcast on loopback (the namespace's only
// interface) finds it.
TEST_F(ListDevicesTest, DiscoveryIsOnlyOnRequest) {
  testing::FakeGvCamera fake({.address = "127.0.0.2", .serial = "GV92"});
  DeviceListOptions options;
  std::string all;
  for (const auto& l : Listed(options)) all += l;
  EXPECT_EQ(all.find("GV92"), std::string::npos) << all;
  EXPECT_NE(all.find("(GigE Vision cameras: --address IP opens one; --discover broadcasts to find "
                     "them)\n"),
            std::string::npos)
      << all;
  options.discover = true;
  all.clear();
  for (const auto& l : Listed(options)) all += l;
  EXPECT_NE(all.find("camera  GigEVision 127.0.0.2"), std::string::npos) << all;
  EXPECT_NE(all.find("serial=GV92"), std::string::npos) << all;
  EXPECT_EQ(all.find("--discover broadcasts"), std::string::npos) << all;
}

}  // namespace
}  // namespace slshadow::capture

int main(int argc, char** argv) {
  slshadow::testing::RunInPrivateNetwork(argc, argv);
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
