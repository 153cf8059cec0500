#include "reconstruct/write_reconstruction.h"

#include <cmath>

#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "core/image_io.h"
#include "core/point_cloud.h"

namespace slshadow {

namespace fs = std::filesystem;

ReconstructionOutputs WriteReconstruction(const ImageSetReconstruction& rec,
                                          const ImageSetReconstructOptions& options, const Rig& rig,
                                          const ReconstructionOutputOptions& output) {
  // An empty cloud is a failure with a reason, not a result (nothing is written).
  SLSHADOW_THROW_IF(rec.cloud.empty(), output.imageset,
                    ": the reconstruction has 0 points: ", rec.EmptyCloudReason());
  ReconstructionOutputs out;
  out.cloud = output.cloud_path;
  out.summary = output.summary_path;
  if (out.summary.empty())
    out.summary = (out.cloud.parent_path() / out.cloud.stem()).string() + ".summary.json";
  PlyWriteOptions ply;
  ply.binary = output.binary_ply;
  WritePly(out.cloud, rec.cloud, ply);
  nlohmann::json summary = rec.ToJson();
  summary["imageset"] = output.imageset;
  summary["cloud"] = out.cloud.string();
  summary["options"] = options.ToJson();
  // Provenance of the rig: the manifest's, or the file given instead.
  summary["rig"] = {
      {"name", rig.name},
      {"source", output.rig_file.empty() ? "manifest" : "file"},
      {"file", output.rig_file.empty() ? (fs::path(output.imageset) / "manifest.json").string()
                                       : fs::absolute(output.rig_file).string()}};
  // Calibration-check maps: the dense correspondences' |epipolar error|, colour-coded from 0 (blue)
  // to 2 x the check's threshold (red); black where no correspondence. Each entry carries the
  // check's verdict and the likely causes it named.
  nlohmann::json maps = nlohmann::json::array();
  for (size_t k = 0; k < rec.residual_maps.size(); ++k) {
    const auto& [name, residuals] = rec.residual_maps[k];
    const CalibrationCheck& check = rec.summaries.at(k).calibration_check;
    const double map_max_px =
        check.available && std::isfinite(check.threshold_px) && check.threshold_px > 0
            ? 2 * check.threshold_px
            : 1.0;
    const fs::path map_path =
        out.cloud.parent_path() / (out.cloud.stem().string() + ".residuals_" + name + ".png");
    cv::Mat scaled, mask = residuals == residuals;  // false at NaN
    residuals.convertTo(scaled, CV_8U, 255.0 / map_max_px);
    cv::Mat colour;
    cv::applyColorMap(scaled, colour, cv::COLORMAP_TURBO);
    colour.setTo(cv::Scalar(0, 0, 0), ~mask);
    WriteFileAtomically(map_path, [&](const fs::path& tmp) {
      WriteImage(tmp.string() + ".png", colour);
      fs::rename(tmp.string() + ".png", tmp);
    });
    maps.push_back({{"reconstruction", name},
                    {"file", map_path.string()},
                    {"scale_max_px", map_max_px},
                    {"calibration_warning", check.warn},
                    {"systematic_px", check.systematic_px},
                    {"likely_causes", check.likely_causes}});
    out.residual_maps.push_back(map_path);
  }
  summary["residual_maps"] = maps;
  WriteTextFileAtomically(out.summary, summary.dump(2) + "\n");
  return out;
}

}  // namespace slshadow
