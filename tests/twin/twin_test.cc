#include "workflows/twin/twin.h"
#include "sim/scene_surface.h"

#include "workflows/pipeline/scan_pipeline.h"

#include <algorithm>
#include <cstdio>
#include <fstream>

#include <gtest/gtest.h>

#include "core/file_util.h"
#include "core/image_set.h"
#include "tests/testing/run_cli.h"
#include "tests/testing/temp_dir.h"
#include "tests/twin/synthetic_scan.h"

namespace slshadow {
namespace {

using testing::DemoPartPose;

const TriangleMesh& DemoPart() {
  static const TriangleMesh mesh = MakeDemoPart(1.0);
  return mesh;
}

void WriteImageSet(const std::filesystem::path& dir, const Rig& rig, const PatternSpec& spec,
                   const std::map<std::string, std::vector<cv::Mat>>& images) {
  ImageSetWriterOptions wo;
  wo.encoding = ImageEncoding::kPgm;
  ImageSetWriter writer(dir, rig, PatternSpecToJson(spec), wo);
  for (const auto& [camera, frames] : images) {
    for (size_t i = 0; i < frames.size(); ++i)
      writer.Add(camera, static_cast<int>(i), frames[i], 10000, ImageSource::kVirtual);
  }
  writer.Commit();
}

// End to end on a folder: a synthetic "real" scan with known physics, shadowed with the true part
// from a pose guess 1 mm / 0.5 deg off: the pose is recovered, the physics fitted to the truth,
// the images and clouds agree, and the report says "consistent with the model".
TEST(ShadowTwin, CleanSyntheticScanEndToEnd) {
  testing::TempDir tmp;
  const Rig rig = testing::HalfDemoRig();
  const PatternSpec spec = testing::DemoSpec();
  const Rigid3d truth = DemoPartPose();
  WriteImageSet(tmp / "real", rig, spec,
                testing::Render(testing::RealScene(DemoPart(), truth), rig, spec));
  const twin::ShadowPart part = testing::PartFromMesh(DemoPart(), "demo_part");
  twin::ShadowOptions options;
  options.rig_from_part =
      Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.5 * M_PI / 180, Eigen::Vector3d::UnitX())) *
                  truth.rotation,
              truth.translation + Eigen::Vector3d(1, 0, 0));
  const twin::ShadowResult r = twin::RunShadow(tmp / "real", part, options, tmp / "out");
  std::printf("%s\n", r.Summary().c_str());
  EXPECT_LT((r.rig_from_part.translation - truth.translation).norm(), 0.1);
  EXPECT_LT(compare::RotationDifferenceDeg(r.rig_from_part, truth), 0.02);
  // Physics: exposure x albedo 0.8 x 0.7 / 0.8 (the part file's albedo) = 0.7.
  ASSERT_NE(r.physics.Find("exposure"), nullptr);
  EXPECT_NEAR(r.physics.Find("exposure")->value, 0.7, 0.01);
  EXPECT_TRUE(r.physics.Kept("ambient"));
  EXPECT_NEAR(r.physics.Find("ambient")->value, 0.03, 0.005);
  EXPECT_TRUE(r.physics.Kept("noise"));
  EXPECT_NEAR(r.physics.Find("noise")->value, 10000, 2000);
  EXPECT_FALSE(r.physics.Kept("gamma"));
  EXPECT_FALSE(r.physics.Kept("defocus"));
  EXPECT_EQ(r.diagnosis.verdict, "consistent with the model") << r.diagnosis.Summary();
  // The report folder.
  std::ifstream in(tmp / "out" / "report.json");
  ASSERT_TRUE(in.good());
  const nlohmann::json report = nlohmann::json::parse(in);
  EXPECT_EQ(report["format"], "slshadow-shadow-report");
  const auto& cam = report["images"]["cameras"][0];
  EXPECT_GT(cam["within_5pct_all_frames"].get<double>(), 0.95);
  EXPECT_LT(cam["projector_coordinates"]["real_vs_truth_rms_px"].get<double>(), 0.2);
  for (const auto& m : report["clouds"]["modes"]) {
    EXPECT_LT(std::abs(m["real_vs_part"]["mean_mm"].get<double>()), 0.02) << m["mode"];
    EXPECT_LT(m["real_vs_twin"]["rms_mm"].get<double>(), 0.1) << m["mode"];
  }
  EXPECT_TRUE(std::filesystem::exists(tmp / "out" / "summary.txt"));
  EXPECT_TRUE(std::filesystem::exists(tmp / "out" / "maps" / "left_projector_residual.png"));
  EXPECT_TRUE(std::filesystem::exists(tmp / "out" / "charts" / "intensity_per_frame.png"));
  EXPECT_TRUE(std::filesystem::exists(tmp / "out" / "charts" / "real_vs_twin_stereo.png"));
  // Map colour ranges scale to the data: the clean scan's decoded residual is a fraction of a
  // projector pixel (p99 of |residual|), not a fixed +-2 px.
  const double range = report["maps"][0]["projector_residual_range_px"].get<double>();
  EXPECT_GT(range, 0.05);
  EXPECT_LT(range, 0.6);
  EXPECT_TRUE(std::filesystem::exists(tmp / "out" / "clouds" / "real_stereo.ply"));
}

}  // namespace
}  // namespace slshadow

