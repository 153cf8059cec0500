#include "workflows/pipeline/scan_pipeline.h"
#include "sim/scene_surface.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include <gtest/gtest.h>

#include "compare/statistics.h"
#include "core/error.h"
#include "tests/testing/temp_dir.h"
#include "workflows/pipeline/significance.h"

namespace slshadow::pipeline {
namespace {

// Byte equality of two images (type, size and every byte; NaN payloads compare as bytes).
bool SameBytes(const cv::Mat& a, const cv::Mat& b) {
  if (a.type() != b.type() || a.size() != b.size()) return false;
  for (int y = 0; y < a.rows; ++y) {
    if (std::memcmp(a.ptr(y), b.ptr(y), a.cols * a.elemSize()) != 0) return false;
  }
  return true;
}

// The demo rig scanning the demo scene, rendered once for the whole suite.
class ScanPipeline : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    rig_ = new Rig(LoadRigOrDemo(""));
    scene_ = new Scene(LoadSceneOrDemo(""));
    spec_ = new PatternSpec(LoadPatternSpecOrDemo(""));
    scan_ = new VirtualScan(RenderVirtualScan(*scene_, *rig_, GeneratePatterns(*spec_)));
  }
  static void TearDownTestSuite() {
    delete scan_;
    delete spec_;
    delete scene_;
    delete rig_;
  }
  static Rig* rig_;
  static Scene* scene_;
  static PatternSpec* spec_;
  static VirtualScan* scan_;
};
Rig* ScanPipeline::rig_ = nullptr;
Scene* ScanPipeline::scene_ = nullptr;
PatternSpec* ScanPipeline::spec_ = nullptr;
VirtualScan* ScanPipeline::scan_ = nullptr;

// Oracle: the in-memory path. A scan written as an ImageSet, read back, decoded once and
// reconstructed in both modes gives the same maps and the same clouds, point for point, as the
// images decoded and reconstructed in memory (the encoding is lossless).
TEST_F(ScanPipeline, WrittenScanDecodesAndReconstructsLikeTheImagesInMemory) {
  ASSERT_EQ(scan_->images.size(), 2u);
  ASSERT_EQ(scan_->geometry.size(), 2u);
  EXPECT_EQ(scan_->images[0].size(), static_cast<size_t>(spec_->NumImages()));
  testing::TempDir dir;
  ImageSetWriterOptions writer;
  writer.encoding = ImageEncoding::kPgm;
  const nlohmann::json extra = {{"note", "pipeline test"}};
  WriteVirtualScan(dir / "scan", *rig_, *spec_, *scene_, scan_->images, writer, extra);
  const ImageSet image_set = ImageSet::Open(dir / "scan");
  EXPECT_EQ(image_set.extra(), extra);
  EXPECT_EQ(image_set.records().front().source, ImageSource::kVirtual);
  EXPECT_EQ(image_set.records().front().exposure_us, scene_->radiometry.exposure_us);

  const DecodedScan decoded = DecodeImageSet(image_set);
  ASSERT_EQ(decoded.cameras, (std::vector<std::string>{"left", "right"}));
  std::vector<ProjectorMap> in_memory;
  for (size_t c = 0; c < 2; ++c) {
    in_memory.push_back(DecodePatterns(*spec_, scan_->images[c]));
    const ProjectorMap& read = decoded.map(decoded.cameras[c]);
    EXPECT_TRUE(SameBytes(read.proj_x, in_memory[c].proj_x)) << c;
    EXPECT_TRUE(SameBytes(read.proj_y, in_memory[c].proj_y)) << c;
    EXPECT_TRUE(SameBytes(read.status, in_memory[c].status)) << c;
    EXPECT_TRUE(SameBytes(read.quality, in_memory[c].quality)) << c;
  }
  EXPECT_THROW(decoded.map("middle"), Error);

  std::vector<StageMeasurement> stages;
  const ReconstructOptions options;
  const std::vector<Reconstruction> recs = ReconstructModes(
      decoded, {ReconstructMode::kProjector, ReconstructMode::kStereo}, options, &stages);
  ASSERT_EQ(recs.size(), 2u);
  ASSERT_EQ(stages.size(), 2u);
  EXPECT_EQ(stages[0].name, "reconstruct projector");
  EXPECT_EQ(stages[1].name, "reconstruct stereo");
  const Reconstruction projector = ReconstructWithProjector(*rig_, "left", in_memory[0], options);
  const Reconstruction stereo =
      ReconstructStereo(*rig_, "left", "right", in_memory[0], in_memory[1], options);
  EXPECT_GT(projector.cloud.size(), 1000000u);
  EXPECT_GT(stereo.cloud.size(), 1000000u);
  EXPECT_EQ(recs[0].summary.mode, ReconstructMode::kProjector);
  EXPECT_EQ(recs[1].summary.mode, ReconstructMode::kStereo);
  EXPECT_EQ(recs[0].cloud.points, projector.cloud.points);
  EXPECT_EQ(recs[1].cloud.points, stereo.cloud.points);
}

