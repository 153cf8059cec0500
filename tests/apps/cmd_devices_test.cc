// `slshadow devices` against a GigE Vision fake camera on loopback, inside a private network
// namespace (tests/capture/fake_gv_camera.h): the only place where --discover may broadcast.
#include <string>

#include <gtest/gtest.h>

#include "tests/capture/fake_gv_camera.h"
#include "tests/testing/run_cli.h"

namespace slshadow::app {
namespace {

class DevicesCommand : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::string reason = testing::SkipReasonWithoutPrivateNetwork();
    if (!reason.empty()) GTEST_SKIP() << reason;
  }
  // Runs the command, returns its exit code; stdout in out_, stderr in err_.
  int Run(std::vector<std::string> args) {
    ::testing::internal::CaptureStdout();
    ::testing::internal::CaptureStderr();
    const int code = testing::RunCli(std::move(args));
    std::fflush(stdout);
    out_ = ::testing::internal::GetCapturedStdout();
    err_ = ::testing::internal::GetCapturedStderr();
    return code;
  }
  std::string out_, err_;
};

TEST_F(DevicesCommand, AddressPrintsTheCamerasInformation) {
  testing::FakeGvCamera fake({.address = "127.0.0.2", .serial = "GV77"});
  ASSERT_EQ(Run({"devices", "--address", "127.0.0.2"}), 0) << err_;
  EXPECT_NE(out_.find("GigEVision 127.0.0.2"), std::string::npos) << out_;
  EXPECT_NE(out_.find("vendor=Aravis model=Fake serial=GV77 sensor=2048x2048 formats=Mono8,Mono16"),
            std::string::npos)
      << out_;
}

TEST_F(DevicesCommand, AddressWithoutACameraFailsNamingIt) {
  EXPECT_NE(Run({"devices", "--address", "127.0.0.3"}), 0);
  EXPECT_NE(err_.find("'127.0.0.3'"), std::string::npos) << err_;
  EXPECT_NE(Run({"devices", "--address", "camera-7"}), 0);
  EXPECT_NE(err_.find("--address: 'camera-7' is not an IPv4 address"), std::string::npos) << err_;
}

TEST_F(DevicesCommand, WithoutDiscoverNoGigEVisionCameraIsSought) {
  testing::FakeGvCamera fake({.address = "127.0.0.2", .serial = "GV78"});
  ASSERT_EQ(Run({"devices"}), 0) << err_;
  EXPECT_EQ(out_.find("GV78"), std::string::npos) << out_;
  EXPECT_NE(out_.find("--discover broadcasts"), std::string::npos) << out_;
}

// Discovery broadcasts; inside the private namespace (SetUp skips outside it) loopback is the
// only interface, so the broadcast reaches the fake camera and nothing else.
TEST_F(DevicesCommand, DiscoverFindsTheCameraOnTheOnlyInterface) {
  testing::FakeGvCamera fake({.address = "127.0.0.2", .serial = "GV79"});
  ASSERT_EQ(Run({"devices", "--discover"}), 0) << err_;
  EXPECT_NE(out_.find("GigEVision 127.0.0.2"), std::string::npos) << out_;
  EXPECT_NE(out_.find("serial=GV79 sensor=2048x2048 formats=Mono8,Mono16"), std::string::npos)
      << out_;
}

}  // namespace
}  // namespace slshadow::app

int main(int argc, char** argv) {
  slshadow::testing::RunInPrivateNetwork(argc, argv);
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