namespace slshadow {
namespace {

// The demo part with a 50 um bump (raised cosine, radius 8 mm) on a flat top face, away from
// walls; `centre` receives its centre in the part frame.
TriangleMesh BumpedPart(Eigen::Vector3d* centre) {
  TriangleMesh mesh = DemoPart();
  const double radius = 8, height = 0.05;
  double best_count = 0;
  Eigen::Vector3d best = Eigen::Vector3d::Zero();
  for (double cx = -70; cx <= 70; cx += 5) {
    for (double cy = -40; cy <= 40; cy += 5) {
      double z_top = -1e9, count = 0;
      bool flat = true;
      for (const auto& v : mesh.vertices) {
        const double r = std::hypot(v.x() - cx, v.y() - cy);
        if (r < 14) z_top = std::max(z_top, v.z());
      }
      for (const auto& v : mesh.vertices) {
        const double r = std::hypot(v.x() - cx, v.y() - cy);
        if (r < 14 && v.z() > z_top - 20 && std::abs(v.z() - z_top) > 1e-9) flat = false;
        if (r < radius && std::abs(v.z() - z_top) < 1e-9) ++count;
      }
      if (flat && count > best_count) best_count = count, best = Eigen::Vector3d(cx, cy, z_top);
    }
  }
  EXPECT_GT(best_count, 50);
  for (auto& v : mesh.vertices) {
    const double r = std::hypot(v.x() - best.x(), v.y() - best.y());
    if (r < radius && std::abs(v.z() - best.z()) < 1e-9)
      v.z() += height * 0.5 * (1 + std::cos(M_PI * r / radius));
  }
  *centre = best;
  return mesh;
}

struct Case {
  std::string name;
  std::vector<std::string> expected;
};

// The confusion table: synthetic "real" scans with one deliberately different physics each; every
// report must name its own cause and no other, and the clean scan none.
TEST(ShadowTwin, ConfusionTableNamesEachCauseAndNoOther) {
  const Rig rig = testing::HalfDemoRig();
  const PatternSpec spec = testing::DemoSpec();
  const Rigid3d truth = DemoPartPose();
  const twin::ShadowPart part = testing::PartFromMesh(DemoPart(), "demo_part");
  const std::vector<Case> cases = {{"clean", {}},
                                   {"gamma 2.2", {"projector_response"}},
                                   {"projector bumped 0.1 deg", {"calibration"}},
                                   {"part shifted 0.2 mm + 50 um bump", {"part"}},
                                   {"two frames swapped", {"wrong_frame"}},
                                   {"projector defocus", {"defocus"}}};
  std::string table = "case                               causes named         evidence\n";
  for (const Case& c : cases) {
    Scene scene = testing::RealScene(DemoPart(), truth);
    Rig real_rig = rig;
    Eigen::Vector3d bump_centre = Eigen::Vector3d::Zero();
    if (c.name == "gamma 2.2") {
      scene.layers.response_enabled = true;
      scene.layers.gamma = 2.2;
    } else if (c.name == "projector bumped 0.1 deg") {
      const Eigen::Quaterniond bump(Eigen::AngleAxisd(0.1 * M_PI / 180, Eigen::Vector3d::UnitY()));
      real_rig.projector->cam_from_rig =
          Rigid3d(bump, Eigen::Vector3d::Zero()) * real_rig.projector->cam_from_rig;
    } else if (c.name == "part shifted 0.2 mm + 50 um bump") {
      auto mesh = std::make_shared<TriangleMesh>(BumpedPart(&bump_centre));
      scene.objects[0].mesh = mesh;
      scene.objects[0].rig_from_object.translation += truth.rotation * Eigen::Vector3d(0.2, 0, 0);
    } else if (c.name == "projector defocus") {
      auto& d = scene.layers.projector_defocus;
      d.enabled = true;
      d.focus_distance_mm = 400;
      d.f_number = 1;
      const double sigma1 = d.SigmaPx(rig.projector->model.fx(), 545);
      d.f_number = sigma1 / 2.0;  // sigma 2 projector px at 545 mm
    }
    auto images = testing::Render(scene, real_rig, spec);
    if (c.name == "two frames swapped") {
      // The x phase frames of steps 1 and 2 swapped (a late frame), in both cameras.
      const auto frames = spec.Frames();
      int a = -1, b = -1;
      for (size_t i = 0; i < frames.size(); ++i) {
        if (frames[i].role == FrameRole::kPhase && frames[i].axis == 0 && frames[i].step == 1)
          a = static_cast<int>(i);
        if (frames[i].role == FrameRole::kPhase && frames[i].axis == 0 && frames[i].step == 2)
          b = static_cast<int>(i);
      }
      ASSERT_GE(a, 0);
      ASSERT_GE(b, 0);
      for (auto& [camera, frames_of_camera] : images)
        std::swap(frames_of_camera[static_cast<size_t>(a)],
                  frames_of_camera[static_cast<size_t>(b)]);
    }
    twin::ShadowOptions options;
    options.rig_from_part = truth;
    const twin::ShadowResult r = twin::RunShadowOnImages(rig, spec, images, part, options);
    std::string named;
    for (const auto& cause : r.diagnosis.causes) named += (named.empty() ? "" : ", ") + cause;
    // The evidence behind each signature, for the table in docs/benchmarks.md.
    double field = 0;
    int wrong_frames = 0;
    int64_t cluster = 0;
    double pose_share = 0;
    for (const auto& f : r.report["diagnosis"]["findings"]) {
      if (f["cause"] == "pose" && f["evaluated"].get<bool>())
        pose_share = f["evidence"]["worst_share"].get<double>();
      if (f["cause"] == "calibration" && f["evaluated"].get<bool>()) {
        for (const auto& cam : f["evidence"]["cameras"])
          field = std::max(field, cam["field_rms_px"].get<double>());
      }
      if (f["cause"] == "wrong_frame")
        wrong_frames = static_cast<int>(f["evidence"]["frames"].size());
      if (f["cause"] == "part" && f["evaluated"].get<bool>()) {
        for (const auto& m : f["evidence"]["modes"])
          cluster = std::max<int64_t>(cluster, m.value("clustered_points", int64_t{0}));
      }
    }
    char line[512];
    std::snprintf(line, sizeof(line),
                  "%-34s %-20s field %.3f px, wrong frames %d, gamma %.2f, blur %.2f px, part "
                  "cluster %lld pts, pose share %.4f\n",
                  c.name.c_str(), named.empty() ? "-" : named.c_str(), field, wrong_frames,
                  r.physics.Find("gamma")->value, r.physics.Find("defocus")->value,
                  static_cast<long long>(cluster), pose_share);
    table += line;
    EXPECT_EQ(r.diagnosis.causes, c.expected) << c.name << "\n"
                                              << r.diagnosis.Summary() << r.physics.Table();
    if (c.expected.empty()) {
      EXPECT_EQ(r.diagnosis.verdict, "consistent with the model");
    }
    if (c.name == "part shifted 0.2 mm + 50 um bump") {
      // The pose follows the shifted part; the deviation sits at the bump.
      EXPECT_NEAR((r.rig_from_part.translation - truth.translation).norm(), 0.2, 0.08);
      const auto& modes = r.report["diagnosis"]["findings"].back()["evidence"]["modes"];
      for (const auto& m : modes) {
        const Eigen::Vector3d at(m["centroid_in_rig_mm"][0].get<double>(),
                                 m["centroid_in_rig_mm"][1].get<double>(),
                                 m["centroid_in_rig_mm"][2].get<double>());
        EXPECT_LT((at - truth * bump_centre).norm(), 6.0) << m.dump();
        EXPECT_GT(m["mean_deviation_mm"].get<double>(), 0.01) << m.dump();
      }
    }
    if (c.name == "gamma 2.2") {
      EXPECT_NEAR(r.physics.Find("gamma")->value, 2.2, 0.1);
    }
    if (c.name == "projector defocus") {
      // Focused at 400 mm: sigma 2.0 px at 545 mm (the base), 1.5 px at 500 mm (the top faces).
      EXPECT_NEAR(r.physics.Find("defocus")->value, 1.75, 0.3);
    }
  }
  std::printf("%s", table.c_str());
}

}  // namespace
}  // namespace slshadow

