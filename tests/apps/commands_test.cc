#include "apps/commands.h"

#include <fstream>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "core/file_util.h"
#include "tests/testing/run_cli.h"
#include "tests/testing/temp_dir.h"
#include "workflows/studies/sweep.h"

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

// `slshadow bench --only decode` to success: exit 0, the table row and the JSON file of that one
// entry (times are not asserted; shadow_bench_test checks the entry's fields).
TEST(Commands, BenchOnlyOneEntryRunsToSuccess) {
  testing::TempDir tmp;
  ::testing::internal::CaptureStdout();
  const int code = RunCli({"bench", "--only", "decode", "--repetitions", "1", "--no-opencv",
                           "--json", (tmp / "bench.json").string()});
  const std::string out = ::testing::internal::GetCapturedStdout();
  ASSERT_EQ(code, 0) << out;
  EXPECT_NE(out.find("DecodePatterns, 2 cameras"), std::string::npos) << out;
  EXPECT_EQ(out.find("simulate"), std::string::npos) << out;  // no other entry ran
  const auto json = nlohmann::json::parse(ReadTextFile(tmp / "bench.json"));
  EXPECT_EQ(json.at("format"), "slshadow-bench");
  ASSERT_EQ(json.at("entries").size(), 1u);
  EXPECT_EQ(json.at("entries")[0].at("name"), "decode");
  EXPECT_GT(json.at("entries")[0].at("throughput").get<double>(), 0);
}

// `slshadow sweep study` in one process to success (no GNU parallel, no scheduler): it prints the
// plan, the shard and the merge, and writes the result the library's RunStudy writes for the same
// study, byte for byte.
TEST(Commands, SweepStudyRunsInOneProcessAsTheLibraryDoes) {
  testing::TempDir tmp;
  std::ofstream(tmp / "study.yaml")
      << "format: slshadow-study\nversion: 1\nname: one\n"
      << "rig: " << (testing::SourceDir() / "config/studies/quarter_demo_rig.yaml").string() << "\n"
      << "modes: [projector, stereo]\n"
         "compare: {threshold_mm: 0.5}\n"
         "set:\n  scene.layers.noise: {full_well_e: 10000, read_noise_e: 6}\n"
         "axes:\n"
         "  - {name: seed, set: scene.layers.noise.seed, values: [11]}\n";
  ::testing::internal::CaptureStdout();
  const int code = RunCli({"sweep", "study", (tmp / "study.yaml").string(), "--out",
                           (tmp / "cli").string(), "--threads", "2"});
  const std::string out = ::testing::internal::GetCapturedStdout();
  ASSERT_EQ(code, 0) << out;
  for (const std::string& line :
       {std::string("threads: 2 (--threads)"),
        "study one: 1 job (1 geometry group) in " + (tmp / "cli" / "jobs").string(),
        std::string("shard 0/1: "), "1 jobs merged: 2 rows in " + (tmp / "cli").string()}) {
    EXPECT_NE(out.find(line), std::string::npos) << line << "\n" << out;
  }
  const studies::SweepStudySummary lib =
      studies::RunStudy(tmp / "study.yaml", tmp / "lib", studies::SweepRunOptions{});
  EXPECT_EQ(lib.run.ran, 1);
  for (const char* f : {"results.csv", "results.json"}) {
    EXPECT_EQ(ReadTextFile(tmp / "cli" / f), ReadTextFile(tmp / "lib" / f)) << f;
  }
}

}  // namespace
}  // namespace slshadow::app
