#include "sim/simulate.h"

#include <cmath>

#include <gtest/gtest.h>

#include "core/config.h"
#include "core/error.h"
#include "core/image_set.h"
#include "tests/sim/sim_test_util.h"

namespace slshadow {
namespace {

using testing::SameFloat;

std::vector<cv::Mat> StripeImages(const Rig& rig) {
  std::vector<cv::Mat> images;
  const int w = rig.projector->model.width, h = rig.projector->model.height;
  for (int period : {8, 16, 32}) {
    cv::Mat m(h, w, CV_8UC1);
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) m.at<uint8_t>(y, x) = (x / period) % 2 ? 255 : 0;
    }
    images.push_back(m);
  }
  images.push_back(testing::FlatProjectorImage(rig, 255));
  return images;
}

// The written ImageSet reads back through core (the same reader as real captures), its images
// equal the in-memory render, and the ground truth files round-trip.
TEST(SimulateTest, WritesImageSetAndGroundTruth) {
  testing::TempDir tmp;
  const Rig rig = testing::SmallDemoRig(8);
  const Scene scene = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
  const auto images = StripeImages(rig);
  const nlohmann::json spec = {{"codec", "test_stripes"}};
  for (ImageEncoding encoding : {ImageEncoding::kPgm, ImageEncoding::kPng}) {
    const auto dir = tmp / (encoding == ImageEncoding::kPgm ? "scan_pgm" : "scan_png");
    SimulateOptions options;
    options.writer.encoding = encoding;
    const SimulateSummary summary = SimulateScan(scene, rig, images, spec, dir, options);
    EXPECT_EQ(summary.cameras, 2);
    EXPECT_EQ(summary.patterns, 4);
    // One primary ray per pixel of each camera (no supersampling in the demo scene).
    EXPECT_EQ(summary.primary_rays,
              int64_t{2} * rig.cameras[0].model.width * rig.cameras[0].model.height);
    EXPECT_FALSE(summary.BriefReport().empty());

    const ImageSet set = ImageSet::Open(dir);
    EXPECT_EQ(set.PatternCount(), 4);
    EXPECT_EQ(set.patterns(), spec);
    EXPECT_EQ(set.extra()["provenance"]["scene"]["summary"]["name"], "demo");
    EXPECT_EQ(set.extra()["provenance"]["generator"], "slshadow simulate");
    EXPECT_EQ(set.extra()["provenance"]["simulate"], SimulateOptionsToJson(options));
    // The reference distance as rendered: the demo scene leaves it at 0, the rig's working
    // distance.
    ASSERT_EQ(scene.radiometry.reference_distance_mm, 0);
    EXPECT_EQ(set.extra()["radiometry_as_rendered"]["reference_distance_mm"],
              rig.working_distance_mm);
    for (const auto& r : set.records()) EXPECT_EQ(r.source, ImageSource::kVirtual);

    std::vector<GeometryBuffer> geometry;
    const auto rendered = RenderScan(scene, rig, images, &geometry);
    for (size_t c = 0; c < 2; ++c) {
      const std::string name = rig.cameras[c].name;
      for (int p = 0; p < 4; ++p) {
        EXPECT_EQ(cv::norm(set.Load(name, p), rendered[c][static_cast<size_t>(p)], cv::NORM_INF), 0)
            << name << " " << p;
      }
      const GroundTruth gt = ReadGroundTruth(dir / "ground_truth" / name);
      const GeometryBuffer& g = geometry[c];
      EXPECT_EQ(cv::norm(gt.visibility, g.visibility, cv::NORM_INF), 0);
      EXPECT_EQ(cv::norm(gt.object_id, g.object_id, cv::NORM_INF), 0);
      EXPECT_EQ(cv::norm(gt.projector.status, g.projector.status, cv::NORM_INF), 0);
      for (int y = 0; y < g.height; ++y) {
        for (int x = 0; x < g.width; ++x) {
          ASSERT_TRUE(SameFloat(gt.depth_mm.at<float>(y, x), g.depth_mm.at<float>(y, x)));
          ASSERT_TRUE(
              SameFloat(gt.projector.proj_x.at<float>(y, x), g.projector.proj_x.at<float>(y, x)));
          ASSERT_TRUE(SameFloat(gt.point_in_rig.at<cv::Vec3f>(y, x)[2],
                                g.point_in_rig.at<cv::Vec3f>(y, x)[2]));
        }
      }
      const PointCloud surface = ReadPly(dir / "ground_truth" / name / "surface.ply");
      EXPECT_EQ(static_cast<int>(surface.size()), cv::countNonZero(g.visibility));
      ASSERT_NE(surface.Scalar("proj_x"), nullptr);
    }
  }
}