namespace slshadow {
namespace {

// The command line: bad input gives one clear error, a non-zero exit and no report folder.
TEST(ShadowTwin, CommandLineRejectsBadInput) {
  testing::TempDir tmp;
  const Rig rig = testing::HalfDemoRig();
  const PatternSpec spec = testing::DemoSpec();
  WriteImageSet(tmp / "real", rig, spec,
                testing::Render(testing::RealScene(DemoPart(), DemoPartPose()), rig, spec));
  std::ofstream(tmp / "part.txt") << "not a mesh\n";
  EXPECT_NE(testing::RunCli({"shadow", (tmp / "real").string(), "--part",
                             (tmp / "part.txt").string(), "--out", (tmp / "out1").string()}),
            0);
  EXPECT_FALSE(std::filesystem::exists(tmp / "out1"));
  // A sphere is not the scanned part: global registration cannot place it credibly.
  WriteMesh(tmp / "sphere.ply", MakeSphereMesh(20, 48));
  EXPECT_NE(testing::RunCli({"shadow", (tmp / "real").string(), "--part",
                             (tmp / "sphere.ply").string(), "--out", (tmp / "out2").string()}),
            0);
  EXPECT_FALSE(std::filesystem::exists(tmp / "out2"));
  // --fixed-pose without --pose.
  WriteMesh(tmp / "part.ply", DemoPart());
  EXPECT_NE(
      testing::RunCli({"shadow", (tmp / "real").string(), "--part", (tmp / "part.ply").string(),
                       "--fixed-pose", "--out", (tmp / "out3").string()}),
      0);
  EXPECT_FALSE(std::filesystem::exists(tmp / "out3"));
  // --strict with a share of points no scan reaches: refused after the real scan, nothing written.
  ::testing::internal::CaptureStderr();
  const int strict_code =
      testing::RunCli({"shadow", (tmp / "real").string(), "--part", (tmp / "part.ply").string(),
                       "--out", (tmp / "out5").string(), "--strict", "--strict-min-points", "1"});
  const std::string strict_err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(strict_code, 0);
  EXPECT_NE(strict_err.find("shadow: the real scan: --strict:"), std::string::npos) << strict_err;
  EXPECT_FALSE(std::filesystem::exists(tmp / "out5"));
  // And the good case through the command line, strict (the clean scan's checks pass): --pose as
  // a rotation vector and a translation.
  const Eigen::AngleAxisd aa(DemoPartPose().rotation);
  const Eigen::Vector3d r = aa.angle() * aa.axis(), t = DemoPartPose().translation;
  std::vector<std::string> args = {
      "shadow", (tmp / "real").string(), "--part",      (tmp / "part.ply").string(),
      "--out",  (tmp / "out4").string(), "--no-clouds", "--strict",
      "--pose"};
  for (double v : {r.x(), r.y(), r.z(), t.x(), t.y(), t.z()}) args.push_back(std::to_string(v));
  ASSERT_EQ(testing::RunCli(args), 0);
  std::ifstream in(tmp / "out4" / "report.json");
  ASSERT_TRUE(in.good());
  const nlohmann::json report = nlohmann::json::parse(in);
  EXPECT_EQ(report["pose"]["source"], "given+icp");
  EXPECT_EQ(report["diagnosis"]["verdict"], "consistent with the model");
  EXPECT_FALSE(std::filesystem::exists(tmp / "out4" / "clouds"));
  // An existing folder is not replaced without --overwrite.
  EXPECT_NE(testing::RunCli(args), 0);
}

}  // namespace
}  // namespace slshadow

