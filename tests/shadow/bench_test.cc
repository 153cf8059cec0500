#include "shadow/bench.h"

#include <gtest/gtest.h>

#include <filesystem>

#include "core/error.h"
#include "patterns/pattern_spec.h"

namespace slshadow::workflow {
namespace {

// `--only decode` runs exactly the decode entry, over the demo's own pattern sequence (its
// description names the image count of config/demo/patterns.yaml), without a peer when the
// OpenCV peer is off; the printed table carries the entry. Times are not asserted (no timed
// assertions; a wall time or a throughput derived from it cannot fail a test honestly).
TEST(Bench, DecodeEntryRunsOnTheDemoScan) {
  BenchOptions options;
  options.repetitions = 1;
  options.only = {"decode"};
  options.with_opencv = false;
  const auto entries = RunBench(options);
  ASSERT_EQ(entries.size(), 1u);
  EXPECT_EQ(entries[0].name, "decode");
  const int images = LoadPatternSpec(std::filesystem::path(SLSHADOW_SOURCE_DIR) / "config/demo/patterns.yaml").NumImages();
  EXPECT_EQ(entries[0].what, "DecodePatterns, 2 cameras, " + std::to_string(images) + " images each");
  EXPECT_EQ(entries[0].unit, "MPix/s");
  EXPECT_TRUE(entries[0].peer.empty());
  EXPECT_EQ(entries[0].ratio, 0);
  EXPECT_TRUE(entries[0].stages.empty());
  const std::string table = FormatBench(entries);
  EXPECT_NE(table.find(entries[0].what), std::string::npos) << table;
  EXPECT_EQ(table.find("simulate"), std::string::npos) << table;
}

TEST(Bench, BadOptionsAreNamed) {
  BenchOptions options;
  options.only = {"render"};
  EXPECT_THROW(options.Check(), Error);
  options.only.clear();
  options.repetitions = 0;
  EXPECT_THROW(options.Check(), Error);
}

}  // namespace
}  // namespace slshadow::workflow
