// `slshadow merge PROJECT --out MODEL`: a multi-view project (workflows/multiview/views.h)
// reconstructed view by view, the views registered into one part frame and fused into one model
// (workflows/multiview/merge.h MergeViews), and its comparison with the CAD model
// (workflows/multiview/cad_compare.h).
//
//  1. Every complete view is reconstructed like any scan (the ImageSet decoded and triangulated
//     with the reconstruct library); one view's images are in memory at a time, each view keeps
//     its cloud (at most max_points_per_view points, every s-th accepted cell). Missing views are
//     left out and named. Views standing on the table (table views, and hand placements with
//     placed_on_table) lose the points of the table (table_crop_mm).
//  2. Initial poses: table views from the rig's turntable axis and the commanded angle
//     (part_from_rig = axis.RigFromTableTurn(a).Inverse()); hand-placed views from their guess,
//     or, without one, by global registration (FPFH + RANSAC, then ICP) against the views posed
//     before them.
//  3. With poses kRegistered (the default): MergeViews refines them (pairwise ICP between
//     overlapping views, one Ceres pose graph, the first merged view as the anchor that fixes the
//     part frame); a view that does not fit (no overlap, a pair that disagrees, a pose that
//     departs from its table angle beyond registration.max_initial_departure_*) is left out and
//     named with the reason. With kAxis the initial poses are used as they are (hand-placed views
//     without a guess are left out).
//  4. The merged cloud: the views fused in the part frame (MergeViews step 4: one point per
//     surface cell where the views agree within their noise, kept apart and flagged where they
//     do not), scalars view (index into the result's views), views_fused, sigma_mm, disagree.
//  5. With a CAD mesh (part frame): CompareWithCad, the deviation painted on the mesh.
//  6. Unless options.mesh is false: the surface mesh of the merged cloud (surface_mesh.h:
//     Poisson, trimmed where no view saw the surface), timed apart (mesh_seconds).
//
// Truth: when a view's ImageSet records the pose it was rendered at (a virtual project's
// extra.view.part_from_rig_true), the report gives each pose's error against it, for the initial
// and the final pose: the rotation angle of estimated * true^-1 (deg) and the displacement it
// gives the part's centre (the CAD's centroid, else the merged cloud's), mm.
#pragma once

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/mesh.h"
#include "core/point_cloud.h"
#include "core/rigid3.h"
#include "core/shard.h"
#include "patterns/codec.h"
#include "reconstruct/reconstruct.h"
#include "workflows/multiview/cad_compare.h"
#include "workflows/multiview/merge.h"
#include "workflows/multiview/surface_mesh.h"
#include "workflows/multiview/view_reconstruction.h"
#include "workflows/multiview/views.h"

