// MergeViews: the views of a multi-view scan (turntable angles or hand-placed), each reconstructed
// in its own rig frame, registered into one part frame and fused into one model (issue 32,
// "Scan and merge"). Four steps:
//
//  1. Initial poses. A view with has_initial keeps part_from_rig_initial (for a table view the
//     inverse of TurntableAxis::RigFromTableTurn(angle)); a view without one is found by
//     compare::Register (global+icp: FPFH + RANSAC, then ICP) against the views posed so far.
//  2. Pairwise registration. Each view is paired with the (up to) max_pairs_per_view views that
//     overlap it at the initial poses (overlap: share of a view's sample points with a
//     neighbour of the other view within initial_gate_mm and a compatible normal; at least
//     min_pair_overlap) and look at the part from the nearest directions (smallest relative
//     rotation; a face all views see makes the overlap high for every pair, so it does not rank
//     them); each pair is registered by point-to-plane ICP (Chen & Medioni 1991)
//     with the symmetric normal, the mean of both points' normals (Rusinkiewicz 2019, so curved
//     surfaces add no bias), from the initial relative pose: up to icp_points source points
//     against all points of the other view, edge points (PCA surface variation above
//     icp_max_surface_variation) and outliers (residual beyond icp_max_residual_sigmas robust
//     standard deviations of the previous iteration's) left out, the gate halving from
//     initial_gate_mm down to 3 x the point spacing each time the pose has settled, each
//     correspondence weighted by 1 / (its two points' measured noise variances), directions
//     the overlap leaves free (icp_degenerate_ratio: a part of planes slides along them) held
//     at the initial relative pose with the prior's information, stopping when the pose moves
//     less than icp_tolerance_mm or icp_noise_tolerance of its own 1-sigma. Each pair
//     yields a_from_b, the residual RMS and the 6x6 information J^T J / sigma^2 of the left
//     perturbation (rotation vector, translation) of a_from_b in frame a, sigma^2 the residual
//     variance.
//  3. Pose graph. One Ceres optimisation of all view poses, residual sqrt(information) x
//     Log(estimated a_from_b x measured a_from_b^-1) per pair, the anchor view (the first
//     accepted view) fixed: its initial pose defines the part frame. Left out and named, with the
//     reason: a pair whose ICP still moves more than icp_max_final_motion_mm per iteration after
//     icp_max_iterations (a direction the overlap leaves free slides), that held a direction
//     at the prior while one view's points stand where the other saw through (max_seen_through:
//     the start was wrong, not the part's geometry degenerate), whose residual exceeds
//     max_pair_rms_ratio x the median of the pairs or whose overlap after ICP is below
//     min_pair_fitness; then, one at a time, the pair that disagrees most with the optimised graph
//     when its disagreement exceeds max(min_edge_error_mm, max_edge_error_ratio x the median); a
//     view left with no pair into the anchor's component; a view with an initial pose whose
//     optimised pose departs from it by more than max_initial_departure_deg / _mm (a wrong table
//     angle, or the part moved). Covariance of each pose from ceres::Covariance at the solution,
//     relative to the anchor, scaled by the pairs' reduced chi^2 (internal/pose_graph.h) when
//     above 1. Where a view's pairs form no loop it assumes independent point errors and is a
//     lower bound of the real uncertainty.
//     With the rig's turntable axis (MergeOptions::turntable) and two or more table views, the
//     graph is the turntable's model instead (internal/turntable_graph.h): one shared axis
//     (direction and point, fitted) and one angle per table view, hand-placed views 6 free
//     unknowns, a Huber loss on each pair, the covariances scaled by the pairs' reduced chi^2.
//     Then the joint refinement: every kept pair re-linearised at the graph's poses (its
//     correspondences found there) and the graph solved again until no view moves, so a pair
//     whose ICP stopped off its minimum does not pull the views (Gauss-Newton on the point-to-
//     plane cost of all pairs at once).
//  4. Fusion. Each point gets its own noise: the view's (noise_mm) raised at edges (PCA surface
//     variation above the larger of fuse_edge_variation and 3 x the view's median variation) and
//     at grazing incidence (fuse_edge_variation, fuse_min_incidence_cos), and weight 1 / noise^2.
//     The accepted views' points, in the part frame, are binned in cubic cells of fuse_cell_mm;
//     within a cell, points off edges whose normals agree (within 60 deg) form one surface, edge
//     points (their normals unreliable) join the surface nearest their normal, and each view's
//     weighted mean height along that surface's normal is compared with the others'. The largest
//     set of views that agree within max(fuse_min_disagreement_mm, fuse_k_sigma x
//     sqrt(sigma_a^2 + sigma_b^2)) (sigma: the noise of each view's weighted mean in the cell) is
//     fused into one point, the weighted mean; each other view keeps its own point; all points of
//     such a surface cell are flagged `disagree`. Then each point one view alone gave with a noise
//     factor of at least fuse_support_min_factor (an edge or grazing point) is checked against
//     the other views' points around it that are no noisier: on the surface of one within
//     fuse_support_cells cells (within the combined noise) it is superseded (left out: the
//     better view measures it); an edge point in front of the surfaces of two or more other
//     views within fuse_reject_cells cells (in the space they see through) and on none is
//     rejected (left out: a point off a depth edge); otherwise, off another view's surface, it is
//     flagged `disagree` and kept apart. Last, the free-space check: any point one view alone
//     gave that fuse_see_through_views or more other views saw through (all their points along
//     their line of sight through it, within fuse_see_through_pixels of their point spacing and
//     ViewCloud::backdrop included, lie beyond it by more than the combined noise) is rejected:
//     ghost points far from any other view's surface (off depth edges, at the part's foot above
//     the cropped table). So the merged cloud has about one point per surface cell and view
//     group, however many views saw it, and a view's edge outliers do not outweigh the fused
//     surface (superseded_points, rejected_points count what was left out).
//
// Units: mm, degrees where named. Frames: each view's cloud is in its rig frame (the first
// camera's frame, camera at the origin, which is also the viewpoint normals are oriented to);
// part_from_rig maps it into the part frame.
// Every pair and the fusion run in parallel (TBB); results do not depend on the thread count.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "compare/registration.h"
#include "core/point_cloud.h"
#include "core/rig.h"
#include "core/rigid3.h"

