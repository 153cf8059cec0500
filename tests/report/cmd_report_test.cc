// The command line's pages: `slshadow compare` writes report.html unless --no-html, and
// `slshadow report DIR` (re)writes it; bad folders are refused with one line, nothing written.
#include <gtest/gtest.h>

#include "core/file_util.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "tests/testing/run_cli.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {
namespace fs = std::filesystem;

// A sphere of radius 20 mm as 642 vertices sampled twice: a mesh reference and a cloud 0.05 mm
// outside it.
void WriteInputs(const testing::TempDir& tmp) {
  TriangleMesh m;
  const int n = 24;
  for (int i = 0; i <= n; ++i) {
    for (int j = 0; j < 2 * n; ++j) {
      const double t = M_PI * i / n, p = M_PI * j / n;
      m.vertices.emplace_back(20 * std::sin(t) * std::cos(p), 20 * std::sin(t) * std::sin(p),
                              400 + 20 * std::cos(t));
    }
  }
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < 2 * n; ++j) {
      const int a = i * 2 * n + j, b = i * 2 * n + (j + 1) % (2 * n), c = a + 2 * n, d = b + 2 * n;
      if (i > 0) m.triangles.emplace_back(a, b, c);
      if (i < n - 1) m.triangles.emplace_back(b, d, c);
    }
  }
  WriteMesh(tmp / "sphere.ply", m);
  PointCloud cloud;
  for (int i = 1; i < 60; ++i) {
    for (int j = 0; j < 120; ++j) {
      const double t = M_PI * i / 60, p = M_PI * j / 60;
      cloud.points.emplace_back(20.05 * std::sin(t) * std::cos(p),
                                20.05 * std::sin(t) * std::sin(p), 400 + 20.05 * std::cos(t));
    }
  }
  WritePly(tmp / "cloud.ply", cloud);
}

TEST(CmdReport, CompareWritesThePageUnlessNoHtmlAndReportRewritesIt) {
  testing::TempDir tmp;
  WriteInputs(tmp);
  const std::string cloud = (tmp / "cloud.ply").string(), ref = (tmp / "sphere.ply").string();
  ASSERT_EQ(testing::RunCli({"compare", cloud, ref, "--out", (tmp / "a").string()}), 0);
  EXPECT_TRUE(fs::exists(tmp / "a" / "report.html"));
  ASSERT_EQ(testing::RunCli({"compare", cloud, ref, "--out", (tmp / "b").string(), "--no-html"}),
            0);
  EXPECT_TRUE(fs::exists(tmp / "b" / "report.json"));
  EXPECT_FALSE(fs::exists(tmp / "b" / "report.html"));
  ASSERT_EQ(testing::RunCli({"report", (tmp / "b").string(), "--max-points", "100"}), 0);
  const std::string page = ReadTextFile(tmp / "b" / "report.html");
  EXPECT_NE(page.find("100 of 7080 points"), std::string::npos);
  EXPECT_LT(page.size(), fs::file_size(tmp / "a" / "report.html"));
}

TEST(CmdReport, AFolderThatIsNoResultIsRefusedAndNothingIsWritten) {
  testing::TempDir tmp;
  EXPECT_NE(testing::RunCli({"report", tmp.path().string()}), 0);
  EXPECT_NE(testing::RunCli({"report", (tmp / "missing").string()}), 0);
  EXPECT_NE(testing::RunCli({"report", tmp.path().string(), "--max-points", "0"}), 0);
  EXPECT_TRUE(fs::is_empty(tmp.path()));
}

}  // namespace
}  // namespace slshadow
