#include "workflows/multiview/merge.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <set>

#include <tbb/parallel_for.h>
#include <Eigen/Geometry>

#include "core/error.h"
#include "core/statistics.h"
#include "core/string_printf.h"
#include "workflows/multiview/internal/fusion.h"
#include "workflows/multiview/internal/hand_views.h"
#include "workflows/multiview/internal/pairwise.h"
#include "workflows/multiview/internal/pose_graph.h"
#include "workflows/multiview/internal/sight_check.h"
#include "workflows/multiview/internal/turntable_graph.h"

namespace slshadow::multiview {
namespace {

using internal::Matrix6d;
using Clock = std::chrono::steady_clock;

double Seconds(Clock::time_point since) {
  return std::chrono::duration<double>(Clock::now() - since).count();
}

// "rotation about (x, y, z)" / "translation along (x, y, z)", the axis rotated into the part
// frame, its sign such that the largest component is positive.
std::string DirectionText(const internal::DegenerateDirection& d, const Eigen::Quaterniond& r) {
  Eigen::Vector3d v = r * d.axis;
  Eigen::Index k = 0;
  v.cwiseAbs().maxCoeff(&k);
  if (v[k] < 0) v = -v;
  return StringPrintf("%s (%.2f, %.2f, %.2f)", d.rotation ? "rotation about" : "translation along",
                      v.x(), v.y(), v.z());
}

// Disagreement of a pair with the graph, in degrees and mm (merge.h, PairRegistration).
void EdgeError(const Rigid3d& discrepancy, const Eigen::Vector3d& centroid, double radius,
               double* deg, double* mm) {
  const double angle = discrepancy.rotation.angularDistance(Eigen::Quaterniond::Identity());
  *deg = angle * 180.0 / M_PI;
  *mm = (discrepancy * centroid - centroid).norm() + angle * radius;
}

}  // namespace

void MergeOptions::Check() const {
  auto positive = [](double v, const char* field) {
    SLSHADOW_THROW_IF(!(v > 0) || !std::isfinite(v), "merge options: ", field,
                      ": must be finite and > 0 (got ", v, ")");
  };
  auto nonneg = [](double v, const char* field) {
    SLSHADOW_THROW_IF(!(v >= 0) || !std::isfinite(v), "merge options: ", field,
                      ": must be finite and >= 0 (got ", v, ")");
  };
  auto share = [](double v, const char* field) {
    SLSHADOW_THROW_IF(!(v > 0 && v <= 1), "merge options: ", field, ": must be in (0, 1] (got ", v,
                      ")");
  };
  positive(initial_gate_mm, "initial_gate_mm");
  share(min_pair_overlap, "min_pair_overlap");
  SLSHADOW_THROW_IF(max_pairs_per_view < 1, "merge options: max_pairs_per_view: must be >= 1 (got ",
                    max_pairs_per_view, ")");
  SLSHADOW_THROW_IF(overlap_samples < 10, "merge options: overlap_samples: must be >= 10 (got ",
                    overlap_samples, ")");
  SLSHADOW_THROW_IF(icp_points < 10, "merge options: icp_points: must be >= 10 (got ", icp_points,
                    ")");
  SLSHADOW_THROW_IF(!(icp_table_share >= 0 && icp_table_share <= 1),
                    "merge options: icp_table_share: must be in [0, 1] (got ", icp_table_share,
                    ")");
  SLSHADOW_THROW_IF(icp_max_iterations < 1, "merge options: icp_max_iterations: must be >= 1 (got ",
                    icp_max_iterations, ")");
  positive(icp_tolerance_mm, "icp_tolerance_mm");
  nonneg(icp_noise_tolerance, "icp_noise_tolerance");
  positive(icp_max_final_motion_mm, "icp_max_final_motion_mm");
  SLSHADOW_THROW_IF(!(icp_max_normal_angle_deg > 0 && icp_max_normal_angle_deg <= 180),
                    "merge options: icp_max_normal_angle_deg: must be in (0, 180] (got ",
                    icp_max_normal_angle_deg, ")");
  nonneg(icp_max_residual_sigmas, "icp_max_residual_sigmas");
  SLSHADOW_THROW_IF(!(icp_hold_gate_sigmas >= 0 && std::isfinite(icp_hold_gate_sigmas)),
                    "merge options: icp_hold_gate_sigmas: must be >= 0 (got ", icp_hold_gate_sigmas,
                    ")");
  SLSHADOW_THROW_IF(!(icp_degenerate_ratio >= 0 && icp_degenerate_ratio < 1),
                    "merge options: icp_degenerate_ratio: must be in [0, 1) (got ",
                    icp_degenerate_ratio, ")");
  SLSHADOW_THROW_IF(!(max_seen_through >= 0 && max_seen_through <= 1),
                    "merge options: max_seen_through: must be in [0, 1] (got ", max_seen_through,
                    ")");
  nonneg(seen_through_tol_gate, "seen_through_tol_gate");
  positive(prior_sigma_deg, "prior_sigma_deg");
  positive(prior_sigma_mm, "prior_sigma_mm");
  SLSHADOW_THROW_IF(!(icp_max_surface_variation > 0 && icp_max_surface_variation <= 1.0 / 3.0),
                    "merge options: icp_max_surface_variation: must be in (0, 1/3] (got ",
                    icp_max_surface_variation, ")");
  SLSHADOW_THROW_IF(normal_neighbors < 3, "merge options: normal_neighbors: must be >= 3 (got ",
                    normal_neighbors, ")");
  SLSHADOW_THROW_IF(icp_normal_neighbors != 0 && icp_normal_neighbors < 3,
                    "merge options: icp_normal_neighbors: must be 0 or >= 3 (got ",
                    icp_normal_neighbors, ")");
  share(min_pair_fitness, "min_pair_fitness");
  SLSHADOW_THROW_IF(!(max_pair_rms_ratio > 1) || !std::isfinite(max_pair_rms_ratio),
                    "merge options: max_pair_rms_ratio: must be finite and > 1 (got ",
                    max_pair_rms_ratio, ")");
  SLSHADOW_THROW_IF(!(max_edge_error_ratio > 1) || !std::isfinite(max_edge_error_ratio),
                    "merge options: max_edge_error_ratio: must be finite and > 1 (got ",
                    max_edge_error_ratio, ")");
  nonneg(min_edge_error_mm, "min_edge_error_mm");
  nonneg(max_initial_departure_deg, "max_initial_departure_deg");
  nonneg(max_initial_departure_mm, "max_initial_departure_mm");
  SLSHADOW_THROW_IF(hand_spread_blocks < 0 || hand_spread_blocks == 1,
                    "merge options: hand_spread_blocks: must be 0 or >= 2 (got ",
                    hand_spread_blocks, ")");
  nonneg(graph_robust_k, "graph_robust_k");
  SLSHADOW_THROW_IF(joint_iterations < 0, "merge options: joint_iterations: must be >= 0 (got ",
                    joint_iterations, ")");
  positive(joint_tolerance_mm, "joint_tolerance_mm");
  if (turntable) {
    SLSHADOW_THROW_IF(!turntable->direction_in_rig.allFinite() ||
                          turntable->direction_in_rig.norm() < 1e-12 ||
                          !turntable->point_in_rig_mm.allFinite(),
                      "merge options: turntable: the axis must have a finite non-zero direction "
                      "and a finite point");
  }
  global.Check();
  nonneg(fuse_cell_mm, "fuse_cell_mm");
  positive(fuse_k_sigma, "fuse_k_sigma");
  nonneg(fuse_min_disagreement_mm, "fuse_min_disagreement_mm");
  nonneg(fuse_edge_variation, "fuse_edge_variation");
  SLSHADOW_THROW_IF(!(fuse_min_incidence_cos >= 0 && fuse_min_incidence_cos <= 1),
                    "merge options: fuse_min_incidence_cos: must be in [0, 1] (got ",
                    fuse_min_incidence_cos, ")");
  nonneg(fuse_support_cells, "fuse_support_cells");
  nonneg(fuse_reject_cells, "fuse_reject_cells");
  SLSHADOW_THROW_IF(!(fuse_support_min_factor >= 1),
                    "merge options: fuse_support_min_factor: must be >= 1 (got ",
                    fuse_support_min_factor, ")");
  SLSHADOW_THROW_IF(fuse_see_through_views < 0,
                    "merge options: fuse_see_through_views: must be >= 0 (got ",
                    fuse_see_through_views, ")");
  positive(fuse_see_through_pixels, "fuse_see_through_pixels");
}

double RotationErrorDeg(const Rigid3d& a, const Rigid3d& b) {
  return a.rotation.angularDistance(b.rotation) * 180.0 / M_PI;
}

double MaxDisplacementMm(const Rigid3d& a, const Rigid3d& b,
                         const std::vector<Eigen::Vector3d>& points) {
  double worst = 0;
  for (const auto& p : points) worst = std::max(worst, (a * p - b * p).norm());
  return worst;
}

int MergeResult::NumAccepted() const {
  int n = 0;
  for (const auto& v : views) n += v.accepted ? 1 : 0;
  return n;
}

std::string MergeResult::BriefReport() const {
  int kept = 0;
  for (const auto& p : pairs) kept += p.kept ? 1 : 0;
  std::string s = StringPrintf("merge: %d of %zu views, %d of %zu pairs", NumAccepted(),
                               views.size(), kept, pairs.size());
  if (has_loop) {
    s += StringPrintf(", loop closure %.4f deg / %.4f mm -> %.4f deg / %.4f mm",
                      loop_closure_before_deg, loop_closure_before_mm, loop_closure_after_deg,
                      loop_closure_after_mm);
  }
  s += StringPrintf(", %zu points -> %zu (%zu disagree), %.2f s", input_points, merged.size(),
                    disagree_points, time_s);
  for (const auto& v : views)
    if (!v.accepted) s += StringPrintf("; left out %s: %s", v.name.c_str(), v.reason.c_str());
  return s;
}

std::string MergeResult::FullReport() const {
  std::string s = BriefReport() + "\n";
  s += "views (pose part_from_rig: rotation deg about axis, translation mm; 1-sigma):\n";
  for (const auto& v : views) {
    const Eigen::AngleAxisd aa(v.part_from_rig.rotation);
    s += StringPrintf(
        "  %-12s %s%-8s %7d points, %2d pairs, rotation %9.4f deg about (%.4f, %.4f, %.4f), "
        "translation (%.4f, %.4f, %.4f), residual %.4f mm, noise %.4f mm, sigma %.2g deg / "
        "%.2g mm%s%s\n",
        v.name.c_str(), v.anchor ? "*" : " ", v.accepted ? "accepted" : "left out", v.points,
        v.pairs, aa.angle() * 180.0 / M_PI, aa.axis().x(), aa.axis().y(), aa.axis().z(),
        v.part_from_rig.translation.x(), v.part_from_rig.translation.y(),
        v.part_from_rig.translation.z(), v.residual_rms_mm, v.noise_mm, v.sigma_rotation_deg,
        v.sigma_translation_mm, v.reason.empty() ? "" : ": ", v.reason.c_str());
    for (const auto& d : v.prior_directions)
      s += "      fixed by the prior (a pair's overlap leaves it free): " + d + "\n";
  }
  s += "pairs (a <- b):\n";
  for (const auto& p : pairs) {
    s += StringPrintf(
        "  %-12s <- %-12s overlap %.2f, fitness %.2f, %6d matches, %2d iterations%s, rms %.4f "
        "-> %.4f mm, graph error %.5f deg / %.5f mm%s%s\n",
        views[static_cast<size_t>(p.view_a)].name.c_str(),
        views[static_cast<size_t>(p.view_b)].name.c_str(), p.overlap_initial, p.fitness,
        p.correspondences, p.iterations, p.converged ? "" : " (not converged)", p.rms_mm,
        p.final_rms_mm, p.graph_error_deg, p.graph_error_mm,
        p.kept ? "" : ", rejected: ", p.reason.c_str());
    for (const auto& d : p.degenerate) s += "      degenerate, held at the prior: " + d + "\n";
    if (p.seen_through >= 0)
      s += StringPrintf("      free-space check: %.2f %% seen through by the other view\n",
                        100.0 * p.seen_through);
    if (p.spread_factor > 0)
      s += StringPrintf(
          "      spread over blocks of the overlap: %.2f x the stated variance "
          "along the weakest direction\n",
          p.spread_factor);
    if (p.untested_floor_deg > 0)
      s += StringPrintf(
          "      no loop tests it: 1-sigma along the weakest direction at least %.4f deg (the "
          "largest disagreement of a weak hand pair a loop tested)\n",
          p.untested_floor_deg);
  }
  if (turntable_model) {
    s += StringPrintf(
        "turntable model: axis (%.6f, %.6f, %.6f) through (%.4f, %.4f, %.4f) mm, 1-sigma %.2g deg "
        "/ %.2g mm, pair variance factor %.3g, Huber corner %.3g\n",
        axis_direction_in_rig.x(), axis_direction_in_rig.y(), axis_direction_in_rig.z(),
        axis_point_in_rig_mm.x(), axis_point_in_rig_mm.y(), axis_point_in_rig_mm.z(),
        axis_sigma_direction_deg, axis_sigma_point_mm, graph_variance_factor, graph_huber_corner);
    for (const auto& v : views) {
      if (!v.table_angle_deg) continue;
      s += StringPrintf("  %-12s table angle %10.5f deg (%+.5f, 1-sigma %.2g)\n", v.name.c_str(),
                        *v.table_angle_deg, v.table_angle_correction_deg, v.sigma_table_angle_deg);
    }
  }
  s += StringPrintf(
      "joint refinement: %d iterations, last motion %.2g mm\n"
      "pose graph: %d iterations, cost %.6g -> %.6g\n"
      "model: cell %.4f mm, %zu input points -> %zu merged, %zu flagged where views disagree, "
      "%zu single-view points superseded by better views, %zu rejected off other views' "
      "surfaces\n"
      "time: normals %.2f s, pairs %.2f s, graph %.2f s, fusion %.2f s, total %.2f s\n",
      joint_iterations, joint_last_motion_mm, graph_iterations, graph_initial_cost,
      graph_final_cost, fuse_cell_mm, input_points, merged.size(), disagree_points,
      superseded_points, rejected_points, time_normals_s, time_pairs_s, time_graph_s, time_fuse_s,
      time_s);
  return s;
}

MergeResult MergeViews(const std::vector<ViewCloud>& views, const MergeOptions& options) {
  options.Check();
  const auto t_start = Clock::now();
  SLSHADOW_THROW_IF(views.empty(), "merge: no views");
  std::set<std::string> names;
  for (size_t i = 0; i < views.size(); ++i) {
    SLSHADOW_THROW_IF(views[i].cloud == nullptr, "merge: view ", i, " ('", views[i].name,
                      "'): no cloud");
    SLSHADOW_THROW_IF(views[i].cloud->empty(), "merge: view '", views[i].name, "': empty cloud");
    views[i].cloud->Check("merge: view '" + views[i].name + "'");
    if (views[i].backdrop) views[i].backdrop->Check("merge: view '" + views[i].name + "' backdrop");
    SLSHADOW_THROW_IF(!names.insert(views[i].name).second, "merge: duplicate view name '",
                      views[i].name, "'");
  }
  const size_t n = views.size();
  MergeResult result;
  result.views.resize(n);
  for (size_t i = 0; i < n; ++i) {
    ViewPose& v = result.views[i];
    v.name = views[i].name;
    v.points = static_cast<int>(views[i].cloud->size());
    v.part_from_rig = v.part_from_rig_initial = views[i].part_from_rig_initial;
  }

  // Per-view geometry.
  auto t0 = Clock::now();
  std::vector<internal::ViewGeometry> geo(n);
  for (size_t i = 0; i < n; ++i)
    internal::PrepareView(*views[i].cloud, options, &geo[i],
                          views[i].table_deg && options.turntable ? &*options.turntable : nullptr);
  result.time_normals_s = Seconds(t0);

  // 1. Initial poses; views without one by global registration against the views posed so far.
  t0 = Clock::now();
  const std::vector<bool> posed =
      internal::PoseByGlobalRegistration(views, geo, options, &result.views);

  // 2. Pairs overlapping at the initial poses, then ICP (pairs in parallel, each serial).
  struct Candidate {
    int a, b;
    double overlap;
    double angle_deg;  // relative rotation of the two views at their initial poses
  };
  std::vector<Candidate> all;
  for (size_t a = 0; a < n && options.refine; ++a) {
    for (size_t b = a + 1; b < n; ++b) {
      if (!posed[a] || !posed[b]) continue;
      const Rigid3d a_from_b =
          result.views[a].part_from_rig.Inverse() * result.views[b].part_from_rig;
      const double share = std::max(
          internal::OverlapShare(geo[a], geo[b], a_from_b, options.initial_gate_mm,
                                 options.icp_max_normal_angle_deg),
          internal::OverlapShare(geo[b], geo[a], a_from_b.Inverse(), options.initial_gate_mm,
                                 options.icp_max_normal_angle_deg));
      if (share >= options.min_pair_overlap)
        all.push_back(
            {static_cast<int>(a), static_cast<int>(b), share,
             RotationErrorDeg(result.views[a].part_from_rig, result.views[b].part_from_rig)});
    }
  }
  // Each view's overlapping partners that look at the part from the nearest directions (the
  // smallest relative rotation; ties: the larger overlap, then the lower index). The overlap share
  // alone does not rank them: a face every view sees (a part's top on a turntable) makes it high
  // for every pair, while views far apart share little else and leave ICP free to slide.
  std::vector<bool> chosen(all.size(), false);
  for (size_t v = 0; v < n; ++v) {
    std::vector<size_t> mine;
    for (size_t k = 0; k < all.size(); ++k)
      if (all[k].a == static_cast<int>(v) || all[k].b == static_cast<int>(v)) mine.push_back(k);
    std::stable_sort(mine.begin(), mine.end(), [&](size_t x, size_t y) {
      const double dx = std::round(all[x].angle_deg * 1e6), dy = std::round(all[y].angle_deg * 1e6);
      if (dx != dy) return dx < dy;
      return all[x].overlap > all[y].overlap;
    });
    for (size_t k = 0; k < mine.size() && k < static_cast<size_t>(options.max_pairs_per_view); ++k)
      chosen[mine[k]] = true;
  }
  std::vector<Candidate> candidates;
  for (size_t k = 0; k < all.size(); ++k)
    if (chosen[k]) candidates.push_back(all[k]);
  std::vector<internal::IcpOutcome> icp(candidates.size());
  // A pair's options: degenerate directions are held at the prior, and the ICP may stop at its
  // noise level, only between two table views (their relative pose from the rig's axis and the
  // table angles). A hand view's initial pose (a guess, or the global registration's) is no
  // prior to keep: such a pair slides where its overlap leaves a direction free, and is rejected.
  const MergeOptions hand_options = internal::HandPairOptions(options);
  auto pair_options = [&](int a, int b) -> const MergeOptions& {
    const bool table = options.turntable.has_value() && views[static_cast<size_t>(a)].table_deg &&
                       views[static_cast<size_t>(b)].table_deg;
    return table ? options : hand_options;
  };
  tbb::parallel_for(size_t{0}, candidates.size(), [&](size_t k) {
    const auto& c = candidates[k];
    const Rigid3d a_from_b = result.views[static_cast<size_t>(c.a)].part_from_rig.Inverse() *
                             result.views[static_cast<size_t>(c.b)].part_from_rig;
    icp[k] =
        internal::RegisterTablePair(geo[static_cast<size_t>(c.a)], geo[static_cast<size_t>(c.b)],
                                    a_from_b, pair_options(c.a, c.b));
  });
  result.pairs.resize(candidates.size());
  std::vector<double> rms_of_good;
  for (size_t k = 0; k < candidates.size(); ++k) {
    PairRegistration& p = result.pairs[k];
    p.view_a = candidates[k].a;
    p.view_b = candidates[k].b;
    p.overlap_initial = candidates[k].overlap;
    p.a_from_b = icp[k].a_from_b;
    p.fitness = icp[k].fitness;
    p.rms_mm = icp[k].rms_mm;
    p.correspondences = icp[k].correspondences;
    p.iterations = icp[k].iterations;
    p.converged = icp[k].converged;
    p.min_eigen_ratio = icp[k].min_eigen_ratio;
    for (const auto& d : icp[k].degenerate)
      p.degenerate.push_back(
          DirectionText(d, result.views[static_cast<size_t>(p.view_a)].part_from_rig.rotation));
    // Not converged, but only jittering (correspondences switching at the noise level), is
    // kept; still moving after icp_max_iterations is sliding along a direction the overlap
    // leaves free.
    const bool sliding = !p.converged && icp[k].last_motion_mm > options.icp_max_final_motion_mm;
    p.kept = p.fitness >= options.min_pair_fitness && p.correspondences >= 7 && !sliding;
    if (p.fitness < options.min_pair_fitness || p.correspondences < 7)
      p.reason = StringPrintf("overlap after ICP %.3f (min_pair_fitness %.3f)", p.fitness,
                              options.min_pair_fitness);
    else if (sliding)
      p.reason = StringPrintf(
          "ICP still moving %.2g mm per iteration after %d iterations (the overlap leaves a "
          "direction free to slide)",
          icp[k].last_motion_mm, p.iterations);
    else
      rms_of_good.push_back(p.rms_mm);
  }
  const double median_rms = rms_of_good.empty() ? 0.0 : Median(rms_of_good);
  for (auto& p : result.pairs) {
    if (p.kept && p.rms_mm > options.max_pair_rms_ratio * median_rms) {
      p.kept = false;
      p.reason = StringPrintf("ICP residual %.4f mm, %.1f x the median of the pairs (%.4f mm)",
                              p.rms_mm, p.rms_mm / median_rms, median_rms);
    }
  }
  // The free-space check of the pairs that held a direction at the prior (sight_check.h): at a
  // wrong start only a face the rotation leaves in place (a top face) matches, the pair is
  // degenerate, and the hold would keep the wrong pose; the other view's walls then stand where
  // this view saw through, which the part's geometry never causes.
  // A hand pair holds nothing, but where its overlap leaves a direction weak (the smallest
  // eigenvalue ratio below icp_degenerate_ratio) the ICP may stop at a wrong pose just as well
  // (a hand view slid 60 mm along the demo part, docs/benchmarks/log/
  // 2026-12-07-degeneracy-default.md, C): checked the same way.
  auto weak_hand = [&](size_t k) {
    const PairRegistration& p = result.pairs[k];
    return &pair_options(p.view_a, p.view_b) == &hand_options &&
           p.min_eigen_ratio < options.icp_degenerate_ratio;
  };
  auto to_check = [&](size_t k) {
    return result.pairs[k].kept && (!icp[k].degenerate.empty() || weak_hand(k));
  };
  if (options.max_seen_through < 1) {
    std::vector<bool> need(n, false);
    for (size_t k = 0; k < result.pairs.size(); ++k) {
      if (!to_check(k)) continue;
      need[static_cast<size_t>(result.pairs[k].view_a)] = true;
      need[static_cast<size_t>(result.pairs[k].view_b)] = true;
    }
    std::vector<internal::Sightlines> sight(n);
    tbb::parallel_for(size_t{0}, n, [&](size_t i) {
      if (need[i])
        internal::BuildSightlines(*geo[i].points,
                                  views[i].backdrop ? &views[i].backdrop->points : nullptr,
                                  options.fuse_see_through_pixels, &sight[i]);
    });
    tbb::parallel_for(size_t{0}, result.pairs.size(), [&](size_t k) {
      if (!to_check(k)) return;
      PairRegistration& p = result.pairs[k];
      const size_t a = static_cast<size_t>(p.view_a), b = static_cast<size_t>(p.view_b);
      const double tol = std::max(options.seen_through_tol_gate * options.initial_gate_mm,
                                  options.fuse_k_sigma * std::sqrt(2.0) * p.rms_mm);
      const internal::SeenThrough b_in_a = internal::CountSeenThrough(
          sight[a], *geo[b].points, geo[b].overlap_sample, p.a_from_b, tol);
      const internal::SeenThrough a_in_b = internal::CountSeenThrough(
          sight[b], *geo[a].points, geo[a].overlap_sample, p.a_from_b.Inverse(), tol);
      p.seen_through = std::max(b_in_a.Share(), a_in_b.Share());
      if (p.seen_through <= options.max_seen_through) return;
      const bool b_worse = b_in_a.Share() >= a_in_b.Share();
      if (icp[k].degenerate.empty()) {  // a hand pair with a weak direction
        p.kept = false;
        p.reason = StringPrintf(
            "its overlap leaves a direction weakly fixed (smallest eigenvalue ratio %.1e, "
            "icp_degenerate_ratio %.1e) and at the ICP's pose %.1f %% of %s's points lie where %s "
            "saw through (in front of its surface by more than %.2f mm; max_seen_through "
            "%.1f %%): the pose is wrong, not the part's geometry",
            p.min_eigen_ratio, options.icp_degenerate_ratio, 100.0 * p.seen_through,
            views[b_worse ? b : a].name.c_str(), views[b_worse ? a : b].name.c_str(), tol,
            100.0 * options.max_seen_through);
        return;
      }
      std::string held = p.degenerate.front();  // a rotation first: what a wrong angle holds
      for (const auto& d : p.degenerate)
        if (d.rfind("rotation", 0) == 0) held = d;
      p.kept = false;
      p.reason = StringPrintf(
          "held at the table's prior where its overlap leaves it free (%s), but there %.1f %% of "
          "%s's points lie where %s saw through (in front of its surface by more than %.2f mm; "
          "max_seen_through %.1f %%): the start is wrong (a wrong table angle, or the part "
          "moved), not the part's geometry",
          held.c_str(), 100.0 * p.seen_through, views[b_worse ? b : a].name.c_str(),
          views[b_worse ? a : b].name.c_str(), tol, 100.0 * options.max_seen_through);
    });
  }
  result.time_pairs_s = Seconds(t0);

  // 3. Pose graph, rejecting pairs and views that do not fit, one at a time.
  t0 = Clock::now();
  std::vector<bool> active = posed;
  std::vector<Rigid3d> initial(n);
  for (size_t i = 0; i < n; ++i) initial[i] = result.views[i].part_from_rig_initial;
  internal::GraphSolution sol;
  std::vector<size_t> edge_pair;  // pair index of each graph edge
  internal::TableModel table_model;
  table_model.robust_k = options.graph_robust_k;
  table_model.angle_rad.assign(n, std::numeric_limits<double>::quiet_NaN());
  if (options.turntable) {  // (its axis: set at each round below)
    for (size_t i = 0; i < n; ++i)
      if (views[i].table_deg)
        table_model.angle_rad[i] =
            options.turntable->TrueAngleDeg(*views[i].table_deg) * M_PI / 180;
  }
  internal::TableFit table_fit;
  bool use_model = false;
  std::vector<Matrix6d> hand_cov;  // hand views' covariance from the widened pairs (empty: none)
  auto optimize = [&](const std::vector<internal::GraphEdge>& edges, bool with_covariance) {
    use_model = options.turntable_model && options.turntable.has_value() &&
                internal::TableModelApplies(table_model, active);
    return use_model ? internal::OptimizeTurntableGraph(initial, active, result.anchor, edges,
                                                        table_model, with_covariance, &table_fit)
                     : internal::OptimizePoseGraph(initial, active, result.anchor, edges,
                                                   with_covariance);
  };
  double axis_sigma[2] = {-1, -1};  // with icp_table_angles: the strided fit's (deg, mm)
  for (;;) {
    if (options.turntable) {  // the axis free again (icp_table_angles holds it in a round)
      table_model.direction_in_rig = options.turntable->direction_in_rig.normalized();
      table_model.point_in_rig_mm = options.turntable->point_in_rig_mm;
      table_model.fix_axis = false;
      axis_sigma[0] = axis_sigma[1] = -1;
    }
    int anchor = -1;
    for (size_t i = 0; i < n && anchor < 0; ++i)
      if (active[i]) anchor = static_cast<int>(i);
    result.anchor = anchor;
    if (anchor < 0) break;
    if (!options.refine) {  // the initial poses as they are
      sol.part_from_rig = initial;
      break;
    }
    // The anchor's connected component over kept pairs.
    std::vector<bool> reached(n, false);
    reached[static_cast<size_t>(anchor)] = true;
    for (bool grew = true; grew;) {
      grew = false;
      for (const auto& p : result.pairs) {
        if (!p.kept || !active[static_cast<size_t>(p.view_a)] ||
            !active[static_cast<size_t>(p.view_b)])
          continue;
        const size_t a = static_cast<size_t>(p.view_a), b = static_cast<size_t>(p.view_b);
        if (reached[a] != reached[b]) {
          reached[a] = reached[b] = true;
          grew = true;
        }
      }
    }
    for (size_t i = 0; i < n; ++i) {
      if (!active[i] || reached[i]) continue;
      active[i] = false;
      int pairs_of_view = 0;
      std::string why;
      for (const auto& p : result.pairs) {
        if (p.view_a != static_cast<int>(i) && p.view_b != static_cast<int>(i)) continue;
        ++pairs_of_view;
        if (!p.kept && why.empty()) why = p.reason;
      }
      result.views[i].reason =
          pairs_of_view == 0
              ? StringPrintf(
                    "overlaps no other view at its initial pose (min_pair_overlap %.2f "
                    "within %.2f mm)",
                    options.min_pair_overlap, options.initial_gate_mm)
              : "no kept pair connects it to " + result.views[static_cast<size_t>(anchor)].name +
                    (why.empty() ? std::string() : " (" + why + ")");
    }
    std::vector<internal::GraphEdge> edges;
    edge_pair.clear();
    for (size_t k = 0; k < result.pairs.size(); ++k) {
      const auto& p = result.pairs[k];
      if (!p.kept || !active[static_cast<size_t>(p.view_a)] ||
          !active[static_cast<size_t>(p.view_b)])
        continue;
      edges.push_back({p.view_a, p.view_b, p.a_from_b, icp[k].information});
      edge_pair.push_back(k);
    }
    sol = optimize(edges, false);
    // The pair that disagrees most with the graph, if beyond the bound.
    std::vector<double> errors;
    for (size_t e = 0; e < edges.size(); ++e) {
      PairRegistration& p = result.pairs[edge_pair[e]];
      const auto& o = icp[edge_pair[e]];
      EdgeError(internal::EdgeDiscrepancy(sol.part_from_rig, edges[e]), o.centroid_in_a,
                o.radius_mm, &p.graph_error_deg, &p.graph_error_mm);
      errors.push_back(p.graph_error_mm);
    }
    const double bound =
        std::max(options.min_edge_error_mm,
                 options.max_edge_error_ratio * Median(std::vector<double>(errors)));
    size_t worst = edges.size();
    for (size_t e = 0; e < edges.size(); ++e)
      if (errors[e] > bound && (worst == edges.size() || errors[e] > errors[worst])) worst = e;
    if (worst < edges.size()) {
      PairRegistration& p = result.pairs[edge_pair[worst]];
      p.kept = false;
      p.reason = StringPrintf("disagrees with the pose graph by %.4f deg / %.4f mm (bound %.4f mm)",
                              p.graph_error_deg, p.graph_error_mm, bound);
      continue;
    }
    // The view whose pose departs most from its initial one, if beyond the bounds.
    int worst_view = -1;
    double worst_excess = 1.0;
    for (size_t i = 0; i < n; ++i) {
      if (!active[i] || !views[i].has_initial || static_cast<int>(i) == anchor) continue;
      const Eigen::Vector3d c = geo[i].centroid;
      const double deg = RotationErrorDeg(sol.part_from_rig[i], initial[i]);
      const double mm = (sol.part_from_rig[i] * c - initial[i] * c).norm();
      double excess = 0;
      if (options.max_initial_departure_deg > 0)
        excess = std::max(excess, deg / options.max_initial_departure_deg);
      if (options.max_initial_departure_mm > 0)
        excess = std::max(excess, mm / options.max_initial_departure_mm);
      if (excess > worst_excess) {
        worst_excess = excess;
        worst_view = static_cast<int>(i);
        result.views[i].reason = StringPrintf(
            "its registered pose departs from its initial pose by %.3f deg / %.3f mm (bounds "
            "%.3f deg / %.3f mm): a wrong table angle, or the part moved",
            deg, mm, options.max_initial_departure_deg, options.max_initial_departure_mm);
      }
    }
    if (worst_view >= 0) {
      active[static_cast<size_t>(worst_view)] = false;
      for (size_t i = 0; i < n; ++i)
        if (active[i] && static_cast<int>(i) != worst_view) result.views[i].reason.clear();
      continue;
    }
    // Joint refinement: every kept pair re-linearised at the graph's poses (its correspondences
    // found there, with its ICP's final gate and residual bound) and the graph solved again, until
    // no view moves: Gauss-Newton on the point-to-plane cost of all pairs at once, so that a pair
    // whose own ICP stopped off its minimum (jittering correspondences) is not taken at its word.
    // table_sample: on the views' table samples (MergeOptions::icp_table_angles).
    auto joint = [&](bool table_sample) {
      for (int it = 0; it < options.joint_iterations && !edges.empty(); ++it) {
        tbb::parallel_for(size_t{0}, edges.size(), [&](size_t e) {
          const size_t k = edge_pair[e];
          const size_t a = static_cast<size_t>(edges[e].a), b = static_cast<size_t>(edges[e].b);
          const internal::IcpOutcome o = internal::LinearizePair(
              geo[a], geo[b], sol.part_from_rig[a].Inverse() * sol.part_from_rig[b],
              initial[a].Inverse() * initial[b], icp[k].gate_mm, icp[k].max_residual_mm,
              // A pair whose free result was kept holds nothing (as a hand pair).
              icp[k].hold_released ? hand_options : pair_options(edges[e].a, edges[e].b),
              // A pair that held a direction at the prior keeps its strided sample: on a part of
              // planes the table sample's walls leave that direction barely fixed, not held.
              table_sample && !geo[b].table_sample.empty() && icp[k].degenerate.empty()
                  ? &geo[b].table_sample
                  : nullptr);
          if (o.correspondences >= 7) {
            edges[e].a_from_b = o.a_from_b;
            edges[e].information = o.information;
          }
        });
        const std::vector<Rigid3d> before = sol.part_from_rig;
        sol = optimize(edges, false);
        double motion = 0;
        for (size_t i = 0; i < n; ++i) {
          if (!active[i]) continue;
          std::vector<Eigen::Vector3d> probe;
          const auto& sample = geo[i].overlap_sample;
          for (size_t k = 0; k < sample.size(); k += std::max<size_t>(1, sample.size() / 16))
            probe.push_back((*geo[i].points)[sample[k]]);
          motion = std::max(motion, MaxDisplacementMm(sol.part_from_rig[i], before[i], probe));
        }
        result.joint_iterations = it + 1;
        result.joint_last_motion_mm = motion;
        if (motion < options.joint_tolerance_mm) break;
      }
    };
    joint(false);
    if (use_model && options.icp_table_angles && options.icp_table_share > 0) {
      // The axis where the strided pairs put it (its 1-sigma theirs), the angles from the table
      // samples.
      const internal::TableFit strided = table_fit;
      optimize(edges, true);
      axis_sigma[0] = table_fit.sigma_direction_deg;
      axis_sigma[1] = table_fit.sigma_point_mm;
      table_model.direction_in_rig = strided.direction_in_rig;
      table_model.point_in_rig_mm = strided.point_in_rig_mm;
      table_model.fix_axis = true;
      joint(true);
    }
    // Hand views' honest covariance (internal/hand_sigma.h): their weak pairs' information
    // widened where the spread over blocks of the overlap exceeds it; too wide a view is left out.
    std::vector<bool> weak(result.pairs.size());
    for (size_t k = 0; k < weak.size(); ++k) weak[k] = weak_hand(k);
    hand_cov = internal::HandCovariance(geo, sol.part_from_rig, edges, edge_pair, icp, weak,
                                        hand_options, options, optimize, &result.pairs);
    // The widest hand view beyond the departure bounds, if any.
    worst_view = internal::WidestHandView(hand_cov, views, active, anchor, sol.part_from_rig, geo,
                                          options, &result.views);
    if (worst_view >= 0) {
      active[static_cast<size_t>(worst_view)] = false;
      for (size_t i = 0; i < n; ++i)
        if (active[i]) result.views[i].reason.clear();
      continue;
    }
    // Final solve with the covariance.
    sol = optimize(edges, true);
    result.graph_iterations = sol.iterations;
    result.graph_initial_cost = sol.initial_cost;
    result.graph_final_cost = sol.final_cost;
    break;
  }
  if (use_model) {
    result.turntable_model = true;
    result.axis_direction_in_rig = table_fit.direction_in_rig;
    result.axis_point_in_rig_mm = table_fit.point_in_rig_mm;
    result.axis_sigma_direction_deg =
        axis_sigma[0] >= 0 ? axis_sigma[0] : table_fit.sigma_direction_deg;
    result.axis_sigma_point_mm = axis_sigma[1] >= 0 ? axis_sigma[1] : table_fit.sigma_point_mm;
    result.graph_variance_factor = table_fit.variance_factor;
    result.graph_huber_corner = table_fit.huber_corner;
    for (size_t i = 0; i < n; ++i) {
      if (!active[i] || !std::isfinite(table_fit.angle_rad[i])) continue;
      ViewPose& v = result.views[i];
      v.table_angle_deg = table_fit.angle_rad[i] * 180 / M_PI;
      v.table_angle_correction_deg =
          (table_fit.angle_rad[i] - table_model.angle_rad[i]) * 180 / M_PI;
      v.sigma_table_angle_deg = table_fit.sigma_angle_deg[i];
    }
  }
  for (auto& p : result.pairs) {
    if (p.kept &&
        (!active[static_cast<size_t>(p.view_a)] || !active[static_cast<size_t>(p.view_b)])) {
      p.kept = false;
      p.reason = "a view of the pair is left out";
    }
  }

  // Per-view outcome: pose, residuals at the final poses, noise, uncertainty.
  std::vector<std::vector<double>> view_rms(n), view_sq(n);
  std::vector<std::vector<internal::DegenerateDirection>> view_free(n);
  for (size_t k = 0; k < result.pairs.size(); ++k) {
    PairRegistration& p = result.pairs[k];
    if (!p.kept) continue;
    const size_t a = static_cast<size_t>(p.view_a), b = static_cast<size_t>(p.view_b);
    const Rigid3d a_from_b = sol.part_from_rig[a].Inverse() * sol.part_from_rig[b];
    const internal::IcpOutcome fin = internal::EvaluatePair(
        geo[a], geo[b], a_from_b, icp[k].gate_mm, icp[k].max_residual_mm, options);
    p.final_rms_mm = fin.rms_mm;
    for (size_t v : {a, b}) {
      view_rms[v].push_back(fin.rms_mm);
      ++result.views[v].pairs;
      for (internal::DegenerateDirection d : icp[k].degenerate) {
        d.axis = sol.part_from_rig[a].rotation * d.axis;  // the part frame
        auto& mine = view_free[v];
        // One entry per direction (within 10 deg), whichever pairs left it free.
        const bool seen = std::any_of(mine.begin(), mine.end(), [&](const auto& e) {
          return e.rotation == d.rotation && std::abs(e.axis.dot(d.axis)) > std::cos(M_PI / 18);
        });
        if (!seen) mine.push_back(d);
      }
    }
  }
  for (size_t i = 0; i < n; ++i) {
    ViewPose& v = result.views[i];
    v.accepted = active[i];
    v.anchor = static_cast<int>(i) == result.anchor;
    if (!v.accepted) {
      if (v.reason.empty()) v.reason = "not registered";
      continue;
    }
    v.reason.clear();
    v.part_from_rig = sol.part_from_rig[i];
    for (const auto& d : view_free[i])
      v.prior_directions.push_back(DirectionText(d, Eigen::Quaterniond::Identity()));
    double sum_sq = 0;
    for (double r : view_rms[i]) sum_sq += r * r;
    v.residual_rms_mm =
        view_rms[i].empty() ? 0.0 : std::sqrt(sum_sq / static_cast<double>(view_rms[i].size()));
    v.noise_mm =
        view_rms[i].empty() ? 0.0 : Median(std::vector<double>(view_rms[i])) / std::sqrt(2.0);
    if (v.anchor || !options.refine) continue;
    if (!sol.covariance_ok) {
      v.sigma_rotation_deg = v.sigma_translation_mm = std::numeric_limits<double>::quiet_NaN();
      continue;
    }
    internal::WorstSigmas(sol.covariance[i], v.part_from_rig, geo[i].centroid,
                          &v.sigma_rotation_deg, &v.sigma_translation_mm);
    v.graph_sigma_rotation_deg = v.sigma_rotation_deg;
    v.graph_sigma_translation_mm = v.sigma_translation_mm;
    if (!hand_cov.empty() && !views[i].table_deg) {
      double deg = 0, mm = 0;
      internal::WorstSigmas(hand_cov[i], v.part_from_rig, geo[i].centroid, &deg, &mm);
      v.sigma_rotation_deg = std::max(v.sigma_rotation_deg, deg);
      v.sigma_translation_mm = std::max(v.sigma_translation_mm, mm);
    }
  }

  // Loop closure over the accepted views in input order.
  std::vector<size_t> cycle;
  for (size_t i = 0; i < n; ++i)
    if (active[i]) cycle.push_back(i);
  if (cycle.size() >= 3) {
    Rigid3d chain;
    double after_deg = 0, after_mm = 0;
    bool closed = true;
    for (size_t k = 0; k < cycle.size() && closed; ++k) {
      const int u = static_cast<int>(cycle[k]), w = static_cast<int>(cycle[(k + 1) % cycle.size()]);
      const PairRegistration* found = nullptr;
      for (const auto& p : result.pairs)
        if (p.kept && ((p.view_a == u && p.view_b == w) || (p.view_a == w && p.view_b == u)))
          found = &p;
      if (found == nullptr) {
        closed = false;
        break;
      }
      chain = chain * (found->view_a == u ? found->a_from_b : found->a_from_b.Inverse());
      after_deg = std::max(after_deg, found->graph_error_deg);
      after_mm = std::max(after_mm, found->graph_error_mm);
    }
    if (closed) {
      const Eigen::Vector3d c = geo[cycle[0]].centroid;
      result.has_loop = true;
      result.loop_closure_before_deg =
          chain.rotation.angularDistance(Eigen::Quaterniond::Identity()) * 180.0 / M_PI;
      result.loop_closure_before_mm = (chain * c - c).norm();
      result.loop_closure_after_deg = after_deg;
      result.loop_closure_after_mm = after_mm;
    }
  }
  result.time_graph_s = Seconds(t0);

  // 4. Fusion.
  t0 = Clock::now();
  std::vector<internal::FusionView> fusion;
  for (size_t i = 0; i < n; ++i) {
    if (!active[i]) continue;
    internal::FusionView f;
    f.view = static_cast<int>(i);
    f.points = geo[i].points;
    f.normals = &geo[i].normals;
    f.variation = &geo[i].variation;
    if (views[i].backdrop) f.backdrop = &views[i].backdrop->points;
    f.part_from_rig = result.views[i].part_from_rig;
    f.sigma_mm = result.views[i].noise_mm > 0
                     ? result.views[i].noise_mm
                     : std::max(options.fuse_min_disagreement_mm / options.fuse_k_sigma, 1e-6);
    fusion.push_back(f);
  }
  if (!fusion.empty()) {
    result.fuse_cell_mm =
        options.fuse_cell_mm > 0
            ? options.fuse_cell_mm
            : std::max(geo[static_cast<size_t>(result.anchor)].area_spacing_mm, 1e-3);
    internal::FusionOptions fo;
    fo.cell_mm = result.fuse_cell_mm;
    fo.k_sigma = options.fuse_k_sigma;
    fo.min_disagreement_mm = options.fuse_min_disagreement_mm;
    fo.edge_variation = options.fuse_edge_variation;
    fo.min_incidence_cos = options.fuse_min_incidence_cos;
    fo.support_radius_mm = options.fuse_support_cells * result.fuse_cell_mm;
    fo.reject_radius_mm = options.fuse_reject_cells * result.fuse_cell_mm;
    fo.support_min_factor = options.fuse_support_min_factor;
    fo.see_through_views = options.fuse_see_through_views;
    fo.see_through_pixels = options.fuse_see_through_pixels;
    internal::FuseViews(fusion, fo, &result);
  }
  result.time_fuse_s = Seconds(t0);
  result.time_s = Seconds(t_start);
  return result;
}

}  // namespace slshadow::multiview
