#include "workflows/multiview/project_shadow.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "compare/statistics.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/point_cloud.h"
#include "core/string_printf.h"
#include "sim/scene.h"
#include "sim/scene_surface.h"
#include "workflows/multiview/views.h"
#include "workflows/pipeline/scan_pipeline.h"

namespace slshadow::multiview {
namespace fs = std::filesystem;
namespace {

// The part surface's bounding-box corners: where the diagnosis across views weighs poses.
std::vector<Eigen::Vector3d> BoxCorners(const TriangleMesh& surface) {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  for (const Eigen::Vector3d& v : surface.vertices) lo = lo.cwiseMin(v), hi = hi.cwiseMax(v);
  std::vector<Eigen::Vector3d> corners;
  for (int i = 0; i < 8; ++i) {
    corners.emplace_back((i & 1) ? hi.x() : lo.x(), (i & 2) ? hi.y() : lo.y(),
                         (i & 4) ? hi.z() : lo.z());
  }
  return corners;
}

// The view's report without its bulk: what the project report keeps per view.
nlohmann::json ViewFigures(const nlohmann::json& report) {
  nlohmann::json j;
  for (const char* key : {"pose", "clouds", "diagnosis"}) {
    if (report.contains(key)) j[key] = report[key];
  }
  return j;
}

// The pose's 1-sigma translation from the view's report (0 when it has none).
double PoseSigmaMm(const nlohmann::json& report) {
  const nlohmann::json* u = &report;
  for (const char* key : {"pose", "refinement", "uncertainty", "sigma_translation_mm"}) {
    if (!u->is_object() || !u->contains(key)) return 0.0;
    u = &(*u)[key];
  }
  return u->is_number() ? u->get<double>() : 0.0;
}

// The clouds of mode `mode` a view's report folder holds (rig frame), real and twin.
std::pair<PointCloud, PointCloud> ReadViewClouds(const fs::path& view_dir,
                                                 const std::string& mode) {
  return {ReadPly(view_dir / "clouds" / ("real_" + mode + ".ply")),
          ReadPly(view_dir / "clouds" / ("twin_" + mode + ".ply"))};
}

// The points of `cloud` (rig frame) at least crop_mm above the table plane (all when crop_mm < 0).
PointCloud AboveTable(const PointCloud& cloud, const TurntableAxis& axis, double crop_mm) {
  PointCloud out;
  const Eigen::Vector3d up = axis.direction_in_rig.normalized();
  for (const Eigen::Vector3d& p : cloud.points) {
    if (crop_mm < 0 || up.dot(p - axis.point_in_rig_mm) >= crop_mm) out.points.push_back(p);
  }
  return out;
}

PointCloud ToPartFrame(const PointCloud& cloud, const Rigid3d& part_from_rig) {
  PointCloud out;
  out.points.reserve(cloud.size());
  for (const Eigen::Vector3d& p : cloud.points) out.points.push_back(part_from_rig * p);
  return out;
}

}  // namespace

twin::ShadowPart LoadTurntablePart(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext != ".yaml" && ext != ".yml" && ext != ".json") return twin::LoadShadowPart(path);
  twin::ShadowPart part;
  part.source = path.string();
  part.scene = LoadScene(path);
  Scene compared = part.scene;
  compared.objects.clear();
  for (const SceneObject& o : part.scene.objects) {
    if (o.type == ObjectType::kMesh || o.type == ObjectType::kPlane) compared.objects.push_back(o);
  }
  SLSHADOW_THROW_IF(compared.objects.empty(), path.string(),
                    ": objects: no mesh or plane; expected the part as a mesh (its table may be a "
                    "cylinder)");
  part.surface = SceneSurface(compared, path.string(), twin::kPartPlaneCells);
  return part;
}

void ProjectShadowOptions::Check() const {
  view.Check();
  if (!drift.probe_points_in_part.empty()) drift.Check();
  cad.Check();
  if (rig_from_part0) {
    SLSHADOW_THROW_IF(
        !rig_from_part0->translation.allFinite() || !rig_from_part0->rotation.coeffs().allFinite(),
        "rig_from_part0: not finite");
  }
  SLSHADOW_THROW_IF(!std::isfinite(table_crop_mm), "table_crop_mm: ", table_crop_mm,
                    "; expected a finite number");
  SLSHADOW_THROW_IF(!view.write_clouds,
                    "write_clouds: false; the multi-view shadow merges the views' clouds");
}

