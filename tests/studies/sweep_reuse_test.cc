// What a sweep shard reuses between jobs (workflows/studies/sweep_reuse.h). Oracles: the images of
// sim::Simulator::Render (what `slshadow simulate` writes) for the same scene and seed, bit for
// bit; MeasureAccuracy(compare::Compare(...)) for the accuracy figures, double for double.
#include "workflows/studies/sweep_reuse.h"

#include "compare/c2m_grid.h"
#include "compare/internal/median_spacing.h"
#include "compare/median_spacing.h"
#include "compare/statistics.h"
#include "core/config.h"
#include "core/error.h"
#include "patterns/codec.h"
#include "reconstruct/reconstruct.h"
#include "sim/scene.h"
#include "sim/scene_surface.h"
#include "tests/testing/temp_dir.h"
#include "workflows/pipeline/scan_pipeline.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <limits>
#include <random>

#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace slshadow::studies {
namespace {
using testing::SourceDir;

struct Fixture {
  Rig rig = LoadRig(SourceDir() / "config/studies/quarter_demo_rig.yaml");
  Scene scene = pipeline::LoadSceneOrDemo("");
  PatternSpec spec = pipeline::LoadPatternSpecOrDemo("");
  std::vector<cv::Mat> patterns = GeneratePatterns(spec);
};

Fixture& Shared() {
  static Fixture* f = new Fixture();
  return *f;
}

int CountDifferentPixels(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return -1;
  cv::Mat diff;
  cv::compare(a, b, diff, cv::CMP_NE);
  return cv::countNonZero(diff);
}

// Each seed's images from the noise-free images equal the renderer's, for 8- and 12-bit ADCs,
// with and without other radiometric layers, and with a read noise so large that signal-free
// pixels are often not 0 (the short cut for them must then not be taken).
TEST(NoiseFreeImages, EverySeedGivesTheRenderersImagesBitForBit) {
  Fixture& f = Shared();
  const Simulator sim(f.scene, f.rig);
  struct Case {
    int adc_bits;
    double read_noise_e, full_well_e, ambient, gamma;
  };
  const std::vector<Case> cases = {
      {8, 6, 10000, 0, 1}, {12, 6, 10000, 0, 1}, {8, 400, 10000, 0.05, 1.8}, {10, 30, 2000, 0, 1}};
  for (const Case& c : cases) {
    Scene noisy = f.scene;
    noisy.radiometry.adc_bits = c.adc_bits;
    noisy.layers.noise_enabled = true;
    noisy.layers.read_noise_e = c.read_noise_e;
    noisy.layers.full_well_e = c.full_well_e;
    noisy.layers.ambient = c.ambient;
    noisy.layers.response_enabled = c.gamma != 1;
    noisy.layers.gamma = c.gamma;
    const NoiseFreeImages cache(sim, noisy, f.rig, f.patterns);
    ASSERT_EQ(cache.num_cameras(), 2);
    ASSERT_EQ(cache.num_patterns(), static_cast<int>(f.patterns.size()));
    std::vector<std::vector<cv::Mat>> images;  // reused across seeds, as in a shard
    for (uint64_t seed : {1u, 2u, 977u}) {
      noisy.layers.seed = seed;
      cache.Render(noisy, &images);
      const auto expected = sim.Render(f.patterns, &noisy);
      int zeros = 0;
      for (size_t cam = 0; cam < expected.size(); ++cam) {
        for (size_t p = 0; p < expected[cam].size(); ++p) {
          ASSERT_EQ(CountDifferentPixels(images[cam][p], expected[cam][p]), 0)
              << "adc " << c.adc_bits << " read noise " << c.read_noise_e << " seed " << seed
              << " camera " << cam << " pattern " << p;
          zeros += cv::countNonZero(images[cam][p] == 0);
        }
      }
      // The short cut for signal-free pixels is exercised: many pixels are dark.
      EXPECT_GT(zeros, 1000);
    }
  }
}

TEST(NoiseFreeImages, SeedsDifferAndNoiseOffIsTheNoiseFreeAdc) {
  Fixture& f = Shared();
  const Simulator sim(f.scene, f.rig);
  Scene noisy = f.scene;
  noisy.layers.noise_enabled = true;
  const NoiseFreeImages cache(sim, noisy, f.rig, f.patterns);
  std::vector<std::vector<cv::Mat>> a, b, off;
  noisy.layers.seed = 5;
  cache.Render(noisy, &a);
  noisy.layers.seed = 6;
  cache.Render(noisy, &b);
  EXPECT_GT(CountDifferentPixels(a[0][3], b[0][3]), a[0][3].rows * a[0][3].cols / 10);
  // Noise off: the renderer's noise-free images (its fused kernel), bit for bit.
  cache.Render(f.scene, &off);
  const auto expected = sim.Render(f.patterns, &f.scene);
  for (size_t cam = 0; cam < expected.size(); ++cam) {
    for (size_t p = 0; p < expected[cam].size(); ++p) {
      ASSERT_EQ(CountDifferentPixels(off[cam][p], expected[cam][p]), 0) << cam << " " << p;
    }
  }
}

TEST(NoiseFreeImages, KeyIgnoresNameAndNoiseOnly) {
  const nlohmann::json scene = {{"name", "a"},
                                {"layers", {{"noise", {{"seed", 1}}}, {"ambient", 0.1}}}};
  nlohmann::json other_seed = scene, other_name = scene, other_ambient = scene;
  other_seed["layers"]["noise"]["seed"] = 2;
  other_name["name"] = "b";
  other_ambient["layers"]["ambient"] = 0.2;
  const nlohmann::json patterns = {{"kind", "gray_code"}};
  EXPECT_EQ(NoiseFreeImages::Key(scene, patterns), NoiseFreeImages::Key(other_seed, patterns));
  EXPECT_EQ(NoiseFreeImages::Key(scene, patterns), NoiseFreeImages::Key(other_name, patterns));
  EXPECT_NE(NoiseFreeImages::Key(scene, patterns), NoiseFreeImages::Key(other_ambient, patterns));
  EXPECT_NE(NoiseFreeImages::Key(scene, patterns),
            NoiseFreeImages::Key(scene, nlohmann::json{{"kind", "phase_shift"}}));
}

// Exact spheres and cylinders (here the parts of a ball bar and a VDI sphere) as meshes whose
// distance to points on the true surfaces stays under 0.5 um; meshes and planes as SceneSurface.
TEST(GroundTruthSurface, TessellatedPrimitivesWithinAFractionOfAMicrometre) {
  const Scene ball_bar = LoadScene(SourceDir() / "config/scenes/ball_bar.yaml");
  const Scene sphere = LoadScene(SourceDir() / "config/scenes/vdi2634_sphere.yaml");
  for (const Scene* scene : {&ball_bar, &sphere}) {
    const TriangleMesh surface = GroundTruthSurface(*scene, "test");
    const compare::MeshDistance distance(surface);
    int checked = 0;
    for (const SceneObject& o : scene->objects) {
      if (o.type != ObjectType::kSphere) continue;
      // Points on the true sphere in every direction (a Fibonacci sphere), and 1 mm outside it.
      for (int i = 0; i < 2000; ++i) {
        const double z = -1 + 2 * (i + 0.5) / 2000, phi = i * 2.399963229728653;
        const Eigen::Vector3d dir(std::sqrt(1 - z * z) * std::cos(phi),
                                  std::sqrt(1 - z * z) * std::sin(phi), z);
        const Eigen::Vector3d on = o.rig_from_object * Eigen::Vector3d(o.radius_mm * dir);
        const Eigen::Vector3d out = o.rig_from_object * Eigen::Vector3d((o.radius_mm + 1) * dir);
        const double d = std::abs(distance.Closest(on).signed_distance_mm);
        // Where the bar enters the sphere its (inner) surface may be nearer: at most as near.
        EXPECT_LT(d, 0.5e-3) << o.name << " " << i;
        // Outside (away from the ball bar's bar and from the plate behind the single sphere).
        if (scene == &sphere) {
          EXPECT_NEAR(distance.Closest(out).signed_distance_mm, 1.0, 0.5e-3) << o.name << " " << i;
        }
        ++checked;
      }
    }
    EXPECT_GE(checked, 2000);
  }
  // Planes (and meshes) are SceneSurface's.
  const Scene plane = LoadScene(SourceDir() / "config/scenes/flat_plane.yaml");
  const TriangleMesh a = GroundTruthSurface(plane, "plane"), b = SceneSurface(plane, "plane");
  EXPECT_EQ(a.vertices, b.vertices);
  EXPECT_EQ(a.triangles, b.triangles);
  // A box is exact: the signed distance of points along random directions from its centre
  // equals the analytic distance to |x|, |y|, |z| <= size / 2, inside (negative) and outside.
  Scene box;
  box.objects.emplace_back();
  box.objects.back().type = ObjectType::kBox;
  box.objects.back().name = "crate";
  box.objects.back().size_mm = Eigen::Vector3d(60, 40, 20);
  box.objects.back().rig_from_object =
      Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized())),
              Eigen::Vector3d(5, -3, 500));
  const TriangleMesh box_surface = GroundTruthSurface(box, "box");
  EXPECT_EQ(box_surface.NumTriangles(), 12u);
  const compare::MeshDistance box_distance(box_surface);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-45, 45);
  for (int i = 0; i < 500; ++i) {
    const Eigen::Vector3d local(u(rng), u(rng) / 1.5, u(rng) / 3);
    const Eigen::Vector3d h(30, 20, 10), q = local.cwiseAbs() - h;
    const double truth = q.maxCoeff() <= 0 ? q.maxCoeff() : q.cwiseMax(0.0).norm();
    const Eigen::Vector3d p = box.objects.back().rig_from_object * local;
    EXPECT_NEAR(box_distance.Closest(p).signed_distance_mm, truth, 1e-9) << local.transpose();
  }
  Scene cloud;
  cloud.objects.emplace_back();
  cloud.objects.back().type = ObjectType::kPointCloud;
  cloud.objects.back().name = "scan";
  EXPECT_THROW(GroundTruthSurface(cloud, "clouds"), Error);
}

