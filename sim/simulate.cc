#include "sim/simulate.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <sstream>

#include <tbb/parallel_for.h>

#include "core/config.h"
#include "core/enum_names.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/progress.h"

namespace slshadow {
namespace {

// Projector images rendered per sweep over a geometry buffer (a 22-image Gray code + phase shift
// sequence is one sweep).
constexpr size_t kBatch = PatternRenderer::kMaxBatch;

// The projector images in batches of kBatch; each batch is interleaved once (on first use) and
// then rendered for every camera.
std::deque<PatternBatch> MakeBatches(const std::vector<cv::Mat>& images) {
  std::deque<PatternBatch> batches;
  for (size_t first = 0; first < images.size(); first += kBatch) {
    batches.emplace_back(std::vector<cv::Mat>(
        images.begin() + static_cast<std::ptrdiff_t>(first),
        images.begin() + static_cast<std::ptrdiff_t>(std::min(first + kBatch, images.size()))));
  }
  return batches;
}

double Since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

// Projector images only (the scene and rig are checked once, by the Simulator's set-up).
void CheckImages(const Rig& rig, const std::vector<cv::Mat>& images) {
  SLSHADOW_THROW_IF(!rig.projector, "rig '", rig.name,
                    "' has no projector: the simulator needs one");
  SLSHADOW_THROW_IF(images.empty(), "no projector images to render");
  for (size_t i = 0; i < images.size(); ++i) {
    const cv::Mat& m = images[i];
    SLSHADOW_THROW_IF(m.type() != CV_8UC1 || m.cols != rig.projector->model.width ||
                          m.rows != rig.projector->model.height,
                      "projector image ", i, " must be 8-bit single-channel ",
                      rig.projector->model.width, "x", rig.projector->model.height, " (got type ",
                      m.type(), ", ", m.cols, "x", m.rows, ")");
  }
}

}  // namespace

double SimulateSummary::MraysPerSecond() const {
  return geometry_seconds > 0 ? (primary_rays + shadow_rays) / geometry_seconds / 1e6 : 0;
}

double SimulateSummary::PrimaryMraysPerSecond() const {
  return geometry_seconds > 0 ? primary_rays / geometry_seconds / 1e6 : 0;
}

std::string SimulateSummary::BriefReport() const {
  std::ostringstream s;
  s.precision(3);
  s << cameras << " cameras x " << patterns << " patterns, " << triangles << " triangles: BVH "
    << build_seconds << " s, camera rays " << camera_rays_seconds << " s, geometry "
    << geometry_seconds << " s (" << (primary_rays + shadow_rays) / 1e6
    << " Mrays = " << primary_rays / 1e6 << " primary + " << shadow_rays / 1e6 << " shadow, "
    << MraysPerSecond() << " Mrays/s, " << PrimaryMraysPerSecond() << " M primary rays/s), images "
    << render_seconds << " s, ground truth " << write_seconds << " s, total " << total_seconds
    << " s";
  return s.str();
}

namespace {

// Viewing rays depend only on the camera model and the supersampling; computing them costs a
// Newton undistortion per sample (~0.04 CPU s per 1920x1200 camera), so the last few are kept
// for the next scan by the same cameras (kCached entries, ~28 MB each at 1920x1200, 1 spp).
std::shared_ptr<const CameraRays> CachedCameraRays(const CameraModel& model, int samples_per_axis) {
  struct Entry {
    int width, height, spp;
    std::array<double, CameraModel::kNumParams> params;
    std::shared_ptr<CameraRays> rays;  // handed out as const
  };
  constexpr size_t kCached = 4;
  static std::mutex mutex;
  static std::deque<Entry> cache;
  {
    const std::lock_guard<std::mutex> lock(mutex);
    for (const Entry& e : cache) {
      if (e.width == model.width && e.height == model.height && e.spp == samples_per_axis &&
          e.params == model.params) {
        return e.rays;
      }
    }
  }
  // A full cache gives up its oldest entry; when no scan holds that one any more, its storage
  // (already faulted in) takes the new rays: a series of scans by changing rigs (tolerance
  // studies) allocates nothing.
  CameraRays storage;
  {
    const std::lock_guard<std::mutex> lock(mutex);
    if (cache.size() >= kCached) {
      if (cache.back().rays.use_count() == 1) storage = std::move(*cache.back().rays);
      cache.pop_back();
    }
  }
  auto rays =
      std::make_shared<CameraRays>(ComputeCameraRays(model, samples_per_axis, std::move(storage)));
  const std::lock_guard<std::mutex> lock(mutex);
  cache.push_front(Entry{model.width, model.height, samples_per_axis, model.params, rays});
  if (cache.size() > kCached) cache.pop_back();
  return rays;
}

}  // namespace

Simulator::Simulator(const Scene& scene, const Rig& rig, TraceMode mode, bool ground_truth)
    : scene_(scene), rig_(rig) {
  const auto start = std::chrono::steady_clock::now();
  scene.Check("scene '" + scene.name + "'");
  rig.Check("rig '" + rig.name + "'");
  SLSHADOW_THROW_IF(!rig.projector, "rig '", rig.name,
                    "' has no projector: the simulator needs one");
  const RayCaster caster(scene);
  setup_.build_seconds = caster.build_seconds();
  Trace(caster, mode, ground_truth);
  setup_.total_seconds = Since(start);
}

Simulator::Simulator(const RayCaster& caster, const Rig& rig, TraceMode mode, bool ground_truth)
    : scene_(caster.scene()), rig_(rig) {
  const auto start = std::chrono::steady_clock::now();
  rig.Check("rig '" + rig.name + "'");
  SLSHADOW_THROW_IF(!rig.projector, "rig '", rig.name,
                    "' has no projector: the simulator needs one");
  Trace(caster, mode, ground_truth);
  setup_.total_seconds = Since(start);
}

void Simulator::Trace(const RayCaster& caster, TraceMode mode, bool ground_truth) {
  setup_.triangles = caster.num_triangles();
  setup_.cameras = static_cast<int>(rig_.cameras.size());
  Progress progress("trace", static_cast<int64_t>(rig_.cameras.size()), false);
  for (size_t c = 0; c < rig_.cameras.size(); ++c) {
    const auto t = std::chrono::steady_clock::now();
    const std::shared_ptr<const CameraRays> rays =
        CachedCameraRays(rig_.cameras[c].model, scene_.layers.supersampling);
    setup_.camera_rays_seconds += Since(t);
    if (geometry_.empty()) geometry_.reserve(rig_.cameras.size());  // moved in, never copied
    geometry_.push_back(
        TraceGeometry(caster, rig_, static_cast<int>(c), *rays, mode, ground_truth));
    setup_.geometry_seconds += geometry_.back().seconds;
    setup_.primary_rays += geometry_.back().primary_rays;
    setup_.shadow_rays += geometry_.back().shadow_rays;
    progress.Advance();
  }
}

Simulator::~Simulator() = default;

std::vector<std::vector<cv::Mat>> Simulator::Render(const std::vector<cv::Mat>& projector_images,
                                                    const Scene* scene,
                                                    SimulateSummary* summary) const {
  const Scene& s = scene ? *scene : scene_;
  SLSHADOW_THROW_IF(
      s.layers.supersampling != scene_.layers.supersampling ||
          s.layers.projector_defocus.enabled != scene_.layers.projector_defocus.enabled ||
          s.objects.size() != scene_.objects.size(),
      "Simulator::Render: the scene's geometry-affecting settings differ from the set-up's");
  s.radiometry.Check("scene '" + s.name + "'");
  s.layers.Check("scene '" + s.name + "'");
  CheckImages(rig_, projector_images);
  const auto start = std::chrono::steady_clock::now();
  std::vector<std::vector<cv::Mat>> images(geometry_.size());
  const std::deque<PatternBatch> batches = MakeBatches(projector_images);
  Progress progress("render", static_cast<int64_t>(geometry_.size() * projector_images.size()),
                    false);
  for (size_t c = 0; c < geometry_.size(); ++c) {
    const PatternRenderer renderer(s, rig_, static_cast<int>(c), geometry_[c]);
    images[c].reserve(projector_images.size());
    for (size_t b = 0; b < batches.size(); ++b) {
      std::vector<cv::Mat> rendered =
          renderer.RenderBatch(batches[b], static_cast<int>(b * kBatch));
      progress.Advance(static_cast<int64_t>(rendered.size()));
      for (cv::Mat& m : rendered) images[c].push_back(std::move(m));
    }
  }
  if (summary) {
    summary->render_seconds += Since(start);
    summary->patterns = static_cast<int>(projector_images.size());
  }
  return images;
}

std::vector<std::vector<cv::Mat>> RenderScan(const Scene& scene, const Rig& rig,
                                             const std::vector<cv::Mat>& projector_images,
                                             std::vector<GeometryBuffer>* geometry,
                                             SimulateSummary* summary, TraceMode mode) {
  const auto start = std::chrono::steady_clock::now();
  CheckImages(rig, projector_images);
  Simulator sim(scene, rig, mode);
  SimulateSummary sum = sim.setup();
  auto images = sim.Render(projector_images, nullptr, &sum);
  if (geometry) {
    for (GeometryBuffer& g : sim.ReleaseGeometry()) geometry->push_back(std::move(g));
  }
  sum.total_seconds = Since(start);
  if (summary) *summary = sum;
  return images;
}

void SimulateOptions::Check() const {
  SLSHADOW_THROW_IF(writer.png_compression < 0 || writer.png_compression > 9,
                    "simulate options: png_compression: must be in [0, 9] (got ",
                    writer.png_compression, ")");
}

nlohmann::json SimulateOptionsToJson(const SimulateOptions& o) {
  return {{"encoding", ToString(o.writer.encoding)},
          {"png_compression", o.writer.png_compression},
          {"overwrite", o.writer.overwrite},
          {"write_ground_truth", o.write_ground_truth},
          {"trace_mode", ToString(o.trace_mode)}};
}

SimulateOptions SimulateOptionsFromConfig(const ConfigNode& node) {
  if (!node.IsObject()) node.Fail("expected a mapping of simulate options");
  node.RejectUnknownKeys(
      {"encoding", "png_compression", "overwrite", "write_ground_truth", "trace_mode"});
  SimulateOptions o;
  if (node.Has("encoding")) {
    try {
      o.writer.encoding = ImageEncodingFromString(node["encoding"].AsString());
    } catch (const Error& e) {
      node["encoding"].Fail(e.what());
    }
  }
  o.writer.png_compression =
      static_cast<int>(node.GetInt("png_compression", o.writer.png_compression));
  o.writer.overwrite = node.GetBool("overwrite", o.writer.overwrite);
  o.write_ground_truth = node.GetBool("write_ground_truth", o.write_ground_truth);
  if (node.Has("trace_mode")) o.trace_mode = EnumFromConfig(node["trace_mode"], kTraceModeNames);
  try {
    o.Check();
  } catch (const Error& e) {
    SLSHADOW_THROW(node.file(), node.path().empty() ? "" : ": ", node.path(), ": ", e.what());
  }
  return o;
}

ScanProvenance VirtualScanProvenance(const Scene& scene, const SimulateOptions& options,
                                     const std::string& generator) {
  ScanProvenance p;
  p.generator = generator;
  p.scene_config = scene.source_config;
  p.scene_base_dir = scene.source_dir.string();
  p.scene_summary = SceneToJson(scene);
  p.simulate = SimulateOptionsToJson(options);
  return p;
}

SimulateSummary SimulateScan(const Scene& scene, const Rig& rig,
                             const std::vector<cv::Mat>& projector_images,
                             const nlohmann::json& pattern_spec,
                             const std::filesystem::path& out_dir, const SimulateOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  options.Check();
  scene.Check("scene '" + scene.name + "'");
  rig.Check("rig '" + rig.name + "'");
  CheckImages(rig, projector_images);
  SLSHADOW_THROW_IF(std::filesystem::exists(out_dir) && !options.writer.overwrite, out_dir.string(),
                    ": already exists (pass --overwrite to replace it)");
  SimulateSummary sum;
  ImageSetWriter writer(out_dir, rig, pattern_spec, options.writer);
  nlohmann::json extra =
      ExtraWithProvenance(VirtualScanProvenance(scene, options, "slshadow simulate"));
  // The radiometry as rendered: reference_distance_mm 0 (the rig's working distance) resolved.
  // (The provenance keeps the scene as configured, so a redo rebuilds the same scene.)
  extra["radiometry_as_rendered"] = {
      {"reference_distance_mm", scene.radiometry.reference_distance_mm > 0
                                    ? scene.radiometry.reference_distance_mm
                                    : rig.working_distance_mm}};
  writer.SetExtra(extra);

  SLSHADOW_THROW_IF(options.shared_bvh && &options.shared_bvh->scene() != &scene,
                    "SimulateScan: the shared BVH was built for another Scene object");
  std::optional<RayCaster> own_caster;
  if (!options.shared_bvh) {
    own_caster.emplace(scene);
    sum.build_seconds = own_caster->build_seconds();
  }
  const RayCaster& caster = options.shared_bvh ? *options.shared_bvh : *own_caster;
  sum.triangles = caster.num_triangles();
  sum.cameras = static_cast<int>(rig.cameras.size());
  sum.patterns = static_cast<int>(projector_images.size());
  Progress progress("simulate",
                    static_cast<int64_t>(rig.cameras.size() * (projector_images.size() + 1)));
  const std::deque<PatternBatch> batches = MakeBatches(projector_images);
  for (size_t c = 0; c < rig.cameras.size(); ++c) {
    const std::string& name = rig.cameras[c].name;
    auto t = std::chrono::steady_clock::now();
    const std::shared_ptr<const CameraRays> rays =
        CachedCameraRays(rig.cameras[c].model, scene.layers.supersampling);
    sum.camera_rays_seconds += Since(t);
    const GeometryBuffer g = TraceGeometry(caster, rig, static_cast<int>(c), *rays,
                                           options.trace_mode, options.write_ground_truth);
    sum.geometry_seconds += g.seconds;
    sum.primary_rays += g.primary_rays;
    sum.shadow_rays += g.shadow_rays;
    progress.Advance();
    t = std::chrono::steady_clock::now();
    const PatternRenderer renderer(scene, rig, static_cast<int>(c), g);
    // Render a batch in one sweep, then encode its images in parallel (Add is thread-safe).
    for (size_t b = 0; b < batches.size(); ++b) {
      const size_t first = b * kBatch;
      const std::vector<cv::Mat> rendered =
          renderer.RenderBatch(batches[b], static_cast<int>(first));
      tbb::parallel_for(size_t{0}, rendered.size(), [&](size_t k) {
        writer.Add(name, static_cast<int>(first + k), rendered[k], scene.radiometry.exposure_us,
                   ImageSource::kVirtual);
        progress.Advance();
      });
    }
    sum.render_seconds += Since(t);
    if (options.write_ground_truth) {
      t = std::chrono::steady_clock::now();
      WriteGroundTruth(g, writer.staging_dir() / "ground_truth" / name);
      sum.write_seconds += Since(t);
    }
  }
  const auto t = std::chrono::steady_clock::now();
  writer.Commit();
  sum.write_seconds += Since(t);
  sum.total_seconds = Since(start);
  return sum;
}

}  // namespace slshadow
