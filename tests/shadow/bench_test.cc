#include "shadow/bench.h"

#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

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
}  // namespace slshadow::workflow
