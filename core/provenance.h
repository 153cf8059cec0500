// Scan provenance: how an ImageSet was made, in its manifest's `extra.provenance`
// (docs/formats.md, "Scan provenance"), so that a scan can be made again with the same settings
// from its folder alone. One schema for every writer (the simulator, the demo job, later captures
// and sweeps); each module serialises its own options into it (sim/ SimulateOptionsToJson,
// patterns/ DecodeOptionsToJson, reconstruct/ ReconstructOptions::ToJson, compare/
// CompareOptionsToJson), and this header only holds them together and checks the frame:
//
//   extra:
//     provenance:
//       format: slshadow-provenance
//       version: 1
//       generator: "slshadow simulate"      # who wrote the scan
//       scene:                              # virtual scans: how to rebuild the scene
//         config: {...}                     # the scene file's tree as read, or null (built in
//         code) base_dir: /abs/folder             # relative paths in `config` resolve against it
//         summary: {...}                    # sim/ SceneToJson of the scene rendered
//       simulate: {...}                     # sim/ SimulateOptionsToJson, null for real captures
//       decode: {...}                       # the settings the writing job used downstream,
//       reconstruct: {...}                  #   each null when it did not run that stage
//       compare: {...}
#pragma once

#include <optional>
#include <string>

#include <nlohmann/json.hpp>

namespace slshadow {

class ConfigNode;
class ImageSet;

struct ScanProvenance {
  static constexpr int kVersion = 1;
  std::string generator;  // who wrote the scan, e.g. "slshadow simulate", "slshadow demo"
  // Virtual scans: the scene as configured (null when built in code), the folder its relative
  // paths resolve against (absolute), and the summary of the scene rendered, which a redo checks
  // its rebuilt scene against (null for real captures).
  nlohmann::json scene_config;
  std::string scene_base_dir;
  nlohmann::json scene_summary;
  nlohmann::json simulate;  // simulator options, null for real captures
  nlohmann::json decode;    // downstream settings of the writing job, null when not run
  nlohmann::json reconstruct;
  nlohmann::json compare;

  // {"format": "slshadow-provenance", "version": 1, ...}: every field, nulls included.
  nlohmann::json ToJson() const;
};

// Reads the mapping ToJson writes. format and version are required and checked; unknown keys are
// rejected; the option blobs are kept as they are (each module's FromConfig reads its own).
// Throws slshadow::Error naming the file, the field and the value.
ScanProvenance ScanProvenanceFromConfig(const ConfigNode& node);

// The provenance of an ImageSet (its manifest's extra.provenance), or nullopt when it has none
// (ImageSets written before version 1 of this schema, or by other tools). Throws like
// ScanProvenanceFromConfig on a malformed one.
std::optional<ScanProvenance> ReadScanProvenance(const ImageSet& image_set);

// The manifest's `extra` carrying `provenance` (other keys of `extra` are free-form).
nlohmann::json ExtraWithProvenance(const ScanProvenance& provenance);

}  // namespace slshadow