std::string ProjectShadowResult::Summary() const {
  std::string s = StringPrintf("multi-view shadow: %zu views\n", views.size());
  for (const ProjectShadowView& v : views) {
    s += StringPrintf("  %-12s %8.2f deg  %s\n", v.name.c_str(), v.table_deg, v.verdict.c_str());
  }
  s += "across views: " + drift.finding + "\n";
  const nlohmann::json& causes = report["per_view_causes"];
  if (causes.is_object()) {
    for (const auto& [cause, count] : causes.items()) {
      s += StringPrintf("named by %zu of %zu views: %s%s\n", count.get<size_t>(), views.size(),
                        cause.c_str(),
                        count.get<size_t>() == views.size() && cause == "calibration"
                            ? " (in every view alike: the rig's calibration, not the table)"
                            : "");
    }
  }
  const nlohmann::json& m = report["merged"];
  if (m.is_object()) {
    s += StringPrintf(
        "merged: real C2M RMS %.4f mm, coverage %.2f %%; twin C2M RMS %.4f mm, coverage %.2f %%; "
        "real - twin on the CAD: mean %+.4f mm, RMS %.4f mm over %zu vertices\n",
        m["real"]["merged"]["rms_mm"].get<double>(),
        100 * m["real"]["coverage"]["reachable"].get<double>(),
        m["twin"]["merged"]["rms_mm"].get<double>(),
        100 * m["twin"]["coverage"]["reachable"].get<double>(),
        m["real_minus_twin"]["signed_mean_mm"].get<double>(),
        m["real_minus_twin"]["rms_mm"].get<double>(), m["real_minus_twin"]["count"].get<size_t>());
  }
  return s;
}