// Re-rendering from a Simulator's cached geometry gives what a fresh scan gives, also for other
// pattern-pass settings (noise seed, gamma, exposure); geometry-changing settings are refused.
TEST(SimulateTest, SimulatorReusesGeometryAcrossScans) {
  const Rig rig = testing::SmallDemoRig(8);
  const Scene scene = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
  const auto images = StripeImages(rig);
  const Simulator sim(scene, rig);
  EXPECT_EQ(sim.num_cameras(), 2);
  EXPECT_EQ(sim.setup().primary_rays,
            int64_t{2} * rig.cameras[0].model.width * rig.cameras[0].model.height);
  Scene other = scene;
  other.layers.noise_enabled = true;
  other.layers.seed = 11;
  other.layers.response_enabled = true;
  other.layers.gamma = 1.8;
  other.radiometry.exposure_fraction = 0.6;
  for (const Scene* s : {&scene, static_cast<const Scene*>(&other)}) {
    const auto cached = sim.Render(images, s);
    const auto fresh = RenderScan(*s, rig, images);
    for (size_t c = 0; c < 2; ++c) {
      for (size_t p = 0; p < images.size(); ++p)
        EXPECT_EQ(cv::norm(cached[c][p], fresh[c][p], cv::NORM_INF), 0);
    }
  }
  Scene supersampled = scene;
  supersampled.layers.supersampling = 2;
  EXPECT_THROW(sim.Render(images, &supersampled), Error);
}

