#include "shadow/bench.h"

#include <gtest/gtest.h>

#include "core/error.h"

namespace slshadow::workflow {
namespace {

TEST(Bench, DecodeEntryRunsOnTheDemoScan) {
  BenchOptions options;
  options.repetitions = 1;
  options.only = {"decode"};
  options.with_opencv = false;
  const auto entries = RunBench(options);
  ASSERT_EQ(entries.size(), 1u);
  EXPECT_EQ(entries[0].name, "decode");
  EXPECT_GT(entries[0].median_wall_s, 0);
  EXPECT_NEAR(entries[0].throughput, 2 * 1920 * 1200 / 1e6 / entries[0].median_wall_s, 1e-9);
  EXPECT_TRUE(entries[0].peer.empty());
  EXPECT_NE(FormatBench(entries).find("decode"), std::string::npos);
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