namespace slshadow::multiview {

// One view's reconstruction, in that view's rig frame. The cloud is borrowed: it must outlive the
// MergeViews call.
struct ViewCloud {
  std::string name;                   // e.g. "view_03"; appears in reports and reasons
  const PointCloud* cloud = nullptr;  // mm; normals used when present, else estimated (PCA)
  // The view's pose guess: x_in_part = part_from_rig_initial * x_in_rig. For table views the
  // inverse of RigFromTableTurn(angle); ignored when has_initial is false.
  Rigid3d part_from_rig_initial;
  bool has_initial = true;  // false: found by global registration against the views posed so far
  // The commanded table angle of a table view (degrees), for the turntable model
  // (MergeOptions::turntable); empty for a view placed by hand.
  std::optional<double> table_deg;
  // Points the view measured that are not part of the model (e.g. the table, cropped by
  // project_merge.h), in the same rig frame; borrowed like `cloud`, may be null. They are never
  // merged: they only show where the view saw through the space in front of them (step 4's
  // free-space check).
  const PointCloud* backdrop = nullptr;
};

struct MergeOptions {
  // false: no registration: every view keeps its initial pose (a view without one is left out,
  // named), steps 1-3 are skipped and the views are only fused (step 4), each view's noise taken
  // as fuse_min_disagreement_mm / fuse_k_sigma.
  bool refine = true;
  // Pairing and ICP.
  double initial_gate_mm = 5.0;   // bound on the initial poses' error where the views overlap:
                                  // the overlap test's and the ICP's first correspondence gate
  double min_pair_overlap = 0.1;  // share of sample points, at the initial poses, to pair views
  int max_pairs_per_view = 4;     // each view is paired with its nearest overlapping views only
  int overlap_samples = 2000;     // sample points per view for the overlap test
  int icp_points = 20000;         // source points per pair (evenly strided subset)
  // With the rig's turntable axis (`turntable`), the share of a table view's icp_points drawn
  // where they fix the table angle: with probability proportional to |n . (u x (p - c))|, the
  // point's motion along its normal per radian of table turn (walls facing along the turn, far
  // from the axis), the rest evenly strided. Used for the table angles only (icp_table_angles);
  // alone it moved the fitted axis point (docs/benchmarks/log/2026-12-07-registration-rotation.md).
  // 0: evenly strided only.
  double icp_table_share = 0.5;
  // With icp_table_share > 0: the pairs, the pose graph, its joint refinement and so the
  // turntable axis (direction and point) from the evenly strided sample alone; then, the axis
  // held, the table angles fitted again from every kept pair re-linearised on the sample with
  // the table share (joint refinement rounds). The table sample's oblique walls carry more of the
  // reconstruction's systematic error, which moved the fitted axis point (and so the views'
  // translation); the axis is fixed by the strided points, the angles by the table sample. A
  // pair that held a direction at the prior (icp_degenerate_ratio) keeps the strided sample: on
  // the self-occluding part's 4 views the table sample moved such angles 0.0071 deg. On by
  // default (with the two settings around it): on the 12-view demo with five sensor-noise draws
  // (no pair holds there) the largest rotation error fell on every draw (median 0.0070 -> 0.0026
  // deg) and the translation stayed within 2 um on the same draws as before; noise-free (every
  // pair holds) nothing changes (docs/benchmarks/log/2026-12-08-rotation-noise-3.md).
  bool icp_table_angles = true;
  // With icp_table_angles: icp_normal_neighbors' normals on the table sample only; the strided
  // sample (the pairs, the graph and so the axis) keeps the reconstruction's normals.
  bool icp_table_normals_only = true;
  int icp_max_iterations = 60;
  double icp_tolerance_mm = 1e-5;  // stop when an update moves the source points less than this
  // or less than this share of the pose's own 1-sigma (its least fixed direction, from the
  // residuals): with noise an ICP jitters at that level instead of settling. Only between two
  // table views (as icp_degenerate_ratio). 0: tolerance only.
  double icp_noise_tolerance = 0.1;
  // A pair still moving more than this per iteration after icp_max_iterations is rejected.
  double icp_max_final_motion_mm = 1e-3;
  double icp_max_normal_angle_deg = 30.0;  // correspondences with normals farther apart: dropped
  // Correspondences whose point-to-plane residual exceeds this many robust standard deviations
  // (1.4826 x the median |residual| of the previous iteration) are dropped: outliers of the
  // reconstruction. 0: none dropped.
  double icp_max_residual_sigmas = 3.0;
  double icp_max_surface_variation = 0.05;  // PCA lambda_min / sum: above it a point is an edge
  // Each correspondence weighted by 1 / (its two points' noise variances), each measured as the
  // PCA plane fit's residual variance over its normal_neighbors (floored at a quarter of the
  // view's median): noisy points (grazing, dark, edges) count less. false: equal weights.
  bool icp_noise_weights = true;
  // Degeneracy (Gelfand et al. 2003, Zhang et al. 2016): an eigenvector of a pair's normal-
  // equation matrix (rotations about the matched points' centroid scaled by their RMS radius)
  // whose eigenvalue is below this share of the largest is a direction the overlap leaves free
  // (planes slide along themselves). The ICP does not move along it and the pair measures its
  // initial relative pose there (the table's, or the global registration's) with the prior's
  // 1-sigma below, instead of sliding (and being rejected). Only between two table views
  // (table_deg, with `turntable`): a hand view's initial pose is no prior. Such a pair must pass
  // the free-space check (max_seen_through): a wrong table angle held so is left out, named.
  // 0: none (pairs slide and are rejected; a part of planes then loses views,
  // docs/benchmarks/log/2026-12-07-degeneracy-default.md).
  double icp_degenerate_ratio = 1e-3;
  // The free-space check of a pair that held a direction at the prior (internal/sight_check.h):
  // the share of either view's points (overlap samples) that, at the pair's pose, lie where the
  // other view saw through (all its points along their line of sight, within
  // see_through_pixels of its point spacing, its backdrop included, beyond them by more than
  // max(seen_through_tol_gate x initial_gate_mm, fuse_k_sigma x sqrt(2) x the pair's RMS)).
  // Above this share the pair is rejected: the start was wrong (a wrong table angle, or the part
  // moved), since at the right pose one view's points are on or behind the other's surfaces.
  // 1: no check.
  double max_seen_through = 0.05;
  // Hold only where the pair would slide: a pair between two table views is first registered
  // without the hold (icp_degenerate_ratio 0); where that converges and its departure from the
  // prior along the directions icp_degenerate_ratio calls weak is within this many of the prior's
  // 1-sigmas (prior_sigma_deg / _mm; the chi of the projected departure), the pair keeps its own
  // result and information there (nothing held), else it is registered again with the hold.
  // 0: always hold (every weak direction held at the prior, the pair's own information there
  // dropped).
  double icp_hold_gate_sigmas = 0;
  double seen_through_tol_gate = 0.1;
  double prior_sigma_deg = 0.05;  // 1-sigma of an initial relative pose's rotation
  double prior_sigma_mm = 0.05;   // and of its translation
  int normal_neighbors = 12;      // k of the PCA normals and surface variation
  // k of the normals the pairwise ICP uses (its residuals and Jacobians): PCA over this many
  // neighbours, whatever normals the cloud brings; 0: the normals above (the cloud's, else PCA
  // over normal_neighbors). With sensor noise the reconstruction's own normals (central
  // differences over +-1 pixel) are several degrees off, and in the point-to-plane cost that
  // noise enters both the residual and the Jacobian: on the demo part's pairs, registered from
  // the true poses, k = 30 lowers the table angles' errors from 0.0096 to 0.0037 deg RMS and
  // their ratio to the stated sigma from 3.3 to 1.3 (docs/benchmarks/log/2026-12-07-rotation-
  // noise-2.md). With icp_table_normals_only (the default) on the table angles' sample only: on
  // every ICP sample it moved the fitted axis point and raised the translation on 4 of 5 draws.
  int icp_normal_neighbors = 30;
  // Rejection.
  double min_pair_fitness = 0.05;    // share of source points matched after ICP, to keep a pair
  double max_pair_rms_ratio = 3.0;   // ICP residual RMS vs the median of all pairs
  double max_edge_error_ratio = 10;  // pair vs graph disagreement vs the median of all pairs
  double min_edge_error_mm = 0.02;   // disagreements below this are never rejected
  // For views with an initial pose: farther than this from it after the graph, the view is left
  // out. 0 disables the check.
  double max_initial_departure_deg = 2.0;
  double max_initial_departure_mm = 10.0;
  // A hand-placed view's honest 1-sigma (internal/hand_sigma.h): each kept pair with a hand view
  // whose overlap leaves a direction weak (smallest eigenvalue ratio below icp_degenerate_ratio)
  // re-solved with each of this many spatial blocks of its overlap left out; its information
  // widened along the weak directions where the spread exceeds it, and for hand views the graph's
  // covariance with the widened pairs reported when larger. A hand view whose 1-sigma so found
  // exceeds max_initial_departure_deg / _mm is left out, named. 0: the graph's covariance only.
  // The jackknife cannot see a bias common to the overlap: a weak hand pair's cost may have its
  // minimum 0.2 deg off (5 stated sigmas; docs/benchmarks/log/2026-12-08-hand-views.md), which
  // only a loop of pairs shows. So the weakest direction of a weak pair that no loop tests (a
  // bridge of the graph) gets a 1-sigma at least the largest disagreement with the graph of a
  // weak hand pair that a loop did test (PairRegistration::untested_floor_deg).
  int hand_spread_blocks = 8;
  // The pose graph on the turntable's model (internal/turntable_graph.h): with the rig's axis
  // and at least two accepted table views (ViewCloud::table_deg) whose angles differ, a table
  // view's pose is the rotation by its own table angle about one shared axis (direction and
  // point fitted, starting from `turntable`), so each table view has one unknown instead of six;
  // hand-placed views keep six. Without an axis, or turntable_model false: six per view.
  bool turntable_model = true;
  std::optional<TurntableAxis> turntable;
  // Huber loss on each pair's whitened residual in the turntable graph, its corner at this many
  // times the median pair's; 0: plain least squares.
  double graph_robust_k = 3.0;
  // Joint refinement after the pose graph: every kept pair re-linearised at the graph's poses and
  // the graph solved again (Gauss-Newton on all pairs' point-to-plane cost), at most this many
  // times, until no view's sample points move more than joint_tolerance_mm. 0: none.
  int joint_iterations = 10;
  double joint_tolerance_mm = 1e-4;
  // Global registration for views without an initial pose (method forced to global+icp). RANSAC's
  // single most supported hypothesis (global_candidates 1), not the comparison of candidates the
  // shadow uses: comparing them starts more hand views near their pose (in the hand fixture of
  // multiview_registration_test, from 0 deg, 5 of 7 hand views merged instead of 3), and with the
  // floor of weak pairs no loop tests (hand_spread_blocks above) every merged one states an honest
  // sigma, but two of them are then 0.23 deg off (within 1.2 sigma), where one hypothesis merges
  // none beyond 0.08 deg (log/2026-12-08-hand-views.md).
  compare::RegistrationOptions global = [] {
    compare::RegistrationOptions g;
    g.global_candidates = 1;
    return g;
  }();
  // Fusion.
  double fuse_cell_mm = 0.0;  // 0: the anchor view's point spacing, sqrt(area per point)
  double fuse_k_sigma = 4.0;  // agreement bound in combined standard deviations
  double fuse_min_disagreement_mm = 0.05;  // agreement bound floor (sampling of curved surfaces)
  // Each point's noise: the view's x (1 + min(v, 5 v_ref) / v_ref) / sqrt(max(cos i,
  // fuse_min_incidence_cos)), v its PCA surface variation (edges), v_ref the larger of
  // fuse_edge_variation and 3 x the view's median variation (what its noise gives a flat
  // surface), i the angle between its normal and the ray to the camera; it weights the point by
  // 1 / noise^2. 0: no edge factor (no incidence factor).
  double fuse_edge_variation = 0.001;
  double fuse_min_incidence_cos = 0.1;
  // The check of points one view alone gave with a noise factor of at least
  // fuse_support_min_factor (step 4): superseded by a no noisier point of another view within
  // fuse_support_cells cells whose surface it lies on; rejected when in front of the surfaces of
  // two or more other views within fuse_reject_cells cells. 0: no such check.
  double fuse_support_cells = 2.0;
  double fuse_reject_cells = 4.0;
  double fuse_support_min_factor = 2.0;
  // The free-space check (step 4): a point one view alone gave is rejected when at least this
  // many other views saw through it, i.e. their measurements along their own lines of sight
  // through it (within fuse_see_through_pixels of their point spacing, backdrop points included)
  // all lie beyond it by more than the combined noise. 0: no such check.
  int fuse_see_through_views = 2;
  double fuse_see_through_pixels = 1.5;

