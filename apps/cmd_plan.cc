// slshadow plan --rig RIG --part PART [--turntable | --tilts-deg 0,90,180 | --candidates V.yaml]
//   [--step-deg S] [--target T] --out VIEWS.yaml  |  --check PROJECT
#include <CLI/CLI.hpp>
#include <cstdio>
#include <optional>
#include <vector>

#include "apps/commands.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/rig.h"
#include "patterns/pattern_spec.h"
#include "workflows/multiview/coverage_prediction.h"
#include "workflows/multiview/plan.h"

namespace slshadow::app {

int RunPlan(int argc, char** argv) {
  CLI::App app{
      "Plan a scan before the part is on the table: the fewest table angles (or, without\n"
      "--turntable, placements by hand) that "
      "reconstruct\n"
      "the target share of the part's reachable surface (what some candidate angle reconstructs; "
      "the\n"
      "face on the table excluded). Each candidate angle (a full turn in --step-deg steps) is "
      "predicted\n"
      "by the simulator's and decoder's rules without rendering images (hidden from a camera or "
      "the\n"
      "projector, grazing, outside an image, too dark), then a set cover picks the views (greedy, "
      "then\n"
      "one view fewer while a swap search or an exhaustive branch and bound finds such a set; "
      "table\n"
      "angles then refined every --refine-deg about the chosen ones). "
      "Prints\n"
      "coverage against the number of views beside uniform steps over a full turn, and writes the "
      "views\n"
      "file that slshadow scan / slshadow simulate --views read (docs/formats.md \"Views YAML\"). "
      "Example:\n"
      "  slshadow plan --rig config/demo/turntable_rig.yaml --part "
      "config/demo/turntable_scene.yaml \\\n"
      "      --turntable --target 0.98 --out views.yaml --coverage coverage.ply",
      argv[0]};
  std::string rig_path, part_path, out_path, coverage_path, report_path, patterns_path, check_path,
      mode = "stereo";
  bool turntable = false;
  multiview::PlanOptions options;
  app.add_option("--rig", rig_path,
                 "rig file with its turntable axis (docs/formats.md \"Rig YAML\")")
      ->required();
  app.add_option("--part", part_path,
                 "the part in the part frame: a mesh (.stl/.ply/.obj), or a scene (.yaml/.json) "
                 "whose meshes are the part at table angle 0 (its radiometry is used)")
      ->required();
  app.add_flag(
      "--turntable", turntable,
      "candidates are table angles (every --step-deg); without it, placements by hand: the "
      "part tilted by each --tilts-deg, then turned about the vertical every --step-deg "
      "(views with a part_from_rig_guess; nothing excluded as on the table)");
  std::vector<double> tilts_deg = {0, 90, 180};
  app.add_option("--tilts-deg", tilts_deg,
                 "hand placements: the tilts about the horizontal axis the user allows, degrees")
      ->delimiter(',')
      ->capture_default_str();
  std::string candidates_path;
  app.add_option("--candidates", candidates_path,
                 "the candidates as a views file (table angles or hand-placed views with their "
                 "part_from_rig_guess) instead of the generated ones");
  app.add_option("--out", out_path, "the planned views file (.yaml or .json); required to plan");
  app.add_option("--step-deg", options.step_deg, "candidate table angles every this many degrees")
      ->capture_default_str();
  app.add_option("--start-deg", options.start_deg, "first candidate angle, degrees")
      ->capture_default_str();
  app.add_option("--refine-deg", options.refine_deg,
                 "--turntable: also the chosen angles' neighbours every this many degrees within "
                 "a step, searched again (0: the grid only)")
      ->capture_default_str();
  app.add_option("--refine-rounds", options.refine_rounds,
                 "--turntable: at most this many refinements (while new neighbours appear)")
      ->capture_default_str();
  app.add_flag("--best-uniform", options.best_uniform_offset,
               "--turntable: also the uniform baseline from its best offset (slower)");
  app.add_option("--search-budget", options.max_evaluations,
                 "the exact search's budget in gain evaluations (past it: the best found)")
      ->capture_default_str();
  app.add_option("--target", options.target, "share of the reachable surface to cover, (0, 1]")
      ->capture_default_str();
  app.add_option("--samples", options.prediction.samples, "CAD surface samples")
      ->capture_default_str();
  app.add_option("--mode", mode, "reconstruction: stereo (both cameras) | projector (first camera)")
      ->capture_default_str()
      ->check(CLI::IsMember({"stereo", "projector"}));
  app.add_option("--albedo", options.prediction.albedo,
                 "the part's albedo for the too-dark rule (default: a scene's darkest mesh, else "
                 "0.5)");
  app.add_option("--patterns", patterns_path,
                 "the pattern spec the scan will project (docs/formats.md \"Pattern spec\"): its "
                 "finest fringe against the scene's defocus layers (default: a 16 px period, both "
                 "axes coded, the demo's)");
  app.add_option("--coverage", coverage_path,
                 "also write the plan's predicted coverage map (PLY of the surface samples, "
                 "docs/formats.md \"Coverage map PLY\")");
  app.add_option("--report", report_path, "also write the plan's figures as JSON");
  app.add_flag("--check-points", options.prediction.predict_points,
               "with --check: measure the prediction by the points each view would reconstruct "
               "(the reference grid ray-cast, the reconstruction's filters run on it) instead of "
               "by its samples; slower");
  bool rendered = false, no_rendered = false;
  app.add_flag("--rendered", rendered,
               "also run the reconstruction on each view's ray-cast projector maps and take the "
               "cells its depth-discontinuity filter rejects from the prediction (the bands along "
               "occlusion edges); the default with --check; for planning ~2.5x slower");
  app.add_flag("--no-rendered", no_rendered,
               "with --check: the prediction's rules alone, without the rendered reconstruction");
  app.add_option("--check", check_path,
                 "instead of planning, check the prediction against a scanned (or simulated) "
                 "project of the planned views (table angles or placed by hand): merged at the "
                 "planned poses, compared with the part per CAD sample, disagreements by reason "
                 "(--out not needed)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  SLSHADOW_THROW_IF(check_path.empty() && out_path.empty(), "--out: required");
  const double albedo = options.prediction.albedo;
  const bool albedo_given = app.count("--albedo") > 0;
  options.prediction.mode = ReconstructModeFromString(mode);
  options.prediction.rendered_reconstruction = check_path.empty() ? rendered : !no_rendered;
  const Rig rig = LoadRig(rig_path);
  const multiview::PlanPart part = multiview::LoadPlanPart(part_path);
  if (part.scene)
    options.prediction = multiview::WithSceneRadiometry(options.prediction, *part.scene);
  if (albedo_given) options.prediction.albedo = albedo;
  if (!patterns_path.empty())
    options.prediction =
        multiview::WithPatterns(options.prediction, LoadPatternSpec(patterns_path));
  if (!check_path.empty()) {
    const multiview::PlanCheck check =
        multiview::CheckPlanAgainstProject(part.cad, rig, check_path, options.prediction);
    std::printf("%s%s", check.prediction.Table().c_str(), check.check.Summary().c_str());
    if (!report_path.empty())
      WriteTextFileAtomically(report_path, check.check.ToJson().dump(1) + "\n");
    return 0;
  }
  const std::optional<TurntableAxis> table =
      turntable ? rig.turntable : std::optional<TurntableAxis>();
  multiview::ViewPlan plan;
  if (turntable && candidates_path.empty()) {
    plan = multiview::PlanTurntableViews(part.cad, rig, options);
  } else {
    std::vector<multiview::ViewCandidate> candidates;
    if (!candidates_path.empty()) {
      for (const multiview::ViewSpec& v : multiview::LoadViews(candidates_path).views)
        candidates.push_back({v.name, v});
    } else {
      candidates = multiview::PlacementCandidates(part.cad, rig, tilts_deg, options.step_deg,
                                                  options.start_deg);
    }
    plan = multiview::PlanViews(part.cad, rig, candidates, table, options);
  }
  std::printf("%s", plan.Table().c_str());
  SLSHADOW_THROW_IF(plan.views.views.empty(), "plan: no view reconstructs anything new");
  multiview::SaveViews(plan.views, out_path);
  if (!coverage_path.empty()) {
    const multiview::CoveragePrediction prediction = multiview::PredictCoverage(
        part.cad, rig, multiview::PosesOfViews(plan.views, rig), table, options.prediction);
    multiview::WriteCoverageMap(coverage_path, prediction);
    std::printf("%s", prediction.Table().c_str());
  }
  if (!report_path.empty()) WriteTextFileAtomically(report_path, plan.ToJson().dump(1) + "\n");
  std::printf("-> %s (%zu views)\n", out_path.c_str(), plan.views.views.size());
  return plan.reached ? 0 : 1;
}

}  // namespace slshadow::app