ProjectShadowResult RunProjectShadow(const fs::path& project_dir, const twin::ShadowPart& part,
                                     const ProjectShadowOptions& options, const fs::path& out_dir,
                                     const Rig* rig_override) {
  options.Check();
  const ProjectManifest project = LoadProject(project_dir);
  const Rig rig = rig_override ? *rig_override : project.rig;
  const std::string project_json = (project_dir / "project.json").string();
  SLSHADOW_THROW_IF(!rig.turntable, project_json,
                    ": the rig has no turntable axis; expected a turntable project (slshadow "
                    "calibrate turntable writes the axis)");
  const TurntableAxis& axis = *rig.turntable;
  SLSHADOW_THROW_IF(fs::exists(out_dir) && !options.view.overwrite, out_dir.string(),
                    ": exists; expected a new folder (or overwrite)");

  std::vector<const ProjectView*> views;
  nlohmann::json left_out = nlohmann::json::array();
  for (const ProjectView& v : project.views) {
    if (v.state != ViewState::kComplete) {
      left_out.push_back({{"view", v.spec.name}, {"reason", "missing: not scanned"}});
    } else if (!v.spec.OnTable()) {
      left_out.push_back({{"view", v.spec.name},
                          {"reason", "placed by hand: the turntable model does not pose it"}});
    } else {
      views.push_back(&v);
    }
  }
  SLSHADOW_THROW_IF(views.size() < 3, project_json, ": ", views.size(),
                    " complete table views; expected at least 3 for the diagnosis across views");

  StagingDirectory staging(out_dir);
  fs::create_directories(staging.path() / "views");
  ProjectShadowResult result;
  std::optional<Rigid3d> placement = options.rig_from_part0;
  const std::string placement_source = placement ? "given" : "registered on the first view";
  std::string mode;
  for (size_t i = 0; i < views.size(); ++i) {
    const ProjectView& v = *views[i];
    if (options.on_view) options.on_view(v.spec.name, i, views.size());
    twin::ShadowOptions o = options.view;
    o.overwrite = false;
    o.rig_from_part.reset();
    if (placement) {
      o.rig_from_part = axis.RigFromTableTurn(*v.spec.table_deg) * *placement;
      o.refine_pose = true;
    }
    const fs::path view_out = staging.path() / v.Folder();
    twin::ShadowResult r;
    try {
      r = twin::RunShadow(project_dir / v.Folder(), part, o, view_out, &rig);
    } catch (const Error& e) {
      SLSHADOW_THROW("view '", v.spec.name, "' (", (project_dir / v.Folder()).string(),
                     "): ", e.what());
    }
    if (!placement)
      placement = axis.RigFromTableTurn(*v.spec.table_deg).Inverse() * r.rig_from_part;
    ProjectShadowView pv;
    pv.name = v.spec.name;
    pv.table_deg = *v.spec.table_deg;
    pv.rig_from_part = r.rig_from_part;
    pv.sigma_mm = PoseSigmaMm(r.report);
    pv.verdict = r.diagnosis.verdict;
    pv.figures = ViewFigures(r.report);
    if (mode.empty() && r.report.contains("clouds")) {
      for (const auto& m : r.report["clouds"]["modes"]) {
        if (mode.empty() || m["mode"] == "stereo") mode = m["mode"].get<std::string>();
      }
    }
    result.views.push_back(std::move(pv));
  }

  // 3. Across views.
  ViewDriftOptions drift = options.drift;
  if (drift.probe_points_in_part.empty()) drift.probe_points_in_part = BoxCorners(part.surface);
  std::vector<ViewPose> poses;
  for (const ProjectShadowView& v : result.views) {
    poses.push_back({v.name, v.table_deg, v.rig_from_part, v.sigma_mm});
  }
  result.drift = DiagnoseViewDrift(axis, poses, drift);

  // 4. Merged, on the CAD surface (the part's meshes; its planes and the table are not the CAD).
  nlohmann::json merged;
  SLSHADOW_THROW_IF(mode.empty(), "the views' reports hold no clouds to merge");
  {
    TriangleMesh cad = SceneMeshSurface(part.scene);
    if (cad.empty()) cad = part.surface;
    const Rigid3d part_from_rig0 = placement->Inverse();
    TurntableAxis axis_in_part = axis;
    axis_in_part.direction_in_rig = part_from_rig0.rotation * axis.direction_in_rig;
    axis_in_part.point_in_rig_mm = part_from_rig0 * axis.point_in_rig_mm;
    std::vector<PointCloud> real(result.views.size()), twin(result.views.size());
    PointCloud real_merged, twin_merged;
    std::vector<CadView> real_views, twin_views;
    for (size_t i = 0; i < result.views.size(); ++i) {
      const ProjectShadowView& v = result.views[i];
      auto [r, t] = ReadViewClouds(staging.path() / "views" / v.name, mode);
      real[i] = AboveTable(r, axis, options.table_crop_mm);
      twin[i] = AboveTable(t, axis, options.table_crop_mm);
      const Rigid3d part_from_rig = v.rig_from_part.Inverse();
      real_merged.Append(ToPartFrame(real[i], part_from_rig));
      twin_merged.Append(ToPartFrame(twin[i], part_from_rig));
      real_views.push_back({v.name, part_from_rig, &real[i]});
      twin_views.push_back({v.name, part_from_rig, &twin[i]});
    }
    const ReconstructMode rmode =
        mode == "stereo" ? ReconstructMode::kStereo : ReconstructMode::kProjector;
    const CadComparison rc =
        CompareWithCad(cad, rig, rmode, real_views, real_merged, axis_in_part, options.cad);
    const CadComparison tc =
        CompareWithCad(cad, rig, rmode, twin_views, twin_merged, axis_in_part, options.cad);
    std::vector<double> diff;
    for (size_t k = 0; k < rc.vertex_deviation_mm.size() && k < tc.vertex_deviation_mm.size();
         ++k) {
      const float a = rc.vertex_deviation_mm[k], b = tc.vertex_deviation_mm[k];
      if (std::isfinite(a) && std::isfinite(b)) diff.push_back(static_cast<double>(a) - b);
    }
    const compare::DistanceStats ds = compare::ComputeStats(diff, true, 0.0);
    merged = {{"mode", mode},
              {"table_crop_mm", options.table_crop_mm},
              {"real", rc.ToJson()},
              {"twin", tc.ToJson()},
              {"real_minus_twin",
               {{"what", "per CAD vertex both cover: the real scan's mean C2M minus the twin's"},
                {"count", ds.count},
                {"signed_mean_mm", ds.signed_mean_mm},
                {"rms_mm", ds.rms_mm},
                {"median_abs_mm", ds.median_mm},
                {"p95_abs_mm", ds.p95_mm}}}};
  }

  // 5. The report.
  nlohmann::json& report = result.report;
  report["format"] = "slshadow-multiview-shadow-report";
  report["version"] = 1;
  report["project"] = fs::absolute(project_dir).lexically_normal().string();
  report["rig"] = rig.name;
  report["turntable"] = {
      {"direction_in_rig",
       {axis.direction_in_rig.x(), axis.direction_in_rig.y(), axis.direction_in_rig.z()}},
      {"point_in_rig_mm",
       {axis.point_in_rig_mm.x(), axis.point_in_rig_mm.y(), axis.point_in_rig_mm.z()}},
      {"angle_offset_deg", axis.angle_offset_deg},
      {"angle_scale", axis.angle_scale}};
  const Eigen::Matrix4d m = placement->ToMatrix();
  nlohmann::json rows = nlohmann::json::array();
  for (int r = 0; r < 4; ++r) rows.push_back({m(r, 0), m(r, 1), m(r, 2), m(r, 3)});
  report["placement"] = {{"source", placement_source}, {"rig_from_part0", rows}};
  nlohmann::json per_view = nlohmann::json::array();
  for (const ProjectShadowView& v : result.views) {
    nlohmann::json j = v.figures;
    j["view"] = v.name;
    j["table_deg"] = v.table_deg;
    j["report"] = "views/" + v.name + "/report.json";
    j["verdict"] = v.verdict;
    j["pose_sigma_mm"] = v.sigma_mm;
    per_view.push_back(j);
  }
  report["views"] = per_view;
  report["left_out"] = left_out;
  // How many views' own diagnoses name each cause: a calibration error names itself in every view.
  nlohmann::json per_view_causes = nlohmann::json::object();
  for (const ProjectShadowView& v : result.views) {
    for (const auto& c : v.figures["diagnosis"]["causes"]) {
      const std::string name = c.get<std::string>();
      per_view_causes[name] = per_view_causes.value(name, 0) + 1;
    }
  }
  report["per_view_causes"] = per_view_causes;
  report["across_views"] = result.drift.ToJson(poses);
  report["merged"] = merged;
  WriteTextFileAtomically(staging.path() / "report.json", report.dump(2) + "\n");
  WriteTextFileAtomically(staging.path() / "summary.txt", result.Summary());
  staging.Commit(options.view.overwrite);
  return result;
}

}  // namespace slshadow::multiview
