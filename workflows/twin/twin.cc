#include "workflows/twin/twin.h"

#include "compare/neighbour_grid.h"
#include "workflows/pipeline/scan_pipeline.h"
#include "workflows/twin/internal/twin_images.h"
#include "workflows/twin/internal/twin_pose.h"
#include "workflows/twin/internal/twin_report.h"
#include "workflows/twin/internal/twin_run.h"
#include "workflows/twin/internal/twin_stats.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <exception>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <utility>

#include <Eigen/Dense>
#include <opencv2/core/utility.hpp>

#include "calib/calibration_io.h"
#include "compare/compare.h"
#include "compare/mesh_distance.h"
#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/image_io.h"
#include "core/image_set.h"
#include "core/kdtree.h"
#include "core/point_cloud.h"
#include "core/pose_io.h"
#include "sim/scene_surface.h"
#include "sim/simulate.h"

namespace slshadow::twin {
namespace fs = std::filesystem;

// The report folder's writers (workflows/twin/twin_report.cc).
using internal::CompareFrames;
using internal::CompareProjectorCoordinates;
using internal::ComputeSampleStats;
using internal::FrameAgreement;
using internal::LitPartMask;
using internal::ModeClouds;
using internal::SampleStats;
using internal::ShadowMaps;
using internal::StagesToJson;
using internal::WriteShadowCharts;
using internal::WriteShadowClouds;
using internal::WriteShadowMaps;

// The run's state and the comparison stages (workflows/twin/twin_compare.cc).
using internal::BackgroundTask;
using internal::CompareClouds;
using internal::CompareImages;
using internal::kComparedPoints;
using internal::Reconstructions;
using internal::ShadowRun;
using internal::SignedC2M;
using internal::StartMapsWriter;

namespace {

constexpr const char* kFormat = "slshadow-shadow-report";
constexpr int kVersion = 1;

// The rig file's pose (core/pose_io.h) with the rotation also as a Rodrigues vector, for readers
// that think in OpenCV's rvec.
nlohmann::json ReportPoseJson(const Rigid3d& p) {
  nlohmann::json j = PoseToJson(p);
  const Eigen::Vector3d r = RotationVectorFromQuaternion(p.rotation);
  j["rotation_rvec_rad"] = {r.x(), r.y(), r.z()};
  return j;
}

// `for_pose`: the registration cloud (stereo's when there is one, else the projector mode's) is
// kept whole; every other cloud is made with at most kComparedPoints points, as compared.
Reconstructions DecodeAndReconstruct(const Rig& rig, const PatternSpec& spec,
                                     const std::vector<std::string>& cameras,
                                     const std::vector<const std::vector<cv::Mat>*>& images,
                                     const ShadowOptions& options, bool for_pose) {
  Reconstructions out;
  const bool stereo = cameras.size() >= 2 && spec.code_x;
  for (size_t c = 0; c < cameras.size(); ++c)
    out.maps.push_back(DecodePatterns(spec, *images[c], options.decode));
  // Only the clouds and summaries are read: each organised grid (~100 MB at 1920x1200) goes back
  // to reconstruct/'s grid pool as soon as its cloud exists, so the next reconstruction (the
  // twin's) reuses its pages instead of faulting in fresh ones.
  const auto release_grid = [](Reconstruction& r) { DenseGrid released = std::move(r.grid); };
  out.modes.emplace_back("projector",
                         ReconstructWithProjector(rig, cameras[0], out.maps[0], options.reconstruct,
                                                  for_pose && !stereo ? 0 : kComparedPoints));
  release_grid(out.modes.back().second);
  if (stereo) {
    out.modes.emplace_back("stereo",
                           ReconstructStereo(rig, cameras[0], cameras[1], out.maps[0], out.maps[1],
                                             options.reconstruct, for_pose ? 0 : kComparedPoints));
    release_grid(out.modes.back().second);
  }
  return out;
}

}  // namespace

std::string ToString(PoseSource source) {
  switch (source) {
    case PoseSource::kGivenFixed:
      return "given";
    case PoseSource::kGivenRefined:
      return "given+icp";
    case PoseSource::kRegistered:
      return "global+icp";
  }
  return "?";
}

ShadowPart LoadShadowPart(const fs::path& path) {
  ShadowPart part;
  part.source = path.string();
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext == ".yaml" || ext == ".yml" || ext == ".json") {
    part.scene = LoadScene(path);
  } else if (ext == ".stl" || ext == ".ply" || ext == ".obj") {
    auto mesh = std::make_shared<TriangleMesh>(ReadMesh(path));
    CheckSceneMesh(*mesh, path.string(), /*allow_non_manifold=*/true);
    SceneObject object;
    object.name = path.stem().string();
    object.type = ObjectType::kMesh;
    object.mesh = mesh;
    object.albedo.value = 0.8;
    part.scene.name = object.name;
    part.scene.objects.push_back(object);
  } else {
    SLSHADOW_THROW(path.string(), ": unknown part format '", ext,
                   "' (expected .stl, .ply, .obj or a scene .yaml/.json)");
  }
  part.surface = SceneSurface(part.scene, path.string(), kPartPlaneCells);
  return part;
}