TEST_F(ScanPipeline, DecodeAndReconstructRefuseWhatWasNotDecoded) {
  testing::TempDir dir;
  ImageSetWriterOptions writer;
  writer.encoding = ImageEncoding::kPgm;
  WriteVirtualScan(dir / "scan", *rig_, *spec_, *scene_, scan_->images, writer,
                   nlohmann::json::object());
  const ImageSet image_set = ImageSet::Open(dir / "scan");
  EXPECT_THROW(DecodeImageSet(image_set, {"middle"}), Error);
  const DecodedScan left_only = DecodeImageSet(image_set, {"left"});
  EXPECT_THROW(ReconstructFromMaps(left_only, ReconstructMode::kStereo, {}), Error);
  EXPECT_GT(ReconstructFromMaps(left_only, ReconstructMode::kProjector, {}).cloud.size(), 1000000u);
  // A wrong image count is refused before anything is written.
  std::vector<std::vector<cv::Mat>> short_scan = scan_->images;
  short_scan[1].pop_back();
  EXPECT_THROW(WriteVirtualScan(dir / "short", *rig_, *spec_, *scene_, short_scan, writer, {}),
               Error);
  EXPECT_FALSE(std::filesystem::exists(dir / "short"));
}

TEST_F(ScanPipeline, SceneSurfaceHoldsMeshesAndPlanesAndNamesOtherObjects) {
  const TriangleMesh meshes = SceneMeshSurface(*scene_);
  const TriangleMesh all = SceneSurface(*scene_, "demo scene");
  ASSERT_EQ(scene_->objects.size(), 2u);  // the part (a mesh) and the table (a plane)
  EXPECT_EQ(meshes.triangles.size(), scene_->objects[0].mesh->triangles.size());
  EXPECT_EQ(all.triangles.size(), meshes.triangles.size() + 2);
  // The part's first vertex moved into the rig frame.
  const SceneObject& part = scene_->objects[0];
  const Eigen::Vector3d expected =
      part.rig_from_object.rotation * part.mesh->vertices[0] + part.rig_from_object.translation;
  EXPECT_LT((meshes.vertices[0] - expected).norm(), 1e-9);

  Scene with_sphere = *scene_;
  SceneObject sphere;
  sphere.name = "ball";
  sphere.type = ObjectType::kSphere;
  sphere.radius_mm = 10;
  with_sphere.objects.push_back(sphere);
  try {
    SceneSurface(with_sphere, "my scene");
    FAIL() << "a sphere was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("my scene"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("'ball'"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("sphere"), std::string::npos) << e.what();
  }
  EXPECT_EQ(SceneMeshSurface(with_sphere).triangles.size(), meshes.triangles.size());
}

// Brute force: every lit pixel at even (x, y), in row order, at its ground-truth point.
TEST_F(ScanPipeline, LitVisibleSurfaceIsEverySecondLitPixel) {
  const GeometryBuffer& g = scan_->geometry[0];
  const std::vector<Eigen::Vector3d> lit = LitVisibleSurface(g);
  size_t k = 0;
  for (int y = 0; y < g.height; y += 2) {
    for (int x = 0; x < g.width; x += 2) {
      if (g.visibility.at<uint8_t>(y, x) != 2) continue;
      ASSERT_LT(k, lit.size());
      const cv::Vec3f p = g.point_in_rig.at<cv::Vec3f>(y, x);
      ASSERT_EQ(lit[k], Eigen::Vector3d(p[0], p[1], p[2]));
      ++k;
    }
  }
  EXPECT_EQ(k, lit.size());
  EXPECT_GT(lit.size(), 100000u);
}

