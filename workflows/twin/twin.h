// Real vs virtual: the digital shadow of one real scan (issue 13; `slshadow shadow`).
//
//   1. reconstruct the real ImageSet (projector mode with its first camera; stereo with its first
//      two cameras when it has two);
//   2. the part's pose in the rig: ICP of the part model to the real cloud (stereo's when there
//      is one: it does not depend on the projector's calibration) from a given pose, global
//      registration + ICP without one, or a given pose as is; fitness and RMSE reported, and the
//      job stops with a clear message when they are not credible;
//   3. the twin's physics fitted from the real images (workflows/twin/physics_fit.h), a layer kept
//   only
//      when the images need it;
//   4. the virtual re-scan: the same rig, pattern spec and exposure, the part at its pose with the
//      fitted physics, reconstructed with the same settings;
//   5. images compared (per pattern intensity; decoded projector coordinates against the twin's
//      ground truth; pixels valid in one and not the other) and clouds (real vs part, virtual vs
//      part: signed C2M; real vs virtual: the difference of the two at the nearest virtual point);
//   6. diagnosis by signatures (workflows/twin/diagnose.h);
//   7. a report folder: report.json (docs/formats.md, "Shadow report"), summary.txt, maps/*.png
//      (with colour bars), charts/*.png, clouds/*.ply (scalar field c2m_part_mm), written
//      atomically.
#pragma once

#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "compare/registration.h"
#include "core/mesh.h"
#include "core/rig.h"
#include "core/rigid3.h"
#include "core/stage_meter.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct.h"
#include "reconstruct/strict_policy.h"
#include "report/html_report.h"
#include "sim/scene.h"
#include "workflows/twin/diagnose.h"
#include "workflows/twin/physics_fit.h"

namespace slshadow::twin {

// The part: its objects (in the part's own frame: each object's rig_from_object is read as
// part_from_object) with their albedo, and its surface for registration and C2M.
struct ShadowPart {
  std::string source;
  Scene scene;
  TriangleMesh surface;  // part frame, mm
};
// A mesh file (.stl/.ply/.obj; one object, uniform albedo 0.8) or a scene file (.yaml/.yml/.json:
// its objects in the part frame, e.g. a plane with a printed checkerboard; meshes and planes
// only). Throws slshadow::Error naming the file.
ShadowPart LoadShadowPart(const std::filesystem::path& path);
// A part's planes are split into this many cells per side for its surface (SceneSurface), so
// registration samples and C2M see the whole plane.
inline constexpr int kPartPlaneCells = 16;

enum class PoseSource { kGivenFixed, kGivenRefined, kRegistered };
std::string ToString(PoseSource source);  // "given", "given+icp", "global+icp"

struct ShadowOptions {
  // rig_from_part: with refine_pose a starting guess for ICP, else used as it is. Absent: global
  // registration + ICP.
  std::optional<Rigid3d> rig_from_part;
  bool refine_pose = true;
  double min_fitness = 0.5;  // credible registration: fitness at least this
  double max_rmse_mm = 0.5;  // and inlier RMSE at most this
  DecodeOptions decode;
  // Real and twin alike: the library's defaults, as `slshadow reconstruct`.
  ReconstructOptions reconstruct;
  PhysicsFitOptions physics;
  bool fit_physics = true;  // false: the twin keeps the part file's radiometry
  DiagnoseOptions diagnose;
  uint64_t noise_seed = 7919;  // the twin's noise (when the noise layer is kept)
  bool write_clouds = true;
  bool overwrite = false;  // replace an existing output folder
  // --strict (reconstruct/strict_policy.h): the real scan's reconstructions must pass their
  // calibration check and keep min_point_share of their decoded pixels, else the job ends before
  // the twin is built, with nothing written.
  StrictOptions strict;
  // report.html beside report.json (report/html_report.h), written into the staged folder.
  bool write_html = true;
  report::HtmlOptions html;
  void Check() const;  // throws slshadow::Error
};

struct ShadowResult {
  nlohmann::json report;  // what report.json holds
  PhysicsFit physics;
  Diagnosis diagnosis;
  Rigid3d rig_from_part;
  std::vector<StageMeasurement> stages;
  std::string Summary() const;  // the one-screen summary (summary.txt)
};

// The whole job on images in memory (real[camera] = that camera's images in spec order).
// `out_dir` empty: nothing is written. Throws slshadow::Error on bad input and on a registration
// that is not credible.
ShadowResult RunShadowOnImages(const Rig& rig, const PatternSpec& spec,
                               const std::map<std::string, std::vector<cv::Mat>>& real,
                               const ShadowPart& part, const ShadowOptions& options,
                               const std::filesystem::path& out_dir = {},
                               const std::string& source = "in memory",
                               const std::vector<StageMeasurement>& earlier_stages = {});

// Reads the ImageSet folder (pattern spec from its manifest; the rig too unless `rig` is given,
// e.g. a calibration made after the capture) and runs the job.
ShadowResult RunShadow(const std::filesystem::path& image_set_dir, const ShadowPart& part,
                       const ShadowOptions& options, const std::filesystem::path& out_dir,
                       const Rig* rig = nullptr);

}  // namespace slshadow::twin
