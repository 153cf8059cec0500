#include "workflows/multiview/view_reconstruction.h"

#include <chrono>
#include <cstdio>

#include <opencv2/core.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "core/image_io.h"
#include "core/image_set.h"
#include "core/string_printf.h"
#include "workflows/pipeline/scan_pipeline.h"

namespace slshadow::multiview {
namespace fs = std::filesystem;

namespace {

constexpr const char* kFormat = "slshadow-view-reconstruction";
constexpr int kVersion = 1;

// The first key path at which `a` and `b` differ ("" when equal), e.g. "decode.shadow_threshold".
std::string FirstDifference(const nlohmann::json& a, const nlohmann::json& b,
                            const std::string& prefix) {
  if (a.is_object() && b.is_object()) {
    for (const auto& [key, value] : a.items()) {
      const std::string path = prefix.empty() ? key : prefix + "." + key;
      if (!b.contains(key)) return path;
      const std::string d = FirstDifference(value, b[key], path);
      if (!d.empty()) return d;
    }
    for (const auto& [key, value] : b.items()) {
      if (!a.contains(key)) return prefix.empty() ? key : prefix + "." + key;
    }
    return "";
  }
  return a == b ? "" : (prefix.empty() ? "(value)" : prefix);
}

const nlohmann::json& At(const nlohmann::json& j, const std::string& path) {
  static const nlohmann::json kNull;
  const nlohmann::json* p = &j;
  size_t start = 0;
  while (start <= path.size()) {
    const size_t dot = path.find('.', start);
    const std::string key = path.substr(start, dot == std::string::npos ? dot : dot - start);
    if (!p->is_object() || !p->contains(key)) return kNull;
    p = &(*p)[key];
    if (dot == std::string::npos) break;
    start = dot + 1;
  }
  return *p;
}

}  // namespace

nlohmann::json ViewReconstructOptions::ToJson() const {
  return {{"mode", ToString(mode)},
          {"max_points_per_view", max_points_per_view},
          {"decode", DecodeOptionsToJson(decode)},
          {"reconstruct", reconstruct.ToJson()}};
}

ViewReconstruction ReconstructProjectView(const ImageSet& image_set,
                                          const ViewReconstructOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  const Rig& rig = image_set.rig();
  SLSHADOW_THROW_IF(options.mode == ReconstructMode::kStereo && rig.cameras.size() < 2,
                    image_set.dir().string(), ": stereo needs two cameras (the rig has ",
                    rig.cameras.size(), ")");
  std::vector<std::string> cameras = {rig.cameras[0].name};
  if (options.mode == ReconstructMode::kStereo) cameras.push_back(rig.cameras[1].name);
  const pipeline::DecodedScan decoded =
      pipeline::DecodeImageSet(image_set, cameras, options.decode);
  ViewReconstruction out;
  for (size_t k = 0; k < cameras.size(); ++k)
    out.dark.push_back(DarkPixels::FromStatus(cameras[k], decoded.maps[k].status));
  Reconstruction rec =
      options.mode == ReconstructMode::kStereo
          ? ReconstructStereo(rig, cameras[0], cameras[1], decoded.maps[0], decoded.maps[1],
                              options.reconstruct, options.max_points_per_view)
          : ReconstructWithProjector(rig, cameras[0], decoded.maps[0], options.reconstruct,
                                     options.max_points_per_view);
  out.cloud = std::move(rec.cloud);
  out.accepted_points = rec.summary.points;
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

std::string Fnv1a64Hex(const std::string& bytes) {
  uint64_t h = 0xcbf29ce484222325ULL;
  for (const char c : bytes) {
    h ^= static_cast<uint8_t>(c);
    h *= 0x100000001b3ULL;
  }
  return StringPrintf("%016llx", static_cast<unsigned long long>(h));
}

ViewReconstructionKey ViewReconstructionKey::For(const std::string& view,
                                                 const fs::path& image_set_dir,
                                                 const ViewReconstructOptions& options) {
  return {view, Fnv1a64Hex(ReadTextFile(image_set_dir / "manifest.json")), options.ToJson()};
}

void WriteViewReconstruction(const fs::path& dir, const ViewReconstructionKey& key,
                             const ViewReconstruction& reconstruction) {
  fs::create_directories(dir);
  StagingDirectory staging(dir / key.view);
  WritePly(staging.path() / "cloud.ply", reconstruction.cloud);
  nlohmann::json cameras = nlohmann::json::array();
  for (const DarkPixels& d : reconstruction.dark) {
    cv::Mat image(d.height, d.width, CV_8UC1);
    for (int y = 0; y < d.height; ++y) {
      uint8_t* row = image.ptr<uint8_t>(y);
      for (int x = 0; x < d.width; ++x)
        row[x] =
            d.dark[static_cast<size_t>(y) * static_cast<size_t>(d.width) + static_cast<size_t>(x)]
                ? 255
                : 0;
    }
    const std::string file = "dark_" + d.camera + ".png";
    WriteImage(staging.path() / file, image);
    cameras.push_back({{"camera", d.camera}, {"dark", file}});
  }
  const nlohmann::json j = {{"format", kFormat},
                            {"version", kVersion},
                            {"view", key.view},
                            {"manifest_fnv1a64", key.manifest_fnv1a64},
                            {"options", key.options},
                            {"accepted_points", reconstruction.accepted_points},
                            {"points", reconstruction.cloud.size()},
                            {"reconstruct_s", reconstruction.seconds},
                            {"cameras", cameras}};
  WriteTextFileAtomically(staging.path() / "reconstruction.json", j.dump(2) + "\n");
  staging.Commit(/*overwrite=*/true);
}

std::optional<ViewReconstruction> ReadViewReconstruction(const fs::path& dir,
                                                         const ViewReconstructionKey& key) {
  const fs::path folder = dir / key.view;
  const fs::path json_path = folder / "reconstruction.json";
  if (!fs::exists(json_path)) return std::nullopt;
  const std::string what = json_path.string();
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(ReadTextFile(json_path));
  } catch (const nlohmann::json::exception& e) {
    SLSHADOW_THROW(what, ": not JSON (", e.what(), ")");
  }
  SLSHADOW_THROW_IF(!j.is_object() || j.value("format", "") != kFormat, what,
                    ": format: expected \"", kFormat, "\"");
  SLSHADOW_THROW_IF(j.value("version", 0) != kVersion, what, ": version: ", j.value("version", 0),
                    "; expected ", kVersion);
  SLSHADOW_THROW_IF(j.value("view", "") != key.view, what, ": view: '", j.value("view", ""),
                    "'; expected '", key.view, "'");
  const std::string manifest = j.value("manifest_fnv1a64", "");
  SLSHADOW_THROW_IF(manifest != key.manifest_fnv1a64, what, ": manifest_fnv1a64: ", manifest,
                    ", but the view's manifest.json now hashes to ", key.manifest_fnv1a64,
                    "; the reconstruction is of other images: reconstruct the view again (delete ",
                    folder.string(), ")");
  const nlohmann::json options = j.contains("options") ? j["options"] : nlohmann::json();
  const std::string diff = FirstDifference(options, key.options, "");
  SLSHADOW_THROW_IF(!diff.empty(), what, ": options.", diff, ": ", At(options, diff).dump(),
                    ", but this merge's is ", At(key.options, diff).dump(),
                    "; reconstruct again with these options (delete ", folder.string(),
                    ") or merge with the options it was made with");
  ViewReconstruction out;
  out.cloud = ReadPly(folder / "cloud.ply");
  out.accepted_points = j.value("accepted_points", int64_t{0});
  out.seconds = j.value("reconstruct_s", 0.0);
  SLSHADOW_THROW_IF(out.cloud.size() != j.value("points", size_t{0}),
                    (folder / "cloud.ply").string(), ": ", out.cloud.size(), " points; ", what,
                    " says ", j.value("points", size_t{0}));
  SLSHADOW_THROW_IF(!j.contains("cameras") || !j["cameras"].is_array(), what,
                    ": cameras: expected a list");
  for (const nlohmann::json& c : j["cameras"]) {
    const std::string file = c.value("dark", "");
    SLSHADOW_THROW_IF(file.empty() || file.find('/') != std::string::npos, what,
                      ": cameras[].dark: '", file, "' is not a file name in the folder");
    const cv::Mat image = ReadImage(folder / file);
    SLSHADOW_THROW_IF(image.type() != CV_8UC1, (folder / file).string(),
                      ": expected an 8-bit single-channel image");
    DarkPixels d;
    d.camera = c.value("camera", "");
    d.width = image.cols;
    d.height = image.rows;
    d.dark.resize(static_cast<size_t>(d.width) * static_cast<size_t>(d.height));
    for (int y = 0; y < d.height; ++y) {
      const uint8_t* row = image.ptr<uint8_t>(y);
      for (int x = 0; x < d.width; ++x)
        d.dark[static_cast<size_t>(y) * static_cast<size_t>(d.width) + static_cast<size_t>(x)] =
            row[x] != 0;
    }
    out.dark.push_back(std::move(d));
  }
  return out;
}

}  // namespace slshadow::multiview
