#include "workflows/multiview/plan.h"

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <map>

#include "core/error.h"
#include "core/string_printf.h"
#include "workflows/multiview/plan_search.h"
#include "workflows/multiview/project_merge.h"
#include "workflows/multiview/turntable_scene.h"
#include "workflows/multiview/virtual_project.h"

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
  SLSHADOW_THROW_IF(!(refine_deg == 0 || (refine_deg >= 0.1 && refine_deg <= 180)),
                    "--refine-deg: must be 0 (off) or in [0.1, 180] (got ", refine_deg, ")");
  SLSHADOW_THROW_IF(refine_rounds < 0 || refine_rounds > 20,
                    "--refine-rounds: must be in [0, 20] (got ", refine_rounds, ")");
  SLSHADOW_THROW_IF(max_evaluations < 1, "--search-budget: must be at least 1");
  prediction.Check();
}

namespace {

// Samples as bits (one per reachable sample), so that a set of views is covered by OR and popcount.
using Bits = std::vector<uint64_t>;

Bits ToBits(const std::vector<uint8_t>& seen, const std::vector<size_t>& reachable_index) {
  Bits b((reachable_index.size() + 63) / 64, 0);
  for (size_t j = 0; j < reachable_index.size(); ++j)
    if (seen[reachable_index[j]]) b[j / 64] |= uint64_t{1} << (j % 64);
  return b;
}

// The reachable samples (off the table, reconstructed by one of the first `reach_from` candidates:
// the grid's, so that refined angles do not move the target) and the fewest
// candidates (FewestCover, plan_search.h; `seeds` as there) whose union covers options.target of
// them over `seen` (per candidate, 1 where it reconstructs the sample). Fills plan's samples,
// off_table, reachable, reachable_share, target and the search's figures; returns the chosen
// candidates and, in *bits, every candidate's reachable samples as bits (for Account).
std::vector<size_t> SetCover(const std::vector<const std::vector<uint8_t>*>& seen,
                             const std::vector<uint8_t>& on_table, const PlanOptions& options,
                             const std::vector<std::vector<size_t>>& seeds, size_t reach_from,
                             const std::string& rig_name, ViewPlan* plan,
                             std::vector<uint8_t>* reachable, std::vector<Bits>* bits) {
  const size_t ns = on_table.size();
  plan->candidates = seen.size();
  plan->samples = ns;
  plan->off_table = 0;
  plan->target = options.target;
  reachable->assign(ns, 0);
  std::vector<size_t> reachable_index;
  for (size_t i = 0; i < ns; ++i) {
    if (on_table[i]) continue;
    ++plan->off_table;
    for (size_t c = 0; c < reach_from; ++c) {
      if ((*seen[c])[i]) {
        (*reachable)[i] = 1;
        reachable_index.push_back(i);
        break;
      }
    }
  }
  plan->reachable = reachable_index.size();
  SLSHADOW_THROW_IF(plan->reachable == 0,
                    "plan: no candidate view reconstructs any of the part (rig '", rig_name, "')");
  plan->reachable_share = Share(plan->reachable, plan->off_table);
  bits->clear();
  std::vector<std::vector<uint8_t>> on_reachable;
  for (const auto* s : seen) {
    bits->push_back(ToBits(*s, reachable_index));
    std::vector<uint8_t>& r = on_reachable.emplace_back(reachable_index.size());
    for (size_t j = 0; j < reachable_index.size(); ++j) r[j] = (*s)[reachable_index[j]];
  }
  size_t needed = 0;  // the fewest samples whose share reaches the target
  while (Share(needed, plan->reachable) < options.target) ++needed;
  std::vector<const std::vector<uint8_t>*> sets;
  for (const auto& r : on_reachable) sets.push_back(&r);
  const CoverInstance instance(sets);
  CoverSearchOptions search;
  search.max_evaluations = options.max_evaluations;
  const CoverPlan cover = FewestCover(instance, needed, seeds, search);
  plan->classes = instance.Classes();
  plan->greedy_views = cover.greedy.size();
  plan->greedy_reached = cover.greedy_covered >= needed;
  plan->one_fewer_coverage = Share(cover.one_fewer.covered, plan->reachable);
  plan->one_fewer_exact = cover.one_fewer.exact;
  plan->search_evaluations = cover.evaluations;
  return cover.picks;
}

// The plan's accounting of `chosen` (indices into `bits`): ordered greedily (each next the one
// adding the most), with its labels, the coverage after 1, 2, ... views and whether it reaches
// the target. Returns the order.
std::vector<size_t> Account(const std::vector<Bits>& bits, std::vector<size_t> chosen,
                            const std::vector<std::string>& labels, ViewPlan* plan) {
  plan->greedy_label.clear();
  plan->greedy_coverage.clear();
  const size_t words = bits.empty() ? 0 : bits[0].size();
  Bits covered(words, 0);
  std::vector<size_t> order;
  size_t n_covered = 0;
  while (!chosen.empty()) {
    size_t best = 0, best_gain = 0;
    for (size_t k = 0; k < chosen.size(); ++k) {
      size_t gain = 0;
      for (size_t w = 0; w < words; ++w)
        gain += static_cast<size_t>(std::popcount(bits[chosen[k]][w] & ~covered[w]));
      if (k == 0 || gain > best_gain) best = k, best_gain = gain;
    }
    const size_t c = chosen[best];
    chosen.erase(chosen.begin() + static_cast<std::ptrdiff_t>(best));
    for (size_t w = 0; w < words; ++w) covered[w] |= bits[c][w];
    n_covered += best_gain;
    order.push_back(c);
    plan->greedy_label.push_back(labels[c]);
    plan->greedy_coverage.push_back(Share(n_covered, plan->reachable));
  }
  plan->reached = !plan->greedy_coverage.empty() && plan->greedy_coverage.back() >= plan->target;
  return order;
}

std::vector<uint8_t> Reconstructed(std::vector<uint8_t> reasons) {
  for (uint8_t& x : reasons) x = x == kReconstructed;
  return reasons;
}

}  // namespace