void ShadowOptions::Check() const {
  SLSHADOW_THROW_IF(!(min_fitness >= 0 && min_fitness <= 1),
                    "shadow: min_fitness must be in [0, 1] (got ", min_fitness, ")");
  SLSHADOW_THROW_IF(!(max_rmse_mm > 0), "shadow: max_rmse_mm must be > 0 (got ", max_rmse_mm, ")");
  decode.Check();
  reconstruct.Check();
  physics.Check();
  diagnose.Check();
  strict.Check();
  html.Check();
}

namespace {

// The checks, the cameras with images, the report's header.
void BeginRun(ShadowRun& run, const std::map<std::string, std::vector<cv::Mat>>& real,
              const std::string& source, const std::vector<StageMeasurement>& earlier_stages) {
  const Rig& rig = run.rig;
  const PatternSpec& spec = run.spec;
  const ShadowPart& part = run.part;
  const ShadowOptions& options = run.options;
  const fs::path& out_dir = run.out_dir;
  options.Check();
  spec.Check();
  SLSHADOW_THROW_IF(!rig.projector, "shadow: the rig '", rig.name, "' has no projector");
  SLSHADOW_THROW_IF(part.surface.empty(), "shadow: the part '", part.source, "' has no surface");
  std::error_code ec;
  if (!out_dir.empty()) {
    SLSHADOW_THROW_IF(fs::exists(out_dir, ec) && !options.overwrite, out_dir.string(),
                      ": exists; choose another --out or pass --overwrite");
  }
  // Cameras with images, in rig order.
  std::vector<std::string>& cameras = run.cameras;
  std::vector<const std::vector<cv::Mat>*>& real_images = run.real_images;
  for (const auto& cam : rig.cameras) {
    auto it = real.find(cam.name);
    if (it == real.end()) continue;
    SLSHADOW_THROW_IF(static_cast<int>(it->second.size()) != spec.NumImages(), "shadow: camera '",
                      cam.name, "' has ", it->second.size(), " images, the pattern spec needs ",
                      spec.NumImages());
    cameras.push_back(cam.name);
    real_images.push_back(&it->second);
  }
  SLSHADOW_THROW_IF(cameras.empty(), "shadow: no camera of the rig has images");
  run.sixteen = real_images[0]->front().depth() == CV_16U;
  run.fs_dn = run.sixteen ? 65535.0 : 255.0;

  ShadowResult& result = run.result;
  result.stages = earlier_stages;
  nlohmann::json& report = result.report;
  report["format"] = kFormat;
  report["version"] = kVersion;
  report["image_set"] = source;
  report["part"] = part.source;
  report["cameras"] = cameras;
}

// 1. The real scan.
void ScanReal(ShadowRun& run) {
  StageMeter meter("real: decode + reconstruct");
  run.real_rec = DecodeAndReconstruct(run.rig, run.spec, run.cameras, run.real_images, run.options,
                                      /*for_pose=*/true);
  run.result.stages.push_back(meter.Stop());
  std::vector<ReconstructSummary> summaries;
  for (const auto& [mode, rec] : run.real_rec.modes) summaries.push_back(rec.summary);
  EnforceStrict(summaries, run.options.strict, "shadow: the real scan");
}

// 2. Pose, after PlacePart found it: fitness and RMSE of the final pose, measured the same way
// for every source: share of the registration cloud within 1 mm of the part, RMS of those
// distances. Not credible with a pose given: the given pose is used.
void JudgePose(ShadowRun& run, PoseSource pose_source, const compare::RegistrationResult& reg,
               Rigid3d rig_from_part) {
  const ShadowPart& part = run.part;
  const ShadowOptions& options = run.options;
  nlohmann::json& report = run.result.report;
  const PointCloud& reg_cloud = run.real_rec.modes.back().second.cloud;
  TriangleMesh& surface_in_rig = run.surface_in_rig;
  std::optional<compare::MeshDistance>& part_distance_at_pose = run.part_distance_at_pose;
  surface_in_rig = part.surface;
  surface_in_rig.Transform(rig_from_part.rotation.toRotationMatrix(), rig_from_part.translation);
  // The part's distance field at the pose used: built once, for the fitness and the clouds.
  part_distance_at_pose.emplace(surface_in_rig);
  const compare::MeshDistance& registered = *part_distance_at_pose;
  std::vector<Eigen::Vector3d> sample;
  for (size_t i = 0; i < reg_cloud.size(); i += std::max<size_t>(1, reg_cloud.size() / 100000))
    sample.push_back(reg_cloud.points[i]);
  const std::vector<double> d = SignedC2M(registered, sample);
  int64_t in = 0;
  double ss = 0;
  for (double x : d) {
    if (std::abs(x) < 1.0) ++in, ss += x * x;
  }
  const double fitness = d.empty() ? 0.0 : static_cast<double>(in) / static_cast<double>(d.size());
  const double rmse = in ? std::sqrt(ss / static_cast<double>(in)) : 0.0;
  report["pose"] = {{"source", ToString(pose_source)},
                    {"rig_from_part", ReportPoseJson(rig_from_part)},
                    {"registration_cloud", run.real_rec.modes.back().first},
                    {"fitness", fitness},
                    {"inlier_rmse_mm", rmse},
                    {"gate_mm", 1.0},
                    {"min_fitness", options.min_fitness},
                    {"max_rmse_mm", options.max_rmse_mm}};
  if (pose_source != PoseSource::kGivenFixed) {
    report["pose"]["registration"] = {{"ran", true},
                                      {"fitness", reg.fitness},
                                      {"inlier_rmse_mm", reg.inlier_rmse_mm},
                                      {"icp_iterations", reg.icp_iterations},
                                      {"converged", reg.converged},
                                      {"global_found", reg.global_found}};
  }
  if (options.rig_from_part) {
    report["pose"]["moved_from_given_mm"] =
        (rig_from_part.translation - options.rig_from_part->translation).norm();
    report["pose"]["rotated_from_given_deg"] =
        compare::RotationDifferenceDeg(rig_from_part, *options.rig_from_part);
  }
  if (run.pose_fit)
    report["pose"]["refinement"] = internal::PoseRefinementToJson(
        *run.pose_fit, options.rig_from_part
                           ? std::optional<Rigid3d>(options.rig_from_part->Inverse())
                           : std::nullopt);
  const bool credible = in > 0 && fitness >= options.min_fitness && rmse <= options.max_rmse_mm;
  report["pose"]["credible"] = credible;
  PoseEvidence& evidence = run.pose_evidence;
  evidence.known = true;
  evidence.source = ToString(pose_source);
  evidence.fitness = fitness;
  evidence.inlier_rmse_mm = rmse;
  if (pose_source == PoseSource::kRegistered) {
    evidence.candidate_fitness = reg.candidate_fitness;
    evidence.alternative_fitness = reg.alternative_fitness;
    evidence.alternative_rotation_deg = reg.alternative_rotation_deg;
    evidence.alternative_translation_mm = reg.alternative_translation_mm;
    report["pose"]["registration"]["global_candidates"] = reg.global_candidates;
    if (reg.alternative_fitness >= 0) {
      report["pose"]["registration"]["candidate_fitness"] = reg.candidate_fitness;
      report["pose"]["registration"]["alternative"] = {
          {"fitness", reg.alternative_fitness},
          {"rotation_deg", reg.alternative_rotation_deg},
          {"translation_mm", reg.alternative_translation_mm}};
    }
  }
  // Not credible: stop, unless a pose was given; then the job goes on from the given pose
  // (a scan corrupted e.g. by a wrong frame still deserves its diagnosis), and says so.
  SLSHADOW_THROW_IF(!credible && !options.rig_from_part,
                    "shadow: the part's pose is not credible (", ToString(pose_source),
                    "): fitness ", fitness, " (need >= ", options.min_fitness, "), inlier RMSE ",
                    rmse, " mm over ", in, " points (need <= ", options.max_rmse_mm,
                    "); give a pose guess with --pose, or check the part file");
  if (pose_source == PoseSource::kGivenFixed) {
    report["pose"]["used"] = "given";  // no registration ran: fitness and RMSE are for information
  } else if (!credible) {
    rig_from_part = *options.rig_from_part;
    surface_in_rig = part.surface;
    surface_in_rig.Transform(rig_from_part.rotation.toRotationMatrix(), rig_from_part.translation);
    part_distance_at_pose.emplace(surface_in_rig);  // `registered` is not used after this
    report["pose"]["used"] = "given";
    report["pose"]["rig_from_part"] = ReportPoseJson(rig_from_part);
    report["pose"]["warning"] =
        "registration not credible (the real cloud is far from the part); the given pose is used "
        "as it is";
  } else {
    report["pose"]["used"] = ToString(pose_source);
  }
  run.result.rig_from_part = rig_from_part;
  run.rig_from_part = rig_from_part;
}

// 2. Pose: given, or registered to the real cloud (from the given pose when there is one) and
// polished; then judged.
void PlacePart(ShadowRun& run) {
  StageMeter meter("pose");
  const ShadowPart& part = run.part;
  const ShadowOptions& options = run.options;
  // Wall and CPU seconds of the stage's parts, for report.json's pose.seconds.
  nlohmann::json seconds = nlohmann::json::object();
  StageTimer timer;
  const auto lap = [&](const char* name) {
    double wall = 0, cpu = 0;
    timer.Elapsed(&wall, &cpu);
    seconds[name] = {{"wall", wall}, {"cpu", cpu}};
    timer.Restart();
  };
  const PointCloud& reg_cloud = run.real_rec.modes.back().second.cloud;  // stereo when there is one
  SLSHADOW_THROW_IF(reg_cloud.size() < 100 && !(options.rig_from_part && !options.refine_pose),
                    "shadow: the real scan reconstructed only ", reg_cloud.size(),
                    " points; cannot place the part");
  PoseSource pose_source;
  compare::RegistrationResult reg;
  Rigid3d rig_from_part;
  nlohmann::json icp_skipped;
  if (options.rig_from_part && !options.refine_pose) {
    pose_source = PoseSource::kGivenFixed;
    rig_from_part = *options.rig_from_part;
  } else {
    const compare::MeshDistance part_distance(part.surface);
    Rigid3d part_from_rig_guess;
    std::vector<Rigid3d> starts;
    bool run_icp = true;
    if (options.rig_from_part) {
      pose_source = PoseSource::kGivenRefined;
      part_from_rig_guess = options.rig_from_part->Inverse();
      starts.push_back(part_from_rig_guess);
      // ICP widens the basin of a rough guess. A given pose whose points already sit within a
      // fraction of the refinement's first scale is inside that basin: ICP, which stops at its
      // sampled correspondences, could only hand the refinement a worse second start.
      const internal::PoseRefineOptions refine_options;
      const internal::PoseFit fit = internal::MeasurePoseFit(
          part_distance, reg_cloud.points, part_from_rig_guess, refine_options.gate_mm, 20000);
      if (internal::WithinRefinementBasin(fit, refine_options)) {
        run_icp = false;
        icp_skipped = {{"fitness", fit.fitness},
                       {"median_abs_mm", fit.median_abs_mm},
                       {"points", fit.points},
                       {"reason",
                        "the given pose is within the refinement's basin (>= 90 % of "
                        "the points within the gate, median |C2M| below a quarter of "
                        "the first scale): ICP not run"}};
      }
      lap("given pose fit");
    } else {
      pose_source = PoseSource::kRegistered;
    }
    if (run_icp) {
      const compare::Reference reference =
          compare::ReferenceFromMesh(part.surface, part.source, 100000);
      lap("reference");
      compare::RegistrationOptions ro;
      ro.method = options.rig_from_part ? compare::RegistrationMethod::kIcp
                                        : compare::RegistrationMethod::kGlobalIcp;
      std::vector<Eigen::Vector3d> cloud = reg_cloud.points;
      if (options.rig_from_part) {
        for (auto& p : cloud) p = part_from_rig_guess * p;
      }
      std::vector<Eigen::Vector3d> normals;
      normals.reserve(reference.cloud.size());
      for (const auto& n : reference.cloud.normals) normals.push_back(n.cast<double>());
      reg = compare::Register(cloud, reference.cloud.points, normals, ro);
      lap("registration");
      // ICP stops at its sampled correspondences: the pose is refined on the exact surface, from
      // the better of the given pose and ICP's, and never left worse than the given one
      // (workflows/twin/internal/twin_pose.h).
      starts.push_back(reg.reference_from_cloud * part_from_rig_guess);
    }
    run.pose_fit =
        internal::RefinePoseOnSurface(part_distance, part.surface, reg_cloud.points, starts);
    rig_from_part = run.pose_fit->part_from_rig.Inverse();
    lap("refinement");
  }
  JudgePose(run, pose_source, reg, rig_from_part);
  if (!icp_skipped.is_null()) {
    run.result.report["pose"]["registration"] = {{"ran", false}, {"skipped", icp_skipped}};
  }
  lap("judgement");
  run.result.report["pose"]["seconds"] = seconds;
  run.result.stages.push_back(meter.Stop());
}

// 3. The twin: the part at its pose; geometry once (focused), then the physics fit.
void BuildTwin(ShadowRun& run) {
  StageMeter meter("twin geometry + physics fit");
  const PatternSpec& spec = run.spec;
  const ShadowPart& part = run.part;
  const ShadowOptions& options = run.options;
  const std::vector<std::string>& cameras = run.cameras;
  Scene& twin = run.twin;
  twin = part.scene;
  twin.name = "twin of " + part.scene.name;
  for (auto& o : twin.objects) o.rig_from_object = run.rig_from_part * o.rig_from_object;
  twin.radiometry.adc_bits = run.sixteen ? 16 : 8;
  twin.layers.noise_enabled = false;
  twin.layers.projector_defocus.enabled = false;
  twin.layers.response_enabled = false;
  twin.layers.ambient = 0;
  run.projector_images = GeneratePatterns(spec);
  Rig& twin_rig = run.twin_rig;
  twin_rig = run.rig;
  run.simulator = std::make_unique<Simulator>(twin, twin_rig);
  std::vector<CameraData>& data = run.data;
  data.resize(cameras.size());
  run.projector_depth_mm = twin_rig.working_distance_mm;
  {
    std::vector<double> depths;
    const GeometryBuffer& g0 = run.simulator->geometry(twin_rig.CameraIndex(cameras[0]));
    for (int y = 0; y < g0.height; y += 8) {
      for (int x = 0; x < g0.width; x += 8) {
        if (g0.visibility.at<uint8_t>(y, x) != 2) continue;
        const cv::Vec3f p = g0.point_in_rig.at<cv::Vec3f>(y, x);
        depths.push_back(
            (twin_rig.projector->cam_from_rig * Eigen::Vector3d(p[0], p[1], p[2])).z());
      }
    }
    SLSHADOW_THROW_IF(depths.empty(), "shadow: the part at its pose is not seen lit by camera '",
                      cameras[0], "'");
    std::nth_element(depths.begin(),
                     depths.begin() + static_cast<std::ptrdiff_t>(depths.size() / 2), depths.end());
    run.projector_depth_mm = depths[depths.size() / 2];
  }
  for (size_t c = 0; c < cameras.size(); ++c) {
    data[c].camera = cameras[c];
    data[c].real = *run.real_images[c];
    data[c].geometry = &run.simulator->geometry(twin_rig.CameraIndex(cameras[c]));
    WhiteBlackImages(spec, data[c].real, &data[c].white, &data[c].black);
  }
  PhysicsFit& fit = run.fit;
  if (options.fit_physics) {
    fit = FitPhysics(spec, twin, data, options.physics);
  } else {
    PhysicsLayer e;
    e.name = "exposure";
    e.kept = true;
    e.value = part.scene.radiometry.exposure_fraction;
    e.reason = "from the part file (--no-physics-fit)";
    fit.layers.push_back(e);
  }
  run.result.stages.push_back(meter.Stop());
}

// 4. Virtual re-scan with the fitted physics; defocus from its fringes against the real ones.
void RenderTwin(ShadowRun& run) {
  StageMeter meter("twin: render (+ defocus fit)");
  const PatternSpec& spec = run.spec;
  const ShadowOptions& options = run.options;
  const std::vector<std::string>& cameras = run.cameras;
  const std::vector<cv::Mat>& projector_images = run.projector_images;
  const Rig& twin_rig = run.twin_rig;
  PhysicsFit& fit = run.fit;
  std::vector<CameraData>& data = run.data;
  Scene& fitted = run.fitted;
  std::vector<std::vector<cv::Mat>>& rendered = run.rendered;
  fitted = fit.Apply(run.twin, twin_rig, run.projector_depth_mm, options.noise_seed);
  // The image layers the renderer does not model (black level, illumination field, global light).
  const std::vector<double> pattern_means = PatternMeans(projector_images);
  const auto apply_image_layers = [&] {
    for (const auto& name : cameras) {
      ApplyImageLayers(fit, spec, pattern_means, name,
                       &rendered[static_cast<size_t>(twin_rig.CameraIndex(name))]);
    }
  };
  const auto render_all = [&] {
    rendered.clear();
    rendered = run.simulator->Render(projector_images, &fitted);
    apply_image_layers();
  };
  if (options.fit_physics) {
    // The defocus fit reads only the white, black and finest fringe frames: with white and black
    // frames in the sequence only those are rendered for it (the rest once the physics is final).
    std::vector<int> fit_frames;
    if (spec.WhiteFrameIndex() >= 0 && spec.BlackFrameIndex() >= 0) {
      fit_frames = ModulationFrames(spec);
      fit_frames.push_back(spec.WhiteFrameIndex());
      fit_frames.push_back(spec.BlackFrameIndex());
    }
    if (fit_frames.empty()) {
      render_all();
    } else {
      std::vector<cv::Mat> subset;
      for (int i : fit_frames) subset.push_back(projector_images[static_cast<size_t>(i)]);
      const std::vector<std::vector<cv::Mat>> part = run.simulator->Render(subset, &fitted);
      rendered.assign(part.size(), std::vector<cv::Mat>(projector_images.size()));
      for (size_t cam = 0; cam < part.size(); ++cam) {
        for (size_t k = 0; k < fit_frames.size(); ++k)
          rendered[cam][static_cast<size_t>(fit_frames[k])] = part[cam][k];
      }
      apply_image_layers();
    }
    for (size_t c = 0; c < cameras.size(); ++c)
      data[c].twin = rendered[static_cast<size_t>(twin_rig.CameraIndex(cameras[c]))];
    FitDefocus(spec, data, options.physics, &fit);
    for (auto& d : data) d.twin.clear();
    if (fit.Kept("defocus")) {
      fitted = fit.Apply(run.twin, twin_rig, run.projector_depth_mm, options.noise_seed);
      for (auto& d : data)
        d.twin_modulation = d.twin_white = d.twin_black = cv::Mat(), d.geometry = nullptr;
      rendered.clear();
      run.simulator = std::make_unique<Simulator>(fitted, twin_rig);
      render_all();
    } else if (!fit_frames.empty()) {
      for (auto& d : data) d.twin_modulation = d.twin_white = d.twin_black = cv::Mat();
      render_all();
    }
  } else {
    render_all();
  }
  run.result.stages.push_back(meter.Stop());
  nlohmann::json& report = run.result.report;
  report["physics"] = {{"layers", fit.ToJson()}, {"twin_scene", SceneToJson(fitted)}};
  report["physics"]["projector_depth_mm"] = run.projector_depth_mm;
}

// 4. The twin's images decoded and reconstructed like the real ones.
void ScanTwin(ShadowRun& run) {
  StageMeter meter("twin: decode + reconstruct");
  for (const auto& name : run.cameras)
    run.twin_images.push_back(&run.rendered[static_cast<size_t>(run.twin_rig.CameraIndex(name))]);
  run.twin_rec = DecodeAndReconstruct(run.twin_rig, run.spec, run.cameras, run.twin_images,
                                      run.options, /*for_pose=*/false);
  run.result.stages.push_back(meter.Stop());
}

// 6. Diagnosis.
void DiagnoseRun(ShadowRun& run) {
  StageMeter meter("diagnose");
  ShadowResult& result = run.result;
  result.diagnosis = Diagnose(run.spec, run.projector_images, run.response, run.fit, run.evidence,
                              run.mode_evidence, run.options.diagnose, run.pose_evidence);
  result.report["diagnosis"] = result.diagnosis.ToJson();
  result.physics = run.fit;
  result.stages.push_back(meter.Stop());
}

// 7. Report folder (with no folder: the stages into the report only).
void WriteReportFolder(ShadowRun& run) {
  ShadowResult& result = run.result;
  nlohmann::json& report = result.report;
  if (run.out_dir.empty()) {
    report["stages"] = StagesToJson(result.stages);
    return;
  }
  StageMeter meter("write report");
  std::error_code ec;
  const fs::path& staging = run.staged->path();
  // The clouds and charts first: the maps are still being drawn in the background (since the
  // images were compared), and writing the clouds does not wait for PLplot.
  if (run.options.write_clouds) {
    fs::create_directories(staging / "clouds", ec);
    WriteShadowClouds(staging / "clouds", &run.clouds);
  }
  fs::create_directories(staging / "charts", ec);
  SLSHADOW_THROW_IF(ec, (staging / "charts").string(), ": cannot create folder: ", ec.message());
  WriteShadowCharts(staging, run.clouds, run.mode_diffs, run.mode_lod95, &report);
  run.maps_writer.Join();
  report["maps"] = run.maps_json;
  result.stages.push_back(meter.Stop());
  report["stages"] = StagesToJson(result.stages);
  WriteTextFileAtomically(staging / "report.json", report.dump(2) + "\n");
  WriteTextFileAtomically(staging / "summary.txt", result.Summary());
  if (run.options.write_html) {
    report::HtmlOptions html = run.options.html;
    html.part_surface = std::make_shared<const TriangleMesh>(run.part.surface);
    report::WriteHtmlReport(staging, html);
  }
  run.staged->Commit(run.options.overwrite);
}

}  // namespace

