// The scan pipeline every workflow is built from (the demo job, `slshadow bench`, real vs
// virtual): the virtual scan of a scene by a rig, in memory or written as an ImageSet exactly as a
// real capture is written; an ImageSet decoded once and reconstructed in any set of modes from
// those maps; a cloud compared against a reference with the demo's coverage figures.
//
// Namespace slshadow::pipeline, the module's name as for every module above the foundation
// (docs/conventions.md): it holds all the workflows (DESIGN.md), not only `slshadow shadow`'s.
//
// Frames and units: rig frame (the first camera's), mm, px (OpenCV's pixel convention).
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "compare/compare.h"
#include "core/image_set.h"
#include "core/mesh.h"
#include "core/projector_map.h"
#include "core/provenance.h"
#include "core/rig.h"
#include "core/stage_meter.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct.h"
#include "sim/scene.h"
#include "sim/simulate.h"

namespace slshadow::pipeline {

// ---- Configuration: the embedded demo (config/demo/, compiled in) or a file in its place.

// `path` empty: the embedded config/demo/rig.yaml; else LoadRig(path).
Rig LoadRigOrDemo(const std::filesystem::path& path);
// `path` empty: the embedded config/demo/scene.yaml (relative mesh paths against `base_dir`);
// else LoadScene(path).
Scene LoadSceneOrDemo(const std::filesystem::path& path,
                      const std::filesystem::path& base_dir = std::filesystem::current_path());
// `path` empty: the embedded config/demo/patterns.yaml; else LoadPatternSpec(path).
PatternSpec LoadPatternSpecOrDemo(const std::filesystem::path& path);

// ---- The virtual scan.

struct VirtualScan {
  std::vector<std::vector<cv::Mat>> images;  // images[camera][pattern], rig camera order
  std::vector<GeometryBuffer> geometry;      // per camera: the geometry pass (ground truth)
  SimulateSummary summary;
};

// Renders every projector image seen by every camera of `rig` in memory (sim/ RenderScan).
// Throws slshadow::Error on an invalid scene or rig, or projector images of the wrong size.
VirtualScan RenderVirtualScan(const Scene& scene, const Rig& rig,
                              const std::vector<cv::Mat>& projector_images);

// Writes images[camera][pattern] (rig camera order, spec.NumImages() per camera) as an ImageSet
// at `dir`, source "virtual", exposure scene.radiometry.exposure_us, the manifest's `extra` set
// to `extra`. Images are encoded in parallel; the folder appears complete or not at all.
void WriteVirtualScan(const std::filesystem::path& dir, const Rig& rig, const PatternSpec& spec,
                      const Scene& scene, const std::vector<std::vector<cv::Mat>>& images,
                      const ImageSetWriterOptions& writer_options, const nlohmann::json& extra);

// ---- Settings and provenance as files (core/provenance.h; each module reads its own options).

// The settings a scan was made and processed with, read from its provenance: each field from its
// module's FromConfig, the default where the provenance has none (null).
struct ScanSettings {
  SimulateOptions simulate;
  DecodeOptions decode;
  ReconstructOptions reconstruct;
  compare::CompareOptions compare;
};
// Throws slshadow::Error naming the manifest and the field on a malformed provenance.
ScanSettings ScanSettingsFromProvenance(const ScanProvenance& provenance, const std::string& file);

// What `slshadow simulate` runs: the spec's projector images rendered by SimulateScan into the
// ImageSet at `out_dir`, after checking that the rig has a projector of the spec's size
// (CheckSimulatorProjector; `spec_what` and `rig_what` name the files in the message).
SimulateSummary SimulateFromSpec(const Scene& scene, const Rig& rig, const PatternSpec& spec,
                                 const std::string& spec_what, const std::string& rig_what,
                                 const std::filesystem::path& out_dir,
                                 const SimulateOptions& options);

// Renders the virtual scan in `scan_dir` again from that folder alone, with the same settings:
// rig and pattern spec from its manifest, the scene rebuilt from extra.provenance.scene (config and
// base_dir), the simulator options from extra.provenance.simulate (overwrite off); writes the new
// ImageSet at `out_dir` (SimulateScan). Throws slshadow::Error when the ImageSet has no
// provenance, its scene was built in code (no config), or the rebuilt scene's summary differs from
// the recorded one (a mesh file changed, or the scene was edited after loading).
SimulateSummary RedoVirtualScan(const std::filesystem::path& scan_dir,
                                const std::filesystem::path& out_dir);

// ---- Decode once, reconstruct any set of modes.

// The decoded maps of an ImageSet's cameras, with the rig and pattern spec it was read with.
struct DecodedScan {
  Rig rig;
  PatternSpec spec;
  std::vector<std::string> cameras;  // decoded, in the order asked
  std::vector<ProjectorMap> maps;    // one per camera
  // The map of `camera`; throws slshadow::Error when it was not decoded.
  const ProjectorMap& map(const std::string& camera) const;
};

// Loads and decodes `cameras` of `image_set` (empty: the first two cameras of its rig, or the
// one camera when the rig has one) with the pattern spec stored in its manifest, one camera
// after the other. Throws slshadow::Error on unknown cameras, missing images or a bad spec.
DecodedScan DecodeImageSet(const ImageSet& image_set, const std::vector<std::string>& cameras = {},
                           const DecodeOptions& options = {});

// One reconstruction from decoded maps: kProjector, the first decoded camera against the
// projector; kStereo, the first decoded camera (left) against the second (right).
Reconstruction ReconstructFromMaps(const DecodedScan& scan, ReconstructMode mode,
                                   const ReconstructOptions& options);

// The reconstructions of `modes`, in that order, each from the same maps. `stages`, if not null,
// receives one StageMeasurement per mode, named "reconstruct <mode>".
std::vector<Reconstruction> ReconstructModes(const DecodedScan& scan,
                                             const std::vector<ReconstructMode>& modes,
                                             const ReconstructOptions& options,
                                             std::vector<StageMeasurement>* stages = nullptr);

// ---- Compare against a reference.

// The share of `visible` that the comparison's inliers (|deviation| <= threshold) reach within
// its coverage radius (compare::Coverage).
double VisibleCoverage(const compare::CompareResult& result,
                       const std::vector<Eigen::Vector3d>& visible);

// The demo's accuracy figures of one compared cloud.
struct ModeAccuracy {
  std::string mode;  // "projector" or "stereo"
  size_t points = 0;
  double coverage = 0;          // of the whole ground-truth surface (hidden faces included)
  double visible_coverage = 0;  // of the surface the reference camera sees lit by the projector
  double rms_mm = 0, p95_mm = 0, max_mm = 0, mean_mm = 0;
  size_t outliers = 0;
  double outlier_fraction = 0;
  // Set by MeasureFigureUncertainty (not by MeasureAccuracy: the sweeps ask for them, the demo
  // does not). RMS and p95 on kSignificanceBands consecutive runs of the points (a scan's cloud is
  // in image-row order, so horizontal bands of the image; NaN for an empty band), and from them the
  // standard uncertainties of rms_mm and p95_mm (workflows/pipeline/significance.h BandSigma; NaN
  // with fewer than 2 bands of points). Two scans of one scene by one rig have the same bands: the
  // effect of a change between them is judged band by band (paired), which cancels what the bands'
  // content adds to each figure's own spread.
  std::vector<double> rms_bands_mm, p95_bands_mm;
  double rms_sigma_mm = 0, p95_sigma_mm = 0;
};
// Sets accuracy's band figures and sigmas from the compared points' deviations (in cloud order),
// each band's RMS and p95 as compare::ComputeStats(band, unsigned, ...) defines them.
void MeasureFigureUncertainty(const std::vector<double>& deviations_mm, ModeAccuracy* accuracy);
ModeAccuracy MeasureAccuracy(const std::string& mode, const compare::CompareResult& result,
                             const std::vector<Eigen::Vector3d>& visible);
// The same with the visible coverage already measured (e.g. by compare::Compare as an extra
// coverage sample set: the same value VisibleCoverage gives).
ModeAccuracy MeasureAccuracy(const std::string& mode, const compare::CompareResult& result,
                             double visible_coverage);
// {"mode", "points", "coverage", "visible_coverage", "mean_mm", "rms_mm", "p95_mm", "max_mm",
//  "outliers", "outlier_fraction"}, and when measured (MeasureFigureUncertainty) "rms_sigma_mm",
//  "p95_sigma_mm", "rms_bands_mm", "p95_bands_mm": what the demo's demo.json and a
//  sweep job's result record.
nlohmann::json ModeAccuracyToJson(const ModeAccuracy& accuracy);

}  // namespace slshadow::pipeline