ViewPlan PlanTurntableViews(const TriangleMesh& cad_in_part, const Rig& rig,
                            const PlanOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  options.Check();
  SLSHADOW_THROW_IF(!rig.turntable, "plan: rig '", rig.name,
                    "' has no turntable axis (calibrate it: slshadow calibrate turntable)");
  const TurntableAxis& axis = *rig.turntable;
  const CoveragePredictor predictor(cad_in_part, rig, axis, options.prediction);
  const size_t ns = predictor.Samples().size();

  // Every candidate's reconstructed samples; a cache by angle (the refinement, the baselines).
  const int count = std::max(1, static_cast<int>(std::floor(360.0 / options.step_deg + 1e-9)));
  std::map<double, std::vector<uint8_t>> by_angle;
  const auto key_of = [](double deg) {
    deg = std::fmod(deg, 360.0);
    if (deg < 0) deg += 360;
    const double key = std::round(deg * 1e6) / 1e6;
    return key >= 360 ? 0.0 : key;
  };
  const auto seen_at = [&](double deg) -> const std::vector<uint8_t>& {
    const double key = key_of(deg);
    auto it = by_angle.find(key);
    if (it == by_angle.end())
      it =
          by_angle.emplace(key, Reconstructed(predictor.View(axis.RigFromTableTurn(key).Inverse())))
              .first;
    return it->second;
  };
  std::vector<double> candidates;
  std::vector<std::string> labels;
  const auto add_candidate = [&](double deg) {
    deg = key_of(deg);  // in [0, 360)
    for (double c : candidates)
      if (key_of(c) == key_of(deg)) return false;
    candidates.push_back(deg);
    labels.push_back(StringPrintf("%.2f deg", deg));
    return true;
  };
  for (int k = 0; k < count; ++k) add_candidate(options.start_deg + k * options.step_deg);
  // Seeds for the swap search: n grid angles evenly spaced, from each grid offset.
  std::vector<std::vector<size_t>> seeds;
  for (int n = 1; n <= count; ++n) {
    for (int o = 0; o * n < count; ++o) {
      std::vector<size_t> s;
      for (int k = 0; k < n; ++k)
        s.push_back(static_cast<size_t>(o + static_cast<int>(std::lround(1.0 * k * count / n))) %
                    static_cast<size_t>(count));
      std::sort(s.begin(), s.end());
      if (std::adjacent_find(s.begin(), s.end()) == s.end()) seeds.push_back(s);
    }
  }

  ViewPlan plan;
  plan.grid_candidates = static_cast<size_t>(count);
  std::vector<uint8_t> reachable;
  std::vector<Bits> bits;
  std::vector<size_t> chosen;
  // The cover over the grid, then, while the chosen angles have neighbours not yet predicted (every
  // refine_deg within a grid step), the cover over the grid and those neighbours.
  for (int round = 0;; ++round) {
    std::vector<const std::vector<uint8_t>*> cand_seen;
    for (double a : candidates) cand_seen.push_back(&seen_at(a));
    chosen = SetCover(cand_seen, predictor.OnTable(), options, seeds, plan.grid_candidates,
                      rig.name, &plan, &reachable, &bits);
    if (options.refine_deg <= 0 || options.refine_deg >= options.step_deg ||
        round >= options.refine_rounds)
      break;
    bool added = false;
    const int m = static_cast<int>(std::ceil(options.step_deg / options.refine_deg - 1e-9)) - 1;
    const std::vector<size_t> picked = chosen;
    for (size_t c : picked) {
      for (int j = 1; j <= m; ++j) {
        added |= add_candidate(candidates[c] - j * options.refine_deg);
        added |= add_candidate(candidates[c] + j * options.refine_deg);
      }
    }
    if (!added) break;
  }

  // The uniform baselines: n views every 360 / n deg from start_deg, and from the best offset.
  const auto uniform_share = [&](double from, int n) {
    std::vector<uint8_t> seen(ns, 0);
    for (int k = 0; k < n; ++k) {
      const std::vector<uint8_t>& s = seen_at(from + 360.0 * k / n);
      for (size_t i = 0; i < ns; ++i) seen[i] |= s[i];
    }
    size_t hit = 0;
    for (size_t i = 0; i < ns; ++i) hit += reachable[i] & seen[i];
    return Share(hit, plan.reachable);
  };
  std::vector<double> uniform_deg;
  for (int n = 1; n <= count; ++n) {
    plan.uniform_coverage.push_back(uniform_share(options.start_deg, n));
    if (plan.uniform_coverage.back() >= options.target) {
      plan.uniform_needed = n;
      for (int k = 0; k < n; ++k) uniform_deg.push_back(options.start_deg + 360.0 * k / n);
      break;
    }
  }
  if (options.best_uniform_offset) {
    const double delta = options.refine_deg > 0 ? options.refine_deg : options.step_deg;
    for (int n = 1; n <= count; ++n) {
      double best = -1, best_from = options.start_deg;
      for (int j = 0; j * delta < 360.0 / n - 1e-9; ++j) {
        const double share = uniform_share(options.start_deg + j * delta, n);
        if (share > best) best = share, best_from = options.start_deg + j * delta;
      }
      plan.best_uniform_coverage.push_back(best);
      plan.best_uniform_offset_deg.push_back(best_from - options.start_deg);
      if (best >= options.target) {
        plan.best_uniform_needed = n;
        break;
      }
    }
  }
  // Uniform steps off the candidate grid (e.g. 72 deg for 5 views) may reach the target with
  // fewer views than any cover of the grid found: then they are the plan.
  if (plan.uniform_needed > 0 && chosen.size() > uniform_deg.size()) {
    std::vector<size_t> reachable_index;
    for (size_t i = 0; i < ns; ++i)
      if (reachable[i]) reachable_index.push_back(i);
    chosen.clear();
    for (double a : uniform_deg) {
      candidates.push_back(a);
      labels.push_back(StringPrintf("%.2f deg", a));
      bits.push_back(ToBits(seen_at(a), reachable_index));
      chosen.push_back(bits.size() - 1);
    }
  }
  for (size_t c : Account(bits, chosen, labels, &plan)) plan.greedy_deg.push_back(candidates[c]);
  std::vector<double> sorted = plan.greedy_deg;
  std::sort(sorted.begin(), sorted.end());
  for (size_t k = 0; k < sorted.size(); ++k) {
    ViewSpec v;
    v.name = DefaultViewName(k);
    v.table_deg = sorted[k];
    plan.views.views.push_back(v);
  }
  plan.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return plan;
}

