// A whole virtual scan: every projector image seen by every camera of the rig, written as an
// ImageSet exactly as a real capture (source "virtual"; the scan's provenance, with the scene
// and these options, in the manifest's `extra.provenance`: core/provenance.h), plus ground truth
// per camera. The renderer takes the projector images
// themselves (CV_8UC1 at the projector's resolution), so this library does not depend on how
// they were made; the CLI makes them with patterns/.
//
// Ground truth, in DIR/ground_truth/<camera>/ (docs/formats.md, "Simulator ground truth"):
// Float maps are NumPy .npy files (version 1.0, '<f4', C order; shape (rows, cols) or
// (rows, cols, 3)), bit-exact and readable with numpy.load; OpenCV's float TIFF is not lossless
// for 3 channels (it writes LogLuv).
//   depth_mm.npy          (H, W)    z of the surface in the camera frame, NaN where none
//   point_in_rig_mm.npy   (H, W, 3) surface point in the rig frame, NaN where none
//   normal_in_rig.npy     (H, W, 3) unit normal facing the camera, NaN where none
//   proj_x.npy, proj_y.npy (H, W)   true projector coordinates (px), NaN where not lit
//   status.png            CV_8UC1   PixelStatus: 0 valid (lit), 1 shadow (not lit or no surface)
//   visibility.png        CV_8UC1   0 no surface, 1 surface not lit by the projector, 2 lit
//   object_id.png         CV_16UC1  1 + index into the scene's objects, 0 where no surface
//   surface.ply           the visible surface: one point per pixel with a surface (rig frame),
//                         normals, scalars object_id, lit, proj_x, proj_y, pixel_x, pixel_y
#pragma once

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/image_set.h"
#include "core/point_cloud.h"
#include "core/projector_map.h"
#include "core/provenance.h"
#include "core/rig.h"
#include "sim/renderer.h"
#include "sim/scene.h"

namespace slshadow {

class ConfigNode;

struct SimulateOptions {
  ImageSetWriterOptions writer;    // encoding (PNG, PGM = fastest lossless, TIFF), overwrite
  bool write_ground_truth = true;  // DIR/ground_truth/<camera>/...; false: not even computed
  TraceMode trace_mode = TraceMode::kPacket16;
  // A BVH built once for many scans of this scene (RayCaster of the same Scene object), or null:
  // SimulateScan builds its own.
  const RayCaster* shared_bvh = nullptr;
  void Check() const;
};

// SimulateOptions as a file (docs/formats.md "Simulate options"): {encoding, png_compression,
// overwrite, write_ground_truth, trace_mode: packet16 | single_ray}; shared_bvh is a run-time
// object and is not written (null after reading). Missing fields keep their defaults, unknown
// keys are rejected, the result is Check()ed. Throws slshadow::Error naming file, field, value.
nlohmann::json SimulateOptionsToJson(const SimulateOptions& options);
SimulateOptions SimulateOptionsFromConfig(const ConfigNode& node);

// The provenance of a virtual scan of `scene` rendered with `options` (core/provenance.h): the
// scene's source config and folder, its summary, the options; `generator` names the writer.
ScanProvenance VirtualScanProvenance(const Scene& scene, const SimulateOptions& options,
                                     const std::string& generator);

struct SimulateSummary {
  int cameras = 0;
  int patterns = 0;
  int64_t triangles = 0;
  int64_t primary_rays = 0;
  int64_t shadow_rays = 0;
  double build_seconds = 0;        // BVH build
  double camera_rays_seconds = 0;  // undistorted viewing rays (cacheable per rig)
  double geometry_seconds = 0;     // geometry passes, all cameras
  double render_seconds = 0;       // pattern passes, all images (in SimulateScan: with encoding)
  double write_seconds = 0;        // ground truth and manifest
  double total_seconds = 0;
  // Rays per second of the geometry passes. Counted: every ray Embree traces, i.e. primary
  // (camera) rays plus shadow (occlusion) rays; shadow rays are cast only where the surface faces
  // the projector inside its image. PrimaryMraysPerSecond counts camera rays only.
  double MraysPerSecond() const;
  double PrimaryMraysPerSecond() const;
  std::string BriefReport() const;
};

// Keeps what does not change between scans of one scene by one rig: the BVH, the cameras'
// viewing rays and their geometry buffers (ground truth). A scan is then only the pattern passes
// (DESIGN.md: one ray-casting pass plus N memory-bound passes), e.g. for many pattern sets,
// noise seeds or layer settings that do not change geometry (all but supersampling and
// projector defocus, which are baked into the geometry buffers). Throws like RenderScan. The
// scene and the rig must outlive it.
class Simulator {
 public:
  // Builds the BVH of `scene`, traces the rig's cameras, then frees the BVH. ground_truth =
  // false: geometry buffers without the ground-truth maps (TraceGeometry), images only.
  Simulator(const Scene& scene, const Rig& rig, TraceMode mode = TraceMode::kPacket16,
            bool ground_truth = true);
  // Traces with a BVH built once by the caller, e.g. for many scans of one part from other rig
  // poses or by other rigs: a scan then costs its geometry passes and pattern passes, not the
  // build. The scene is `caster.scene()`; `caster` is needed only
  // during construction.
  Simulator(const RayCaster& caster, const Rig& rig, TraceMode mode = TraceMode::kPacket16,
            bool ground_truth = true);
  ~Simulator();
  int num_cameras() const { return static_cast<int>(geometry_.size()); }
  const GeometryBuffer& geometry(int camera) const {
    return geometry_.at(static_cast<size_t>(camera));
  }
  // Hands the geometry buffers over (no copy); the Simulator has no cameras afterwards.
  std::vector<GeometryBuffer> ReleaseGeometry() { return std::move(geometry_); }
  // Timings of the set-up: BVH, camera rays, geometry passes.
  const SimulateSummary& setup() const { return setup_; }
  // images[camera][pattern] for `scene` (the constructor's scene, or a copy of it with other
  // radiometry / layers of the kinds listed above). `summary` gets render_seconds added.
  std::vector<std::vector<cv::Mat>> Render(const std::vector<cv::Mat>& projector_images,
                                           const Scene* scene = nullptr,
                                           SimulateSummary* summary = nullptr) const;