// The scorer's figures are those of the demo's path (compare::Compare, then MeasureAccuracy),
// for both modes of a noisy scan and two thresholds; an empty cloud is rejected as Compare does.
// Both modes' clouds of a noisy scan (seed 3) of the fixture, and its lit visible surface.
struct NoisyScan {
  std::vector<ReconstructMode> modes = {ReconstructMode::kProjector, ReconstructMode::kStereo};
  std::vector<Reconstruction> recs;
  std::vector<Eigen::Vector3d> visible;
};

const NoisyScan& SharedScan() {
  static const NoisyScan* scan = [] {
    Fixture& f = Shared();
    auto* s = new NoisyScan();
    const Simulator sim(f.scene, f.rig);
    Scene noisy = f.scene;
    noisy.layers.noise_enabled = true;
    noisy.layers.seed = 3;
    const auto images = sim.Render(f.patterns, &noisy);
    pipeline::DecodedScan decoded;
    decoded.rig = f.rig;
    decoded.spec = f.spec;
    for (size_t c = 0; c < 2; ++c) {
      decoded.cameras.push_back(f.rig.cameras[c].name);
      decoded.maps.push_back(DecodePatterns(f.spec, images[c], DecodeOptions{}));
    }
    s->recs = pipeline::ReconstructModes(decoded, s->modes, ReconstructOptions{});
    s->visible = LitVisibleSurface(sim.geometry(0));
    return s;
  }();
  return *scan;
}