std::vector<ViewCandidate> PlacementCandidates(const TriangleMesh& cad_in_part, const Rig& rig,
                                               const std::vector<double>& tilts_deg,
                                               double step_deg, double start_deg) {
  SLSHADOW_THROW_IF(!(step_deg >= 0.5 && step_deg <= 360),
                    "--step-deg: must be in [0.5, 360] (got ", step_deg, ")");
  SLSHADOW_THROW_IF(!std::isfinite(start_deg), "--start-deg: must be finite (got ", start_deg, ")");
  SLSHADOW_THROW_IF(tilts_deg.empty(), "--tilts-deg: at least one tilt");
  for (double t : tilts_deg) {
    SLSHADOW_THROW_IF(!(std::abs(t) <= 180), "--tilts-deg: each tilt must be in [-180, 180] (got ",
                      t, ")");
  }
  SLSHADOW_THROW_IF(cad_in_part.empty(), "plan: the part has no triangles");
  const Eigen::Vector3d centre = 0.5 * (cad_in_part.BoundsMin() + cad_in_part.BoundsMax());
  const Eigen::Vector3d up =
      rig.turntable ? rig.turntable->direction_in_rig.normalized() : Eigen::Vector3d(0, -1, 0);
  Eigen::Vector3d across = Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitX().dot(up) * up;
  if (across.norm() < 1e-6)
    across = Eigen::Vector3d::UnitZ() - Eigen::Vector3d::UnitZ().dot(up) * up;
  across.normalize();
  const int count = std::max(1, static_cast<int>(std::floor(360.0 / step_deg + 1e-9)));
  std::vector<ViewCandidate> candidates;
  for (double tilt : tilts_deg) {
    for (int k = 0; k < count; ++k) {
      const double yaw = start_deg + k * step_deg;
      const Eigen::Quaterniond r(Eigen::AngleAxisd(yaw * M_PI / 180, up) *
                                 Eigen::AngleAxisd(tilt * M_PI / 180, across));
      // The part turned about its centre: x -> centre + r (x - centre), in the part frame at rest.
      const Rigid3d rig_from_part(r, centre - (r * centre));
      ViewCandidate c;
      c.label = StringPrintf("yaw %g tilt %g", yaw, tilt);
      c.view.part_from_rig_guess = rig_from_part.Inverse();
      candidates.push_back(c);
    }
  }
  return candidates;
}

