// What a sweep shard keeps from one job to the next so that jobs differing only in a noise seed
// (or in what is measured of them) pay only for what differs (workflows/studies/sweep.h):
//
//   NoiseFreeImages     the noise-free irradiance of every pattern seen by every camera, rendered
//                       once per geometry group, pattern sequence and noise-free scene; each
//                       seed then costs only the sensor-noise and quantisation pass (the
//                       renderer's own: sim/sensor_noise.h QuantizeIrradiance), written into
//                       image buffers reused from job to job.
//   GroundTruthScorer   the ground-truth surface's distance hierarchy (compare::MeshDistance),
//                       its area samples and the lit visible surface, built once per geometry
//                       group, and from the group's second job on a grid of cells near the
//                       surface listing the triangles that can be closest to a point in each
//                       (compare/c2m_grid.h), kept job to job; each cloud is
//                       then measured against them.
//
// Reconstruction needs nothing of its own here: what it computes from the rig and the image size
// alone (undistorted pixel rays, rectified-to-source pixel maps, grid and scratch buffers) is
// already kept process-wide between reconstructions (reconstruct/ray_cache.h, the rectified
// source grids of reconstruct/stereo_matcher.cc, its per-thread buffers and grid pool).
//
// Both give exactly what the per-job path gives: the images bit for bit what
// sim::Simulator::Render (and so `slshadow simulate`) renders for the job's scene, the figures
// the same doubles as MeasureAccuracy(compare::Compare(...)). tests/studies/sweep_reuse_test.cc
// checks both against those oracles.
#pragma once

#include "compare/compare.h"
#include "compare/mesh_distance.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "sim/scene.h"
#include "sim/simulate.h"
#include "workflows/pipeline/scan_pipeline.h"

#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include <memory>
#include <string>
#include <vector>

namespace slshadow::compare {
class C2mGrid;
}  // namespace slshadow::compare

namespace slshadow::studies {

// The noise-free irradiance images of one pattern sequence seen by every camera of a Simulator.
class NoiseFreeImages {
 public:
  // What the irradiance depends on beyond the geometry group: the scene without its name and its
  // noise layer, and the pattern spec (both as the job's JSON). Jobs with equal keys in one
  // geometry group share the images.
  static std::string Key(const nlohmann::json& scene, const nlohmann::json& patterns);

  // Renders images[camera][pattern] of `projector_images` without noise or quantisation. `scene`
  // must be one the simulator accepts (Simulator::Render); it is read here only.
  NoiseFreeImages(const Simulator& simulator, const Scene& scene, const Rig& rig,
                  const std::vector<cv::Mat>& projector_images);

  // images[camera][pattern] with the noise and ADC of `scene` (its seed), into `images`, whose
  // buffers are reused when their sizes match: Simulator::Render's images for `scene`, bit for
  // bit.
  void Render(const Scene& scene, std::vector<std::vector<cv::Mat>>* images) const;

  int num_cameras() const { return static_cast<int>(irradiance_.size()); }
  int num_patterns() const {
    return irradiance_.empty() ? 0 : static_cast<int>(irradiance_[0].size());
  }

 private:
  std::vector<std::vector<cv::Mat>> irradiance_;  // [camera][pattern], CV_32FC1
};

// The accuracy figures of clouds against one ground-truth surface, with the hierarchy and the
// samples built once.
class GroundTruthScorer {
 public:
  // `surface`: the ground truth (SceneSurface), sampled as compare::ReferenceFromMesh samples it;
  // `visible`: the lit visible surface (LitVisibleSurface). `what` names the surface in errors.
  GroundTruthScorer(TriangleMesh surface, std::vector<Eigen::Vector3d> visible,
                    const std::string& what);
  ~GroundTruthScorer();

  // MeasureAccuracy(mode, compare::Compare(cloud, reference, options, mode), visible) with
  // MeasureFigureUncertainty of its deviations, the same doubles, for options without registration,
  // M3C2 or artefacts (what a sweep job's compare options may hold: anything else goes through
  // compare::Compare). Throws slshadow::Error on an empty cloud, as compare::Compare does.
  pipeline::ModeAccuracy Measure(const PointCloud& cloud, const compare::CompareOptions& options,
                                 const std::string& mode) const;

  // Announces the clouds about to be measured (one job's), before Measure is called on them; not
  // to be called while Measure runs. From the second call on, when at least kGridJobs jobs
  // (`jobs_left`, this one included) are still to be measured and the clouds are dense on the
  // ground truth's triangles (compare/c2m_grid.h), the signed distances of the
  // points come from a grid of cells near the surface (compare::MeshDistance's doubles, in a
  // fraction of its time). The call that makes the grid builds the cells of `clouds`; each later
  // call builds the cells that the points measured since fell in unbuilt (those points were
  // answered by compare::MeshDistance): a noise sweep's clouds fall in the same cells job after job
  // (the cells cost about two jobs' worth of distances). Otherwise Measure asks
  // compare::MeshDistance for every point. Results are the same either way.
  static constexpr int kGridJobs = 4;
  void Prepare(const std::vector<const PointCloud*>& clouds, int jobs_left = kGridJobs);

  const compare::Reference& reference() const { return reference_; }

 private:
  compare::Reference reference_;
  compare::MeshDistance distance_;
  std::vector<Eigen::Vector3d> visible_;
  // The surface samples and the visible points in one uniform grid, for both coverages at once.
  struct SampleGrid;
  std::unique_ptr<const SampleGrid> samples_;
  int prepared_ = 0;  // calls of Prepare
  std::unique_ptr<compare::C2mGrid> grid_;
};

}  // namespace slshadow::studies
