#include "workflows/multiview/plan.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>

#include "core/error.h"
#include "core/string_printf.h"
#include "workflows/multiview/project_merge.h"
#include "workflows/multiview/turntable_scene.h"

namespace slshadow::multiview {

namespace {

constexpr auto kReconstructed = static_cast<uint8_t>(PredictedReason::kReconstructed);

double Share(size_t a, size_t b) { return b ? static_cast<double>(a) / static_cast<double>(b) : 0; }

}  // namespace

void PlanOptions::Check() const {
  SLSHADOW_THROW_IF(!(step_deg >= 0.5 && step_deg <= 180),
                    "--step-deg: must be in [0.5, 180] (got ", step_deg, ")");
  SLSHADOW_THROW_IF(!std::isfinite(start_deg), "--start-deg: must be finite (got ", start_deg, ")");
  SLSHADOW_THROW_IF(!(target > 0 && target <= 1), "--target: must be in (0, 1] (got ", target, ")");
  prediction.Check();
}

ViewPlan PlanTurntableViews(const TriangleMesh& cad_in_part, const Rig& rig,
                            const PlanOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  options.Check();
  SLSHADOW_THROW_IF(!rig.turntable, "plan: rig '", rig.name,
                    "' has no turntable axis (calibrate it: slshadow calibrate turntable)");
  const TurntableAxis& axis = *rig.turntable;
  const CoveragePredictor predictor(cad_in_part, rig, axis, options.prediction);
  const size_t ns = predictor.Samples().size();
  const std::vector<uint8_t>& on_table = predictor.OnTable();

  // Every candidate's reconstructed samples; a cache by angle for the uniform baseline.
  const int count = std::max(1, static_cast<int>(std::floor(360.0 / options.step_deg + 1e-9)));
  std::map<double, std::vector<uint8_t>> by_angle;
  const auto seen_at = [&](double deg) -> const std::vector<uint8_t>& {
    const double key = std::round(deg * 1e6) / 1e6;
    auto it = by_angle.find(key);
    if (it == by_angle.end()) {
      std::vector<uint8_t> v = predictor.View(axis.RigFromTableTurn(key).Inverse());
      for (uint8_t& x : v) x = x == kReconstructed;
      it = by_angle.emplace(key, std::move(v)).first;
    }
    return it->second;
  };
  std::vector<double> candidates;
  for (int k = 0; k < count; ++k) candidates.push_back(options.start_deg + k * options.step_deg);
  std::vector<const std::vector<uint8_t>*> cand_seen;
  for (double a : candidates) cand_seen.push_back(&seen_at(a));

  ViewPlan plan;
  plan.candidates = candidates.size();
  plan.samples = ns;
  plan.target = options.target;
  std::vector<uint8_t> reachable(ns, 0);
  for (size_t i = 0; i < ns; ++i) {
    if (on_table[i]) continue;
    ++plan.off_table;
    for (const auto* s : cand_seen) {
      if ((*s)[i]) {
        reachable[i] = 1;
        ++plan.reachable;
        break;
      }
    }
  }
  SLSHADOW_THROW_IF(plan.reachable == 0,
                    "plan: no candidate view reconstructs any of the part (rig '", rig.name, "')");
  plan.reachable_share = Share(plan.reachable, plan.off_table);

  // Greedy set cover.
  std::vector<uint8_t> covered(ns, 0);
  std::vector<bool> used(candidates.size(), false);
  size_t n_covered = 0;
  while (Share(n_covered, plan.reachable) < options.target) {
    size_t best = candidates.size(), best_gain = 0;
    for (size_t c = 0; c < candidates.size(); ++c) {
      if (used[c]) continue;
      size_t gain = 0;
      const std::vector<uint8_t>& s = *cand_seen[c];
      for (size_t i = 0; i < ns; ++i) gain += reachable[i] & s[i] & (covered[i] ^ 1);
      if (gain > best_gain) best = c, best_gain = gain;
    }
    if (best == candidates.size()) break;  // nothing more to gain
    used[best] = true;
    const std::vector<uint8_t>& s = *cand_seen[best];
    for (size_t i = 0; i < ns; ++i) covered[i] |= reachable[i] & s[i];
    n_covered += best_gain;
    plan.greedy_deg.push_back(candidates[best]);
    plan.greedy_coverage.push_back(Share(n_covered, plan.reachable));
  }
  plan.reached = Share(n_covered, plan.reachable) >= options.target;
  std::vector<double> sorted = plan.greedy_deg;
  std::sort(sorted.begin(), sorted.end());
  for (size_t k = 0; k < sorted.size(); ++k) {
    ViewSpec v;
    v.name = DefaultViewName(k);
    v.table_deg = sorted[k];
    plan.views.views.push_back(v);
  }

  // The uniform baseline.
  for (int n = 1; n <= count; ++n) {
    std::vector<uint8_t> seen(ns, 0);
    for (int k = 0; k < n; ++k) {
      const std::vector<uint8_t>& s = seen_at(options.start_deg + 360.0 * k / n);
      for (size_t i = 0; i < ns; ++i) seen[i] |= s[i];
    }
    size_t hit = 0;
    for (size_t i = 0; i < ns; ++i) hit += reachable[i] & seen[i];
    plan.uniform_coverage.push_back(Share(hit, plan.reachable));
    if (plan.uniform_coverage.back() >= options.target) {
      plan.uniform_needed = n;
      break;
    }
  }
  plan.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return plan;
}

nlohmann::json ViewPlan::ToJson() const {
  return {{"target", target},
          {"reached", reached},
          {"views", greedy_deg.size()},
          {"greedy_deg", greedy_deg},
          {"greedy_coverage", greedy_coverage},
          {"uniform_coverage", uniform_coverage},
          {"uniform_needed", uniform_needed},
          {"candidates", candidates},
          {"samples", samples},
          {"off_table", off_table},
          {"reachable", reachable},
          {"reachable_share", reachable_share},
          {"seconds", seconds}};
}

std::string ViewPlan::Table() const {
  std::string out = StringPrintf(
      "reachable surface: %.2f %% of the part off the table (%zu of %zu samples, %zu candidate "
      "angles)\n"
      "views  plan: angle added  coverage   uniform: coverage\n",
      100 * reachable_share, reachable, off_table, candidates);
  const size_t rows = std::max(greedy_deg.size(), uniform_coverage.size());
  for (size_t k = 0; k < rows; ++k) {
    std::string plan_cell = "                           ";
    if (k < greedy_deg.size())
      plan_cell = StringPrintf("%11.2f deg  %7.2f %%", greedy_deg[k], 100 * greedy_coverage[k]);
    std::string uni = k < uniform_coverage.size()
                          ? StringPrintf("%7.2f %%", 100 * uniform_coverage[k])
                          : std::string("      -");
    out += StringPrintf("%5zu  %s   %s\n", k + 1, plan_cell.c_str(), uni.c_str());
  }
  out += StringPrintf(
      "target %.2f %%: the plan needs %zu views%s; uniform steps need %s (%.2f s)\n", 100 * target,
      greedy_deg.size(), reached ? "" : " (not reached)",
      uniform_needed > 0 ? std::to_string(uniform_needed).c_str() : "more than the candidates",
      seconds);
  return out;
}

PlanCheck CheckPlanAgainstProject(const TriangleMesh& cad_in_part, const Rig& rig,
                                  const std::filesystem::path& project_dir,
                                  const CoveragePredictionOptions& options) {
  SLSHADOW_THROW_IF(!rig.turntable, "plan check: rig '", rig.name, "' has no turntable axis");
  ProjectMergeOptions merge;
  merge.mode = options.mode;
  merge.poses = PoseSource::kAxis;  // the prediction is checked, not the registration
  merge.mesh = false;
  merge.cad.samples = options.samples;
  merge.cad.table_tolerance_mm = options.table_tolerance_mm;
  ProjectMergeResult merged = MergeProject(project_dir, &cad_in_part, merge);
  SLSHADOW_THROW_IF(!merged.cad, project_dir.string(), ": the merge made no CAD comparison");
  ViewsFile views;
  for (const MergedView& v : merged.views) {
    SLSHADOW_THROW_IF(!v.table_deg, project_dir.string(), ": view '", v.name,
                      "' has no table angle (the plan check predicts table views)");
    ViewSpec spec;
    spec.name = v.name;
    spec.table_deg = v.table_deg;
    views.views.push_back(spec);
  }
  PlanCheck result;
  result.prediction =
      PredictCoverage(cad_in_part, rig, PosesOfViews(views, rig), rig.turntable, options);
  result.check = CheckPrediction(result.prediction, *merged.cad);
  result.scan = std::move(*merged.cad);
  return result;
}

PlanPart LoadPlanPart(const std::filesystem::path& path) {
  PlanPart part;
  const std::string ext = path.extension().string();
  if (ext == ".yaml" || ext == ".yml" || ext == ".json") {
    part.scene = LoadScene(path);
    part.cad = PartSurface(*part.scene);
  } else {
    part.cad = ReadMesh(path);
  }
  SLSHADOW_THROW_IF(part.cad.empty(), path.string(), ": --part: the part has no triangles");
  return part;
}

}  // namespace slshadow::multiview
