// Reconstruction of a whole ImageSet: decode every camera's images with the ImageSet's own pattern
// spec (patterns/ DecodePatterns), then reconstruct in projector mode (each camera against the
// projector, clouds merged) or stereo mode (two cameras), in the rig frame (mm). What
// `slshadow reconstruct` runs.
#pragma once

#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/image_set.h"
#include "core/point_cloud.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct.h"

namespace slshadow {

struct ImageSetReconstructOptions {
  ReconstructMode mode = ReconstructMode::kProjector;
  // Projector mode: the cameras to reconstruct (empty: every camera with images). Stereo: the
  // left and right camera (empty: the first two cameras with images, in rig order).
  std::vector<std::string> cameras;
  ReconstructOptions reconstruct;
  DecodeOptions decode;

  void Check() const;  // throws slshadow::Error
  // {mode, cameras, reconstruct: ReconstructOptions::ToJson, decode: DecodeOptionsToJson}.
  nlohmann::json ToJson() const;
};

// The same as a file (docs/formats.md "Reconstruct options"); missing fields keep their
// defaults, unknown keys are rejected, the result is Check()ed. Throws slshadow::Error naming the
// file, the field and the value.
ImageSetReconstructOptions ImageSetReconstructOptionsFromConfig(const ConfigNode& node);

struct ImageSetReconstruction {
  // Merged cloud; besides the per-point fields of reconstruct.h it has "camera", the index in the
  // rig of the reference camera each point came from.
  PointCloud cloud;
  std::vector<ReconstructSummary> summaries;  // one per reconstruction (camera, or stereo pair)
  std::vector<std::string> cameras;           // cameras decoded, in order
  // Calibration-check maps, one per reconstruction ("<camera>-<other device>"): per cell of the
  // reconstruction grid (the camera image; stereo: the rectified left image) the absolute value
  // of the residual the calibration check judges (calibration_check.h: the epipolar error, or
  // one-axis stereo's projector error, projector px), or the reprojection error (px) where the
  // check has none. CV_32FC1, NaN where no correspondence.
  std::vector<std::pair<std::string, cv::Mat>> residual_maps;
  // All summaries' calibration-check warnings.
  std::vector<std::string> Warnings() const;
  // The messages of the calibration checks that could not run: what this capture cannot reveal
  // (e.g. camera-projector with one coded axis) and what would reveal it.
  std::vector<std::string> Notices() const;
  // Why the cloud is empty, in one line: the largest rejection reasons per reconstruction with
  // their share of the cells and what they usually mean (e.g. "stereo left-right: 54 % of cells
  // found no stereo match: wrong rig file?"), and each
  // reconstruction's calibration-check warning when it has one. Empty when the cloud has points.
  std::string EmptyCloudReason() const;
  double load_s = 0;         // reading and decoding image files
  double decode_s = 0;       // fringe decoding (DecodePatterns), all cameras
  double reconstruct_s = 0;  // triangulation, filters, normals, merging

  std::string FullReport() const;
  nlohmann::json ToJson() const;
};

// From images already in memory: `images` maps camera name -> that camera's images in pattern
// order (spec.NumImages() each). Throws slshadow::Error on unknown cameras, missing images or a
// bad spec / options.
ImageSetReconstruction ReconstructFromImages(
    const Rig& rig, const PatternSpec& spec,
    const std::map<std::string, std::vector<cv::Mat>>& images,
    const ImageSetReconstructOptions& options);

// Loads the ImageSet's images (in parallel) and calls ReconstructFromImages with the rig and
// the pattern spec stored in its manifest.
ImageSetReconstruction ReconstructImageSet(const ImageSet& image_set,
                                           const ImageSetReconstructOptions& options);
// The same with another rig than the manifest's (e.g. a refined one; the manifest is not read
// for it): it must name the ImageSet's cameras, at the images' size.
ImageSetReconstruction ReconstructImageSet(const ImageSet& image_set,
                                           const ImageSetReconstructOptions& options,
                                           const Rig& rig);

// The mode a rig supports by default: projector mode when it has a projector, else stereo.
ReconstructMode DefaultReconstructMode(const Rig& rig);

}  // namespace slshadow