namespace slshadow {
namespace {

// Exposure x albedo per object: a part on a table whose file albedos (0.8 both) are not the real
// ones (0.7 and 0.4). Only the products exposure x albedo are observable: the fit recovers both
// (0.8 x 0.7 and 0.8 x 0.4), the reference object's through the exposure, the other's through
// its own albedo layer.
TEST(ShadowTwin, ExposureTimesAlbedoPerObject) {
  const Rig rig = testing::HalfDemoRig();
  const PatternSpec spec = testing::DemoSpec();
  const Rigid3d truth = DemoPartPose();
  Scene real = testing::RealScene(DemoPart(), truth);
  SceneObject table;
  table.name = "table";
  table.type = ObjectType::kPlane;
  table.size_mm = Eigen::Vector3d(400, 300, 0);
  table.albedo.value = 0.4;
  table.rig_from_object =
      Rigid3d(truth.rotation, truth.translation + truth.rotation * Eigen::Vector3d(0, 0, -0.05));
  real.objects.push_back(table);
  twin::ShadowPart part = testing::PartFromMesh(DemoPart(), "demo_part");
  SceneObject table_in_part = table;
  table_in_part.albedo.value = 0.8;
  table_in_part.rig_from_object =
      Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 0, -0.05));
  part.scene.objects.push_back(table_in_part);
  part.surface = SceneSurface(part.scene, "part + table", twin::kPartPlaneCells);
  twin::ShadowOptions options;
  options.rig_from_part = truth;
  const twin::ShadowResult r =
      twin::RunShadowOnImages(rig, spec, testing::Render(real, rig, spec), part, options);
  std::printf("%s", r.physics.Table().c_str());
  const double e = r.physics.Find("exposure")->value;
  const twin::PhysicsLayer* part_albedo = r.physics.Find("albedo_demo_part");
  const twin::PhysicsLayer* table_albedo = r.physics.Find("albedo_table");
  ASSERT_TRUE(part_albedo || table_albedo);
  if (table_albedo) {  // the part is the reference object
    EXPECT_NEAR(e * 0.8, 0.8 * 0.7, 0.01);
    EXPECT_TRUE(table_albedo->kept);
    EXPECT_NEAR(e * table_albedo->value, 0.8 * 0.4, 0.01);
  } else {  // the table is
    EXPECT_NEAR(e * 0.8, 0.8 * 0.4, 0.01);
    EXPECT_TRUE(part_albedo->kept);
    EXPECT_NEAR(e * part_albedo->value, 0.8 * 0.7, 0.01);
  }
  EXPECT_EQ(r.diagnosis.verdict, "consistent with the model") << r.diagnosis.Summary();
}

}  // namespace
}  // namespace slshadow