// One BVH shared by scans from several rig poses (the scanner moved around the part) gives the
// images and ground truth of a Simulator that builds its own BVH for each pose.
TEST(SimulateTest, SharedBvhEqualsOwnBvhForMovedRigs) {
  const Rig base = testing::SmallDemoRig(8);
  const Scene scene = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
  const auto images = StripeImages(base);
  const RayCaster caster(scene);
  for (double angle_deg : {0.0, 4.0, -7.0}) {
    // Rotate the whole rig about the vertical axis through the working point (0, 0, 500).
    const Eigen::Matrix3d r =
        Eigen::AngleAxisd(angle_deg * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix();
    const Eigen::Vector3d pivot(0, 0, base.working_distance_mm);
    const Rigid3d moved_from_rig(Eigen::Quaterniond(r), pivot - r * pivot);
    Rig rig = base;
    for (RigDevice& d : rig.cameras) d.cam_from_rig = d.cam_from_rig * moved_from_rig.Inverse();
    rig.projector->cam_from_rig = rig.projector->cam_from_rig * moved_from_rig.Inverse();
    const Simulator shared(caster, rig);
    const Simulator own(scene, rig);
    EXPECT_EQ(shared.setup().build_seconds, 0);
    EXPECT_EQ(shared.setup().primary_rays, own.setup().primary_rays);
    EXPECT_EQ(shared.setup().shadow_rays, own.setup().shadow_rays);
    const auto a = shared.Render(images);
    const auto b = own.Render(images);
    for (size_t c = 0; c < 2; ++c) {
      EXPECT_EQ(cv::norm(shared.geometry(static_cast<int>(c)).visibility,
                         own.geometry(static_cast<int>(c)).visibility, cv::NORM_INF),
                0);
      for (size_t p = 0; p < images.size(); ++p)
        EXPECT_EQ(cv::norm(a[c][p], b[c][p], cv::NORM_INF), 0) << angle_deg;
    }
    // The views differ between poses (the rig really moved).
    if (angle_deg != 0) {
      const Simulator still(caster, base);
      EXPECT_GT(cv::norm(still.geometry(0).visibility, shared.geometry(0).visibility, cv::NORM_L1),
                0);
    }
  }
}

// SimulateScan with a shared BVH writes the images of a scan that builds its own; a BVH of
// another Scene object is refused.
TEST(SimulateTest, SimulateScanWithSharedBvh) {
  testing::TempDir tmp;
  const Rig rig = testing::SmallDemoRig(8);
  const Scene scene = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
  const auto images = StripeImages(rig);
  const RayCaster caster(scene);
  SimulateOptions options;
  options.writer.encoding = ImageEncoding::kPgm;
  options.write_ground_truth = false;
  options.shared_bvh = &caster;
  const nlohmann::json spec = {{"codec", "test_stripes"}};
  const SimulateSummary summary = SimulateScan(scene, rig, images, spec, tmp / "scan", options);
  EXPECT_EQ(summary.build_seconds, 0);
  EXPECT_EQ(summary.triangles, caster.num_triangles());
  const ImageSet set = ImageSet::Open(tmp / "scan");
  const auto rendered = RenderScan(scene, rig, images);
  for (size_t c = 0; c < 2; ++c) {
    for (int p = 0; p < 4; ++p) {
      EXPECT_EQ(cv::norm(set.Load(rig.cameras[c].name, p), rendered[c][static_cast<size_t>(p)],
                         cv::NORM_INF),
                0);
    }
  }
  const Scene copy = scene;
  EXPECT_THROW(SimulateScan(copy, rig, images, spec, tmp / "other", options), Error);
  EXPECT_FALSE(std::filesystem::exists(tmp / "other"));
}

// Without ground truth the geometry pass fills only the per-sample buffers; the images are the
// same (1 and 2x2 samples per pixel; camera defocus needs depth, so the maps are made then).
TEST(SimulateTest, ImagesWithoutGroundTruthAreTheSame) {
  const Rig rig = testing::SmallDemoRig(8);
  const Scene base = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
  const auto images = StripeImages(rig);
  for (int variant = 0; variant < 3; ++variant) {
    Scene scene = base;
    if (variant == 1) scene.layers.supersampling = 2;
    if (variant == 2) {
      scene.layers.camera_defocus.enabled = true;
      scene.layers.camera_defocus.focus_distance_mm = 450;
    }
    const Simulator with(scene, rig);
    const Simulator without(scene, rig, TraceMode::kPacket16, /*ground_truth=*/false);
    EXPECT_EQ(
        without.setup().primary_rays,
        with.setup().primary_rays -
            (variant == 1 ? 2 * rig.cameras[0].model.width * rig.cameras[0].model.height : 0));
    EXPECT_EQ(without.geometry(0).depth_mm.empty(), variant != 2) << variant;
    EXPECT_EQ(without.geometry(1).projector.proj_x.empty(), variant != 2) << variant;
    EXPECT_FALSE(with.geometry(0).depth_mm.empty());
    const auto a = with.Render(images);
    const auto b = without.Render(images);
    for (size_t c = 0; c < 2; ++c) {
      for (size_t p = 0; p < images.size(); ++p)
        EXPECT_EQ(cv::norm(a[c][p], b[c][p], cv::NORM_INF), 0) << variant;
    }
  }
}

TEST(SimulateTest, RefusesToOverwriteAndChecksImages) {
  testing::TempDir tmp;
  const Rig rig = testing::SmallDemoRig(8);
  const Scene scene = LoadScene(testing::SourceDir() / "config/scenes/vdi2634_sphere.yaml");
  const auto images = StripeImages(rig);
  std::filesystem::create_directories(tmp / "exists");
  EXPECT_THROW(SimulateScan(scene, rig, images, {}, tmp / "exists"), Error);
  std::vector<cv::Mat> wrong = {cv::Mat(10, 10, CV_8UC1, cv::Scalar(0))};
  EXPECT_THROW(SimulateScan(scene, rig, wrong, {}, tmp / "new"), Error);
  EXPECT_FALSE(std::filesystem::exists(tmp / "new"));
  Rig no_projector = rig;
  no_projector.projector.reset();
  EXPECT_THROW(SimulateScan(scene, no_projector, images, {}, tmp / "new"), Error);
}

// Options as files: every field written is read back from JSON and YAML; unknown keys and bad
// values are refused naming the file and the field.
TEST(SimulateOptionsFile, RoundTripsEveryFieldAndRejectsUnknownKeys) {
  SimulateOptions o;
  o.writer.encoding = ImageEncoding::kTiff;
  o.writer.png_compression = 6;
  o.writer.overwrite = true;
  o.write_ground_truth = false;
  o.trace_mode = TraceMode::kSingleRay;
  const nlohmann::json j = SimulateOptionsToJson(o);
  for (const ConfigNode& node :
       {ConfigNode::FromJson(j, "s.json"), ConfigNode::ParseYaml(JsonToYaml(j), "s.yaml")}) {
    const SimulateOptions r = SimulateOptionsFromConfig(node);
    EXPECT_EQ(r.writer.encoding, ImageEncoding::kTiff);
    EXPECT_EQ(r.writer.png_compression, 6);
    EXPECT_TRUE(r.writer.overwrite);
    EXPECT_FALSE(r.write_ground_truth);
    EXPECT_EQ(r.trace_mode, TraceMode::kSingleRay);
    EXPECT_EQ(r.shared_bvh, nullptr);
    EXPECT_EQ(SimulateOptionsToJson(r), j);
  }
  EXPECT_EQ(SimulateOptionsToJson(SimulateOptionsFromConfig(
                ConfigNode::FromJson(nlohmann::json::object(), "s.json"))),
            SimulateOptionsToJson(SimulateOptions{}));
  nlohmann::json typo = j;
  typo["ground_truth"] = true;
  try {
    SimulateOptionsFromConfig(ConfigNode::FromJson(typo, "s.json"));
    FAIL() << "unknown key accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("ground_truth"), std::string::npos) << e.what();
  }
  for (const auto& [key, value] : std::vector<std::pair<std::string, nlohmann::json>>{
           {"encoding", "jpeg"}, {"trace_mode", "fast"}, {"png_compression", 12}}) {
    nlohmann::json bad = j;
    bad[key] = value;
    try {
      SimulateOptionsFromConfig(ConfigNode::FromJson(bad, "s.json"));
      FAIL() << key << " accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(key), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("s.json"), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace slshadow