 private:
  const Scene& scene_;
  const Rig& rig_;
  std::vector<GeometryBuffer> geometry_;
  SimulateSummary setup_;
  void Trace(const RayCaster& caster, TraceMode mode, bool ground_truth);
};

// Renders all images in memory: images[camera][pattern]. `geometry`, if not null, receives the
// geometry buffers (ground truth) per camera.
std::vector<std::vector<cv::Mat>> RenderScan(const Scene& scene, const Rig& rig,
                                             const std::vector<cv::Mat>& projector_images,
                                             std::vector<GeometryBuffer>* geometry = nullptr,
                                             SimulateSummary* summary = nullptr,
                                             TraceMode mode = TraceMode::kPacket16);

// Renders and writes the ImageSet (atomically: nothing appears at out_dir until complete).
// `pattern_spec` is stored as the manifest's `patterns` (what patterns/ PatternSpecToJson gives).
// Throws slshadow::Error on an invalid scene / rig, projector images of the wrong size, or an
// existing out_dir without options.writer.overwrite.
SimulateSummary SimulateScan(const Scene& scene, const Rig& rig,
                             const std::vector<cv::Mat>& projector_images,
                             const nlohmann::json& pattern_spec,
                             const std::filesystem::path& out_dir,
                             const SimulateOptions& options = {});

// Ground truth of one camera as files (layout above) and back (sim/ground_truth.cc).
void WriteGroundTruth(const GeometryBuffer& geometry, const std::filesystem::path& dir);
struct GroundTruth {
  cv::Mat depth_mm, point_in_rig, normal_in_rig, visibility,
      object_id;           // object_id CV_32SC1, -1 none
  ProjectorMap projector;  // status valid / shadow; quality 0
};
GroundTruth ReadGroundTruth(const std::filesystem::path& dir);
// The visible surface of one camera as a cloud (rig frame) with the scalars listed above.
PointCloud VisibleSurface(const GeometryBuffer& geometry);

// Frees the simulator's cache of recycled image and geometry blocks (up to ~640 MB kept after a
// scan so the next one does not fault its pages in again): for a process done simulating.
void ReleaseSimulatorPool();

}  // namespace slshadow
