#include "compare/vdi2634.h"

#include <cmath>
#include <fstream>
#include <random>

#include <gtest/gtest.h>

#include "core/error.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::compare {
namespace {

constexpr double kDiameter = 25.4, kDistance = 120.0, kPlaneZ = 545.0;

ArtefactSpec Spec() {
  ArtefactSpec s;
  // Nominal positions a little off the true ones (as a fixture's drawing would be).
  s.spheres = {{"s1", {-60.4, 0.3, 500.5}, kDiameter}, {"s2", {60.2, -0.4, 499.6}, kDiameter}};
  s.pairs = {{"bar", "s1", "s2", kDistance}};
  s.planes = {{"flat", {0.5, 0.2, kPlaneZ + 0.4}, {0, 0.02, -1}, 35.0}};
  return s;
}

struct Scene {
  PointCloud cloud;
  double sphere_noise_range[2] = {0, 0};  // range of the injected radial noise per sphere
  double plane_noise_range = 0;
};

// Visible halves of two spheres seen from the origin, a flat behind them, random clutter;
// `sigma` mm of Gaussian noise along the surface normal.
Scene MakeScene(double sigma, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Scene s;
  const Eigen::Vector3d centers[2] = {{-60, 0, 500}, {60, 0, 500}};
  for (int k = 0; k < 2; ++k) {
    double lo = 1e9, hi = -1e9;
    for (int i = 0; i < 20000;) {
      const Eigen::Vector3d d = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
      if (d.dot(-centers[k]) <= 0) continue;  // back side: not visible
      const double e = sigma * g(rng);
      lo = std::min(lo, e);
      hi = std::max(hi, e);
      s.cloud.points.push_back(centers[k] + (kDiameter / 2 + e) * d);
      ++i;
    }
    s.sphere_noise_range[k] = hi - lo;
  }
  double lo = 1e9, hi = -1e9;
  for (int i = 0; i < 20000; ++i) {
    const double e = sigma * g(rng);
    lo = std::min(lo, e);
    hi = std::max(hi, e);
    s.cloud.points.emplace_back(-30 + 60 * u(rng), -30 + 60 * u(rng), kPlaneZ + e);
  }
  s.plane_noise_range = hi - lo;
  for (int i = 0; i < 500; ++i) {
    s.cloud.points.emplace_back(-100 + 200 * u(rng), -50 + 100 * u(rng), 450 + 120 * u(rng));
  }
  return s;
}

TEST(Vdi2634, NoiseFreeArtefactsGiveZeroFigures) {
  const Scene scene = MakeScene(0.0, 61);
  const Vdi2634Result r = EvaluateVdi2634(scene.cloud, Spec());
  SCOPED_TRACE(r.Summary());
  ASSERT_EQ(r.spheres.size(), 2u);
  for (const auto& s : r.spheres) {
    ASSERT_TRUE(s.found);
    EXPECT_LT(s.pf_mm, 1e-3 * 1e-3);  // below 1 nm, far below 1 um
    EXPECT_LT(std::abs(s.ps_mm), 1e-6);
    EXPECT_EQ(s.points, 20000u);  // every sphere point, no clutter
  }
  ASSERT_TRUE(r.pairs[0].found);
  EXPECT_LT(std::abs(r.pairs[0].sd_mm), 1e-6);
  ASSERT_TRUE(r.planes[0].found);
  EXPECT_LT(r.planes[0].f_mm, 1e-6);
  EXPECT_NEAR(std::abs(r.planes[0].fit.normal.z()), 1.0, 1e-12);
}

TEST(Vdi2634, FiguresGrowWithNoiseAsTheNoiseRange) {
  for (const double sigma : {0.005, 0.02}) {
    const Scene scene = MakeScene(sigma, 62);
    const Vdi2634Result r = EvaluateVdi2634(scene.cloud, Spec());
    SCOPED_TRACE(r.Summary());
    for (int k = 0; k < 2; ++k) {
      const auto& s = r.spheres[static_cast<size_t>(k)];
      ASSERT_TRUE(s.found);
      // PF is the range of the radial noise (the fit absorbs almost nothing of it)...
      EXPECT_NEAR(s.pf_mm, scene.sphere_noise_range[k], 0.1 * scene.sphere_noise_range[k]);
      // ... while size and spacing errors average out: ~ sigma / sqrt(n).
      EXPECT_LT(std::abs(s.ps_mm), 0.1 * sigma);
    }
    EXPECT_LT(std::abs(r.pairs[0].sd_mm), 0.1 * sigma);
    EXPECT_NEAR(r.planes[0].f_mm, scene.plane_noise_range, 0.1 * scene.plane_noise_range);
  }
}

TEST(Vdi2634, ExclusionDropsTheLargestResiduals) {
  const Scene scene = MakeScene(0.02, 63);
  Vdi2634Options o;
  o.exclude_fraction = 0.003;
  const Vdi2634Result all = EvaluateVdi2634(scene.cloud, Spec());
  const Vdi2634Result cut = EvaluateVdi2634(scene.cloud, Spec(), o);
  EXPECT_LT(cut.spheres[0].pf_mm, all.spheres[0].pf_mm);
  EXPECT_EQ(cut.spheres[0].points, all.spheres[0].points - 60);
  o.exclude_fraction = 0.01;
  EXPECT_THROW(EvaluateVdi2634(scene.cloud, Spec(), o), Error);
}

TEST(Vdi2634, MissingArtefactIsReportedNotThrown) {
  ArtefactSpec spec = Spec();
  spec.spheres[1].nominal_center_mm = {0, 200, 500};  // nothing there
  const Vdi2634Result r = EvaluateVdi2634(MakeScene(0.0, 64).cloud, spec);
  EXPECT_TRUE(r.spheres[0].found);
  EXPECT_FALSE(r.spheres[1].found);
  EXPECT_FALSE(r.pairs[0].found);
}

TEST(LoadArtefactSpec, ReadsYamlAndNamesBadFields) {
  slshadow::testing::TempDir tmp;
  std::ofstream(tmp / "a.yaml")
      << "spheres:\n"
         "  - {name: s1, center_mm: [-60, 0, 500], diameter_mm: 25.4}\n"
         "  - {name: s2, center_mm: [60, 0, 500], diameter_mm: 25.4}\n"
         "sphere_pairs:\n  - {name: bar, spheres: [s1, s2], distance_mm: 120}\n"
         "planes:\n  - {name: flat, point_mm: [0, 0, 545], normal: [0, 0, -1], half_size_mm: 35}\n";
  const ArtefactSpec s = LoadArtefactSpec(tmp / "a.yaml");
  EXPECT_EQ(s.spheres.size(), 2u);
  EXPECT_EQ(s.pairs[0].sphere_b, "s2");
  EXPECT_EQ(s.planes[0].nominal_normal, Eigen::Vector3d(0, 0, -1));
  std::ofstream(tmp / "b.yaml")
      << "sphere_pairs:\n  - {name: bar, spheres: [s1, s9], distance_mm: 120}\n";
  try {
    LoadArtefactSpec(tmp / "b.yaml");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("sphere_pairs[0].spheres: unknown sphere"),
              std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace slshadow::compare
