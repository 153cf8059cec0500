#include "reconstruct/reconstruct_image_set.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>

#include "core/config.h"
#include "core/error.h"
#include "core/progress.h"

namespace slshadow {

namespace {
using Clock = std::chrono::steady_clock;
double Seconds(Clock::time_point since) {
  return std::chrono::duration<double>(Clock::now() - since).count();
}

// The cameras to decode, checked against the rig and the available images.
std::vector<std::string> SelectCameras(const Rig& rig, const std::vector<std::string>& available,
                                       const ImageSetReconstructOptions& options) {
  std::vector<std::string> cameras = options.cameras;
  if (cameras.empty()) {
    for (const auto& cam : rig.cameras) {
      if (std::find(available.begin(), available.end(), cam.name) != available.end())
        cameras.push_back(cam.name);
    }
    if (options.mode == ReconstructMode::kStereo && cameras.size() > 2) cameras.resize(2);
  }
  for (const auto& name : cameras) {
    rig.Camera(name);  // throws listing the rig's cameras
    SLSHADOW_THROW_IF(std::find(available.begin(), available.end(), name) == available.end(),
                      "reconstruct: camera '", name, "' has no images");
  }
  if (options.mode == ReconstructMode::kStereo) {
    SLSHADOW_THROW_IF(cameras.size() != 2,
                      "reconstruct: stereo mode needs exactly two cameras (got ", cameras.size(),
                      ")");
  } else {
    SLSHADOW_THROW_IF(cameras.empty(), "reconstruct: no camera has images");
  }
  return cameras;
}

cv::Mat ResidualMap(const Reconstruction& rec) {
  const DenseGrid& g = rec.grid;
  // The calibration check's residual: the epipolar error, or one-axis stereo's projector error;
  // the reprojection error where the check has none.
  const bool epipolar = rec.summary.epipolar_error_px.count > 0;
  const std::vector<float>& values = !rec.projector_error_px.empty() ? rec.projector_error_px
                                     : epipolar                      ? g.epipolar_error_px
                                                                     : g.reprojection_error_px;
  cv::Mat map(g.height, g.width, CV_32FC1, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  for (int v = 0; v < g.height; ++v) {
    float* row = map.ptr<float>(v);
    for (int u = 0; u < g.width; ++u) {
      const size_t i = g.Index(u, v);
      if (i < values.size() && std::isfinite(values[i]))
        row[u] = std::abs(values[i]);  // epipolar: signed
    }
  }
  return map;
}

void TagCamera(PointCloud* cloud, int index) {
  cloud->SetScalar("camera", std::vector<float>(cloud->size(), static_cast<float>(index)));
}

}  // namespace

void ImageSetReconstructOptions::Check() const {
  reconstruct.Check();
  decode.Check();
  SLSHADOW_THROW_IF(mode == ReconstructMode::kStereo && !cameras.empty() && cameras.size() != 2,
                    "reconstruct options: cameras: stereo mode takes two cameras (got ",
                    cameras.size(), ")");
}

nlohmann::json ImageSetReconstructOptions::ToJson() const {
  return {{"mode", ToString(mode)},
          {"cameras", cameras},
          {"reconstruct", reconstruct.ToJson()},
          {"decode", DecodeOptionsToJson(decode)}};
}

ImageSetReconstructOptions ImageSetReconstructOptionsFromConfig(const ConfigNode& node) {
  if (!node.IsObject()) node.Fail("expected a mapping of reconstruct options");
  node.RejectUnknownKeys({"mode", "cameras", "reconstruct", "decode"});
  ImageSetReconstructOptions o;
  if (node.Has("mode")) {
    const ConfigNode mode = node["mode"];
    try {
      o.mode = ReconstructModeFromString(mode.AsString());
    } catch (const Error& e) {
      mode.Fail(e.what());
    }
  }
  if (node.Has("cameras")) {
    const ConfigNode cameras = node["cameras"];
    for (size_t i = 0; i < cameras.size(); ++i) o.cameras.push_back(cameras.at(i).AsString());
  }
  if (node.Has("reconstruct")) o.reconstruct = ReconstructOptionsFromConfig(node["reconstruct"]);
  if (node.Has("decode")) o.decode = DecodeOptionsFromConfig(node["decode"]);
  try {
    o.Check();
  } catch (const Error& e) {
    SLSHADOW_THROW(node.file(), node.path().empty() ? "" : ": ", node.path(), ": ", e.what());
  }
  return o;
}

ImageSetReconstruction ReconstructFromImages(
    const Rig& rig, const PatternSpec& spec,
    const std::map<std::string, std::vector<cv::Mat>>& images,
    const ImageSetReconstructOptions& options) {
  options.Check();
  spec.Check();
  std::vector<std::string> available;
  for (const auto& [name, frames] : images) available.push_back(name);
  ImageSetReconstruction out;
  SLSHADOW_THROW_IF(
      options.mode == ReconstructMode::kProjector && !rig.projector, "reconstruct: rig '", rig.name,
      "' has no projector, which projector mode needs; reconstruct in stereo mode (--mode stereo) ",
      "with two of its ", rig.cameras.size(), " camera(s)");
  out.cameras = SelectCameras(rig, available, options);
  for (const auto& name : out.cameras) {
    const CameraModel& model = rig.Camera(name).model;
    const cv::Size size = images.at(name).empty() ? cv::Size() : images.at(name)[0].size();
    SLSHADOW_THROW_IF(size.width != model.width || size.height != model.height,
                      "reconstruct: rig '", rig.name, "' camera '", name, "' is ", model.width, "x",
                      model.height, " px but its images are ", size.width, "x", size.height,
                      ": a rig of another camera?");
  }
  std::map<std::string, ProjectorMap> maps;
  auto t0 = Clock::now();
  // Steps: one decode per camera, then one triangulation per camera (stereo: one for the pair).
  const auto n = static_cast<int64_t>(out.cameras.size());
  Progress progress("reconstruct", n + (options.mode == ReconstructMode::kStereo ? 1 : n), false);
  for (const auto& name : out.cameras) {
    maps[name] = DecodePatterns(spec, images.at(name), options.decode);
    progress.Advance();
  }
  out.decode_s = Seconds(t0);
  t0 = Clock::now();
  if (options.mode == ReconstructMode::kStereo) {
    Reconstruction rec =
        ReconstructStereo(rig, out.cameras[0], out.cameras[1], maps[out.cameras[0]],
                          maps[out.cameras[1]], options.reconstruct);
    TagCamera(&rec.cloud, rig.CameraIndex(out.cameras[0]));
    out.residual_maps.emplace_back(rec.summary.camera + "-" + rec.summary.other_device,
                                   ResidualMap(rec));
    out.cloud = std::move(rec.cloud);
    out.summaries.push_back(rec.summary);
    progress.Advance();
  } else {
    for (const auto& name : out.cameras) {
      Reconstruction rec = ReconstructWithProjector(rig, name, maps[name], options.reconstruct);
      TagCamera(&rec.cloud, rig.CameraIndex(name));
      out.residual_maps.emplace_back(rec.summary.camera + "-" + rec.summary.other_device,
                                     ResidualMap(rec));
      if (out.cloud.empty() && out.summaries.empty()) {
        out.cloud = std::move(rec.cloud);
      } else {
        out.cloud.Append(rec.cloud);
      }
      out.summaries.push_back(rec.summary);
      progress.Advance();
    }
  }
  out.reconstruct_s = Seconds(t0);
  return out;
}

ReconstructMode DefaultReconstructMode(const Rig& rig) {
  return rig.projector ? ReconstructMode::kProjector : ReconstructMode::kStereo;
}

ImageSetReconstruction ReconstructImageSet(const ImageSet& image_set,
                                           const ImageSetReconstructOptions& options) {
  return ReconstructImageSet(image_set, options, image_set.rig());
}

ImageSetReconstruction ReconstructImageSet(const ImageSet& image_set,
                                           const ImageSetReconstructOptions& options,
                                           const Rig& rig) {
  options.Check();
  const PatternSpec spec = PatternSpecFromConfig(ConfigNode::FromJson(
      image_set.patterns(), (image_set.dir() / "manifest.json").string(), "patterns"));
  const std::vector<std::string> cameras = SelectCameras(rig, image_set.CameraNames(), options);
  auto t0 = Clock::now();
  std::map<std::string, std::vector<cv::Mat>> images;
  for (const auto& name : cameras) {
    images[name] = image_set.LoadCamera(name);
    SLSHADOW_THROW_IF(static_cast<int>(images[name].size()) != spec.NumImages(),
                      image_set.dir().string(), ": camera '", name, "' has ", images[name].size(),
                      " images but the pattern spec has ", spec.NumImages());
  }
  const double load_s = Seconds(t0);
  ImageSetReconstructOptions selected = options;
  selected.cameras = cameras;
  ImageSetReconstruction out = ReconstructFromImages(rig, spec, images, selected);
  out.load_s = load_s;
  return out;
}

std::vector<std::string> ImageSetReconstruction::Warnings() const {
  std::vector<std::string> all;
  for (const auto& s : summaries) all.insert(all.end(), s.warnings.begin(), s.warnings.end());
  return all;
}

std::vector<std::string> ImageSetReconstruction::Notices() const {
  std::vector<std::string> all;
  for (const auto& s : summaries) {
    if (!s.calibration_check.available) all.push_back(s.calibration_check.Message());
  }
  return all;
}

std::string ImageSetReconstruction::EmptyCloudReason() const {
  if (!cloud.empty()) return "";
  const auto meaning = [](RejectReason r, bool stereo) -> const char* {
    switch (r) {
      case RejectReason::kNotDecoded:
        return "were not decoded: wrong pattern spec, or images too dark / saturated?";
      case RejectReason::kLowQuality:
        return "were below --min-quality";
      case RejectReason::kNoMatch:
      case RejectReason::kAmbiguousMatch:
        return "found no stereo match: wrong rig file?";
      case RejectReason::kBehindDevice:
        return stereo ? "triangulated behind a camera: wrong rig file, or left and right swapped?"
                      : "triangulated behind a device: wrong rig file?";
      case RejectReason::kParallelRays:
        return "had near-parallel rays: wrong rig file?";
      case RejectReason::kOutOfDepthRange:
        return "fell outside the depth range (--min-depth-mm, --max-depth-mm)";
      case RejectReason::kReprojectionError:
      case RejectReason::kEpipolarError:
        return "failed the residual gates: wrong rig file, or a rig that does not fit the images?";
      default:
        return "were rejected";
    }
  };
  std::ostringstream out;
  if (summaries.empty()) return "nothing was reconstructed";
  for (size_t k = 0; k < summaries.size(); ++k) {
    const ReconstructSummary& s = summaries[k];
    int best = 1;
    for (int r = 1; r < kNumRejectReasons; ++r) {
      if (s.rejected[static_cast<size_t>(r)] > s.rejected[static_cast<size_t>(best)]) best = r;
    }
    const double share =
        s.cells > 0 ? 100.0 * static_cast<double>(s.rejected[static_cast<size_t>(best)]) / s.cells
                    : 0;
    char line[320];
    std::snprintf(line, sizeof(line), "%s%s-%s: %.0f %% of %lld cells %s (%s)", k ? "; " : "",
                  s.camera.c_str(), s.other_device.c_str(), share, static_cast<long long>(s.cells),
                  meaning(static_cast<RejectReason>(best), s.mode == ReconstructMode::kStereo),
                  ToString(static_cast<RejectReason>(best)).c_str());
    out << line;
    if (s.calibration_check.warn) out << " (" << s.calibration_check.Message() << ")";
  }
  return out.str();
}

std::string ImageSetReconstruction::FullReport() const {
  std::ostringstream out;
  for (const auto& s : summaries) out << s.FullReport();
  char line[256];
  std::snprintf(line, sizeof(line),
                "cloud: %zu points; time: load %.3f s, decode %.3f s, reconstruct %.3f s\n",
                cloud.size(), load_s, decode_s, reconstruct_s);
  out << line;
  return out.str();
}

nlohmann::json ImageSetReconstruction::ToJson() const {
  nlohmann::json list = nlohmann::json::array();
  for (const auto& s : summaries) list.push_back(s.ToJson());
  return {{"points", cloud.size()},
          {"cameras", cameras},
          {"reconstructions", list},
          {"time_s", {{"load", load_s}, {"decode", decode_s}, {"reconstruct", reconstruct_s}}}};
}

}  // namespace slshadow
