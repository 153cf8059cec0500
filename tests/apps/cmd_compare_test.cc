// `slshadow compare` end to end through the command table (apps/cmd_compare.cc).
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "apps/commands.h"
#include "core/file_util.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "tests/compare/test_shapes.h"
#include "tests/testing/run_cli.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::compare {
namespace {

TEST(CmdCompare, WritesAReportAndRejectsBadInput) {
  slshadow::testing::TempDir tmp;
  const TriangleMesh mesh = testing::IcoSphere(20.0, 4);
  WriteMesh(tmp / "part.stl", mesh);
  PointCloud cloud;
  for (const auto& v : mesh.vertices)
    cloud.points.push_back(v * (20.05 / 20.0));  // 0.05 mm outside
  WritePly(tmp / "scan.ply", cloud);
  ASSERT_EQ(slshadow::testing::RunCli({"compare", (tmp / "scan.ply").string(),
                                       (tmp / "part.stl").string(), "--out",
                                       (tmp / "report").string(), "--threshold-mm", "0.1"}),
            0);
  const auto j = nlohmann::json::parse(ReadTextFile(tmp / "report" / "report.json"));
  EXPECT_EQ(j["c2c"]["count"].get<size_t>(), cloud.size());
  EXPECT_EQ(j["c2c"]["outliers"].get<size_t>(), 0u);
  // Vertices moved 0.05 mm radially: the nearest mesh point is the vertex itself, or a point of an
  // adjacent edge a hair closer where the radial direction leaves the vertex's normal cone.
  EXPECT_NEAR(j["c2m"]["signed_mean_mm"].get<double>(), 0.05, 1e-6);
  EXPECT_LE(j["c2m"]["signed_mean_mm"].get<double>(), 0.05 + 1e-12);
  EXPECT_EQ(j["options"]["threshold_mm"].get<double>(), 0.1);
  // Refuses to replace with --no-overwrite and leaves the report untouched.
  const std::string before = ReadTextFile(tmp / "report" / "report.json");
  EXPECT_NE(slshadow::testing::RunCli({"compare", (tmp / "scan.ply").string(),
                                       (tmp / "part.stl").string(), "--out",
                                       (tmp / "report").string(), "--no-overwrite"}),
            0);
  EXPECT_EQ(ReadTextFile(tmp / "report" / "report.json"), before);
  // Bad values fail with a non-zero exit and write nothing.
  EXPECT_NE(slshadow::testing::RunCli({"compare", (tmp / "scan.ply").string(),
                                       (tmp / "part.stl").string(), "--out", (tmp / "r2").string(),
                                       "--threshold-mm", "-1"}),
            0);
  EXPECT_NE(slshadow::testing::RunCli({"compare", (tmp / "scan.ply").string(),
                                       (tmp / "part.stl").string(), "--out", (tmp / "r2").string(),
                                       "--register", "magic"}),
            0);
  EXPECT_FALSE(std::filesystem::exists(tmp / "r2"));
}

}  // namespace
}  // namespace slshadow::compare
