// What the stages of `slshadow shadow` share (RunShadowOnImages, workflows/twin/twin.cc): the run's
// state, filled stage by stage, and the comparison stages (workflows/twin/twin_compare.cc).
#pragma once

#include <cstddef>
#include <exception>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "compare/mesh_distance.h"
#include "core/file_util.h"
#include "core/mesh.h"
#include "core/rig.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct.h"
#include "sim/scene.h"
#include "sim/simulate.h"
#include "workflows/twin/diagnose.h"
#include "workflows/twin/internal/twin_pose.h"
#include "workflows/twin/internal/twin_report.h"
#include "workflows/twin/physics_fit.h"
#include "workflows/twin/twin.h"

namespace slshadow::twin::internal {

// One task on a thread of its own, joined (its exception rethrown) by Join() or, on the way out
// of an exception, by the destructor (the exception then dropped).
class BackgroundTask {
 public:
  BackgroundTask() = default;
  BackgroundTask(const BackgroundTask&) = delete;
  BackgroundTask& operator=(const BackgroundTask&) = delete;
  ~BackgroundTask() {
    if (thread_.joinable()) thread_.join();
  }
  template <typename F>
  void Start(F&& task) {
    thread_ = std::thread([this, task = std::forward<F>(task)] {
      try {
        task();
      } catch (...) {
        error_ = std::current_exception();
      }
    });
  }
  void Join() {
    if (thread_.joinable()) thread_.join();
    if (error_) std::rethrow_exception(std::exchange(error_, nullptr));
  }

 private:
  std::thread thread_;
  std::exception_ptr error_;
};

// The signed distance of every point to the mesh (MeshDistance::Closest), in parallel.
std::vector<double> SignedC2M(const compare::MeshDistance& mesh,
                              const std::vector<Eigen::Vector3d>& points);

struct Reconstructions {
  std::vector<ProjectorMap> maps;  // per camera
  std::vector<std::pair<std::string, Reconstruction>> modes;
};

// At most this many points of a cloud are compared (and written), so that C2M stays a small part
// of the run.
inline constexpr size_t kComparedPoints = 400000;

// What the stages of RunShadowOnImages share, in the order they fill it. The maps' writer comes
// last: on the way out of an exception it is joined before what it reads (and the staging
// folder) goes away.
struct ShadowRun {
  ShadowRun(const Rig& rig, const PatternSpec& spec, const ShadowPart& part,
            const ShadowOptions& options, const std::filesystem::path& out_dir)
      : rig(rig), spec(spec), part(part), options(options), out_dir(out_dir) {}

  const Rig& rig;
  const PatternSpec& spec;
  const ShadowPart& part;
  const ShadowOptions& options;
  const std::filesystem::path& out_dir;
  std::vector<std::string> cameras;  // cameras with images, in rig order
  std::vector<const std::vector<cv::Mat>*> real_images;
  bool sixteen = false;
  double fs_dn = 255.0;
  ShadowResult result;
  // 1. The real scan.
  Reconstructions real_rec;
  // 2. Pose: the refinement (when it ran) and the part's distance field at the pose used, for
  // the fitness and the clouds.
  std::optional<PoseRefinement> pose_fit;
  Rigid3d rig_from_part;
  TriangleMesh surface_in_rig;
  std::optional<compare::MeshDistance> part_distance_at_pose;
  // 3. The twin.
  Scene twin;
  std::vector<cv::Mat> projector_images;
  Rig twin_rig;
  std::unique_ptr<Simulator> simulator;
  std::vector<CameraData> data;
  double projector_depth_mm = 0;
  PhysicsFit fit;
  // 4. Virtual re-scan.
  Scene fitted;
  std::vector<std::vector<cv::Mat>> rendered;
  std::vector<const std::vector<cv::Mat>*> twin_images;
  Reconstructions twin_rec;
  // 5. Images and clouds.
  std::vector<float> response;
  std::vector<CameraEvidence> evidence;
  ShadowMaps maps;
  std::vector<ModeClouds> clouds;
  std::vector<ModeEvidence> mode_evidence;
  PoseEvidence pose_evidence;                   // the pose stage's figures, for the diagnosis
  std::vector<std::vector<double>> mode_diffs;  // real - twin C2M per mode, for the charts
  std::vector<double> mode_lod95;
  // 7. Report folder.
  std::optional<StagingDirectory> staged;
  nlohmann::json maps_json = nlohmann::json::array();
  BackgroundTask maps_writer;
};

// 5. The comparison stages (workflows/twin/twin_compare.cc): the images, their maps drawn in the
// background, the clouds.
void CompareImages(ShadowRun& run);
void StartMapsWriter(ShadowRun& run);
void CompareClouds(ShadowRun& run);

}  // namespace slshadow::twin::internal