  // Throws slshadow::Error naming the field and its value when one is out of range.
  void Check() const;
};

// One view's outcome. Poses are relative to the anchor view (see above).
struct ViewPose {
  std::string name;
  Rigid3d part_from_rig;            // optimised (the initial or global guess when left out)
  Rigid3d part_from_rig_initial;    // what the graph started from (the global result if found)
  double residual_rms_mm = 0;       // point-to-plane RMS over the view's kept pairs, final poses
  double noise_mm = 0;              // the view's noise along the normal, from its pairs' residuals
  double sigma_rotation_deg = 0;    // 1-sigma along the worst axis (covariance, see above)
  double sigma_translation_mm = 0;  // 1-sigma displacement of the view's centroid, worst axis
  // The pose graph's own 1-sigma (its pairs' information as they state it); a hand view's
  // sigma_* above is the larger of these and the widened pairs' (hand_spread_blocks).
  double graph_sigma_rotation_deg = 0, graph_sigma_translation_mm = 0;
  int pairs = 0;  // kept pairs this view is in
  // Turntable model (MergeResult::turntable_model), table views: the fitted true table angle,
  // its departure from the commanded one's (TurntableAxis::TrueAngleDeg) and its 1-sigma.
  std::optional<double> table_angle_deg;
  double table_angle_correction_deg = 0;
  double sigma_table_angle_deg = 0;
  // The directions, in the part frame, that some kept pair of the view left free (degenerate,
  // MergeOptions::icp_degenerate_ratio) and the prior (the initial poses) fixed: e.g.
  // "translation along (0.000, 0.342, -0.940)" or "rotation about (...)".
  std::vector<std::string> prior_directions;
  int points = 0;         // points of the view's cloud
  bool anchor = false;    // the view that fixes the part frame
  bool accepted = false;  // registered and merged
  std::string reason;     // why it was left out (empty when accepted)
};

// One registered pair of views: view a is the reference, b is moved onto it.
struct PairRegistration {
  int view_a = 0, view_b = 0;  // indices into the views
  double overlap_initial = 0;  // share of b's samples near a at the initial poses
  Rigid3d a_from_b;            // ICP result: x_in_rig_a = a_from_b * x_in_rig_b
  double fitness = 0;          // share of b's ICP points matched at the final gate
  double rms_mm = 0;           // point-to-plane residual RMS at the ICP result
  int correspondences = 0;
  int iterations = 0;
  bool converged = false;
  // Disagreement with the optimised graph: rotation, and the displacement of the matched points'
  // centroid plus rotation x their RMS radius.
  double graph_error_deg = 0, graph_error_mm = 0;
  double final_rms_mm = 0;  // point-to-plane RMS at the optimised poses
  // Directions the overlap leaves free (frame a; MergeOptions::icp_degenerate_ratio), held at
  // the initial relative pose, and the smallest eigenvalue ratio of the pair.
  std::vector<std::string> degenerate;
  double min_eigen_ratio = 0;
  // Pairs with degenerate directions: the larger share of either view's points that lie where
  // the other saw through, at the ICP result (MergeOptions::max_seen_through); -1: not checked.
  double seen_through = -1;
  // Kept pairs with a hand view (MergeOptions::hand_spread_blocks): the variance along the pair's
  // weakest direction from the spread over blocks of its overlap over what its information
  // states (about 1 when the information is right; internal/hand_sigma.h); 0: not measured.
  double spread_factor = 0;
  // Those pairs when no loop of kept pairs tests them (a bridge of the graph) and a weak hand pair
  // a loop did test disagreed with it: that largest disagreement (deg), the floor this pair's
  // weakest direction's 1-sigma was raised to (a rotation about its matched points' centroid);
  // 0: not raised.
  double untested_floor_deg = 0;
  bool kept = false;
  std::string reason;  // why it was rejected (empty when kept)
};

struct MergeResult {
  std::vector<ViewPose> views;  // in input order
  std::vector<PairRegistration> pairs;
  int anchor = -1;  // index of the anchor view, -1 when no view is accepted
  // Loop closure, when the accepted views in input order form a closed cycle of kept pairs
  // (a full turn): before = the error of chaining the cycle's pairwise registrations (what a
  // sequential merge leaves at its seam); after = the largest disagreement between one of the
  // cycle's pairs and the optimised graph (the worst seam left). Rotation in degrees, translation
  // as the displacement of the first view's centroid.
  bool has_loop = false;
  double loop_closure_before_deg = 0, loop_closure_before_mm = 0;
  double loop_closure_after_deg = 0, loop_closure_after_mm = 0;
  // Pose graph. With the turntable model: the fitted axis (rig frame; the point nearest the given
  // one), its 1-sigma (worst direction), the reduced chi^2 of the pairs the sigmas are scaled by
  // (at least 1) and the Huber corner (whitened units; 0: none).
  bool turntable_model = false;
  Eigen::Vector3d axis_direction_in_rig = Eigen::Vector3d::Zero();
  Eigen::Vector3d axis_point_in_rig_mm = Eigen::Vector3d::Zero();
  double axis_sigma_direction_deg = 0, axis_sigma_point_mm = 0;
  double graph_variance_factor = 1, graph_huber_corner = 0;
  int joint_iterations = 0;  // joint refinement rounds run
  double joint_last_motion_mm = 0;
  int graph_iterations = 0;
  double graph_initial_cost = 0, graph_final_cost = 0;
  // The merged model in the part frame, with normals and the scalar fields "view",
  // "views_fused", "sigma_mm" and "disagree" (the vectors below, as floats).
  PointCloud merged;
  std::vector<int> point_view;        // the view with the most points in the point's cell
  std::vector<uint8_t> point_views;   // views fused into the point (1 when kept apart)
  std::vector<float> point_sigma_mm;  // standard deviation along the normal (its quality)
  std::vector<uint8_t> disagree;      // 1: the views disagree beyond their noise here
  double fuse_cell_mm = 0;            // the cell size used
  size_t input_points = 0;            // points of the accepted views
  size_t disagree_points = 0;
  size_t superseded_points = 0;  // one view's noisy points other views measure better (step 4)
  size_t rejected_points = 0;    // one view's points off two or more other views' surfaces or
                                 // seen through by two or more other views
  double time_normals_s = 0, time_pairs_s = 0, time_graph_s = 0, time_fuse_s = 0, time_s = 0;

  int NumAccepted() const;
  std::string BriefReport() const;  // one line
  std::string FullReport() const;   // one line per view and per pair, then the model
};

// Throws slshadow::Error on bad options, no views, a null or empty cloud, or duplicate names.
// A view that cannot be registered is reported in the result, not thrown.
MergeResult MergeViews(const std::vector<ViewCloud>& views, const MergeOptions& options = {});

// Rotation angle between two transforms (degrees) and the largest displacement they give the
// points (mm): the error measures of the reports and tests.
double RotationErrorDeg(const Rigid3d& a, const Rigid3d& b);
double MaxDisplacementMm(const Rigid3d& a, const Rigid3d& b,
                         const std::vector<Eigen::Vector3d>& points);

}  // namespace slshadow::multiview