ShadowResult RunShadowOnImages(const Rig& rig, const PatternSpec& spec,
                               const std::map<std::string, std::vector<cv::Mat>>& real,
                               const ShadowPart& part, const ShadowOptions& options,
                               const fs::path& out_dir, const std::string& source,
                               const std::vector<StageMeasurement>& earlier_stages) {
  ShadowRun run(rig, spec, part, options, out_dir);
  BeginRun(run, real, source, earlier_stages);
  ScanReal(run);           // 1. The real scan.
  PlacePart(run);          // 2. Pose.
  BuildTwin(run);          // 3. The twin: geometry and physics fit.
  RenderTwin(run);         // 4. Virtual re-scan,
  ScanTwin(run);           //    decoded and reconstructed.
  CompareImages(run);      // 5. Images,
  StartMapsWriter(run);    //    their maps drawn in the background,
  CompareClouds(run);      //    clouds.
  DiagnoseRun(run);        // 6. Diagnosis.
  WriteReportFolder(run);  // 7. Report folder.
  return std::move(run.result);
}

ShadowResult RunShadow(const fs::path& image_set_dir, const ShadowPart& part,
                       const ShadowOptions& options, const fs::path& out_dir, const Rig* rig) {
  StageMeter meter("read ImageSet");
  const ImageSet set = ImageSet::Open(image_set_dir);
  const PatternSpec spec = PatternSpecFromConfig(
      ConfigNode::FromJson(set.patterns(), (image_set_dir / "manifest.json").string(), "patterns"));
  std::map<std::string, std::vector<cv::Mat>> images;
  for (const auto& name : set.CameraNames()) images[name] = set.LoadCamera(name);
  const StageMeasurement read = meter.Stop();
  return RunShadowOnImages(rig ? *rig : set.rig(), spec, images, part, options, out_dir,
                           image_set_dir.string(), {read});
}

}  // namespace slshadow::twin