// The scorer's figures are those of the demo's path (compare::Compare, then MeasureAccuracy),
// for both modes of a noisy scan and two thresholds, with the signed distances from
// compare::MeshDistance (before Prepare), from the grid of cells (after two) and from it again
// after a third (which builds the cells the measured points fell in unbuilt); an empty cloud is
// rejected as Compare does.
TEST(GroundTruthScorer, EqualsCompareThenMeasureAccuracy) {
  Fixture& f = Shared();
  const NoisyScan& scan = SharedScan();
  const std::vector<ReconstructMode>& modes = scan.modes;
  const std::vector<Reconstruction>& recs = scan.recs;
  const std::vector<Eigen::Vector3d>& visible = scan.visible;
  const TriangleMesh surface = SceneSurface(f.scene, "demo");
  GroundTruthScorer scorer(surface, visible, "truth");
  const compare::Reference reference = compare::ReferenceFromMesh(surface, "truth");
  for (const int prepared : {0, 2, 3}) {
    for (int k = prepared == 3 ? 2 : 0; k < prepared; ++k) {
      scorer.Prepare({&recs[0].cloud, &recs[1].cloud});
    }
    // The automatic coverage radius, and one of several grid cells.
    for (const auto& [threshold, radius] :
         std::vector<std::pair<double, double>>{{0.1, 0.0}, {0.5, 0.0}, {0.5, 6.0}}) {
      compare::CompareOptions options;
      options.threshold_mm = threshold;
      options.coverage_radius_mm = radius;
      for (size_t k = 0; k < modes.size(); ++k) {
        const std::string mode = ToString(modes[k]);
        ASSERT_GT(recs[k].cloud.size(), 10000u);
        const pipeline::ModeAccuracy got = scorer.Measure(recs[k].cloud, options, mode);
        const compare::CompareResult result =
            compare::Compare(recs[k].cloud, reference, options, mode);
        pipeline::ModeAccuracy want = pipeline::MeasureAccuracy(mode, result, visible);
        pipeline::MeasureFigureUncertainty(result.deviations_mm, &want);
        EXPECT_EQ(pipeline::ModeAccuracyToJson(got).dump(),
                  pipeline::ModeAccuracyToJson(want).dump())
            << mode << " threshold " << threshold << " radius " << radius << " prepared "
            << prepared;
        EXPECT_GT(got.coverage, 0.1);
        EXPECT_GT(got.visible_coverage, 0.5);
        EXPECT_LT(got.rms_mm, threshold * 2);
      }
    }
  }
  EXPECT_THROW(scorer.Measure(PointCloud{}, compare::CompareOptions{}, "empty"), Error);

  // The median spacing behind the automatic radius on the scans' clouds (reconstructions, in grid
  // order): compare::MedianSpacing answers them by its scan-order grid, the same double as its
  // general method (tests/compare/statistics_test.cc checks both against a brute force and the
  // tree on synthetic clouds).
  for (size_t k = 0; k < 2; ++k) {
    const std::vector<Eigen::Vector3d>& pts = recs[k].cloud.points;
    const size_t stride = std::max<size_t>(1, pts.size() / 20000);
    std::vector<double> d((pts.size() + stride - 1) / stride);
    EXPECT_TRUE(compare::internal::ScanOrderSpacings(pts, stride, &d)) << k;
    EXPECT_EQ(compare::MedianSpacing(pts), compare::internal::MedianSpacingByCells(pts, 20000))
        << k;
  }
}

