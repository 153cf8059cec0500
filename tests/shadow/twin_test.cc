#include "shadow/twin.h"

#include <cstdio>
#include <fstream>

#include <gtest/gtest.h>

#include "core/file_util.h"
#include "core/image_set.h"
#include "tests/shadow/synthetic_scan.h"
#include "tests/testing/run_cli.h"
#include "tests/testing/temp_dir.h"

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
    for (size_t i = 0; i < frames.size(); ++i) writer.Add(camera, static_cast<int>(i), frames[i], 10000, ImageSource::kVirtual);
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
  WriteImageSet(tmp / "real", rig, spec, testing::Render(testing::RealScene(DemoPart(), truth), rig, spec));
  const shadow::ShadowPart part = testing::PartFromMesh(DemoPart(), "demo_part");
  shadow::ShadowOptions options;
  options.rig_from_part = Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.5 * M_PI / 180, Eigen::Vector3d::UnitX())) * truth.rotation,
                                  truth.translation + Eigen::Vector3d(1, 0, 0));
  const shadow::ShadowResult r = shadow::RunShadow(tmp / "real", part, options, tmp / "out");
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
  EXPECT_TRUE(std::filesystem::exists(tmp / "out" / "clouds" / "real_stereo.ply"));
}

}  // namespace
}  // namespace slshadow