namespace slshadow {
namespace {

// A checkerboard plane facing the half demo rig: two reflectances in view, so a black-level offset
// and ambient light can be told apart. `part_frame`: in its own frame (the shadow's part), else at
// its pose in the rig.
Rigid3d BoardPose() {
  return Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.15, Eigen::Vector3d::UnitY())),
                 Eigen::Vector3d(100, 0, 520));
}

Scene BoardScene(bool part_frame) {
  Scene s;
  s.name = "board";
  s.radiometry.exposure_fraction = 0.6;
  SceneObject o;
  o.name = "board";
  o.type = ObjectType::kPlane;
  o.size_mm = Eigen::Vector3d(300, 220, 0);
  o.albedo.kind = Albedo::Kind::kCheckerboard;
  o.albedo.square_mm = 20;
  o.albedo.squares_x = 15;
  o.albedo.squares_y = 11;
  o.albedo.dark = 0.1;
  o.albedo.light = 0.8;
  o.albedo_offset_mm = Eigen::Vector2d(140, 100);
  if (!part_frame) o.rig_from_object = BoardPose();
  s.objects.push_back(o);
  return s;
}

// What the camera adds beyond the renderer, written out here as the oracle: a share `global` of
// the light scattered from the whole lit projector image, an illumination field
// G = 1 + cu u + cv v + cuu u^2 (u, v in [-1, 1] over the image), a black-level offset.
struct CameraPhysics {
  double offset_dn = 0, global = 0, cu = 0, cv = 0, cuu = 0;
  double Field(int x, int y, int w, int h) const {
    const double u = (x - 0.5 * w) / (0.5 * w), v = (y - 0.5 * h) / (0.5 * h);
    return 1 + cu * u + cv * v + cuu * u * u;
  }
};