// The grid's signed distances are compare::MeshDistance's, bit for bit (value and sign), for the
// scan's clouds, for points scattered up to 3 mm off the demo's ground truth (part and table), on
// its vertices and edges (ties between triangles), far from it and outside the grid; and most of
// the clouds' cells are answered by the grid, not by MeshDistance.
TEST(C2mGrid, SignedDistancesAreMeshDistancesBitForBit) {
  Fixture& f = Shared();
  const NoisyScan& scan = SharedScan();
  const TriangleMesh surface = GroundTruthSurface(f.scene, "demo");
  const compare::MeshDistance distance(surface);
  compare::C2mGrid grid(surface, distance);
  EXPECT_GT(grid.cell_mm(), 0.1);
  EXPECT_LT(grid.cell_mm(), 2.0);
  std::vector<std::vector<Eigen::Vector3d>> sets = {scan.recs[0].cloud.points,
                                                    scan.recs[1].cloud.points};
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> unit(0, 1), offset(-3, 3);
  std::uniform_int_distribution<size_t> pick(0, surface.triangles.size() - 1);
  std::vector<Eigen::Vector3d> near, features, far;
  for (int i = 0; i < 200000; ++i) {
    const Eigen::Vector3i& t = surface.triangles[pick(rng)];
    const Eigen::Vector3d a = surface.vertices[static_cast<size_t>(t[0])],
                          b = surface.vertices[static_cast<size_t>(t[1])],
                          c = surface.vertices[static_cast<size_t>(t[2])];
    double u = unit(rng), v = unit(rng);
    if (u + v > 1) u = 1 - u, v = 1 - v;
    const Eigen::Vector3d n = (b - a).cross(c - a).normalized();
    const double d = i % 4 == 0 ? offset(rng) : offset(rng) / 30;
    near.push_back(a + u * (b - a) + v * (c - a) + d * n);
    if (i % 8 == 0) {
      features.push_back(a);
      features.push_back(0.5 * (a + b));
      features.push_back(a + 1e-3 * n);
      features.push_back(0.5 * (b + c) - 1e-3 * n);
    }
    if (i % 50 == 0) far.push_back(a + (20 + 100 * unit(rng)) * n);
  }
  far.push_back({1e4, 0, 0});
  far.push_back({0, -3e3, 500});
  sets.push_back(near);
  sets.push_back(features);
  sets.push_back(far);
  const auto same_bits = [](double x, double y) {
    uint64_t a = 0, b = 0;
    std::memcpy(&a, &x, sizeof(a));
    std::memcpy(&b, &y, sizeof(b));
    return a == b;
  };
  EXPECT_TRUE(grid.enabled());
  for (const bool prepared : {false, true}) {
    if (prepared) {
      for (const auto& points : sets) grid.Prepare(points);
      EXPECT_GT(grid.built_cells(), 10000u);
      EXPECT_LT(grid.far_cells() * 4, grid.built_cells());
    }
    for (size_t s = 0; s < sets.size(); ++s) {
      std::vector<double> got;
      grid.SignedDistances(sets[s], &got);
      ASSERT_EQ(got.size(), sets[s].size());
      size_t differ = 0, negative = 0;
      for (size_t i = 0; i < got.size(); ++i) {
        const double want = distance.Closest(sets[s][i]).signed_distance_mm;
        if (!same_bits(got[i], want)) {
          if (++differ <= 5) {
            ADD_FAILURE() << "set " << s << " point " << i << " (" << sets[s][i].transpose()
                          << "): " << got[i] << " != " << want << " prepared " << prepared;
          }
        }
        negative += got[i] < 0;
      }
      EXPECT_EQ(differ, 0u) << "set " << s << " prepared " << prepared;
      if (s < 3) {
        EXPECT_GT(negative, got.size() / 10) << "set " << s;  // both signs are met
      }
    }
  }
  // The cells SignedDistances finds unbuilt are those Prepare would build for the same points:
  // BuildMissed builds them, and the distances stay the same bits.
  compare::C2mGrid lazy(surface, distance), eager(surface, distance);
  std::vector<double> before, after;
  lazy.SignedDistances(sets[0], &before);
  EXPECT_EQ(lazy.built_cells(), 0u);
  lazy.BuildMissed();
  eager.Prepare(sets[0]);
  EXPECT_GT(lazy.built_cells(), 1000u);
  EXPECT_EQ(lazy.built_cells(), eager.built_cells());
  EXPECT_EQ(lazy.far_cells(), eager.far_cells());
  lazy.SignedDistances(sets[0], &after);
  ASSERT_EQ(after.size(), before.size());
  for (size_t i = 0; i < after.size(); ++i) ASSERT_TRUE(same_bits(after[i], before[i])) << i;
  lazy.BuildMissed();  // nothing was missed this time
  EXPECT_EQ(lazy.built_cells(), eager.built_cells());

  // Clouds far sparser than the triangles: no grid, MeshDistance answers every point.
  compare::C2mGrid coarse(surface, distance, 1.0);
  EXPECT_FALSE(coarse.enabled());
  coarse.Prepare(sets[0]);
  EXPECT_EQ(coarse.built_cells(), 0u);
  std::vector<double> got;
  coarse.SignedDistances(sets[0], &got);
  ASSERT_EQ(got.size(), sets[0].size());
  for (size_t i = 0; i < got.size(); i += 97) {
    EXPECT_TRUE(same_bits(got[i], distance.Closest(sets[0][i]).signed_distance_mm)) << i;
  }
}

}  // namespace
}  // namespace slshadow::studies
