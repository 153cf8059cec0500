#include "workflows/multiview/project_merge.h"

#include <malloc.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>

#include "compare/distances.h"
#include "compare/statistics.h"
#include "core/config.h"
#include "core/enum_names.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/image_set.h"
#include "core/pose_io.h"
#include "core/string_printf.h"
#include "report/html_report.h"
#include "workflows/pipeline/scan_pipeline.h"

namespace slshadow::multiview {
namespace fs = std::filesystem;

namespace {

double SecondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

std::optional<Rigid3d> RecordedTruth(const ImageSet& image_set) {
  const nlohmann::json& extra = image_set.extra();
  if (!extra.is_object() || !extra.contains("view") || !extra["view"].is_object() ||
      !extra["view"].contains("part_from_rig_true"))
    return std::nullopt;
  return PoseFromConfig(ConfigNode::FromJson(extra["view"]["part_from_rig_true"],
                                             (image_set.dir() / "manifest.json").string(),
                                             "extra.view.part_from_rig_true"));
}

ViewReconstructOptions ViewOptions(const ProjectMergeOptions& options) {
  return {options.mode, options.decode, options.reconstruct, options.max_points_per_view};
}

// The view's reconstruction: read from options.reconstructions when it is there (and made from
// the same images with the same options), else reconstructed (and written there). `source` says
// which.
ViewReconstruction ObtainView(const fs::path& project_dir, const ProjectView& pv,
                              const ImageSet& image_set, const ProjectMergeOptions& options,
                              std::string* source) {
  const ViewReconstructOptions vo = ViewOptions(options);
  std::optional<ViewReconstructionKey> key;
  if (!options.reconstructions.empty()) {
    key = ViewReconstructionKey::For(pv.spec.name, project_dir / pv.Folder(), vo);
    if (std::optional<ViewReconstruction> stored =
            ReadViewReconstruction(options.reconstructions, *key)) {
      *source = "read from " + (options.reconstructions / pv.spec.name).string();
      return std::move(*stored);
    }
  }
  ViewReconstruction rec = ReconstructProjectView(image_set, vo);
  ReleaseReconstructionBuffers();
  malloc_trim(0);
  *source = "reconstructed";
  if (key) {
    WriteViewReconstruction(options.reconstructions, *key, rec);
    *source += ", written to " + (options.reconstructions / pv.spec.name).string();
  }
  return rec;
}

nlohmann::json OptionalPose(const std::optional<Rigid3d>& pose) {
  return pose ? PoseToJson(*pose) : nlohmann::json(nullptr);
}

}  // namespace

constexpr EnumName<PoseSource> kPoseSourceNames[] = {{PoseSource::kRegistered, "registered"},
                                                     {PoseSource::kAxis, "axis"}};

std::string ToString(PoseSource value) { return EnumToString(value, kPoseSourceNames); }

PoseSource PoseSourceFromString(const std::string& name) {
  return EnumFromString("poses", name, kPoseSourceNames);
}

void ProjectMergeOptions::Check() const {
  SLSHADOW_THROW_IF(!std::isfinite(table_crop_mm), "merge: table_crop_mm must be finite (got ",
                    table_crop_mm, ")");
  reconstruct.Check();
  decode.Check();
  registration.Check();
  cad.Check();
  mesh_options.Check();
}

namespace {

// Rotation angle (deg) of estimated * truth^-1 and the displacement it gives `centre` (mm).
void PoseError(const Rigid3d& estimated, const Rigid3d& truth, const Eigen::Vector3d& centre,
               double* deg, double* mm) {
  const Rigid3d delta = estimated * truth.Inverse();
  *deg = Eigen::AngleAxisd(delta.rotation).angle() * 180.0 / M_PI;
  *mm = (delta * centre - centre).norm();
}

}  // namespace

ProjectMergeResult MergeProject(const fs::path& project_dir, const TriangleMesh* cad_in_part,
                                const ProjectMergeOptions& options) {
  const auto t_start = std::chrono::steady_clock::now();
  options.Check();
  const ProjectManifest project = LoadProject(project_dir);
  const std::string what = (project_dir / "project.json").string();
  const bool refine = options.poses == PoseSource::kRegistered;
  ProjectMergeResult result;
  result.project = project_dir.string();
  result.refined = refine;
  result.pose_method =
      refine ? "turntable axis and table angles (hand-placed views: their guess, else global "
               "registration), refined by pairwise ICP and the pose graph"
             : "turntable axis and table angles; hand-placed views from their guess (not "
               "registered: --poses axis)";

  // 1.-2. Reconstruct every complete view, one at a time; initial poses.
  std::vector<PointCloud> clouds(project.views.size());
  // The table points cropped from each view: not merged, but where the view saw the table, the
  // space in front of it is empty (the fusion's free-space check, merge.h step 4).
  std::vector<PointCloud> backdrops(project.views.size());
  std::vector<std::vector<DarkPixels>> dark(project.views.size());
  for (size_t i = 0; i < project.views.size(); ++i) {
    const ProjectView& pv = project.views[i];
    MergedView v;
    v.name = pv.spec.name;
    v.table_deg = pv.spec.table_deg;
    SLSHADOW_THROW_IF(pv.spec.placed_on_table && !project.rig.turntable, what, ": view '",
                      pv.spec.name,
                      "': placed_on_table, but the rig has no turntable axis (rig.turntable) to "
                      "give the table plane");
    if (pv.spec.OnTable()) {
      v.part_from_rig_initial =
          project.rig.turntable->RigFromTableTurn(*pv.spec.table_deg).Inverse();
    } else {
      v.part_from_rig_initial = pv.spec.part_from_rig_guess;
    }
    if (pv.state != ViewState::kComplete) {
      v.reason = "missing: the view was not captured (project state missing)";
    } else if (!v.part_from_rig_initial && !refine) {
      v.reason =
          "no pose: placed by hand without part_from_rig_guess, and --poses axis registers no "
          "view";
    } else {
      const auto t0 = std::chrono::steady_clock::now();
      const ImageSet image_set = ImageSet::Open(project_dir / pv.Folder());
      SLSHADOW_THROW_IF(RigToJson(image_set.rig()) != RigToJson(project.rig),
                        (project_dir / pv.Folder() / "manifest.json").string(),
                        ": rig differs from the project's (", what, ")");
      v.part_from_rig_true = RecordedTruth(image_set);
      ViewReconstruction rec = ObtainView(project_dir, pv, image_set, options, &v.reconstruction);
      dark[i] = std::move(rec.dark);
      if (pv.spec.StandsOnTable() && options.table_crop_mm >= 0) {
        // The table plane does not move when the table turns, nor when the part is put down on
        // it by hand: the same plane in every view that stands on the table.
        const TurntableAxis& axis = *project.rig.turntable;
        const Eigen::Vector3d up = axis.direction_in_rig.normalized();
        std::vector<bool> keep(rec.cloud.size());
        for (size_t k = 0; k < rec.cloud.size(); ++k)
          keep[k] = up.dot(rec.cloud.points[k] - axis.point_in_rig_mm) >= options.table_crop_mm;
        for (size_t k = 0; k < rec.cloud.size(); ++k)
          if (!keep[k]) backdrops[i].points.push_back(rec.cloud.points[k]);
        rec.cloud = rec.cloud.Select(keep);
      }
      v.accepted_points = rec.accepted_points;
      v.reconstruct_seconds = SecondsSince(t0);
      result.reconstruct_seconds += v.reconstruct_seconds;
      v.points = rec.cloud.size();
      if (rec.cloud.size() <= static_cast<size_t>(options.registration.normal_neighbors)) {
        v.reason = StringPrintf("too few points: the reconstruction kept %zu (need more than %d)",
                                rec.cloud.size(), options.registration.normal_neighbors);
      } else {
        clouds[i] = std::move(rec.cloud);
      }
    }
    result.views.push_back(std::move(v));
  }
  std::vector<ViewCloud> inputs;
  for (size_t i = 0; i < result.views.size(); ++i) {
    const MergedView& v = result.views[i];
    if (clouds[i].empty()) continue;
    inputs.push_back({v.name, &clouds[i], v.part_from_rig_initial.value_or(Rigid3d()),
                      v.part_from_rig_initial.has_value(), v.table_deg,
                      backdrops[i].empty() ? nullptr : &backdrops[i]});
    result.registration_view.push_back(static_cast<int>(i));
  }
  SLSHADOW_THROW_IF(inputs.empty(), what, ": no view can be merged (",
                    result.views.empty() ? "no views" : result.views.front().reason, ")");

  // 3.-4. Registration and fusion.
  auto t0 = std::chrono::steady_clock::now();
  MergeOptions mo = options.registration;
  mo.refine = refine;
  if (!mo.turntable) mo.turntable = project.rig.turntable;
  result.registration = MergeViews(inputs, mo);
  MergeResult& reg = result.registration;
  for (size_t k = 0; k < reg.views.size(); ++k) {
    const ViewPose& p = reg.views[k];
    MergedView& v = result.views[static_cast<size_t>(result.registration_view[k])];
    if (!v.part_from_rig_initial && p.accepted) v.part_from_rig_initial = p.part_from_rig_initial;
    if (!p.accepted) {
      v.reason = "registration: " + p.reason;
      continue;
    }
    v.merged = true;
    v.part_from_rig = p.part_from_rig;
    v.anchor = p.anchor;
    v.pairs = p.pairs;
    v.residual_rms_mm = p.residual_rms_mm;
    v.noise_mm = p.noise_mm;
    v.sigma_rotation_deg = p.sigma_rotation_deg;
    v.sigma_translation_mm = p.sigma_translation_mm;
    v.graph_sigma_rotation_deg = p.graph_sigma_rotation_deg;
    v.graph_sigma_translation_mm = p.graph_sigma_translation_mm;
    v.prior_directions = p.prior_directions;
    v.table_angle_deg = p.table_angle_deg;
    v.table_angle_correction_deg = p.table_angle_correction_deg;
    v.sigma_table_angle_deg = p.sigma_table_angle_deg;
  }
  result.merged = std::move(reg.merged);
  reg.merged = PointCloud();
  std::vector<float> view_index(reg.point_view.size());
  for (size_t k = 0; k < view_index.size(); ++k)
    view_index[k] =
        static_cast<float>(result.registration_view[static_cast<size_t>(reg.point_view[k])]);
  result.merged.SetScalar("view", std::move(view_index));
  reg.point_view = {};
  reg.point_views = {};
  reg.point_sigma_mm = {};
  reg.disagree = {};
  result.merge_seconds = SecondsSince(t0);

  // Pose errors against the truth, at the part's centre.
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  if (cad_in_part && !cad_in_part->vertices.empty()) {
    for (const auto& p : cad_in_part->vertices) centre += p;
    centre /= static_cast<double>(cad_in_part->vertices.size());
  } else if (!result.merged.empty()) {
    for (const auto& p : result.merged.points) centre += p;
    centre /= static_cast<double>(result.merged.size());
  }
  for (MergedView& v : result.views) {
    if (!v.merged || !v.part_from_rig_true) continue;
    PoseError(v.part_from_rig, *v.part_from_rig_true, centre, &v.rotation_error_deg,
              &v.translation_error_mm);
    if (v.part_from_rig_initial)
      PoseError(*v.part_from_rig_initial, *v.part_from_rig_true, centre,
                &v.initial_rotation_error_deg, &v.initial_translation_error_mm);
    result.has_truth = true;
    result.max_rotation_error_deg = std::max(result.max_rotation_error_deg, v.rotation_error_deg);
    result.max_translation_error_mm =
        std::max(result.max_translation_error_mm, v.translation_error_mm);
    result.max_initial_rotation_error_deg =
        std::max(result.max_initial_rotation_error_deg, v.initial_rotation_error_deg);
    result.max_initial_translation_error_mm =
        std::max(result.max_initial_translation_error_mm, v.initial_translation_error_mm);
  }
  const bool any = std::any_of(result.views.begin(), result.views.end(),
                               [](const MergedView& v) { return v.merged; });
  SLSHADOW_THROW_IF(!any, what, ": no view can be merged (", result.views.front().name, ": ",
                    result.views.front().reason, ")");

  // 5. The CAD comparison.
  if (cad_in_part) {
    t0 = std::chrono::steady_clock::now();
    std::vector<CadView> cad_views;
    for (size_t i = 0; i < result.views.size(); ++i) {
      const MergedView& v = result.views[i];
      // Views without a pose cannot be placed; the others count in the geometry.
      if (!v.part_from_rig_initial) continue;
      cad_views.push_back(CadView{v.name, v.merged ? v.part_from_rig : *v.part_from_rig_initial,
                                  v.merged ? &clouds[i] : nullptr,
                                  dark[i].empty() ? nullptr : &dark[i]});
    }
    result.cad = CompareWithCad(*cad_in_part, project.rig, options.mode, cad_views, result.merged,
                                project.rig.turntable, options.cad);
    result.merged.SetScalar("deviation_mm",
                            std::vector<float>(result.cad->merged_deviations_mm.begin(),
                                               result.cad->merged_deviations_mm.end()));
    result.compare_seconds = SecondsSince(t0);
  }
  result.total_seconds = SecondsSince(t_start);

  // 6. The surface mesh, timed apart.
  if (options.mesh) {
    t0 = std::chrono::steady_clock::now();
    result.mesh = BuildSurfaceMesh(result.merged, options.mesh_options);
    if (cad_in_part) {
      result.mesh_c2m = compare::ComputeStats(
          compare::CloudToMesh(result.mesh->mesh.vertices, *cad_in_part).signed_distances_mm, true,
          options.cad.threshold_mm);
    }
    result.mesh_seconds = SecondsSince(t0);
  }
  return result;
}

std::string ReconstructShardSummary::Brief() const {
  return StringPrintf("%d view%s in this shard: %d reconstructed, %d already stored (%.1f s)\n",
                      assigned, assigned == 1 ? "" : "s", reconstructed, already_done, seconds);
}

ReconstructShardSummary ReconstructProjectShard(
    const fs::path& project_dir, const ProjectMergeOptions& options, Shard shard,
    const std::function<void(const std::string&, size_t, size_t)>& on_view) {
  const auto t_start = std::chrono::steady_clock::now();
  options.Check();
  SLSHADOW_THROW_IF(options.reconstructions.empty(),
                    "reconstructions: empty; expected the folder the views' reconstructions go to");
  SLSHADOW_THROW_IF(shard.count < 1 || shard.index < 0 || shard.index >= shard.count,
                    "shard: ", shard.index, "/", shard.count, " is not I/N with 0 <= I < N");
  const ProjectManifest project = LoadProject(project_dir);
  std::vector<const ProjectView*> complete;
  for (const ProjectView& pv : project.views)
    if (pv.state == ViewState::kComplete) complete.push_back(&pv);
  ReconstructShardSummary summary;
  const size_t begin = shard.Begin(complete.size()), end = shard.End(complete.size());
  summary.assigned = static_cast<int>(end - begin);
  for (size_t k = begin; k < end; ++k) {
    const ProjectView& pv = *complete[k];
    if (on_view) on_view(pv.spec.name, k - begin, end - begin);
    const ImageSet image_set = ImageSet::Open(project_dir / pv.Folder());
    SLSHADOW_THROW_IF(RigToJson(image_set.rig()) != RigToJson(project.rig),
                      (project_dir / pv.Folder() / "manifest.json").string(),
                      ": rig differs from the project's (", (project_dir / "project.json").string(),
                      ")");
    std::string source;
    ObtainView(project_dir, pv, image_set, options, &source);
    if (source == "reconstructed" || source.rfind("reconstructed,", 0) == 0) {
      ++summary.reconstructed;
    } else {
      ++summary.already_done;
    }
  }
  summary.seconds = SecondsSince(t_start);
  return summary;
}

nlohmann::json ProjectMergeResult::ToJson() const {
  nlohmann::json j = {{"format", "slshadow-merge-report"},
                      {"version", 2},
                      {"project", project},
                      {"pose_method", pose_method},
                      {"merged_points", merged.size()}};
  j["views"] = nlohmann::json::array();
  for (const MergedView& v : views) {
    nlohmann::json view = {
        {"name", v.name},
        {"table_deg", v.table_deg ? nlohmann::json(*v.table_deg) : nlohmann::json(nullptr)},
        {"merged", v.merged},
        {"reason", v.reason},
        {"part_from_rig_initial", OptionalPose(v.part_from_rig_initial)},
        {"part_from_rig", v.merged ? PoseToJson(v.part_from_rig) : nlohmann::json(nullptr)},
        {"points", v.points},
        {"accepted_points", v.accepted_points},
        {"reconstruct_s", v.reconstruct_seconds},
        {"reconstruction", v.reconstruction}};
    if (v.merged && refined) {
      if (v.table_angle_deg) {
        view["table_angle_fitted_deg"] = *v.table_angle_deg;
        view["table_angle_correction_deg"] = v.table_angle_correction_deg;
        view["sigma_table_angle_deg"] = v.sigma_table_angle_deg;
      }
      view["anchor"] = v.anchor;
      view["pairs"] = v.pairs;
      view["residual_rms_mm"] = v.residual_rms_mm;
      view["noise_mm"] = v.noise_mm;
      view["sigma_rotation_deg"] = v.sigma_rotation_deg;
      view["sigma_translation_mm"] = v.sigma_translation_mm;
      view["graph_sigma_rotation_deg"] = v.graph_sigma_rotation_deg;
      view["graph_sigma_translation_mm"] = v.graph_sigma_translation_mm;
      view["prior_directions"] = v.prior_directions;
    }
    if (v.part_from_rig_true) {
      view["part_from_rig_true"] = PoseToJson(*v.part_from_rig_true);
      view["rotation_error_deg"] = v.rotation_error_deg;
      view["translation_error_mm"] = v.translation_error_mm;
      view["initial_rotation_error_deg"] = v.initial_rotation_error_deg;
      view["initial_translation_error_mm"] = v.initial_translation_error_mm;
    }
    j["views"].push_back(std::move(view));
  }
  std::vector<std::string> left_out;
  for (const MergedView& v : views) {
    if (!v.merged) left_out.push_back(v.name);
  }
  j["left_out"] = left_out;
  if (has_truth) {
    j["pose_errors"] = {{"max_rotation_deg", max_rotation_error_deg},
                        {"max_translation_mm", max_translation_error_mm},
                        {"initial_max_rotation_deg", max_initial_rotation_error_deg},
                        {"initial_max_translation_mm", max_initial_translation_error_mm}};
  }
  const MergeResult& r = registration;
  nlohmann::json pairs = nlohmann::json::array();
  for (const PairRegistration& p : r.pairs) {
    pairs.push_back(
        {{"a", views[static_cast<size_t>(registration_view[static_cast<size_t>(p.view_a)])].name},
         {"b", views[static_cast<size_t>(registration_view[static_cast<size_t>(p.view_b)])].name},
         {"overlap_initial", p.overlap_initial},
         {"fitness", p.fitness},
         {"rms_mm", p.rms_mm},
         {"final_rms_mm", p.final_rms_mm},
         {"correspondences", p.correspondences},
         {"iterations", p.iterations},
         {"converged", p.converged},
         {"graph_error_deg", p.graph_error_deg},
         {"graph_error_mm", p.graph_error_mm},
         {"min_eigen_ratio", p.min_eigen_ratio},
         {"degenerate", p.degenerate},
         {"seen_through", p.seen_through >= 0 ? nlohmann::json(p.seen_through) : nullptr},
         {"spread_factor", p.spread_factor > 0 ? nlohmann::json(p.spread_factor) : nullptr},
         {"untested_floor_deg",
          p.untested_floor_deg > 0 ? nlohmann::json(p.untested_floor_deg) : nullptr},
         {"kept", p.kept},
         {"reason", p.reason}});
  }
  nlohmann::json loop = nullptr;
  if (r.has_loop) {
    loop = {{"before_deg", r.loop_closure_before_deg},
            {"before_mm", r.loop_closure_before_mm},
            {"after_deg", r.loop_closure_after_deg},
            {"after_mm", r.loop_closure_after_mm}};
  }
  j["registration"] = {
      {"refined", refined},
      {"anchor",
       r.anchor >= 0
           ? nlohmann::json(
                 views[static_cast<size_t>(registration_view[static_cast<size_t>(r.anchor)])].name)
           : nlohmann::json(nullptr)},
      {"pairs", std::move(pairs)},
      {"loop_closure", std::move(loop)},
      {"turntable_model",
       r.turntable_model
           ? nlohmann::json{{"axis_direction",
                             {r.axis_direction_in_rig.x(), r.axis_direction_in_rig.y(),
                              r.axis_direction_in_rig.z()}},
                            {"axis_point_mm",
                             {r.axis_point_in_rig_mm.x(), r.axis_point_in_rig_mm.y(),
                              r.axis_point_in_rig_mm.z()}},
                            {"sigma_direction_deg", r.axis_sigma_direction_deg},
                            {"sigma_point_mm", r.axis_sigma_point_mm},
                            {"variance_factor", r.graph_variance_factor},
                            {"huber_corner", r.graph_huber_corner}}
           : nlohmann::json(nullptr)},
      {"joint_refinement",
       {{"iterations", r.joint_iterations}, {"last_motion_mm", r.joint_last_motion_mm}}},
      {"graph",
       {{"iterations", r.graph_iterations},
        {"initial_cost", r.graph_initial_cost},
        {"final_cost", r.graph_final_cost}}},
      {"fusion",
       {{"cell_mm", r.fuse_cell_mm},
        {"input_points", r.input_points},
        {"merged_points", merged.size()},
        {"disagree_points", r.disagree_points},
        {"superseded_points", r.superseded_points},
        {"rejected_points", r.rejected_points}}},
      {"time_s",
       {{"normals", r.time_normals_s},
        {"pairs", r.time_pairs_s},
        {"graph", r.time_graph_s},
        {"fusion", r.time_fuse_s},
        {"total", r.time_s}}}};
  j["cad"] = cad ? cad->ToJson() : nlohmann::json(nullptr);
  j["mesh"] = nullptr;
  if (mesh) {
    const SurfaceMeshResult& m = *mesh;
    j["mesh"] = {{"file", "mesh.ply"},
                 {"vertices", m.mesh.vertices.size()},
                 {"triangles", m.mesh.triangles.size()},
                 {"boundary_edges", m.boundary_edges},
                 {"non_manifold_edges", m.non_manifold_edges},
                 {"area_mm2", m.area_mm2},
                 {"trimmed_area_mm2", m.trimmed_area_mm2},
                 {"trim_distance_mm", m.trim_distance_mm},
                 {"cell_mm", m.cell_mm},
                 {"poisson",
                  {{"vertices", m.poisson_vertices},
                   {"triangles", m.poisson_triangles},
                   {"boundary_edges", m.poisson_boundary_edges},
                   {"non_manifold_edges", m.poisson_non_manifold_edges},
                   {"seconds", m.poisson_seconds}}},
                 {"trim_s", m.trim_seconds}};
    if (mesh_c2m) {
      j["mesh"]["cad_c2m"] = {{"count", mesh_c2m->count},
                              {"rms_mm", mesh_c2m->rms_mm},
                              {"signed_mean_mm", mesh_c2m->signed_mean_mm},
                              {"median_abs_mm", mesh_c2m->median_mm},
                              {"p95_abs_mm", mesh_c2m->p95_mm},
                              {"max_abs_mm", mesh_c2m->max_mm}};
    }
  }
  j["time_s"] = {{"reconstruct", reconstruct_seconds},
                 {"merge", merge_seconds},
                 {"compare", compare_seconds},
                 {"total", total_seconds},
                 {"mesh", mesh_seconds}};
  return j;
}

std::string ProjectMergeResult::Summary() const {
  std::string out = StringPrintf("merge of %s: %zu views, poses from the %s\n", project.c_str(),
                                 views.size(), pose_method.c_str());
  out +=
      "view        table (deg)   points  pairs  residual   sigma rot / trans    error vs truth: "
      "rotation   translation\n"
      "                                          (mm)     (deg)      (mm)      initial -> final "
      "(deg)      (mm)\n";
  for (const MergedView& v : views) {
    const std::string table = v.table_deg ? StringPrintf("%9.3f", *v.table_deg) : "     hand";
    if (!v.merged) {
      out += StringPrintf("%-10s  %s   left out: %s\n", v.name.c_str(), table.c_str(),
                          v.reason.c_str());
      continue;
    }
    out += StringPrintf("%-10s%s %s %8zu  %5d  %8.4f  %8.5f  %8.5f", v.name.c_str(),
                        v.anchor ? "*" : " ", table.c_str(), v.points, v.pairs, v.residual_rms_mm,
                        v.sigma_rotation_deg, v.sigma_translation_mm);
    if (v.part_from_rig_true) {
      out += StringPrintf("   %8.5f -> %8.5f   %7.4f -> %7.4f\n", v.initial_rotation_error_deg,
                          v.rotation_error_deg, v.initial_translation_error_mm,
                          v.translation_error_mm);
    } else {
      out += "   -\n";
    }
  }
  out += "(* the anchor: its initial pose fixes the part frame)\n";
  const MergeResult& r = registration;
  if (r.has_loop) {
    out += StringPrintf(
        "loop closure (full turn): %.5f deg / %.4f mm chaining the pairs -> %.5f deg / %.4f mm "
        "after the pose graph\n",
        r.loop_closure_before_deg, r.loop_closure_before_mm, r.loop_closure_after_deg,
        r.loop_closure_after_mm);
  }
  if (r.turntable_model) {
    out += StringPrintf(
        "pose graph on the turntable model: axis (%.6f, %.6f, %.6f) through (%.4f, %.4f, %.4f) "
        "mm in the rig frame, 1-sigma %.2g deg / %.2g mm; pair variance factor %.3g; joint "
        "refinement %d rounds\n",
        r.axis_direction_in_rig.x(), r.axis_direction_in_rig.y(), r.axis_direction_in_rig.z(),
        r.axis_point_in_rig_mm.x(), r.axis_point_in_rig_mm.y(), r.axis_point_in_rig_mm.z(),
        r.axis_sigma_direction_deg, r.axis_sigma_point_mm, r.graph_variance_factor,
        r.joint_iterations);
  }
  if (has_truth) {
    out += StringPrintf(
        "pose errors against the truth (largest): initial %.5f deg / %.4f mm -> final %.5f deg / "
        "%.4f mm\n",
        max_initial_rotation_error_deg, max_initial_translation_error_mm, max_rotation_error_deg,
        max_translation_error_mm);
  }
  int kept = 0;
  for (const PairRegistration& p : r.pairs) kept += p.kept ? 1 : 0;
  out += StringPrintf(
      "merged cloud: %zu points fused from %zu (cell %.3f mm), %zu flagged where views "
      "disagree; %d of %zu pairs kept\n",
      merged.size(), r.input_points, r.fuse_cell_mm, r.disagree_points, kept, r.pairs.size());
  for (const PairRegistration& p : r.pairs) {
    if (p.kept) continue;
    out += StringPrintf(
        "  pair %s <- %s rejected: %s\n",
        views[static_cast<size_t>(registration_view[static_cast<size_t>(p.view_a)])].name.c_str(),
        views[static_cast<size_t>(registration_view[static_cast<size_t>(p.view_b)])].name.c_str(),
        p.reason.c_str());
  }
  for (const MergedView& v : views) {
    if (v.prior_directions.empty()) continue;
    std::string list;
    for (const std::string& d : v.prior_directions) list += (list.empty() ? "" : "; ") + d;
    out += StringPrintf(
        "  %s: held at the table's prior where its pairs' overlap leaves it free: %s\n",
        v.name.c_str(), list.c_str());
  }
  if (cad) out += cad->Summary();
  if (mesh) {
    out += mesh->Summary() + "\n";
    if (mesh_c2m) {
      out += StringPrintf(
          "mesh vertices to the CAD: signed C2M RMS %.4f mm, mean %+.4f mm, median |d| %.4f mm, "
          "p95 |d| %.4f mm, max |d| %.3f mm\n",
          mesh_c2m->rms_mm, mesh_c2m->signed_mean_mm, mesh_c2m->median_mm, mesh_c2m->p95_mm,
          mesh_c2m->max_mm);
    }
  }
  out += StringPrintf(
      "time: reconstruct %.2f s, merge %.2f s (normals %.2f, pairs %.2f, graph %.2f, fusion "
      "%.2f), CAD comparison %.2f s, total %.2f s; mesh %.2f s apart\n",
      reconstruct_seconds, merge_seconds, r.time_normals_s, r.time_pairs_s, r.time_graph_s,
      r.time_fuse_s, compare_seconds, total_seconds, mesh_seconds);
  return out;
}

void WriteModel(const ProjectMergeResult& result, const TriangleMesh* cad_in_part,
                const fs::path& model_dir, bool overwrite, bool write_html) {
  std::error_code ec;
  SLSHADOW_THROW_IF(fs::exists(model_dir, ec) && !overwrite, model_dir.string(),
                    ": already exists (pass --overwrite to replace it)");
  StagingDirectory staged(model_dir);
  const fs::path& dir = staged.path();
  WriteTextFileAtomically(dir / "report.json", result.ToJson().dump(1) + "\n");
  WriteTextFileAtomically(dir / "summary.txt", result.Summary());
  WritePly(dir / "merged.ply", result.merged);
  if (result.mesh) WriteMesh(dir / "mesh.ply", result.mesh->mesh);
  if (cad_in_part && result.cad) {
    WritePaintedMesh(dir / "cad_deviation.ply", *cad_in_part, *result.cad);
    PointCloud samples;
    samples.points = result.cad->sample_points;
    std::vector<float> reason(samples.size());
    samples.colors.resize(samples.size());
    for (size_t i = 0; i < samples.size(); ++i) {
      reason[i] = result.cad->sample_reason[i];
      samples.colors[i] = ReasonColor(static_cast<CoverageReason>(result.cad->sample_reason[i]));
    }
    samples.SetScalar("reason", std::move(reason));
    WritePly(dir / "cad_coverage.ply", samples);
  }
  if (write_html) report::WriteHtmlReport(dir);
  staged.Commit(overwrite);
}

}  // namespace slshadow::multiview
