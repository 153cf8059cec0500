// `slshadow merge PROJECT --out MODEL`: a multi-view project (workflows/multiview/views.h)
// reconstructed view by view, the views' poses, the merged cloud in the part frame, and its
// comparison with the CAD model (workflows/multiview/cad_compare.h).
//
//  1. Every complete view is reconstructed like any scan (the ImageSet decoded and triangulated
//     with the reconstruct library); one view's images are in memory at a time, each view keeps
//     its cloud (at most max_points_per_view points, every s-th accepted cell). Missing views are
//     left out and named.
//  2. Initial poses: table views from the rig's turntable axis and the commanded angle
//     (part_from_rig = axis.RigFromTableTurn(a).Inverse()); hand-placed views from their guess.
//     A hand-placed view without a guess has no pose here and is left out, named. Table views
//     lose the points of the table (table_crop_mm).
//  3. The merged cloud: every view's cloud moved into the part frame by its pose, with per-point
//     scalars `view` (index into the result's views) and `quality`.
//  4. With a CAD mesh (part frame): CompareWithCad, the deviation painted on the mesh.
//
// Truth: when a view's ImageSet records the pose it was rendered at (a virtual project's
// extra.view.part_from_rig_true), the report gives each pose's error against it: the rotation
// angle of estimated * true^-1 (deg) and the displacement it gives the part's centre (the CAD's
// centroid, else the merged cloud's), mm.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/mesh.h"
#include "core/point_cloud.h"
#include "core/rigid3.h"
#include "patterns/codec.h"
#include "reconstruct/reconstruct.h"
#include "workflows/multiview/cad_compare.h"
#include "workflows/multiview/views.h"

namespace slshadow::multiview {

struct ProjectMergeOptions {
  ReconstructMode mode = ReconstructMode::kStereo;
  ReconstructOptions reconstruct = [] {
    ReconstructOptions r;
    r.report_residuals = false;  // the gates and the cloud are the same, faster
    return r;
  }();
  DecodeOptions decode;
  size_t max_points_per_view = 400000;  // 0: every accepted point
  // Table views: points less than this above the table plane (the plane through the axis point
  // perpendicular to the axis, where the part stands) are the table, not the part, and are
  // dropped from the view's cloud. Negative: keep every point.
  double table_crop_mm = 0.5;
  CadCompareOptions cad;
  void Check() const;  // throws slshadow::Error naming the bad field
};

// One view of the merge.
struct MergedView {
  std::string name;
  std::optional<double> table_deg;
  bool merged = false;  // false: left out; `reason` says why
  std::string reason;
  std::optional<Rigid3d> part_from_rig_initial;
  Rigid3d part_from_rig;        // the pose used (merged views)
  size_t points = 0;            // in the view's cloud (after max_points_per_view)
  int64_t accepted_points = 0;  // the reconstruction's accepted cells
  double reconstruct_seconds = 0;
  std::optional<Rigid3d> part_from_rig_true;  // recorded by a virtual project
  double rotation_error_deg = 0;              // against the truth, when known
  double translation_error_mm = 0;            // displacement of the part's centre, when known
};

struct ProjectMergeResult {
  std::string project;
  std::string pose_method;  // how the poses were found, e.g. "turntable axis (not registered)"
  std::vector<MergedView> views;
  PointCloud merged;  // part frame, scalars view and quality
  std::optional<CadComparison> cad;
  double reconstruct_seconds = 0, merge_seconds = 0, compare_seconds = 0, total_seconds = 0;
  // Largest pose errors against the truth over the merged views (0 when no truth is known).
  double max_rotation_error_deg = 0, max_translation_error_mm = 0;
  bool has_truth = false;

  nlohmann::json ToJson() const;  // the report's report.json
  std::string Summary() const;    // the report's summary.txt and what the command prints
};

// Steps 1 to 4 of the header comment. `cad_in_part`: the CAD mesh in the part frame, or null.
// Throws slshadow::Error naming the project, the view and the field on bad input, and when no
// view can be merged.
ProjectMergeResult MergeProject(const std::filesystem::path& project_dir,
                                const TriangleMesh* cad_in_part,
                                const ProjectMergeOptions& options = {});

// The model folder, written atomically (an existing folder is replaced only with `overwrite`):
//  - MODEL/report.json: ToJson(): views (poses, figures, left out with the reason), CAD figures;
//  - MODEL/summary.txt: Summary();
//  - MODEL/merged.ply: the merged cloud, part frame, scalars view, quality (and deviation_mm with
//    a CAD mesh);
//  - MODEL/cad_deviation.ply: with a CAD mesh, WritePaintedMesh;
//  - MODEL/cad_coverage.ply: with a CAD mesh, the surface samples with scalar reason
//    (CoverageReason), coloured covered green, not reconstructed red, grazing orange, occluded
//    blue, outside the field grey, table black.
//  - MODEL/report.html: with `write_html`, the self-contained page (report/html_report.h).
void WriteModel(const ProjectMergeResult& result, const TriangleMesh* cad_in_part,
                const std::filesystem::path& model_dir, bool overwrite, bool write_html = true);

}  // namespace slshadow::multiview