ViewPlan PlanViews(const TriangleMesh& cad_in_part, const Rig& rig,
                   const std::vector<ViewCandidate>& candidates,
                   const std::optional<TurntableAxis>& table_axis, const PlanOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  options.Check();
  SLSHADOW_THROW_IF(candidates.empty(), "plan: no candidate views");
  const CoveragePredictor predictor(cad_in_part, rig, table_axis, options.prediction);
  std::vector<std::vector<uint8_t>> seen;
  std::vector<std::string> labels;
  for (const ViewCandidate& c : candidates) {
    seen.push_back(Reconstructed(predictor.View(VirtualViewPose(c.view, rig))));
    labels.push_back(c.label);
  }
  std::vector<const std::vector<uint8_t>*> cand_seen;
  for (const auto& s : seen) cand_seen.push_back(&s);
  ViewPlan plan;
  std::vector<uint8_t> reachable;
  std::vector<Bits> bits;
  const std::vector<size_t> chosen = SetCover(cand_seen, predictor.OnTable(), options, {},
                                              cand_seen.size(), rig.name, &plan, &reachable, &bits);
  for (size_t c : Account(bits, chosen, labels, &plan)) {
    ViewSpec v = candidates[c].view;
    v.name = DefaultViewName(plan.views.views.size());
    if (v.table_deg) plan.greedy_deg.push_back(*v.table_deg);
    plan.views.views.push_back(v);
  }
  plan.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return plan;
}

nlohmann::json ViewPlan::ToJson() const {
  return {{"target", target},
          {"reached", reached},
          {"views", greedy_label.size()},
          {"greedy_deg", greedy_deg},
          {"greedy_label", greedy_label},
          {"greedy_coverage", greedy_coverage},
          {"uniform_coverage", uniform_coverage},
          {"uniform_needed", uniform_needed},
          {"best_uniform_coverage", best_uniform_coverage},
          {"best_uniform_offset_deg", best_uniform_offset_deg},
          {"best_uniform_needed", best_uniform_needed},
          {"greedy_views", greedy_views},
          {"greedy_reached", greedy_reached},
          {"one_fewer_coverage", one_fewer_coverage},
          {"one_fewer_exact", one_fewer_exact},
          {"classes", classes},
          {"search_evaluations", search_evaluations},
          {"candidates", candidates},
          {"grid_candidates", grid_candidates},
          {"samples", samples},
          {"off_table", off_table},
          {"reachable", reachable},
          {"reachable_share", reachable_share},
          {"seconds", seconds}};
}

