#include "workflows/pipeline/demo.h"

#include <chrono>
#include <cstdio>
#include <exception>
#include <future>
#include <memory>
#include <thread>
#include <utility>

#include <malloc.h>

#include "compare/compare.h"
#include "compare/report.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/image_set.h"
#include "core/mesh.h"
#include "core/provenance.h"
#include "core/stage_meter.h"
#include "reconstruct/dense_grid.h"
#include "sim/scene_surface.h"
#include "sim/simulate.h"
#include "workflows/pipeline/scan_pipeline.h"

namespace slshadow::pipeline {
namespace fs = std::filesystem;

namespace {

constexpr const char* kMarker = "demo.json";  // marks a folder as an earlier demo output

}  // namespace

void DemoOptions::Check() const {
  SLSHADOW_THROW_IF(out_dir.empty(), "--out: an output folder is required");
  SLSHADOW_THROW_IF(!(threshold_mm > 0), "--threshold-mm: must be positive (got ", threshold_mm,
                    ")");
  TriangulationMethodFromString(method);
  ImageEncodingFromString(encoding);
  html.Check();
}

nlohmann::json DemoResult::ToJson() const {
  nlohmann::json j;
  j["modes"] = nlohmann::json::array();
  for (const auto& m : modes) {
    nlohmann::json mode = ModeAccuracyToJson(m);
    mode["report"] = m.report_dir.string();
    j["modes"].push_back(std::move(mode));
  }
  j["stages"] = nlohmann::json::array();
  for (const auto& s : stages) {
    j["stages"].push_back({{"name", s.name},
                           {"wall_s", s.wall_s},
                           {"cpu_s", s.cpu_s},
                           {"peak_rss_mb", s.peak_rss_mb}});
    if (s.concurrent) j["stages"].back()["concurrent"] = true;
  }
  return j;
}

std::string DemoResult::Table() const {
  std::string out =
      "mode         points   coverage  visible cov.   RMS (mm)   p95 (mm)   max (mm)   outliers > "
      "thr\n";
  char buf[256];
  for (const auto& m : modes) {
    std::snprintf(buf, sizeof(buf),
                  "%-10s %8zu   %7.1f%%      %7.1f%%   %8.4f   %8.4f   %8.3f   %6zu (%.3f%%)\n",
                  m.mode.c_str(), m.points, 100 * m.coverage, 100 * m.visible_coverage, m.rms_mm,
                  m.p95_mm, m.max_mm, m.outliers, 100 * m.outlier_fraction);
    out += buf;
  }
  out += '\n';  // (not "\n" + ...: GCC 12 reports a false -Wrestrict on that once inlined)
  out += FormatStageTable(stages);
  return out;
}

DemoResult RunDemoJob(const DemoOptions& options) {
  options.Check();
  std::error_code ec;
  const fs::path out_dir = options.out_dir;
  SLSHADOW_THROW_IF(fs::exists(out_dir, ec) && !fs::exists(out_dir / kMarker, ec), out_dir.string(),
                    ": exists and is not an earlier demo output; choose another --out");
  StagingDirectory staged(out_dir);
  const fs::path& staging = staged.path();

  DemoResult result;
  result.out_dir = out_dir;
  const bool verbose = options.verbose;

  // 1. Configuration: rig, scene (the part is generated in code), patterns.
  StageMeter meter("load rig, build scene, patterns");
  const Rig rig = LoadRigOrDemo(options.rig_path);
  SLSHADOW_THROW_IF(rig.cameras.size() < 2 || !rig.projector, "demo rig '", rig.name,
                    "': needs two cameras and a projector");
  const Scene scene = LoadSceneOrDemo(options.scene_path);
  const PatternSpec spec = LoadPatternSpecOrDemo(options.patterns_path);
  std::vector<cv::Mat> projector_images = GeneratePatterns(spec);
  const TriangleMesh truth =
      SceneSurface(scene, options.scene_path.empty() ? "demo scene" : options.scene_path.string());
  result.stages.push_back(meter.Stop());

  const DecodeOptions decode_options;
  ReconstructOptions reconstruct_options;
  reconstruct_options.method = TriangulationMethodFromString(options.method);
  compare::CompareOptions compare_options;
  compare_options.threshold_mm = options.threshold_mm;

  // 2. The virtual scan, in memory.
  meter = StageMeter("simulate (ray cast + patterns)");
  VirtualScan scan = RenderVirtualScan(scene, rig, projector_images);
  std::vector<cv::Mat>().swap(projector_images);  // ~50 MB not needed any more
  result.stages.push_back(meter.Stop());
  if (verbose) std::printf("%s\n", scan.summary.BriefReport().c_str());

  // The reference (surface samples and the distance hierarchy, shared by both comparisons) needs
  // only the ground-truth mesh: it is built on a thread of its own (single-threaded, ~0.15 s)
  // while the ImageSet is written, read, decoded and reconstructed, and waited for by the
  // comparison. Its row in the stage table holds its own wall and thread CPU time.
  struct BuiltReference {
    compare::Reference reference;
    StageMeasurement stage;
  };
  std::future<BuiltReference> reference_task = std::async(std::launch::async, [&truth] {
    BuiltReference built;
    const auto t0 = std::chrono::steady_clock::now();
    const double cpu0 = ThreadCpuSeconds();
    built.reference = compare::ReferenceFromMesh(truth, "ground truth (scene meshes and planes)");
    built.stage.name = "reference: sample ground truth";
    built.stage.wall_s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    built.stage.cpu_s = ThreadCpuSeconds() - cpu0;
    built.stage.concurrent = true;
    return built;
  });
  // Its row, listed where its thread starts (before the stages it runs alongside); the figures are
  // filled in when it ends.
  const size_t reference_row = result.stages.size();
  result.stages.push_back(StageMeasurement{"reference: sample ground truth"});
  result.stages.back().concurrent = true;

  // 3. Write it as an ImageSet, exactly as a real capture is written.
  meter = StageMeter("write ImageSet");
  {
    // Provenance: the scan renders again as SimulateScan with these options (the demo keeps its
    // ground truth in memory), and records the settings it decodes, reconstructs and compares with.
    SimulateOptions simulate_options;
    simulate_options.writer.encoding = ImageEncodingFromString(options.encoding);
    simulate_options.write_ground_truth = false;
    ScanProvenance provenance = VirtualScanProvenance(scene, simulate_options, "slshadow demo");
    provenance.decode = DecodeOptionsToJson(decode_options);
    provenance.reconstruct = reconstruct_options.ToJson();
    provenance.compare = compare::CompareOptionsToJson(compare_options);
    WriteVirtualScan(staging / "scan", rig, spec, scene, scan.images, simulate_options.writer,
                     ExtraWithProvenance(provenance));
  }
  WriteMesh(staging / "ground_truth.ply", truth);
  result.stages.push_back(meter.Stop());

  // What the left camera sees lit, from the virtual scan's ground truth; then the scan's images
  // and geometry are freed with the simulator's block cache: everything below reads the ImageSet.
  meter = StageMeter("lit visible surface, free the scan");
  const std::vector<Eigen::Vector3d> visible = LitVisibleSurface(scan.geometry[0]);
  scan = VirtualScan();
  ReleaseSimulatorPool();
  malloc_trim(0);
  result.stages.push_back(meter.Stop());

  // 4. Read the ImageSet back and decode both cameras: the path a real capture takes.
  meter = StageMeter("read ImageSet + decode");
  const ImageSet image_set = ImageSet::Open(staging / "scan");
  auto decoded = std::make_unique<DecodedScan>(DecodeImageSet(image_set, {}, decode_options));
  result.stages.push_back(meter.Stop());

  // 5. Reconstruct both modes, then compare and report them concurrently: each comparison is
  // parallel inside, but its report (PLY, map, charts) and parts of the comparison are serial.
  const std::vector<std::string> mode_names = {"projector", "stereo"};
  // One mode at a time, stereo first: its working set (rectified maps and matches, ~150 MB more
  // than the projector mode's) then runs before the other cloud exists. The demo keeps each cloud
  // and summary, not its grid (~100 MB); after each mode the reconstruction's reused buffers are
  // freed (the other mode's grid differs in size).
  std::vector<Reconstruction> recs(mode_names.size());
  for (const ReconstructMode mode : {ReconstructMode::kStereo, ReconstructMode::kProjector}) {
    Reconstruction& rec = recs[mode == ReconstructMode::kProjector ? 0 : 1];
    rec =
        std::move(ReconstructModes(*decoded, {mode}, reconstruct_options, &result.stages).front());
    rec.grid = DenseGrid();
    std::vector<float>().swap(rec.projector_error_px);
    ReleaseReconstructionBuffers();
    malloc_trim(0);
  }
  decoded.reset();  // the maps are not needed any more
  malloc_trim(0);
  if (verbose) {
    for (const auto& rec : recs) std::printf("%s\n", rec.summary.FullReport().c_str());
  }

  meter = StageMeter("compare + report (2 modes at once)");
  // Any wait for the reference counts in this stage.
  BuiltReference built = reference_task.get();
  const compare::Reference& reference = built.reference;
  result.stages[reference_row] = std::move(built.stage);
  std::vector<DemoModeResult> modes(mode_names.size());
  std::vector<std::string> texts(mode_names.size());
  std::vector<std::exception_ptr> errors(mode_names.size());
  const auto run_mode = [&](size_t k) {
    try {
      const std::string& mode = mode_names[k];
      const auto t0 = std::chrono::steady_clock::now();
      compare::CompareResult cmp =
          compare::Compare(std::move(recs[k].cloud), reference, compare_options,
                           mode + " reconstruction", {&visible});
      const auto t1 = std::chrono::steady_clock::now();
      compare::ReportOptions report_options;
      report_options.view = compare::ViewCamera{image_set.rig().cameras[0].model,
                                                image_set.rig().cameras[0].cam_from_rig};
      compare::WriteReport(staging / mode, cmp, report_options);
      const auto t2 = std::chrono::steady_clock::now();
      DemoModeResult& m = modes[k];
      static_cast<ModeAccuracy&>(m) = MeasureAccuracy(mode, cmp, cmp.extra_coverage.front());
      m.report_dir = out_dir / mode;
      if (verbose) {
        char buf[160];
        std::snprintf(
            buf, sizeof(buf),
            "%s: compare %.3f s wall, then report %.3f s wall (concurrently with the other mode)\n",
            mode.c_str(), std::chrono::duration<double>(t1 - t0).count(),
            std::chrono::duration<double>(t2 - t1).count());
        texts[k] = cmp.Summary() + buf;
      }
    } catch (...) {
      errors[k] = std::current_exception();
    }
  };
  {
    std::thread first(run_mode, size_t{0});  // the other mode on this thread
    for (size_t k = 1; k < mode_names.size(); ++k) run_mode(k);
    first.join();
  }
  for (const auto& e : errors) {
    if (e) std::rethrow_exception(e);
  }
  for (const auto& t : texts) {
    if (!t.empty()) std::printf("%s\n", t.c_str());
  }
  result.modes = std::move(modes);
  result.stages.push_back(meter.Stop());

  WriteTextFileAtomically(staging / kMarker, result.ToJson().dump(2) + "\n");
  if (options.write_html) report::WriteHtmlReport(staging, options.html);
  staged.Commit(/*overwrite=*/true);
  return result;
}

}  // namespace slshadow::pipeline
