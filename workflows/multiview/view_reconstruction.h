// One view of a multi-view project reconstructed as the merge uses it, and kept on disk, so that
// the views of a large project reconstruct as independent jobs (one process, GNU parallel, a Slurm
// job array: `slshadow merge PROJECT --reconstructions DIR --reconstruct-only --shard I/N`) and a
// merge reads them instead of reconstructing (`slshadow merge PROJECT --reconstructions DIR`),
// and a second merge with other registration, fusion or comparison options does not decode again.
//
// The folder DIR/<view>/ (docs/formats.md "View reconstructions"), written atomically per view:
//   cloud.ply            the view's cloud in the rig frame, every accepted point the merge keeps
//                        (max_points_per_view), before the table crop: binary PLY with double
//                        positions, so it reads back bit for bit;
//   dark_<camera>.png    8-bit, 255 where the decoder found the camera's pixel too dark to decode
//                        (shadow or low contrast), 0 elsewhere (cad_compare.h DarkPixels);
//   reconstruction.json  {"format": "slshadow-view-reconstruction", "version": 1, "view",
//                        "manifest_fnv1a64": the view's ImageSet manifest.json, hashed (FNV-1a,
//                        64 bit, hex), "options": {"mode", "max_points_per_view", "decode",
//                        "reconstruct"}, "accepted_points", "points", "reconstruct_s", "cameras"}.
// A reconstruction is used only for the same view's same manifest and the same options; any other
// is refused with the file, the field and both values (never silently used, never silently
// replaced).
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/point_cloud.h"
#include "patterns/codec.h"
#include "reconstruct/reconstruct.h"
#include "workflows/multiview/cad_compare.h"

namespace slshadow {
class ImageSet;
}

namespace slshadow::multiview {

// What a view's reconstruction depends on besides its images.
struct ViewReconstructOptions {
  ReconstructMode mode = ReconstructMode::kStereo;
  DecodeOptions decode;
  ReconstructOptions reconstruct;
  size_t max_points_per_view = 400000;  // 0: every accepted point
  nlohmann::json ToJson() const;
};

struct ViewReconstruction {
  PointCloud cloud;  // rig frame, before any table crop
  int64_t accepted_points = 0;
  std::vector<DarkPixels> dark;  // per camera of the mode
  double seconds = 0;            // wall time of decode and reconstruction
};

// Decodes and reconstructs one view's ImageSet (its images alone). Throws slshadow::Error naming
// the folder when the mode needs cameras the rig lacks.
ViewReconstruction ReconstructProjectView(const ImageSet& image_set,
                                          const ViewReconstructOptions& options);

// The key a stored reconstruction must match: the view's name, its manifest's hash, the options.
struct ViewReconstructionKey {
  std::string view;
  std::string manifest_fnv1a64;
  nlohmann::json options;
  // For the view folder `image_set_dir` (its manifest.json is read and hashed).
  static ViewReconstructionKey For(const std::string& view,
                                   const std::filesystem::path& image_set_dir,
                                   const ViewReconstructOptions& options);
};

// DIR/<view>/, written into a staging folder and renamed (an existing folder is replaced).
void WriteViewReconstruction(const std::filesystem::path& dir, const ViewReconstructionKey& key,
                             const ViewReconstruction& reconstruction);
// The stored reconstruction of key.view under `dir`; nullopt when DIR/<view>/reconstruction.json
// does not exist. Throws slshadow::Error naming the file, the field and both values when it was
// made from other images or with other options, and when a file is unreadable or inconsistent.
std::optional<ViewReconstruction> ReadViewReconstruction(const std::filesystem::path& dir,
                                                         const ViewReconstructionKey& key);

// 64-bit FNV-1a of `bytes` as 16 hex digits.
std::string Fnv1a64Hex(const std::string& bytes);

}  // namespace slshadow::multiview
