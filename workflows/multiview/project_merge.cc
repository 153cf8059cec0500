#include "workflows/multiview/project_merge.h"

#include <malloc.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>

#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/image_set.h"
#include "core/pose_io.h"
#include "core/string_printf.h"
#include "report/html_report.h"
#include "shadow/scan_pipeline.h"

namespace slshadow::multiview {
namespace fs = std::filesystem;

namespace {

double SecondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// The view's cloud (rig frame): decoded and reconstructed from its ImageSet alone.
Reconstruction ReconstructView(const ImageSet& image_set, const ProjectMergeOptions& options) {
  const Rig& rig = image_set.rig();
  SLSHADOW_THROW_IF(options.mode == ReconstructMode::kStereo && rig.cameras.size() < 2,
                    image_set.dir().string(), ": stereo needs two cameras (the rig has ",
                    rig.cameras.size(), ")");
  std::vector<std::string> cameras = {rig.cameras[0].name};
  if (options.mode == ReconstructMode::kStereo) cameras.push_back(rig.cameras[1].name);
  const shadow::DecodedScan decoded = shadow::DecodeImageSet(image_set, cameras, options.decode);
  Reconstruction rec =
      options.mode == ReconstructMode::kStereo
          ? ReconstructStereo(rig, cameras[0], cameras[1], decoded.maps[0], decoded.maps[1],
                              options.reconstruct, options.max_points_per_view)
          : ReconstructWithProjector(rig, cameras[0], decoded.maps[0], options.reconstruct,
                                     options.max_points_per_view);
  rec.grid = DenseGrid();
  return rec;
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

nlohmann::json OptionalPose(const std::optional<Rigid3d>& pose) {
  return pose ? PoseToJson(*pose) : nlohmann::json(nullptr);
}

}  // namespace

void ProjectMergeOptions::Check() const {
  SLSHADOW_THROW_IF(!std::isfinite(table_crop_mm), "merge: table_crop_mm must be finite (got ",
                    table_crop_mm, ")");
  reconstruct.Check();
  decode.Check();
  cad.Check();
}

ProjectMergeResult MergeProject(const fs::path& project_dir, const TriangleMesh* cad_in_part,
                                const ProjectMergeOptions& options) {
  const auto t_start = std::chrono::steady_clock::now();
  options.Check();
  const ProjectManifest project = LoadProject(project_dir);
  const std::string what = (project_dir / "project.json").string();
  ProjectMergeResult result;
  result.project = project_dir.string();
  result.pose_method =
      "turntable axis and table angles; hand-placed views from their guess (not "
      "registered)";

  // 1.-2. Reconstruct every complete view, one at a time; initial poses.
  std::vector<PointCloud> clouds(project.views.size());
  for (size_t i = 0; i < project.views.size(); ++i) {
    const ProjectView& pv = project.views[i];
    MergedView v;
    v.name = pv.spec.name;
    v.table_deg = pv.spec.table_deg;
    if (pv.spec.OnTable()) {
      v.part_from_rig_initial =
          project.rig.turntable->RigFromTableTurn(*pv.spec.table_deg).Inverse();
    } else {
      v.part_from_rig_initial = pv.spec.part_from_rig_guess;
    }
    if (pv.state != ViewState::kComplete) {
      v.reason = "missing: the view was not captured (project state missing)";
    } else if (!v.part_from_rig_initial) {
      v.reason =
          "no pose: placed by hand without part_from_rig_guess, and views are not registered";
    } else {
      const auto t0 = std::chrono::steady_clock::now();
      const ImageSet image_set = ImageSet::Open(project_dir / pv.Folder());
      SLSHADOW_THROW_IF(RigToJson(image_set.rig()) != RigToJson(project.rig),
                        (project_dir / pv.Folder() / "manifest.json").string(),
                        ": rig differs from the project's (", what, ")");
      v.part_from_rig_true = RecordedTruth(image_set);
      Reconstruction rec = ReconstructView(image_set, options);
      ReleaseReconstructionBuffers();
      malloc_trim(0);
      if (pv.spec.OnTable() && options.table_crop_mm >= 0) {
        // The table plane does not move when the table turns: the same plane in every view.
        const TurntableAxis& axis = *project.rig.turntable;
        const Eigen::Vector3d up = axis.direction_in_rig.normalized();
        std::vector<bool> keep(rec.cloud.size());
        for (size_t k = 0; k < rec.cloud.size(); ++k)
          keep[k] = up.dot(rec.cloud.points[k] - axis.point_in_rig_mm) >= options.table_crop_mm;
        rec.cloud = rec.cloud.Select(keep);
      }
      v.accepted_points = rec.summary.points;
      v.reconstruct_seconds = SecondsSince(t0);
      result.reconstruct_seconds += v.reconstruct_seconds;
      if (rec.cloud.empty()) {
        v.reason = "empty: the reconstruction accepted no point";
      } else {
        v.merged = true;
        v.part_from_rig = *v.part_from_rig_initial;
        v.points = rec.cloud.size();
        clouds[i] = std::move(rec.cloud);
      }
    }
    result.views.push_back(std::move(v));
  }
  const bool any = std::any_of(result.views.begin(), result.views.end(),
                               [](const MergedView& v) { return v.merged; });
  SLSHADOW_THROW_IF(!any, what, ": no view can be merged (",
                    result.views.empty() ? "no views" : result.views.front().reason, ")");

  // 3. The merged cloud in the part frame.
  auto t0 = std::chrono::steady_clock::now();
  size_t total = 0;
  for (const PointCloud& c : clouds) total += c.size();
  PointCloud& merged = result.merged;
  merged.points.reserve(total);
  merged.normals.reserve(total);
  std::vector<float> view_index, quality;
  view_index.reserve(total);
  quality.reserve(total);
  for (size_t i = 0; i < clouds.size(); ++i) {
    const MergedView& v = result.views[i];
    if (!v.merged) continue;
    const PointCloud& c = clouds[i];
    const Eigen::Matrix3f r = v.part_from_rig.rotation.toRotationMatrix().cast<float>();
    const std::vector<float>* q = c.Scalar("quality");
    for (size_t k = 0; k < c.size(); ++k) {
      merged.points.push_back(v.part_from_rig * c.points[k]);
      merged.normals.push_back(c.HasNormals() ? Eigen::Vector3f(r * c.normals[k])
                                              : Eigen::Vector3f::Zero());
      view_index.push_back(static_cast<float>(i));
      quality.push_back(q ? (*q)[k] : 0.0f);
    }
  }
  merged.SetScalar("view", std::move(view_index));
  merged.SetScalar("quality", std::move(quality));
  result.merge_seconds = SecondsSince(t0);

  // Pose errors against the truth, at the part's centre.
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  if (cad_in_part && !cad_in_part->vertices.empty()) {
    for (const auto& p : cad_in_part->vertices) centre += p;
    centre /= static_cast<double>(cad_in_part->vertices.size());
  } else {
    for (const auto& p : merged.points) centre += p;
    centre /= static_cast<double>(merged.size());
  }
  for (MergedView& v : result.views) {
    if (!v.merged || !v.part_from_rig_true) continue;
    const Rigid3d delta = v.part_from_rig * v.part_from_rig_true->Inverse();
    v.rotation_error_deg = Eigen::AngleAxisd(delta.rotation).angle() * 180.0 / M_PI;
    v.translation_error_mm = (delta * centre - centre).norm();
    result.has_truth = true;
    result.max_rotation_error_deg = std::max(result.max_rotation_error_deg, v.rotation_error_deg);
    result.max_translation_error_mm =
        std::max(result.max_translation_error_mm, v.translation_error_mm);
  }

  // 4. The CAD comparison.
  if (cad_in_part) {
    t0 = std::chrono::steady_clock::now();
    std::vector<CadView> cad_views;
    for (size_t i = 0; i < result.views.size(); ++i) {
      const MergedView& v = result.views[i];
      // Views without a pose cannot be placed; the others count in the geometry.
      if (!v.part_from_rig_initial) continue;
      cad_views.push_back(CadView{v.name, v.merged ? v.part_from_rig : *v.part_from_rig_initial,
                                  v.merged ? &clouds[i] : nullptr});
    }
    result.cad = CompareWithCad(*cad_in_part, project.rig, options.mode, cad_views, merged,
                                project.rig.turntable, options.cad);
    result.merged.SetScalar("deviation_mm",
                            std::vector<float>(result.cad->merged_deviations_mm.begin(),
                                               result.cad->merged_deviations_mm.end()));
    result.compare_seconds = SecondsSince(t0);
  }
  result.total_seconds = SecondsSince(t_start);
  return result;
}

nlohmann::json ProjectMergeResult::ToJson() const {
  nlohmann::json j = {{"format", "slshadow-merge-report"},
                      {"version", 1},
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
        {"reconstruct_s", v.reconstruct_seconds}};
    if (v.part_from_rig_true) {
      view["part_from_rig_true"] = PoseToJson(*v.part_from_rig_true);
      view["rotation_error_deg"] = v.rotation_error_deg;
      view["translation_error_mm"] = v.translation_error_mm;
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
                        {"max_translation_mm", max_translation_error_mm}};
  }
  j["cad"] = cad ? cad->ToJson() : nlohmann::json(nullptr);
  j["time_s"] = {{"reconstruct", reconstruct_seconds},
                 {"merge", merge_seconds},
                 {"compare", compare_seconds},
                 {"total", total_seconds}};
  return j;
}

std::string ProjectMergeResult::Summary() const {
  std::string out = StringPrintf("merge of %s: %zu views, poses from the %s\n", project.c_str(),
                                 views.size(), pose_method.c_str());
  out += "view        table (deg)   points   rotation err (deg)   translation err (mm)\n";
  for (const MergedView& v : views) {
    const std::string table = v.table_deg ? StringPrintf("%9.3f", *v.table_deg) : "     hand";
    if (!v.merged) {
      out += StringPrintf("%-10s  %s   left out: %s\n", v.name.c_str(), table.c_str(),
                          v.reason.c_str());
      continue;
    }
    if (v.part_from_rig_true) {
      out += StringPrintf("%-10s  %s   %8zu   %18.5f   %20.4f\n", v.name.c_str(), table.c_str(),
                          v.points, v.rotation_error_deg, v.translation_error_mm);
    } else {
      out += StringPrintf("%-10s  %s   %8zu   %18s   %20s\n", v.name.c_str(), table.c_str(),
                          v.points, "-", "-");
    }
  }
  out += StringPrintf("merged cloud: %zu points\n", merged.size());
  if (cad) out += cad->Summary();
  out +=
      StringPrintf("time: reconstruct %.2f s, merge %.2f s, CAD comparison %.2f s, total %.2f s\n",
                   reconstruct_seconds, merge_seconds, compare_seconds, total_seconds);
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
  if (cad_in_part && result.cad) {
    WritePaintedMesh(dir / "cad_deviation.ply", *cad_in_part, *result.cad);
    PointCloud samples;
    samples.points = result.cad->sample_points;
    std::vector<float> reason(samples.size());
    samples.colors.resize(samples.size());
    static const std::array<uint8_t, 3> kColors[kNumCoverageReasons] = {
        {40, 170, 60}, {220, 30, 30}, {240, 150, 20}, {40, 80, 220}, {150, 150, 150}, {0, 0, 0}};
    for (size_t i = 0; i < samples.size(); ++i) {
      reason[i] = result.cad->sample_reason[i];
      samples.colors[i] = kColors[result.cad->sample_reason[i]];
    }
    samples.SetScalar("reason", std::move(reason));
    WritePly(dir / "cad_coverage.ply", samples);
  }
  if (write_html) report::WriteHtmlReport(dir);
  staged.Commit(overwrite);
}

}  // namespace slshadow::multiview