void AddCameraPhysics(const PatternSpec& spec, const CameraPhysics& truth,
                      std::vector<cv::Mat>* images) {
  const std::vector<cv::Mat> projector = GeneratePatterns(spec);
  const cv::Mat white = (*images)[static_cast<size_t>(spec.WhiteFrameIndex())].clone();
  const cv::Mat black = (*images)[static_cast<size_t>(spec.BlackFrameIndex())].clone();
  for (size_t k = 0; k < images->size(); ++k) {
    const double m = cv::mean(projector[k])[0] / 255;
    cv::Mat& img = (*images)[k];
    for (int y = 0; y < img.rows; ++y) {
      for (int x = 0; x < img.cols; ++x) {
        const double b = black.at<uint8_t>(y, x), w = white.at<uint8_t>(y, x),
                     i = img.at<uint8_t>(y, x);
        const double scattered = b + (1 - truth.global) * (i - b) + truth.global * m * (w - b);
        img.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(
            truth.offset_dn + truth.Field(x, y, img.cols, img.rows) * scattered);
      }
    }
  }
}

twin::ShadowResult ShadowBoard(const CameraPhysics& truth) {
  const Rig rig = testing::HalfDemoRig();
  PatternSpec spec;
  spec.kind = PatternKind::kGrayCode;
  spec.projector_width = 1280;
  spec.projector_height = 800;
  spec.code_y = false;
  spec.Check();
  Scene real = BoardScene(false);
  real.layers.ambient = 0.01;
  real.layers.noise_enabled = true;
  real.layers.full_well_e = 10000;
  real.layers.read_noise_e = 6;
  real.layers.seed = 99;
  std::map<std::string, std::vector<cv::Mat>> images = testing::Render(real, rig, spec);
  for (auto& [camera, frames] : images) AddCameraPhysics(spec, truth, &frames);
  twin::ShadowPart part;
  part.source = "board";
  part.scene = BoardScene(true);
  part.surface = SceneSurface(part.scene, part.source, twin::kPartPlaneCells);
  twin::ShadowOptions options;
  options.rig_from_part = BoardPose();
  options.refine_pose = false;
  options.write_clouds = false;
  twin::ShadowResult r = twin::RunShadowOnImages(rig, spec, images, part, options);
  std::printf("%s\n", r.physics.Table().c_str());
  return r;
}

