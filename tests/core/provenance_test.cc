#include "core/provenance.h"

#include <gtest/gtest.h>

#include "core/config.h"
#include "core/error.h"
#include "core/image_set.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

ScanProvenance Example() {
  ScanProvenance p;
  p.generator = "slshadow demo";
  p.scene_config = {{"name", "demo"}, {"objects", {{{"type", "plane"}, {"size_mm", {10, 20}}}}}};
  p.scene_base_dir = "/data/scenes";
  p.scene_summary = {{"name", "demo"}, {"layers", nlohmann::json::object()}};
  p.simulate = {{"encoding", "pgm"}, {"write_ground_truth", false}};
  p.reconstruct = {{"method", "midpoint"}, {"max_reprojection_error_px", "inf"}};
  p.compare = {{"threshold_mm", 0.25}};
  return p;  // decode stays null: the writer did not decode
}

TEST(ScanProvenance, RoundTripsThroughJsonAndYaml) {
  const ScanProvenance p = Example();
  const nlohmann::json j = p.ToJson();
  EXPECT_EQ(j["format"], "slshadow-provenance");
  EXPECT_EQ(j["version"], 1);
  EXPECT_TRUE(j["decode"].is_null());
  for (const ConfigNode& node :
       {ConfigNode::FromJson(j, "p.json"), ConfigNode::ParseYaml(JsonToYaml(j), "p.yaml")}) {
    const ScanProvenance r = ScanProvenanceFromConfig(node);
    EXPECT_EQ(r.generator, p.generator);
    EXPECT_EQ(r.scene_config, p.scene_config);
    EXPECT_EQ(r.scene_base_dir, p.scene_base_dir);
    EXPECT_EQ(r.scene_summary, p.scene_summary);
    EXPECT_EQ(r.simulate, p.simulate);
    EXPECT_TRUE(r.decode.is_null());
    EXPECT_EQ(r.reconstruct, p.reconstruct);
    EXPECT_EQ(r.compare, p.compare);
    EXPECT_EQ(r.ToJson(), j);
  }
}

TEST(ScanProvenance, RefusesUnknownKeysAndOtherFormatsOrVersions) {
  const nlohmann::json j = Example().ToJson();
  const auto message = [](const nlohmann::json& tree) -> std::string {
    try {
      ScanProvenanceFromConfig(ConfigNode::FromJson(tree, "manifest.json", "extra.provenance"));
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  };
  nlohmann::json bad = j;
  bad["simulator"] = nlohmann::json::object();
  EXPECT_NE(message(bad).find("simulator"), std::string::npos) << message(bad);
  bad = j;
  bad["scene"]["path"] = "x";
  EXPECT_NE(message(bad).find("path"), std::string::npos) << message(bad);
  bad = j;
  bad["version"] = 2;
  EXPECT_NE(message(bad).find("extra.provenance.version"), std::string::npos) << message(bad);
  bad = j;
  bad["format"] = "slshadow-scene";
  EXPECT_NE(message(bad).find("format"), std::string::npos) << message(bad);
  bad = j;
  bad["compare"] = 3;
  EXPECT_NE(message(bad).find("compare"), std::string::npos) << message(bad);
  bad = j;
  bad.erase("generator");
  EXPECT_NE(message(bad).find("generator"), std::string::npos) << message(bad);
}

TEST(ScanProvenance, IsReadFromAnImageSetsManifestOrAbsent) {
  testing::TempDir dir;
  Rig rig;
  rig.name = "one";
  rig.cameras.push_back({"cam", CameraModel(4, 3, 2, 2, 1.5, 1), Rigid3d()});
  for (const bool with : {true, false}) {
    const auto path = dir / (with ? "with" : "without");
    {
      ImageSetWriter writer(path, rig, nlohmann::json::object());
      writer.Add("cam", 0, cv::Mat(3, 4, CV_8UC1, cv::Scalar(7)), 100, ImageSource::kVirtual);
      writer.SetExtra(with ? ExtraWithProvenance(Example()) : nlohmann::json{{"scene", "test"}});
      writer.Commit();
    }
    const std::optional<ScanProvenance> read = ReadScanProvenance(ImageSet::Open(path));
    ASSERT_EQ(read.has_value(), with);
    if (with) {
      EXPECT_EQ(read->ToJson(), Example().ToJson());
    }
  }
}

}  // namespace
}  // namespace slshadow
