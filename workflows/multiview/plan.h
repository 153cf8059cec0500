// `slshadow plan`: the fewest views that cover a part, before it is on the table (turntable angles,
// or placements by hand: PlanViews / PlacementCandidates below). Every
// candidate table angle (a full turn in steps) is predicted (coverage_prediction.h, no images
// rendered); the part's reachable surface is what at least one candidate of the grid reconstructs;
// the set cover (plan_search.h) then picks the fewest candidates covering the target share of it:
// greedy, then one view fewer at a time by a swap search and a branch and bound that either finds
// such a set or proves there is none. Table plans then refine: the chosen angles' neighbours every
// refine_deg within a grid step are predicted and the cover searched again over the grid and
// them (the reachable surface stays the grid's, so refining never moves the target). Beside it,
// the uniform baseline: n views evenly spaced over a full turn from the first candidate angle (and,
// on request, from the best offset), for n = 1, 2, ... until the target is reached (or n = the
// number of candidates); a table plan that would need more views than the uniform steps (whose
// angles may lie off the candidate grid, 72 deg for 5 views) takes the uniform steps.
// The picks are reported in greedy order (each next the one adding the most).
//
// Frames and units: the part frame (views.h), mm, degrees.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/mesh.h"
#include "core/rig.h"
#include "sim/scene.h"
#include "workflows/multiview/coverage_prediction.h"
#include "workflows/multiview/views.h"

namespace slshadow::multiview {

struct PlanOptions {
  double step_deg = 15;  // candidate table angles: start_deg + k * step_deg over a full turn
  double start_deg = 0;
  double target = 0.98;  // share of the reachable surface, (0, 1]
  // Table plans: after the cover of the grid, the chosen angles' neighbours every refine_deg
  // within a grid step (+-5, +-10 deg for 5 in 15) are predicted too and the cover searched again
  // over all, up to refine_rounds times (while new neighbours appear); 0 (or not less than
  // step_deg): the grid only.
  double refine_deg = 5;
  int refine_rounds = 3;
  // The uniform baseline also from its best offset (every refine_deg, else step_deg, within one
  // uniform step; predicts those angles too: slower).
  bool best_uniform_offset = false;
  // The exact search's budget (plan_search.h CoverSearchOptions::max_evaluations).
  uint64_t max_evaluations = 200'000'000;
  CoveragePredictionOptions prediction;
  void Check() const;  // throws slshadow::Error naming the bad field (the option's name)
};

struct ViewPlan {
  // The plan, named view_00, view_01, ...: table views by increasing angle; placed views (hand
  // plans) in the order greedy picked them, each with its part_from_rig_guess.
  ViewsFile views;
  std::vector<double> greedy_deg;  // table plans: the chosen angles in the order greedy picked
  std::vector<std::string> greedy_label;  // every plan: the chosen candidates' labels, same order
  std::vector<double> greedy_coverage;    // of the reachable surface after 1, 2, ... views
  bool reached = false;                   // the plan reaches the target
  // Uniform baseline: uniform_coverage[n - 1] for n views evenly spaced; uniform_needed the first
  // n reaching the target (0: none up to the number of candidates).
  std::vector<double> uniform_coverage;
  int uniform_needed = 0;
  // Uniform from the best offset (PlanOptions::best_uniform_offset; empty otherwise): per n, the
  // best coverage and its offset from start_deg; best_uniform_needed as uniform_needed.
  std::vector<double> best_uniform_coverage, best_uniform_offset_deg;
  int best_uniform_needed = 0;
  // The search (plan_search.h): greedy alone's views (and whether it reached the target); the
  // best coverage found with one view fewer than the plan, exact when the search was exhaustive
  // (no set of candidates one fewer reaches the target); classes of samples; its gain evaluations.
  size_t greedy_views = 0;
  bool greedy_reached = false;
  double one_fewer_coverage = 0;
  bool one_fewer_exact = false;
  size_t classes = 0;
  uint64_t search_evaluations = 0;
  size_t candidates = 0;       // the candidates searched (the grid and the refined angles)
  size_t grid_candidates = 0;  // table plans: the grid's
  size_t samples = 0, off_table = 0, reachable = 0;
  double reachable_share = 0;  // reachable / off the table
  double target = 0;
  double seconds = 0;
  nlohmann::json ToJson() const;
  std::string Table() const;  // coverage against the number of views, plan beside uniform
};

// Plans table views of `cad_in_part` for `rig` (which must have a turntable axis). Throws
// slshadow::Error on a rig without an axis, bad options or nothing reachable.
ViewPlan PlanTurntableViews(const TriangleMesh& cad_in_part, const Rig& rig,
                            const PlanOptions& options = {});

// A plan confirmed by its scan (`slshadow plan --check PROJECT`): the project (the planned views,
// scanned or simulated) merged at the planned poses (ProjectMergeOptions poses kAxis, no mesh:
// table views at their angle on the axis, views placed by hand at their part_from_rig_guess) with
// options.reconstruct and compared with `cad_in_part` on options.samples samples; the prediction
// of the project's views at those poses against it, per sample (CheckPrediction); the face on
// the rig's turntable (when it has one) is excluded in both; with options.predict_points the
// prediction's coverage is that of its predicted points. Throws slshadow::Error as
// MergeProject, and when a view has no pose.
struct PlanCheck {
  CoveragePrediction prediction;
  PredictionCheck check;
  CadComparison scan;
};
PlanCheck CheckPlanAgainstProject(const TriangleMesh& cad_in_part, const Rig& rig,
                                  const std::filesystem::path& project_dir,
                                  const CoveragePredictionOptions& options);

// A candidate placement of the part: a label for the tables ("15.00 deg", "yaw 30 tilt 45") and
// the view it would be (a table view with its angle, or a hand-placed view whose
// part_from_rig_guess is its pose).
struct ViewCandidate {
  std::string label;
  ViewSpec view;
};

// Hand-placed candidates (`slshadow plan` without --turntable): the part turned about its centre
// (the centre of its bounding box in the part frame) from where the part frame puts it, first
// tilted by each of `tilts_deg` about the horizontal axis (the rig's x axis made orthogonal to
// "up"), then turned about "up" by start_deg + k * step_deg over a full turn; "up" is the rig's
// turntable axis when it has one, else the first camera's -y (image up). A tilt of 0 turns once
// per step, as a table would; tilts of +-180 deg the same for the flipped part. Throws
// slshadow::Error naming the option on bad steps or tilts.
std::vector<ViewCandidate> PlacementCandidates(const TriangleMesh& cad_in_part, const Rig& rig,
                                               const std::vector<double>& tilts_deg,
                                               double step_deg, double start_deg = 0);

// The fewest of `candidates` that reach options.target of the reachable surface (the set cover
// of PlanTurntableViews; no uniform baseline). `table_axis`: the face on that table is
// excluded (nullopt for parts placed by hand: nothing excluded). Throws slshadow::Error on no
// candidates, bad options or nothing reachable.
ViewPlan PlanViews(const TriangleMesh& cad_in_part, const Rig& rig,
                   const std::vector<ViewCandidate>& candidates,
                   const std::optional<TurntableAxis>& table_axis, const PlanOptions& options);

// The part for `slshadow plan --part` / `merge --cad`: a mesh (.stl/.ply/.obj) is the CAD model;
// a scene (.yaml/.yml/.json) gives its meshes as the CAD model (PartSurface) and its radiometry.
struct PlanPart {
  TriangleMesh cad;
  std::optional<Scene> scene;
};
PlanPart LoadPlanPart(const std::filesystem::path& path);

}  // namespace slshadow::multiview