// Oracle: a black level of 6 DN, an illumination field of +-8 % and 8 % scattered light added to
// a rendered scan are recovered within their uncertainty, kept, and put into the twin; on the
// clean scan the same layers are left off.
TEST(ShadowTwin, BlackLevelIlluminationAndGlobalLightRecovered) {
  CameraPhysics truth;
  truth.offset_dn = 6;
  truth.global = 0.08;
  truth.cu = 0.06;
  truth.cv = -0.04;
  truth.cuu = 0.05;
  const twin::ShadowResult r = ShadowBoard(truth);
  for (const std::string camera : {"left", "right"}) {
    const twin::PhysicsLayer* bl = r.physics.Find("black_level_" + camera);
    ASSERT_NE(bl, nullptr);
    EXPECT_TRUE(bl->kept) << bl->reason;
    // Within max(3 sigma, the keep floor 0.002 FS = 0.5 DN): the jackknife sigma does not see the
    // bias of a mean of integers when the black frame's noise is below 1 DN (0.14 DN here).
    EXPECT_NEAR(bl->value, truth.offset_dn, std::max(3 * bl->sigma, 0.002 * 255)) << camera;
    const twin::PhysicsLayer* il = r.physics.Find("illumination_" + camera);
    ASSERT_NE(il, nullptr);
    EXPECT_TRUE(il->kept) << il->reason;
    // The fitted field times the exposure is the true one times the true exposure, at every lit
    // pixel (the fit leaves the split between E and the field's mean free).
    const Rig rig = testing::HalfDemoRig();
    const auto& model = rig.cameras[static_cast<size_t>(rig.CameraIndex(camera))].model;
    const cv::Mat g = twin::IlluminationField(r.physics, camera, model.width, model.height);
    const double e = r.physics.Find("exposure")->value;
    double worst = 0;
    for (int y = 0; y < model.height; y += 10) {
      for (int x = 0; x < model.width; x += 10)
        worst = std::max(worst, std::abs(e * g.at<float>(y, x) / 0.6 -
                                         truth.Field(x, y, model.width, model.height)));
    }
    EXPECT_LT(worst, 0.02) << camera;  // over the whole image, extrapolated beyond the board too
  }
  ASSERT_NE(r.physics.Find("global_light"), nullptr);
  EXPECT_TRUE(r.physics.Kept("global_light"));
  EXPECT_NEAR(r.physics.Find("global_light")->value, truth.global,
              3 * r.physics.Find("global_light")->sigma + 0.01);
  for (const auto& cam : r.report["images"]["cameras"])
    EXPECT_GT(cam["within_5pct_all_frames"].get<double>(), 0.99) << cam["camera"];

  const twin::ShadowResult clean = ShadowBoard(CameraPhysics{});
  for (const std::string camera : {"left", "right"}) {
    const twin::PhysicsLayer* bl = clean.physics.Find("black_level_" + camera);
    ASSERT_NE(bl, nullptr);
    EXPECT_TRUE(bl->observable) << bl->reason;
    EXPECT_FALSE(bl->kept) << bl->reason;
    EXPECT_FALSE(clean.physics.Kept("illumination_" + camera))
        << clean.physics.Find("illumination_" + camera)->reason;
  }
  EXPECT_FALSE(clean.physics.Kept("global_light")) << clean.physics.Find("global_light")->reason;
  EXPECT_TRUE(clean.physics.Kept("ambient")) << clean.physics.Find("ambient")->reason;
  EXPECT_NEAR(clean.physics.Find("ambient")->value, 0.01, 0.003);
}

}  // namespace
}  // namespace slshadow

namespace slshadow {
namespace {

// Oracle: the real projector's focal length 4 px longer than the rig file says: the calibration
// finding names the focal-length equivalent of the smooth projector-coordinate field, about 4 px.
TEST(ShadowTwin, CalibrationFieldNamesItsFocalLengthEquivalent) {
  const Rig rig = testing::HalfDemoRig();
  Rig real_rig = rig;
  real_rig.projector->model.params[CameraModel::kFx] += 4;
  real_rig.projector->model.params[CameraModel::kFy] += 4;
  const PatternSpec spec = testing::DemoSpec();
  const Rigid3d truth = DemoPartPose();
  const auto images = testing::Render(testing::RealScene(DemoPart(), truth), real_rig, spec);
  twin::ShadowOptions options;
  options.rig_from_part = truth;
  options.write_clouds = false;
  const twin::ShadowResult r = twin::RunShadowOnImages(
      rig, spec, images, testing::PartFromMesh(DemoPart(), "demo_part"), options);
  std::printf("%s\n", r.diagnosis.Summary().c_str());
  const twin::Finding* cal = nullptr;
  for (const auto& f : r.diagnosis.findings) {
    if (f.cause == "calibration") cal = &f;
  }
  ASSERT_NE(cal, nullptr);
  EXPECT_TRUE(cal->detected) << cal->message;
  EXPECT_NE(cal->message.find("focal length off by"), std::string::npos) << cal->message;
  for (const auto& cam : cal->evidence["cameras"]) {
    ASSERT_TRUE(cam.contains("equivalent_projector_focal_error_x_px")) << cam.dump();
    EXPECT_NEAR(cam["equivalent_projector_focal_error_x_px"].get<double>(), 4.0, 1.0)
        << cam["camera"];
  }
}

}  // namespace
}  // namespace slshadow
