// Whole parts, speed against accuracy (the study key `whole_part`; docs/formats.md "Study YAML",
// docs/studies/whole_part_quick/README.md). Each job is a whole-part virtual scan of the study's
// scene on a turntable: `views` table views in uniform steps over a full turn rendered into a
// multi-view project (workflows/multiview/virtual_project.h), the project merged per mode
// (workflows/multiview/project_merge.h: every view reconstructed, registered, fused) and the merged
// model compared with the part's CAD (workflows/multiview/cad_compare.h). An axis sets
// `whole_part.views` beside the usual pattern axes (codec files, patterns.phase_steps).
//
// Figures per job and mode: coverage of the part's reachable CAD surface (the face on the table
// excluded; reachable: what a full turn of `reference_views` uniform steps lets every device of the
// mode see unoccluded and not grazing, cad_compare.h's rules, so one denominator for every number
// of views: covered samples / samples reachable or covered), the coverage of what this job's views
// reach (cad_compare.h's coverage_reachable) and of the whole surface off the table, the merged
// cloud's C2M RMS (signed C2M, mm), the median over the views of each
// view's own C2M RMS, and the scan time
//
//   scan_time_s = acquisition_s + processing_s
//   acquisition_s = views x (patterns x frame_s + turn_s)     modelled: patterns = the pattern
//                   spec's image count (PatternSpec::NumImages), frame_s = whole_part.frame_ms, by
//                   default the scene's exposure (radiometry.exposure_us), turn_s = the table's
//                   turn and settle per view (whole_part.turn_s, default 0)
//   processing_s  = reconstructing every view + registering and fusing them (MergeProject's
//                   reconstruct_seconds + merge_seconds): measured wall seconds on this machine
//
// acquisition_s is in results.csv (reproducible); processing_s and scan_time_s are measured, so
// they are in timings and pareto.csv only. The merge writes the Pareto fronts of scan time against
// coverage (higher is better) and against RMS (lower is better), per mode.
#pragma once

#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <vector>

namespace slshadow {
class ConfigNode;
}  // namespace slshadow

namespace slshadow::studies {

struct WholePartOptions {
  int views = 8;  // table views over a full turn, in uniform steps (1..360)
  double start_deg = 0;
  // The scene object that stands on the turntable (its local +z through its origin is the axis,
  // workflows/multiview/turntable_scene.h MakeTurntableSetup) and the objects removed (the fixed
  // table plane the disc replaces).
  std::string part_object = "part";
  std::vector<std::string> remove_objects = {"table"};
  std::string poses = "registered";  // registered | axis (project_merge.h PoseSource)
  double frame_ms = 0;               // per pattern image; 0: the scene's exposure_us / 1000
  double turn_s = 0;                 // per view: the table's turn and settle
  int max_points_per_view = 400000;  // 0: every accepted point
  // The part's reachable surface, the denominator of `coverage`: what a full turn in this many
  // uniform steps from start_deg lets every device of the mode see (cad_compare.h's rules).
  int reference_views = 36;
  // CAD comparison (cad_compare.h CadCompareOptions; the inlier threshold is compare.threshold_mm).
  int cad_samples = 200000;
  double grazing_deg = 80;
  double table_tolerance_mm = 0.5;
  double coverage_radius_mm = 0;  // 0: per cloud, max(threshold, 3 x median spacing)

  nlohmann::json ToJson() const;  // every field
};

// The study key (or a job's `whole_part` tree). Unknown keys are errors; throws slshadow::Error
// naming the field and the value.
WholePartOptions WholePartOptionsFromConfig(const ConfigNode& node);

// The modelled acquisition: views x (patterns x frame_s + turn_s).
double AcquisitionSeconds(int views, int patterns, double frame_s, double turn_s);

namespace internal {

// Runs one whole-part job (read from `file`, named in errors): its result's `modes` (per mode the
// figures of the header comment) and `timing` (render_s, per mode reconstruct_s, merge_s,
// cad_compare_s and method_s = processing_s; total_s, cpu_s). The multi-view project is written
// under JOBS/work/<id>/ and removed when the job ends. Throws slshadow::Error naming the file.
nlohmann::json RunWholePartJob(const nlohmann::json& job, const std::filesystem::path& file);

// The merge of a whole-part study into `out_dir`: results.csv (one row per job and mode: id, the
// axis values, mode, views_merged, points, coverage, coverage_views, coverage_total,
// reachable_share, mean_mm, rms_mm, median_mm, p95_mm, max_mm, single_view_rms_mm, patterns,
// acquisition_s), pareto.csv (per job and mode: acquisition_s, processing_s, scan_time_s, coverage,
// rms_mm, and per front on_front and key), time_vs_coverage.png/.svg and time_vs_rms.png/.svg.
// Returns the rows written and the fronts' lines ("C1 stereo: 000004 (views=2 ...)").
struct WholePartMerge {
  int rows = 0;
  std::vector<std::string> coverage_front, rms_front;
};
WholePartMerge WriteWholePartResults(const std::filesystem::path& out_dir,
                                     const std::vector<std::string>& axes,
                                     const std::vector<nlohmann::json>& results,
                                     const std::string& study);

}  // namespace internal
}  // namespace slshadow::studies
