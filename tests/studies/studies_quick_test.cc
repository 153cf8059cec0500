// The built-in quick studies (config/studies/*_quick.yaml) run from one call, as `slshadow sweep
// study` runs them, and their merged tables checked against what they must say: the Pareto flags
// against a brute-force front, the layer verdicts against their own changes and thresholds, error
// growing with sensor noise and every method breaking inside the swept range.
#include <cmath>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/file_util.h"
#include "tests/testing/read_csv.h"
#include "tests/testing/temp_dir.h"
#include "workflows/studies/sweep.h"

namespace slshadow::studies {
namespace {

namespace fs = std::filesystem;
using testing::ReadCsv;
using testing::SourceDir;
using testing::TempDir;

SweepStudySummary RunQuickStudy(const std::string& name, const fs::path& out) {
  SweepRunOptions options;
  return RunStudy(SourceDir() / "config/studies" / (name + ".yaml"), out, options);
}

// Study 1: every job on the chart, and a point is on its mode's front exactly when no other point
// of that mode is at least as fast and as accurate and better in one (brute force).
TEST(QuickStudies, SpeedAgainstAccuracyFrontIsTheBruteForceFront) {
  TempDir tmp;
  const SweepStudySummary s = RunQuickStudy("speed_accuracy_quick", tmp / "result");
  EXPECT_EQ(s.plan.jobs, 24);
  const auto points = ReadCsv(tmp / "result/pareto.csv");
  ASSERT_EQ(points.size(), 48u);  // 24 jobs, 2 modes, all reconstructed
  std::map<std::string, int> front_per_mode;
  for (const auto& p : points) {
    bool dominated = false;
    const double t = std::stod(p.at("time_s")), e = std::stod(p.at("rms_mm"));
    for (const auto& q : points) {
      if (q.at("mode") != p.at("mode") || &q == &p) continue;
      const double tq = std::stod(q.at("time_s")), eq = std::stod(q.at("rms_mm"));
      if (tq <= t && eq <= e && (tq < t || eq < e)) dominated = true;
    }
    EXPECT_EQ(p.at("on_front"), dominated ? "0" : "1") << p.at("id") << " " << p.at("mode");
    if (!dominated) ++front_per_mode[p.at("mode")];
  }
  // Keys: the mode's initial and the rank by time on its front (P1 fastest), none off the front.
  for (const auto& p : points) {
    if (p.at("on_front") == "0") {
      EXPECT_EQ(p.at("key"), "") << p.at("id");
      continue;
    }
    int faster = 0;
    for (const auto& q : points) {
      faster += q.at("mode") == p.at("mode") && q.at("on_front") == "1" &&
                std::stod(q.at("time_s")) < std::stod(p.at("time_s"));
    }
    std::string key(1, p.at("mode") == "projector" ? 'P' : 'S');
    key.append(std::to_string(faster + 1));
    EXPECT_EQ(p.at("key"), key);
  }
  EXPECT_GE(front_per_mode["projector"], 1);
  EXPECT_GE(front_per_mode["stereo"], 1);
  ASSERT_EQ(s.merge.front.size(),
            static_cast<size_t>(front_per_mode["projector"] + front_per_mode["stereo"]));
  // Printed by key, each line naming the axes of its combination.
  EXPECT_EQ(s.merge.front[0].rfind("P1 projector: ", 0), 0u) << s.merge.front[0];
  EXPECT_NE(s.merge.front[0].find("codec="), std::string::npos) << s.merge.front[0];
}

// Study 3: 8 layers x 2 modes; each verdict is its change against its threshold (the full-model
// verdict when planned), and the layers whose physics must matter do: sensor noise and the fill
// factor alone raise the error in both modes.
TEST(QuickStudies, PhysicsLayersVerdictsFollowTheirChangesAndThresholds) {
  TempDir tmp;
  const SweepStudySummary s = RunQuickStudy("physics_layers_quick", tmp / "result");
  EXPECT_EQ(s.plan.jobs, 18);
  const auto layers = ReadCsv(tmp / "result/layers.csv");
  ASSERT_EQ(layers.size(), 16u);
  EXPECT_EQ(s.merge.effects.size(), 16u);
  for (const auto& r : layers) {
    const std::string what = r.at("layer") + " " + r.at("mode");
    const bool off =
        std::abs(std::stod(r.at("off_d_rms_mm"))) > std::stod(r.at("off_threshold_rms_mm")) ||
        std::abs(std::stod(r.at("off_d_p95_mm"))) > std::stod(r.at("off_threshold_p95_mm"));
    EXPECT_EQ(r.at("off_needed"), off ? "1" : "0") << what;
    EXPECT_EQ(r.at("needed"), r.at("off_needed")) << what;
    EXPECT_GE(std::stod(r.at("off_threshold_rms_mm")), 0.005) << what;  // the tolerance
    if (r.at("layer") == "noise" || r.at("layer") == "fill_factor") {
      EXPECT_GT(std::stod(r.at("alone_d_rms_mm")), 0.005) << what;
      EXPECT_EQ(r.at("alone_needed"), "1") << what;
    }
  }
}

// Study 2: for each codec and mode, the p95 error grows from the lowest to the highest read noise
// (or nothing is reconstructed any more), and its break point (0.5 mm) lies inside the swept range.
TEST(QuickStudies, StabilityErrorGrowsWithNoiseAndEveryMethodBreaksInRange) {
  TempDir tmp;
  const SweepStudySummary s = RunQuickStudy("stability_quick", tmp / "result");
  EXPECT_EQ(s.plan.jobs, 16);
  std::map<std::string, std::map<double, double>> p95;  // codec + mode -> read noise -> p95
  for (const auto& r : ReadCsv(tmp / "result/results.csv")) {
    // An empty figure: nothing reconstructed, the method broke (an error beyond any limit).
    p95[r.at("codec") + " " + r.at("mode")][std::stod(r.at("read_noise_e"))] =
        r.at("p95_mm").empty() ? INFINITY : std::stod(r.at("p95_mm"));
  }
  ASSERT_EQ(p95.size(), 4u);
  for (const auto& [series, curve] : p95) {
    EXPECT_GT(curve.rbegin()->second, 2 * curve.begin()->second) << series;
  }
  int broke = 0;
  for (const auto& b : ReadCsv(tmp / "result/break_points.csv")) {
    if (b.at("metric") != "p95_mm") continue;
    EXPECT_EQ(b.at("status"), "broke") << b.at("series") << " " << b.at("mode");
    const double x = std::stod(b.at("read_noise_e"));
    EXPECT_GT(x, 5);
    EXPECT_LE(x, 800);
    ++broke;
  }
  EXPECT_EQ(broke, 4);
}

}  // namespace
}  // namespace slshadow::studies
