#include "workflows/pipeline/scan_pipeline.h"

#include <tbb/parallel_for.h>
#include <opencv2/core/utility.hpp>

#include <cmath>
#include <optional>

#include "compare/coverage.h"
#include "compare/statistics.h"
#include "core/config.h"
#include "core/error.h"
#include "core/statistics.h"
#include "patterns/simulator_projector.h"
#include "workflows/pipeline/demo_config.h"  // generated: the embedded config/demo files
#include "workflows/pipeline/significance.h"

namespace slshadow::pipeline {
namespace fs = std::filesystem;

Rig LoadRigOrDemo(const fs::path& path) {
  return path.empty()
             ? RigFromConfig(ConfigNode::ParseYaml(kDemoRigYaml, "<embedded config/demo/rig.yaml>"))
             : LoadRig(path);
}

Scene LoadSceneOrDemo(const fs::path& path, const fs::path& base_dir) {
  return path.empty() ? SceneFromConfig(ConfigNode::ParseYaml(kDemoSceneYaml,
                                                              "<embedded config/demo/scene.yaml>"),
                                        base_dir)
                      : LoadScene(path);
}

PatternSpec LoadPatternSpecOrDemo(const fs::path& path) {
  return path.empty() ? PatternSpecFromConfig(ConfigNode::ParseYaml(
                            kDemoPatternsYaml, "<embedded config/demo/patterns.yaml>"))
                      : LoadPatternSpec(path);
}

VirtualScan RenderVirtualScan(const Scene& scene, const Rig& rig,
                              const std::vector<cv::Mat>& projector_images) {
  VirtualScan scan;
  scan.images = RenderScan(scene, rig, projector_images, &scan.geometry, &scan.summary);
  return scan;
}

void WriteVirtualScan(const fs::path& dir, const Rig& rig, const PatternSpec& spec,
                      const Scene& scene, const std::vector<std::vector<cv::Mat>>& images,
                      const ImageSetWriterOptions& writer_options, const nlohmann::json& extra) {
  const int num_cameras = static_cast<int>(images.size());
  const int num_patterns = spec.NumImages();
  SLSHADOW_THROW_IF(num_cameras != static_cast<int>(rig.cameras.size()),
                    "WriteVirtualScan: ", num_cameras, " cameras of images for a rig of ",
                    rig.cameras.size());
  for (const auto& camera_images : images) {
    SLSHADOW_THROW_IF(static_cast<int>(camera_images.size()) != num_patterns,
                      "WriteVirtualScan: ", camera_images.size(), " images for a pattern spec of ",
                      num_patterns);
  }
  ImageSetWriter writer(dir, rig, PatternSpecToJson(spec), writer_options);
  std::vector<std::string> errors(static_cast<size_t>(num_cameras * num_patterns));
  cv::parallel_for_(cv::Range(0, num_cameras * num_patterns), [&](const cv::Range& range) {
    for (int k = range.start; k < range.end; ++k) {
      try {
        writer.Add(
            rig.cameras[static_cast<size_t>(k / num_patterns)].name, k % num_patterns,
            images[static_cast<size_t>(k / num_patterns)][static_cast<size_t>(k % num_patterns)],
            scene.radiometry.exposure_us, ImageSource::kVirtual);
      } catch (const Error& e) {
        errors[static_cast<size_t>(k)] = e.what();
      }
    }
  });
  for (const auto& e : errors) SLSHADOW_THROW_IF(!e.empty(), e);
  writer.SetExtra(extra);
  writer.Commit();
}

ScanSettings ScanSettingsFromProvenance(const ScanProvenance& provenance, const std::string& file) {
  ScanSettings settings;
  const auto node = [&file](const nlohmann::json& json, const char* key) {
    return ConfigNode::FromJson(json, file, std::string("extra.provenance.") + key);
  };
  if (!provenance.simulate.is_null())
    settings.simulate = SimulateOptionsFromConfig(node(provenance.simulate, "simulate"));
  if (!provenance.decode.is_null())
    settings.decode = DecodeOptionsFromConfig(node(provenance.decode, "decode"));
  if (!provenance.reconstruct.is_null()) {
    settings.reconstruct =
        ReconstructOptionsFromConfig(node(provenance.reconstruct, "reconstruct"));
  }
  if (!provenance.compare.is_null()) {
    settings.compare = compare::CompareOptionsFromConfig(node(provenance.compare, "compare"));
  }
  return settings;
}

SimulateSummary SimulateFromSpec(const Scene& scene, const Rig& rig, const PatternSpec& spec,
                                 const std::string& spec_what, const std::string& rig_what,
                                 const fs::path& out_dir, const SimulateOptions& options) {
  CheckSimulatorProjector(rig, spec, spec_what, rig_what);
  return SimulateScan(scene, rig, GeneratePatterns(spec), PatternSpecToJson(spec), out_dir,
                      options);
}

SimulateSummary RedoVirtualScan(const fs::path& scan_dir, const fs::path& out_dir) {
  const ImageSet image_set = ImageSet::Open(scan_dir);
  const std::string manifest = (scan_dir / "manifest.json").string();
  const std::optional<ScanProvenance> provenance = ReadScanProvenance(image_set);
  SLSHADOW_THROW_IF(!provenance, manifest,
                    ": extra.provenance: missing; the scan cannot be redone from its folder");
  SLSHADOW_THROW_IF(provenance->scene_config.is_null(), manifest,
                    ": extra.provenance.scene.config: null (the scene was built in code); the scan "
                    "cannot be redone");
  const Scene scene = SceneFromConfig(
      ConfigNode::FromJson(provenance->scene_config, manifest, "extra.provenance.scene.config"),
      provenance->scene_base_dir);
  SLSHADOW_THROW_IF(SceneToJson(scene) != provenance->scene_summary, manifest,
                    ": extra.provenance.scene: the scene rebuilt from its config differs from the "
                    "recorded summary "
                    "(a mesh or image file changed, or the scene was edited after loading)");
  ScanSettings settings = ScanSettingsFromProvenance(*provenance, manifest);
  settings.simulate.writer.overwrite = false;
  const PatternSpec spec =
      PatternSpecFromConfig(ConfigNode::FromJson(image_set.patterns(), manifest, "patterns"));
  return SimulateScan(scene, image_set.rig(), GeneratePatterns(spec), image_set.patterns(), out_dir,
                      settings.simulate);
}

const ProjectorMap& DecodedScan::map(const std::string& camera) const {
  for (size_t i = 0; i < cameras.size(); ++i) {
    if (cameras[i] == camera) return maps[i];
  }
  SLSHADOW_THROW("decoded scan: camera '", camera, "' was not decoded");
}

DecodedScan DecodeImageSet(const ImageSet& image_set, const std::vector<std::string>& cameras,
                           const DecodeOptions& options) {
  DecodedScan scan;
  scan.rig = image_set.rig();
  scan.spec = PatternSpecFromConfig(ConfigNode::FromJson(
      image_set.patterns(), (image_set.dir() / "manifest.json").string(), "patterns"));
  scan.cameras = cameras;
  if (scan.cameras.empty()) {
    for (size_t c = 0; c < std::min<size_t>(2, scan.rig.cameras.size()); ++c) {
      scan.cameras.push_back(scan.rig.cameras[c].name);
    }
  }
  for (const std::string& camera : scan.cameras) {
    scan.maps.push_back(DecodePatterns(scan.spec, image_set.LoadCamera(camera), options));
  }
  return scan;
}

Reconstruction ReconstructFromMaps(const DecodedScan& scan, ReconstructMode mode,
                                   const ReconstructOptions& options) {
  SLSHADOW_THROW_IF(scan.cameras.empty(), "reconstruct: no camera was decoded");
  if (mode == ReconstructMode::kProjector) {
    return ReconstructWithProjector(scan.rig, scan.cameras[0], scan.maps[0], options);
  }
  SLSHADOW_THROW_IF(scan.cameras.size() < 2, "reconstruct stereo: needs two decoded cameras (got ",
                    scan.cameras.size(), ")");
  return ReconstructStereo(scan.rig, scan.cameras[0], scan.cameras[1], scan.maps[0], scan.maps[1],
                           options);
}

std::vector<Reconstruction> ReconstructModes(const DecodedScan& scan,
                                             const std::vector<ReconstructMode>& modes,
                                             const ReconstructOptions& options,
                                             std::vector<StageMeasurement>* stages) {
  std::vector<Reconstruction> recs;
  recs.reserve(modes.size());
  for (const ReconstructMode mode : modes) {
    const StageMeter meter(std::string("reconstruct ") + ToString(mode));
    recs.push_back(ReconstructFromMaps(scan, mode, options));
    if (stages) stages->push_back(meter.Stop());
  }
  return recs;
}

double VisibleCoverage(const compare::CompareResult& result,
                       const std::vector<Eigen::Vector3d>& visible) {
  std::vector<Eigen::Vector3d> reached;
  reached.reserve(result.compared.size());
  for (size_t i = 0; i < result.compared.size(); ++i) {
    if (std::abs(result.deviations_mm[i]) <= result.options.threshold_mm)
      reached.push_back(result.compared.points[i]);
  }
  return compare::Coverage(visible, reached, result.coverage_radius_mm);
}

ModeAccuracy MeasureAccuracy(const std::string& mode, const compare::CompareResult& result,
                             const std::vector<Eigen::Vector3d>& visible) {
  return MeasureAccuracy(mode, result, VisibleCoverage(result, visible));
}

ModeAccuracy MeasureAccuracy(const std::string& mode, const compare::CompareResult& result,
                             double visible_coverage) {
  ModeAccuracy m;
  m.mode = mode;
  m.points = result.compared.size();
  m.coverage = result.coverage;
  m.visible_coverage = visible_coverage;
  m.mean_mm = result.c2c.mean_mm;
  m.rms_mm = result.c2c.rms_mm;
  m.p95_mm = result.c2c.p95_mm;
  m.max_mm = result.c2c.max_mm;
  m.outliers = result.c2c.outliers;
  m.outlier_fraction = result.c2c.count ? static_cast<double>(result.c2c.outliers) /
                                              static_cast<double>(result.c2c.count)
                                        : 0;
  return m;
}

void MeasureFigureUncertainty(const std::vector<double>& deviations_mm, ModeAccuracy* accuracy) {
  const size_t n = deviations_mm.size(), bands = kSignificanceBands;
  std::vector<double> rms(bands, std::nan("")), p95(bands, std::nan(""));
  tbb::parallel_for(size_t{0}, bands, [&](size_t b) {
    // ComputeStats's definitions: over the finite values, RMS of |d| and its nearest-rank 95th
    // percentile (core/statistics.h Percentile), without its other figures.
    const double* first = deviations_mm.data() + n * b / bands;
    const double* last = deviations_mm.data() + n * (b + 1) / bands;
    size_t count = 0;
    double sum2 = 0;
    for (const double* d = first; d != last; ++d) {
      if (!std::isfinite(*d)) continue;
      ++count;
      sum2 += *d * *d;
    }
    if (count == 0) return;
    rms[b] = std::sqrt(sum2 / static_cast<double>(count));
    p95[b] = compare::AbsPercentile(first, last, 95.0);
  });
  accuracy->rms_sigma_mm = BandSigma(rms);
  accuracy->p95_sigma_mm = BandSigma(p95);
  accuracy->rms_bands_mm = std::move(rms);
  accuracy->p95_bands_mm = std::move(p95);
}

nlohmann::json ModeAccuracyToJson(const ModeAccuracy& m) {
  nlohmann::json j = {{"mode", m.mode},         {"points", m.points},
                      {"coverage", m.coverage}, {"visible_coverage", m.visible_coverage},
                      {"mean_mm", m.mean_mm},   {"rms_mm", m.rms_mm},
                      {"p95_mm", m.p95_mm},     {"max_mm", m.max_mm},
                      {"outliers", m.outliers}, {"outlier_fraction", m.outlier_fraction}};
  if (!m.rms_bands_mm.empty()) {
    j["rms_sigma_mm"] = m.rms_sigma_mm;
    j["p95_sigma_mm"] = m.p95_sigma_mm;
    j["rms_bands_mm"] = m.rms_bands_mm;
    j["p95_bands_mm"] = m.p95_bands_mm;
  }
  return j;
}

}  // namespace slshadow::pipeline