std::string ViewPlan::Table() const {
  std::string out = StringPrintf(
      "reachable surface: %.2f %% of the part off the table (%zu of %zu samples, %zu candidates",
      100 * reachable_share, reachable, off_table, candidates);
  if (grid_candidates && grid_candidates < candidates)
    out += StringPrintf(": %zu on the grid, %zu refined", grid_candidates,
                        candidates - grid_candidates);
  out += ")\nviews  plan: view added       coverage   uniform: coverage";
  const bool best = !best_uniform_coverage.empty();
  if (best) out += "   from the best offset";
  out += "\n";
  const size_t rows =
      std::max({greedy_label.size(), uniform_coverage.size(), best_uniform_coverage.size()});
  for (size_t k = 0; k < rows; ++k) {
    std::string plan_cell = "                           ";
    if (k < greedy_label.size())
      plan_cell = StringPrintf("%15s  %7.2f %%", greedy_label[k].c_str(), 100 * greedy_coverage[k]);
    std::string uni = k < uniform_coverage.size()
                          ? StringPrintf("%7.2f %%", 100 * uniform_coverage[k])
                          : std::string("      -  ");
    if (best && k < best_uniform_coverage.size())
      uni += StringPrintf("          %7.2f %% (+%.1f deg)", 100 * best_uniform_coverage[k],
                          best_uniform_offset_deg[k]);
    out += StringPrintf("%5zu  %s   %s\n", k + 1, plan_cell.c_str(), uni.c_str());
  }
  out += StringPrintf("target %.2f %%: the plan needs %zu views%s; uniform steps need %s",
                      100 * target, greedy_label.size(), reached ? "" : " (not reached)",
                      uniform_coverage.empty() ? "- (no uniform baseline for placed views)"
                      : uniform_needed > 0     ? std::to_string(uniform_needed).c_str()
                                               : "more than the candidates");
  if (best)
    out += StringPrintf(", from the best offset %s",
                        best_uniform_needed > 0 ? std::to_string(best_uniform_needed).c_str()
                                                : "more than the candidates");
  out += StringPrintf(" (%.2f s)\n", seconds);
  if (reached && greedy_label.size() > 1) {
    out += StringPrintf("search: greedy alone %zu views; with %zu views at most %.2f %% (%s)\n",
                        greedy_views, greedy_label.size() - 1, 100 * one_fewer_coverage,
                        one_fewer_exact ? "exhaustive: none reaches the target"
                                        : "the best found; the search's budget ran out");
  }
  return out;
}

PlanCheck CheckPlanAgainstProject(const TriangleMesh& cad_in_part, const Rig& rig,
                                  const std::filesystem::path& project_dir,
                                  const CoveragePredictionOptions& options) {
  ProjectMergeOptions merge;
  merge.mode = options.mode;
  merge.poses = PoseSource::kAxis;  // the prediction is checked, not the registration
  merge.mesh = false;
  merge.reconstruct = options.reconstruct;
  merge.cad.samples = options.samples;
  merge.cad.table_tolerance_mm = options.table_tolerance_mm;
  ProjectMergeResult merged = MergeProject(project_dir, &cad_in_part, merge);
  SLSHADOW_THROW_IF(!merged.cad, project_dir.string(), ": the merge made no CAD comparison");
  // Each view at the pose the merge placed it: a table view at its angle on the axis, a view
  // placed by hand at its part_from_rig_guess (the planned pose).
  std::vector<PredictedViewPose> poses;
  for (const MergedView& v : merged.views) {
    SLSHADOW_THROW_IF(!v.merged && !v.part_from_rig_initial, project_dir.string(), ": view '",
                      v.name, "' has no pose (neither a table angle nor a part_from_rig_guess)");
    poses.push_back({v.name, v.merged ? v.part_from_rig : *v.part_from_rig_initial});
  }
  PlanCheck result;
  // The table face as the merge's comparison excludes it (the project's rig's axis).
  result.prediction = PredictCoverage(cad_in_part, rig, poses, rig.turntable, options);
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