// Oracle: the ground truth itself. The lit surface as a cloud lies on the reference (RMS ~ the
// float rounding of the ground-truth points) and covers all of what is visible; half of it
// covers about half.
TEST_F(ScanPipeline, AccuracyOfTheGroundTruthCloudIsPerfectAndHalfCoversHalf) {
  const std::vector<Eigen::Vector3d> visible = LitVisibleSurface(scan_->geometry[0]);
  const compare::Reference reference =
      compare::ReferenceFromMesh(SceneSurface(*scene_, "demo"), "truth");
  PointCloud cloud;
  cloud.points = visible;
  const compare::CompareOptions options;
  const ModeAccuracy full =
      MeasureAccuracy("truth", compare::Compare(cloud, reference, options), visible);
  EXPECT_EQ(full.mode, "truth");
  EXPECT_EQ(full.points, visible.size());
  EXPECT_LT(full.rms_mm, 1e-3);
  EXPECT_EQ(full.outliers, 0u);
  EXPECT_EQ(full.outlier_fraction, 0);
  EXPECT_GT(full.visible_coverage, 0.999);
  EXPECT_GT(full.coverage, 0.3);

  // Keep the points left of the median x: about half the visible surface.
  std::vector<double> xs;
  for (const auto& p : visible) xs.push_back(p.x());
  std::nth_element(xs.begin(), xs.begin() + static_cast<std::ptrdiff_t>(xs.size() / 2), xs.end());
  const double median_x = xs[xs.size() / 2];
  PointCloud half;
  for (const auto& p : visible) {
    if (p.x() < median_x) half.points.push_back(p);
  }
  const ModeAccuracy part =
      MeasureAccuracy("half", compare::Compare(half, reference, options), visible);
  EXPECT_GT(part.visible_coverage, 0.45);
  EXPECT_LT(part.visible_coverage, 0.55);
  EXPECT_LT(part.coverage, full.coverage);

  // The visible coverage measured inside Compare (the demo's path, one grid for both sample sets)
  // is the same double.
  const compare::CompareResult with_extra = compare::Compare(
      PointCloud(half), reference, options, "half", {&visible, &reference.cloud.points});
  ASSERT_EQ(with_extra.extra_coverage.size(), 2u);
  EXPECT_EQ(with_extra.extra_coverage[0], part.visible_coverage);
  EXPECT_EQ(with_extra.extra_coverage[1], part.coverage);
  EXPECT_EQ(with_extra.coverage, part.coverage);
  const ModeAccuracy same = MeasureAccuracy("half", with_extra, with_extra.extra_coverage[0]);
  EXPECT_EQ(same.visible_coverage, part.visible_coverage);
  EXPECT_EQ(same.rms_mm, part.rms_mm);
}

// Every image of `b` equals the same (camera, pattern) image of `a`, pixel for pixel, and both have
// the same records.
void ExpectSameImages(const ImageSet& a, const ImageSet& b) {
  ASSERT_EQ(a.records().size(), b.records().size());
  for (const ImageRecord& r : a.records()) {
    const cv::Mat image = b.Load(r.camera, r.pattern_index);
    ASSERT_TRUE(SameBytes(a.Load(r.camera, r.pattern_index), image))
        << r.camera << " " << r.pattern_index;
    EXPECT_EQ(b.Find(r.camera, r.pattern_index)->exposure_us, r.exposure_us);
    EXPECT_EQ(b.Find(r.camera, r.pattern_index)->source, ImageSource::kVirtual);
  }
}

