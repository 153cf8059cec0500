#include "apps/demo.h"

#include "apps/demo_config.h"  // generated: the embedded config/demo files
#include "compare/compare.h"
#include "compare/report.h"
#include "compare/statistics.h"
#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/image_set.h"
#include "core/mesh.h"
#include "core/rig.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct.h"
#include "sim/scene.h"
#include "sim/simulate.h"

#include <opencv2/core/utility.hpp>

#include <chrono>
#include <cstdio>
#include <exception>
#include <fstream>
#include <thread>

namespace slshadow::app {
namespace fs = std::filesystem;

namespace {

constexpr const char* kMarker = "demo.json";  // marks a folder as an earlier demo output

// The ground-truth surface of the scene's meshes and planes in the rig frame. Other object
// types would need their exact surfaces; the demo scene has none, and a user's scene with them
// is rejected with a clear message.
TriangleMesh SceneSurface(const Scene& scene, const std::string& what) {
  TriangleMesh surface;
  for (const auto& object : scene.objects) {
    TriangleMesh part;
    if (object.type == ObjectType::kMesh) {
      part = *object.mesh;
    } else if (object.type == ObjectType::kPlane) {
      const double hx = object.size_mm.x() / 2, hy = object.size_mm.y() / 2;
      part.vertices = {{-hx, -hy, 0}, {hx, -hy, 0}, {hx, hy, 0}, {-hx, hy, 0}};
      part.triangles = {{0, 1, 2}, {0, 2, 3}};
    } else {
      SLSHADOW_THROW(what, ": object '", object.name, "' is a ", ToString(object.type),
                     "; the demo compares against meshes and planes only");
    }
    part.Transform(object.rig_from_object.rotation.toRotationMatrix(),
                   object.rig_from_object.translation);
    surface.Append(part);
  }
  return surface;
}

// Points of the surface the camera sees lit by the projector (every second pixel).
std::vector<Eigen::Vector3d> LitVisibleSurface(const GeometryBuffer& geometry) {
  std::vector<Eigen::Vector3d> points;
  for (int y = 0; y < geometry.height; y += 2) {
    const uint8_t* vis = geometry.visibility.ptr<uint8_t>(y);
    const cv::Vec3f* p = geometry.point_in_rig.ptr<cv::Vec3f>(y);
    for (int x = 0; x < geometry.width; x += 2) {
      if (vis[x] == 2) points.emplace_back(p[x][0], p[x][1], p[x][2]);
    }
  }
  return points;
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

}  // namespace

void DemoOptions::Check() const {
  SLSHADOW_THROW_IF(out_dir.empty(), "--out: an output folder is required");
  SLSHADOW_THROW_IF(!(threshold_mm > 0), "--threshold-mm: must be positive (got ", threshold_mm,
                    ")");
  TriangulationMethodFromString(method);
  ImageEncodingFromString(encoding);
}

nlohmann::json DemoResult::ToJson() const {
  nlohmann::json j;
  j["modes"] = nlohmann::json::array();
  for (const auto& m : modes) {
    j["modes"].push_back({{"mode", m.mode},
                          {"points", m.points},
                          {"coverage", m.coverage},
                          {"visible_coverage", m.visible_coverage},
                          {"mean_mm", m.mean_mm},
                          {"rms_mm", m.rms_mm},
                          {"p95_mm", m.p95_mm},
                          {"max_mm", m.max_mm},
                          {"outliers", m.outliers},
                          {"outlier_fraction", m.outlier_fraction},
                          {"report", m.report_dir.string()}});
  }
  j["stages"] = nlohmann::json::array();
  for (const auto& s : stages) {
    j["stages"].push_back({{"name", s.name},
                           {"wall_s", s.wall_s},
                           {"cpu_s", s.cpu_s},
                           {"peak_rss_mb", s.peak_rss_mb}});
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
  out += "\n" + FormatStageTable(stages);
  return out;
}

DemoResult RunDemoJob(const DemoOptions& options) {
  options.Check();
  std::error_code ec;
  const fs::path out_dir = options.out_dir;
  SLSHADOW_THROW_IF(fs::exists(out_dir, ec) && !fs::exists(out_dir / kMarker, ec), out_dir.string(),
                    ": exists and is not an earlier demo output; choose another --out");
  const fs::path staging = TemporarySibling(out_dir);
  fs::create_directories(staging, ec);
  SLSHADOW_THROW_IF(ec, staging.string(), ": cannot create folder: ", ec.message());
  struct Cleanup {
    fs::path dir;
    bool keep = false;
    ~Cleanup() {
      std::error_code e;
      if (!keep) fs::remove_all(dir, e);
    }
  } cleanup{staging};

  DemoResult result;
  result.out_dir = out_dir;
  const bool verbose = options.verbose;

  // 1. Configuration: rig, scene (the part is generated in code), patterns.
  StageMeter meter("load rig, build scene, patterns");
  const Rig rig =
      options.rig_path.empty()
          ? RigFromConfig(ConfigNode::ParseYaml(kDemoRigYaml, "<embedded config/demo/rig.yaml>"))
          : LoadRig(options.rig_path);
  SLSHADOW_THROW_IF(rig.cameras.size() < 2 || !rig.projector, "demo rig '", rig.name,
                    "': needs two cameras and a projector");
  const Scene scene =
      options.scene_path.empty()
          ? SceneFromConfig(
                ConfigNode::ParseYaml(kDemoSceneYaml, "<embedded config/demo/scene.yaml>"),
                fs::current_path())
          : LoadScene(options.scene_path);
  const PatternSpec spec = options.patterns_path.empty()
                               ? PatternSpecFromConfig(ConfigNode::ParseYaml(
                                     kDemoPatternsYaml, "<embedded config/demo/patterns.yaml>"))
                               : LoadPatternSpec(options.patterns_path);
  const std::vector<cv::Mat> projector_images = GeneratePatterns(spec);
  const TriangleMesh truth =
      SceneSurface(scene, options.scene_path.empty() ? "demo scene" : options.scene_path.string());
  result.stages.push_back(meter.Stop());

  // 2. The virtual scan, in memory.
  meter = StageMeter("simulate (ray cast + patterns)");
  std::vector<GeometryBuffer> geometry;
  SimulateSummary sim_summary;
  const auto images = RenderScan(scene, rig, projector_images, &geometry, &sim_summary);
  result.stages.push_back(meter.Stop());
  if (verbose) std::printf("%s\n", sim_summary.BriefReport().c_str());

  // 3. Write it as an ImageSet, exactly as a real capture is written.
  meter = StageMeter("write ImageSet");
  {
    ImageSetWriterOptions writer_options;
    writer_options.encoding = ImageEncodingFromString(options.encoding);
    ImageSetWriter writer(staging / "scan", rig, PatternSpecToJson(spec), writer_options);
    const int num_cameras = static_cast<int>(images.size());
    const int num_patterns = spec.NumImages();
    std::vector<std::string> errors(static_cast<size_t>(num_cameras * num_patterns));
    cv::parallel_for_(cv::Range(0, num_cameras * num_patterns), [&](const cv::Range& range) {
      for (int k = range.start; k < range.end; ++k) {
        try {
          writer.Add(rig.cameras[k / num_patterns].name, k % num_patterns,
                     images[k / num_patterns][k % num_patterns], scene.radiometry.exposure_us,
                     ImageSource::kVirtual);
        } catch (const Error& e) {
          errors[k] = e.what();
        }
      }
    });
    for (const auto& e : errors) SLSHADOW_THROW_IF(!e.empty(), e);
    writer.SetExtra({{"generator", "slshadow demo"}, {"scene", SceneToJson(scene)}});
    writer.Commit();
  }
  WriteMesh(staging / "ground_truth.ply", truth);
  result.stages.push_back(meter.Stop());

  // 4. Read the ImageSet back and decode both cameras: the path a real capture takes.
  meter = StageMeter("read ImageSet + decode");
  const ImageSet image_set = ImageSet::Open(staging / "scan");
  const PatternSpec stored_spec = PatternSpecFromConfig(ConfigNode::FromJson(
      image_set.patterns(), (staging / "scan" / "manifest.json").string(), "patterns"));
  const std::string left = image_set.rig().cameras[0].name, right = image_set.rig().cameras[1].name;
  const ProjectorMap left_map = DecodePatterns(stored_spec, image_set.LoadCamera(left));
  const ProjectorMap right_map = DecodePatterns(stored_spec, image_set.LoadCamera(right));
  result.stages.push_back(meter.Stop());

  ReconstructOptions reconstruct_options;
  reconstruct_options.method = TriangulationMethodFromString(options.method);
  compare::CompareOptions compare_options;
  compare_options.threshold_mm = options.threshold_mm;
  meter = StageMeter("reference: sample ground truth");
  const compare::Reference reference =
      compare::ReferenceFromMesh(truth, "ground truth (scene meshes and planes)");
  const std::vector<Eigen::Vector3d> visible = LitVisibleSurface(geometry[0]);
  result.stages.push_back(meter.Stop());

  // 5. Reconstruct both modes, then compare and report them concurrently: each comparison is
  // parallel inside, but its report (PLY, map, charts) and parts of the comparison are serial.
  const std::vector<std::string> mode_names = {"projector", "stereo"};
  std::vector<Reconstruction> recs;
  for (const std::string& mode : mode_names) {
    meter = StageMeter("reconstruct " + mode);
    recs.push_back(mode == "projector" ? ReconstructWithProjector(image_set.rig(), left, left_map,
                                                                  reconstruct_options)
                                       : ReconstructStereo(image_set.rig(), left, right, left_map,
                                                           right_map, reconstruct_options));
    result.stages.push_back(meter.Stop());
    if (verbose) std::printf("%s\n", recs.back().summary.FullReport().c_str());
  }

  meter = StageMeter("compare + report (2 modes at once)");
  std::vector<DemoModeResult> modes(mode_names.size());
  std::vector<std::string> texts(mode_names.size());
  std::vector<std::exception_ptr> errors(mode_names.size());
  const auto run_mode = [&](size_t k) {
    try {
      const std::string& mode = mode_names[k];
      const auto t0 = std::chrono::steady_clock::now();
      compare::CompareResult cmp =
          compare::Compare(recs[k].cloud, reference, compare_options, mode + " reconstruction");
      recs[k].cloud = PointCloud();  // the compared copy lives on in cmp
      const auto t1 = std::chrono::steady_clock::now();
      compare::ReportOptions report_options;
      report_options.view = compare::ViewCamera{image_set.rig().cameras[0].model,
                                                image_set.rig().cameras[0].cam_from_rig};
      compare::WriteReport(staging / mode, cmp, report_options);
      const auto t2 = std::chrono::steady_clock::now();
      DemoModeResult& m = modes[k];
      m.mode = mode;
      m.points = cmp.compared.size();
      m.coverage = cmp.coverage;
      m.visible_coverage = VisibleCoverage(cmp, visible);
      m.mean_mm = cmp.c2c.mean_mm;
      m.rms_mm = cmp.c2c.rms_mm;
      m.p95_mm = cmp.c2c.p95_mm;
      m.max_mm = cmp.c2c.max_mm;
      m.outliers = cmp.c2c.outliers;
      m.outlier_fraction =
          cmp.c2c.count ? static_cast<double>(cmp.c2c.outliers) / static_cast<double>(cmp.c2c.count)
                        : 0;
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
  CommitDirectory(staging, out_dir, /*overwrite=*/true);
  cleanup.keep = true;
  return result;
}

}  // namespace slshadow::app
