#include "workflows/pipeline/bench.h"

#include <gtest/gtest.h>

#include <filesystem>

#include <nlohmann/json.hpp>

#include "core/error.h"
#include "patterns/pattern_spec.h"

namespace slshadow::pipeline {
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
  const int images =
      LoadPatternSpec(std::filesystem::path(SLSHADOW_SOURCE_DIR) / "config/demo/patterns.yaml")
          .NumImages();
  EXPECT_EQ(entries[0].what,
            "DecodePatterns, 2 cameras, " + std::to_string(images) + " images each");
  EXPECT_EQ(entries[0].unit, "MPix/s");
  EXPECT_TRUE(entries[0].peer.empty());
  EXPECT_EQ(entries[0].ratio, 0);
  EXPECT_TRUE(entries[0].stages.empty());
  const std::string table = FormatBench(entries);
  EXPECT_NE(table.find(entries[0].what), std::string::npos) << table;
  EXPECT_EQ(table.find("simulate"), std::string::npos) << table;

  // --json: every field, numbers exact.
  const auto json = nlohmann::json::parse(BenchToJson(entries, options));
  EXPECT_EQ(json.at("format"), "slshadow-bench");
  EXPECT_EQ(json.at("version"), 1);
  EXPECT_EQ(json.at("repetitions"), 1);
  ASSERT_EQ(json.at("entries").size(), 1u);
  const auto& e = json.at("entries")[0];
  EXPECT_EQ(e.at("name"), "decode");
  EXPECT_EQ(e.at("median_wall_s").get<double>(), entries[0].median_wall_s);
  EXPECT_EQ(e.at("cpu_s").get<double>(), entries[0].cpu_s);
  EXPECT_EQ(e.at("throughput").get<double>(), entries[0].throughput);
  EXPECT_EQ(e.at("unit"), entries[0].unit);
  EXPECT_EQ(e.at("peer"), "");
  EXPECT_EQ(e.at("ratio").get<double>(), 0.0);
  EXPECT_EQ(e.at("stages").size(), entries[0].stages.size());
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
}  // namespace slshadow::pipeline
