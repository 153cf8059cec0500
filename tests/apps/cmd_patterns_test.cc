// slshadow patterns generate / show, called through the dispatcher as a user would.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>

#include "apps/commands.h"
#include "core/image_set.h"
#include "patterns/codec.h"
#include "tests/testing/run_cli.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::app {
namespace {

using slshadow::testing::RunCli;

TEST(CmdPatterns, GenerateWritesEveryFrameAndASpecThatLoadsBack) {
  testing::TempDir tmp;
  const std::string spec_path =
      (testing::SourceDir() / "config/patterns/graycode_phase.yaml").string();
  const std::filesystem::path out = tmp / "patterns";
  ::testing::internal::CaptureStdout();
  ASSERT_EQ(RunCli({"patterns", "generate", spec_path, "--out", out.string()}), 0);
  EXPECT_NE(::testing::internal::GetCapturedStdout().find("wrote 38 1280x800"), std::string::npos);
  const PatternSpec spec = LoadPatternSpec(out / "patterns.json");
  EXPECT_EQ(PatternSpecToJson(spec), PatternSpecToJson(LoadPatternSpec(spec_path)));
  const std::vector<cv::Mat> expected = GeneratePatterns(spec);
  ASSERT_EQ(expected.size(), 38u);
  for (size_t i = 0; i < expected.size(); ++i) {
    char name[64];
    std::snprintf(name, sizeof(name), "pattern_%02zu.png", i);
    const cv::Mat image = ReadGrayImage(out / name);
    ASSERT_EQ(cv::norm(image, expected[i], cv::NORM_INF), 0) << name;
  }
  EXPECT_TRUE(std::filesystem::exists(out / "frames.json"));
  // Only the finished folder is left: no temporary siblings.
  int entries = 0;
  for (const auto& e : std::filesystem::directory_iterator(tmp.path())) entries += e.exists();
  EXPECT_EQ(entries, 1);

  // An existing folder is kept unless --overwrite.
  ::testing::internal::CaptureStderr();
  EXPECT_NE(RunCli({"patterns", "generate", spec_path, "--out", out.string()}), 0);
  EXPECT_NE(::testing::internal::GetCapturedStderr().find("output folder exists"),
            std::string::npos);
  ::testing::internal::CaptureStdout();
  EXPECT_EQ(RunCli({"patterns", "generate",
                    (testing::SourceDir() / "config/patterns/kamino_opencv_graycode.yaml").string(),
                    "--out", out.string(), "--overwrite"}),
            0);
  ::testing::internal::GetCapturedStdout();
  EXPECT_EQ(LoadPatternSpec(out / "patterns.json").NumImages(), 42);
  EXPECT_TRUE(std::filesystem::exists(out / "pattern_41.png"));
}

TEST(CmdPatterns, ShowListsFramesAndBadSpecsFailWithOneLine) {
  ::testing::internal::CaptureStdout();
  EXPECT_EQ(
      RunCli({"patterns", "show",
              (testing::SourceDir() / "config/patterns/kamino_opencv_graycode.yaml").string()}),
      0);
  const std::string out = ::testing::internal::GetCapturedStdout();
  EXPECT_NE(out.find(" 40  white"), std::string::npos) << out;
  EXPECT_NE(out.find("  0  gray_x_bit9"), std::string::npos) << out;

  testing::TempDir tmp;
  const std::filesystem::path bad = tmp / "bad.yaml";
  {
    std::FILE* f = std::fopen(bad.c_str(), "w");
    std::fputs("kind: phase_shift\nprojector_width: 640\nprojector_height: 480\nperiod_px: 2\n", f);
    std::fclose(f);
  }
  ::testing::internal::CaptureStderr();
  EXPECT_NE(RunCli({"patterns", "generate", bad.string(), "--out", (tmp / "o").string()}), 0);
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(err.find("bad.yaml: pattern spec: period_px: must be in [4, 65536]"), std::string::npos)
      << err;
  EXPECT_FALSE(std::filesystem::exists(tmp / "o"));
}

}  // namespace
}  // namespace slshadow::app