namespace slshadow::multiview {

// Where the merged views' poses come from (step 3 of the header comment).
enum class PoseSource { kRegistered, kAxis };
std::string ToString(PoseSource source);                // "registered", "axis"
PoseSource PoseSourceFromString(const std::string& s);  // throws slshadow::Error

struct ProjectMergeOptions {
  ReconstructMode mode = ReconstructMode::kStereo;
  PoseSource poses = PoseSource::kRegistered;
  MergeOptions registration;  // MergeViews' options; `refine` is set from `poses`
  ReconstructOptions reconstruct = [] {
    ReconstructOptions r;
    r.report_residuals = false;  // the gates and the cloud are the same, faster
    return r;
  }();
  DecodeOptions decode;
  size_t max_points_per_view = 400000;  // 0: every accepted point
  // Views standing on the table (ViewSpec::StandsOnTable): points less than this above the table
  // plane (the plane through the axis point
  // perpendicular to the axis, where the part stands) are the table, not the part, and are
  // dropped from the view's cloud. Negative: keep every point.
  double table_crop_mm = 0.5;
  CadCompareOptions cad;
  // Step 1's reconstructions kept on disk (view_reconstruction.h): a view stored here (same
  // images, same mode, decode and reconstruct options, same max_points_per_view) is read instead
  // of reconstructed; a view not stored yet is reconstructed and written here. Empty: none kept.
  std::filesystem::path reconstructions;
  // Step 6: the surface mesh (surface_mesh.h BuildSurfaceMesh) of the merged cloud.
  bool mesh = true;
  SurfaceMeshOptions mesh_options;
  void Check() const;  // throws slshadow::Error naming the bad field
};

// One view of the merge.
struct MergedView {
  std::string name;
  std::optional<double> table_deg;
  bool merged = false;  // false: left out; `reason` says why
  std::string reason;
  std::optional<Rigid3d> part_from_rig_initial;  // the global registration's for hand views
  Rigid3d part_from_rig;                         // the pose used (merged views)
  // Registration (poses kRegistered, merged views): MergeViews' ViewPose figures.
  bool anchor = false;            // the view whose initial pose fixes the part frame
  int pairs = 0;                  // kept pairs the view is in
  double residual_rms_mm = 0;     // point-to-plane RMS over its pairs at the final poses
  double noise_mm = 0;            // its noise along the normal, from the residuals
  double sigma_rotation_deg = 0;  // 1-sigma (pose graph covariance; hand views: ViewPose)
  double sigma_translation_mm = 0;
  double graph_sigma_rotation_deg = 0, graph_sigma_translation_mm = 0;  // the graph's own
  // Turntable model (MergeResult::turntable_model): the fitted true table angle, its departure
  // from the commanded one's and its 1-sigma, deg.
  std::optional<double> table_angle_deg;
  double table_angle_correction_deg = 0;
  double sigma_table_angle_deg = 0;
  // Directions (part frame) some pair of the view left free, held at the prior (ViewPose).
  std::vector<std::string> prior_directions;
  size_t points = 0;            // in the view's cloud (after max_points_per_view)
  int64_t accepted_points = 0;  // the reconstruction's accepted cells
  double reconstruct_seconds = 0;
  std::string
      reconstruction;  // "reconstructed", or where it was read from (options.reconstructions)
  std::optional<Rigid3d> part_from_rig_true;  // recorded by a virtual project
  double rotation_error_deg = 0;              // against the truth, when known
  double translation_error_mm = 0;            // displacement of the part's centre, when known
  double initial_rotation_error_deg = 0;      // the same for the initial pose
  double initial_translation_error_mm = 0;
};

struct ProjectMergeResult {
  std::string project;
  std::string pose_method;  // how the poses were found, in words
  bool refined = false;     // poses kRegistered: MergeViews registered the views
  std::vector<MergedView> views;
  PointCloud merged;  // part frame, normals, scalars view, views_fused, sigma_mm, disagree
  // MergeViews' outcome without its cloud: pairs, loop closure, pose graph, fusion figures and
  // times. Its view indices are into registration.views; registration_view maps each to the
  // index in `views`.
  MergeResult registration;
  std::vector<int> registration_view;
  std::optional<CadComparison> cad;
  // The watertight (then trimmed) surface mesh, with options.mesh; with a CAD mesh, the signed
  // distances of its vertices to the CAD (mesh_c2m, threshold as the cloud's).
  std::optional<SurfaceMeshResult> mesh;
  std::optional<compare::DistanceStats> mesh_c2m;
  double mesh_seconds = 0;  // apart from total_seconds
  double reconstruct_seconds = 0, merge_seconds = 0, compare_seconds = 0, total_seconds = 0;
  // Largest pose errors against the truth over the merged views (0 when no truth is known).
  double max_rotation_error_deg = 0, max_translation_error_mm = 0;
  double max_initial_rotation_error_deg = 0, max_initial_translation_error_mm = 0;
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

// Step 1 alone, for shard `shard` of the project's complete views (in project order, cut into
// contiguous blocks: core/shard.h): each view not yet in options.reconstructions (which must be
// set) is reconstructed and written there; a stored one made from other images or with other
// options is refused (view_reconstruction.h). `on_view(name, k, n)` reports progress. The views
// are independent jobs: shards may run at once, in any order, on any machine sharing the folder.
struct ReconstructShardSummary {
  int assigned = 0;       // complete views of this shard
  int already_done = 0;   // stored before, with the same images and options
  int reconstructed = 0;  // reconstructed and written now
  double seconds = 0;
  std::string Brief() const;
};
ReconstructShardSummary ReconstructProjectShard(
    const std::filesystem::path& project_dir, const ProjectMergeOptions& options, Shard shard,
    const std::function<void(const std::string&, size_t, size_t)>& on_view = {});

// The model folder, written atomically (an existing folder is replaced only with `overwrite`):
//  - MODEL/report.json: ToJson(): views (poses, figures, left out with the reason), CAD figures;
//  - MODEL/summary.txt: Summary();
//  - MODEL/merged.ply: the merged cloud, part frame, normals, scalars view, views_fused,
//    sigma_mm, disagree (and deviation_mm with a CAD mesh);
//  - MODEL/mesh.ply: with a mesh, the trimmed surface mesh (binary PLY, part frame);
//  - MODEL/cad_deviation.ply: with a CAD mesh, WritePaintedMesh;
//  - MODEL/cad_coverage.ply: with a CAD mesh, the surface samples with scalar reason
//    (CoverageReason), coloured covered green, not reconstructed red, grazing orange, occluded
//    blue, outside the field grey, table black.
//  - MODEL/report.html: with `write_html`, the self-contained page (report/html_report.h).
void WriteModel(const ProjectMergeResult& result, const TriangleMesh* cad_in_part,
                const std::filesystem::path& model_dir, bool overwrite, bool write_html = true);

}  // namespace slshadow::multiview
