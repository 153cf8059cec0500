// The files of `slshadow reconstruct` (docs/formats.md, "Reconstruction outputs"), written from an
// ImageSetReconstruction as compare::WriteReport writes a comparison: the cloud (PLY), its JSON
// summary and one calibration-check residual map (PNG) per reconstruction, each atomically
// (temporary name, then rename).
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "core/rig.h"
#include "reconstruct/reconstruct_image_set.h"

namespace slshadow {

struct ReconstructionOutputOptions {
  std::filesystem::path cloud_path;    // CLOUD.ply
  std::filesystem::path summary_path;  // empty: CLOUD's folder / <CLOUD stem>.summary.json
  bool binary_ply = true;
  std::string imageset;  // the ImageSet folder, recorded in the summary (and its manifest as the
                         // rig's source)
  std::string rig_file;  // the rig file used instead of the manifest's (empty: the manifest's rig)
};

struct ReconstructionOutputs {
  std::filesystem::path cloud;
  std::filesystem::path summary;
  std::vector<std::filesystem::path> residual_maps;  // <CLOUD stem>.residuals_<reconstruction>.png
};

// Writes the cloud, then the residual maps (|residual| colour-coded with OpenCV's TURBO map from 0
// to 2 x the calibration check's threshold, or 0-1 px where the check has no threshold; black where
// no correspondence), then the summary: `reconstruction.ToJson()` plus imageset, cloud, options,
// rig {name, source: manifest|file, file} and residual_maps [{reconstruction, file, scale_max_px,
// calibration_warning, systematic_px, likely_causes}]. Throws slshadow::Error naming the ImageSet
// and the reasons when the cloud is empty (nothing is written), or naming a file that cannot be
// written.
ReconstructionOutputs WriteReconstruction(const ImageSetReconstruction& reconstruction,
                                          const ImageSetReconstructOptions& options, const Rig& rig,
                                          const ReconstructionOutputOptions& output);

}  // namespace slshadow