// Oracle: the scan itself. A scan written by SimulateScan from scene, rig and pattern files is
// rendered again from its folder alone (manifest rig and patterns, extra.provenance's scene and
// simulator options) into identical images.
TEST_F(ScanPipeline, RedoFromTheFoldersProvenanceGivesIdenticalImages) {
  testing::TempDir dir;
  const std::filesystem::path demo = std::filesystem::path(SLSHADOW_SOURCE_DIR) / "config" / "demo";
  const Scene scene = LoadScene(demo / "scene.yaml");
  const Rig rig = LoadRig(demo / "rig.yaml");
  const PatternSpec spec = LoadPatternSpec(demo / "patterns.yaml");
  SimulateOptions options;
  options.writer.encoding = ImageEncoding::kPgm;
  options.write_ground_truth = false;
  SimulateScan(scene, rig, GeneratePatterns(spec), PatternSpecToJson(spec), dir / "scan", options);
  const ImageSet scan = ImageSet::Open(dir / "scan");
  const std::optional<ScanProvenance> provenance = ReadScanProvenance(scan);
  ASSERT_TRUE(provenance.has_value());
  EXPECT_EQ(provenance->generator, "slshadow simulate");
  EXPECT_EQ(provenance->scene_base_dir, std::filesystem::absolute(demo).string());
  const ScanSettings settings = ScanSettingsFromProvenance(*provenance, "manifest.json");
  EXPECT_EQ(SimulateOptionsToJson(settings.simulate), SimulateOptionsToJson(options));

  RedoVirtualScan(dir / "scan", dir / "redo");
  const ImageSet redo = ImageSet::Open(dir / "redo");
  ExpectSameImages(scan, redo);
  EXPECT_EQ(redo.patterns(), scan.patterns());
  EXPECT_EQ(RigToJson(redo.rig()), RigToJson(scan.rig()));
  EXPECT_EQ(ReadScanProvenance(redo)->ToJson(), provenance->ToJson());
  // The same images as the suite's in-memory render of the embedded demo (same files).
  for (size_t c = 0; c < 2; ++c) {
    for (int p = 0; p < spec.NumImages(); ++p) {
      ASSERT_TRUE(
          SameBytes(redo.Load(rig.cameras[c].name, p), scan_->images[c][static_cast<size_t>(p)]))
          << c << " " << p;
    }
  }
  // An existing output folder is not replaced.
  EXPECT_THROW(RedoVirtualScan(dir / "scan", dir / "redo"), Error);
}

TEST_F(ScanPipeline, RedoRefusesScansItCannotRebuild) {
  testing::TempDir dir;
  ImageSetWriterOptions writer;
  writer.encoding = ImageEncoding::kPgm;
  const auto message = [&](const std::string& name) -> std::string {
    try {
      RedoVirtualScan(dir / name, dir / (name + "-redo"));
    } catch (const Error& e) {
      EXPECT_FALSE(std::filesystem::exists(dir / (name + "-redo")));
      return e.what();
    }
    return "";
  };
  // No provenance at all.
  WriteVirtualScan(dir / "bare", *rig_, *spec_, *scene_, scan_->images, writer,
                   {{"note", "hand-made"}});
  EXPECT_NE(message("bare").find("extra.provenance: missing"), std::string::npos)
      << message("bare");
  // A scene built in code has no config to rebuild it from.
  Scene in_code = *scene_;
  in_code.source_config = nullptr;
  WriteVirtualScan(dir / "code", *rig_, *spec_, in_code, scan_->images, writer,
                   ExtraWithProvenance(VirtualScanProvenance(in_code, SimulateOptions{}, "test")));
  EXPECT_NE(message("code").find("built in code"), std::string::npos) << message("code");
  // A scene edited after loading: its config no longer rebuilds what was rendered.
  Scene edited = *scene_;
  edited.radiometry.exposure_fraction = 0.5;
  WriteVirtualScan(dir / "edited", *rig_, *spec_, edited, scan_->images, writer,
                   ExtraWithProvenance(VirtualScanProvenance(edited, SimulateOptions{}, "test")));
  EXPECT_NE(message("edited").find("differs from the recorded summary"), std::string::npos)
      << message("edited");
  // A malformed option in the provenance names the manifest and the field.
  ScanProvenance typo = VirtualScanProvenance(*scene_, SimulateOptions{}, "test");
  typo.simulate["trace"] = "packet16";
  WriteVirtualScan(dir / "typo", *rig_, *spec_, *scene_, scan_->images, writer,
                   ExtraWithProvenance(typo));
  EXPECT_NE(message("typo").find("extra.provenance.simulate"), std::string::npos)
      << message("typo");
  EXPECT_NE(message("typo").find("trace"), std::string::npos) << message("typo");
}

