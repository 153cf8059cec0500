#include "core/provenance.h"

#include "core/config.h"
#include "core/error.h"
#include "core/image_set.h"

namespace slshadow {

nlohmann::json ScanProvenance::ToJson() const {
  return {{"format", "slshadow-provenance"},
          {"version", kVersion},
          {"generator", generator},
          {"scene",
           {{"config", scene_config}, {"base_dir", scene_base_dir}, {"summary", scene_summary}}},
          {"simulate", simulate},
          {"decode", decode},
          {"reconstruct", reconstruct},
          {"compare", compare}};
}

ScanProvenance ScanProvenanceFromConfig(const ConfigNode& node) {
  if (!node.IsObject()) node.Fail("expected a provenance mapping");
  node.RejectUnknownKeys(
      {"format", "version", "generator", "scene", "simulate", "decode", "reconstruct", "compare"});
  if (node["format"].AsString() != "slshadow-provenance")
    node["format"].Fail("expected slshadow-provenance");
  if (node["version"].AsInt() != ScanProvenance::kVersion) {
    node["version"].Fail("unsupported provenance version (this build reads 1)");
  }
  ScanProvenance p;
  p.generator = node["generator"].AsString();
  if (node.Has("scene") && !node["scene"].json().is_null()) {
    const ConfigNode scene = node["scene"];
    if (!scene.IsObject()) scene.Fail("expected a mapping {config, base_dir, summary}");
    scene.RejectUnknownKeys({"config", "base_dir", "summary"});
    if (scene.Has("config")) p.scene_config = scene["config"].json();
    p.scene_base_dir = scene.GetString("base_dir", "");
    if (scene.Has("summary")) p.scene_summary = scene["summary"].json();
  }
  const auto blob = [&node](const char* key) {
    if (!node.Has(key)) return nlohmann::json(nullptr);
    const ConfigNode n = node[key];
    if (!n.json().is_null() && !n.IsObject()) n.Fail("expected a mapping of options or null");
    return n.json();
  };
  p.simulate = blob("simulate");
  p.decode = blob("decode");
  p.reconstruct = blob("reconstruct");
  p.compare = blob("compare");
  return p;
}

std::optional<ScanProvenance> ReadScanProvenance(const ImageSet& image_set) {
  const nlohmann::json& extra = image_set.extra();
  if (!extra.is_object() || !extra.contains("provenance")) return std::nullopt;
  return ScanProvenanceFromConfig(ConfigNode::FromJson(
      extra, (image_set.dir() / "manifest.json").string(), "extra")["provenance"]);
}

nlohmann::json ExtraWithProvenance(const ScanProvenance& provenance) {
  return {{"provenance", provenance.ToJson()}};
}

}  // namespace slshadow
