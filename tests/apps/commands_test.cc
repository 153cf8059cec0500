#include "apps/commands.h"

#include <gtest/gtest.h>

#include "tests/testing/run_cli.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::app {
namespace {

using slshadow::testing::RunCli;

TEST(Commands, HelpListsEverySubcommand) {
  ::testing::internal::CaptureStdout();
  EXPECT_EQ(RunCli({"--help"}), 0);
  const std::string out = ::testing::internal::GetCapturedStdout();
  for (const auto& c : Commands()) EXPECT_NE(out.find("  " + c.name), std::string::npos) << c.name;
  ::testing::internal::CaptureStdout();
  EXPECT_EQ(RunCli({"--version"}), 0);
  EXPECT_NE(::testing::internal::GetCapturedStdout().find("slshadow 0."), std::string::npos);
}

TEST(Commands, RigShowPrintsGeometry) {
  ::testing::internal::CaptureStdout();
  EXPECT_EQ(RunCli({"rig", "show", (testing::SourceDir() / "config/demo/rig.yaml").string()}), 0);
  const std::string out = ::testing::internal::GetCapturedStdout();
  EXPECT_NE(out.find("left - right                    200.00"), std::string::npos) << out;
  EXPECT_NE(out.find("projector"), std::string::npos);
}

TEST(Commands, ErrorsAreOneLineAndNonZero) {
  ::testing::internal::CaptureStderr();
  EXPECT_NE(RunCli({"rig", "show", "/nonexistent/rig.yaml"}), 0);
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(err, "slshadow: error: /nonexistent/rig.yaml: file not found\n");
  ::testing::internal::CaptureStderr();
  EXPECT_NE(RunCli({"frobnicate"}), 0);
  EXPECT_NE(::testing::internal::GetCapturedStderr().find("unknown command 'frobnicate'"),
            std::string::npos);
}

}  // namespace
}  // namespace slshadow::app