// The rule shared by the physics fit and study 3: an effect counts beyond max(3 sigma, floor).
TEST(Significance, AnEffectCountsBeyondThreeSigmaAndTheFloor) {
  EXPECT_DOUBLE_EQ(SignificanceThreshold(0.01, 0.002), 0.03);
  EXPECT_DOUBLE_EQ(SignificanceThreshold(0.0001, 0.002), 0.002);
  EXPECT_TRUE(Significant(-0.031, 0.01, 0.002));
  EXPECT_FALSE(Significant(0.029, 0.01, 0.002));
  EXPECT_FALSE(Significant(0.0019, 0, 0.002));
  EXPECT_FALSE(Significant(1e9, std::nan(""), 0.002));  // unknown uncertainty: nothing counts
  // sd of 1..8 (sample) / sqrt(8); NaN values are left out; fewer than two: NaN.
  EXPECT_NEAR(BandSigma({1, 2, 3, 4, 5, 6, 7, 8}), std::sqrt(6.0) / std::sqrt(8.0), 1e-15);
  EXPECT_NEAR(BandSigma({1, std::nan(""), 3}), std::sqrt(2.0) / std::sqrt(2.0), 1e-15);
  EXPECT_TRUE(std::isnan(BandSigma({1, std::nan("")})));
}

// A figure's uncertainty from 8 consecutive runs of the points: bands whose RMS and p95 are known
// (each band one value, (b + 1) / 100 mm, signs mixed: the figures are of |d|).
TEST(MeasureFigureUncertainty, IsTheSpreadOfTheFiguresOfEightConsecutiveBands) {
  for (const size_t per_band : {size_t{1}, size_t{100}}) {
    std::vector<double> d;
    for (int b = 0; b < kSignificanceBands; ++b) {
      for (size_t i = 0; i < per_band; ++i) d.push_back((i % 2 ? -1 : 1) * (b + 1) / 100.0);
    }
    ModeAccuracy m;
    MeasureFigureUncertainty(d, &m);
    const double expected = std::sqrt(6.0) / std::sqrt(8.0) / 100;  // BandSigma of 0.01 .. 0.08
    EXPECT_NEAR(m.rms_sigma_mm, expected, 1e-15) << per_band;
    EXPECT_NEAR(m.p95_sigma_mm, expected, 1e-15) << per_band;
  }
  // Each band's figures are compare::ComputeStats's (non-finite values left out), band by band.
  std::vector<double> d(1003);
  for (size_t i = 0; i < d.size(); ++i) d[i] = std::sin(0.37 * i) * (i % 7 + 1) / 10;
  d[5] = std::nan("");
  d[600] = INFINITY;
  ModeAccuracy bands;
  MeasureFigureUncertainty(d, &bands);
  ASSERT_EQ(bands.rms_bands_mm.size(), 8u);
  for (size_t b = 0; b < 8; ++b) {
    const std::vector<double> band(d.begin() + static_cast<std::ptrdiff_t>(d.size() * b / 8),
                                   d.begin() + static_cast<std::ptrdiff_t>(d.size() * (b + 1) / 8));
    const compare::DistanceStats s = compare::ComputeStats(band, false, 0.5);
    EXPECT_NEAR(bands.rms_bands_mm[b], s.rms_mm, 1e-15) << b;
    EXPECT_EQ(bands.p95_bands_mm[b], s.p95_mm) << b;
  }
  EXPECT_EQ(bands.rms_sigma_mm, BandSigma(bands.rms_bands_mm));
  ModeAccuracy m;
  MeasureFigureUncertainty({0.1}, &m);  // one point: one band with a figure
  EXPECT_TRUE(std::isnan(m.rms_sigma_mm));
  EXPECT_TRUE(std::isnan(m.p95_sigma_mm));
}

}  // namespace
}  // namespace slshadow::pipeline
