// slshadow merge PROJECT --out MODEL [--cad MESH|SCENE] [--poses registered|axis] [--no-mesh]
#include <CLI/CLI.hpp>
#include <cstdio>

#include "apps/commands.h"
#include "core/error.h"
#include "core/mesh.h"
#include "core/shard.h"
#include "core/threads.h"
#include "sim/scene.h"
#include "workflows/multiview/merge.h"
#include "workflows/multiview/project_merge.h"
#include "workflows/multiview/turntable_scene.h"

namespace slshadow::app {

void AddFusionOptions(CLI::App* app, multiview::MergeOptions* m) {
  CLI::App* g = app->add_option_group(
      "Fusion",
      "The merged cloud (docs/formats.md \"Merge model folder\"). Points of the registered views "
      "are "
      "binned in cubic cells; per cell and surface, views that agree within their noise become "
      "one point, the mean weighted by 1 / noise^2 of each point; views that disagree are kept "
      "apart and flagged. A point's noise is its view's (from its pairs' ICP residuals) x its "
      "noise factor: (1 + min(v, 5 v_ref) / v_ref) / sqrt(max(cos i, --fuse-min-incidence-cos)), "
      "v the PCA surface variation of its 12 neighbours (0 on a plane, up to 1/3 at corners, "
      "edges and stray points), v_ref the larger of --fuse-edge-variation and 3 x the view's "
      "median v, i the angle between its normal and the ray to its camera. Then the points one "
      "view alone gave are checked against the other views (superseded, rejected, flagged).");
  g->add_option("--fuse-cell-mm", m->fuse_cell_mm,
                "edge of the fusion cells, mm; 0: the anchor view's point spacing (sqrt of the "
                "area per point). Larger averages more points into each merged point and blurs "
                "edges; smaller leaves single-view cells where views interleave")
      ->capture_default_str();
  g->add_option("--fuse-k-sigma", m->fuse_k_sigma,
                "two views agree on a surface when their heights along its normal differ by at "
                "most this many combined standard deviations (of each view's weighted mean in the "
                "cell); beyond, they are kept apart and flagged `disagree`")
      ->capture_default_str();
  g->add_option("--fuse-min-disagreement-mm", m->fuse_min_disagreement_mm,
                "floor of that bound, mm: height differences below it never count as a "
                "disagreement (a curved surface sampled within one cell)")
      ->capture_default_str();
  g->add_option("--fuse-edge-variation", m->fuse_edge_variation,
                "noise model: the smallest v_ref (above). A point with v > v_ref is an edge point: "
                "up to 6x noisier, and its normal is not trusted to start a surface. Lower it to "
                "distrust more of a noisy rig's points; 0: no edge factor")
      ->capture_default_str();
  g->add_option("--fuse-min-incidence-cos", m->fuse_min_incidence_cos,
                "noise model: the bound on cos i (above), so a grazing point counts at most "
                "1 / sqrt(this) times noisier (0.1: 3.2x); 0: no incidence factor")
      ->capture_default_str();
  g->add_option("--fuse-support-min-factor", m->fuse_support_min_factor,
                "a point one view alone gave with a noise factor of at least this (an edge or "
                "grazing point) is checked against the other views' points around it "
                "(--fuse-support-cells, --fuse-reject-cells)")
      ->capture_default_str();
  g->add_option("--fuse-support-cells", m->fuse_support_cells,
                "such a point on the surface of a no noisier point of another view within this "
                "many cells (within the combined noise) is superseded: left out, the other view "
                "measures that surface better; 0: no such check")
      ->capture_default_str();
  g->add_option("--fuse-reject-cells", m->fuse_reject_cells,
                "such an edge point in front of the surfaces of two or more other views within "
                "this many cells, and on none, is rejected (a point off a depth edge); otherwise, "
                "off another view's surface, it is flagged `disagree`")
      ->capture_default_str();
  g->add_option(
       "--fuse-see-through-views", m->fuse_see_through_views,
       "free-space check: a point one view alone gave that at least this many other views saw "
       "through (all their points along their line of sight through it, the table points "
       "--table-crop-mm cropped included, lie beyond it by more than the combined noise) "
       "is rejected when noisy (noise factor >= --fuse-support-min-factor) or when no "
       "other view's point lies within --fuse-reject-cells: the ghost points off depth "
       "edges and at the part's foot that no other surface lies near. A clean point near "
       "another view's surface is flagged `disagree` and kept apart instead. 1: trust "
       "one view's sight; 0: no such check")
      ->capture_default_str();
  g->add_option("--fuse-see-through-pixels", m->fuse_see_through_pixels,
                "radius of a line of sight, in that view's point spacing (the angle between "
                "neighbouring points from its camera); 3 or more of its points must lie within it "
                "for the view to count")
      ->capture_default_str();
}

int RunMerge(int argc, char** argv) {
  CLI::App app{
      "Merge a multi-view project (slshadow simulate --views, slshadow scan --views; "
      "docs/formats.md\n"
      "\"Multi-view project\") into one model in the part frame (the rig frame at table angle 0):\n"
      "  1. every complete view is reconstructed like any scan, one view's images in memory at a "
      "time;\n"
      "  2. initial poses from the rig's turntable axis and each view's commanded table angle\n"
      "     (hand-placed views: their part_from_rig_guess, else global registration, FPFH + "
      "RANSAC);\n"
      "     then pairwise ICP between overlapping views and one pose graph (Ceres) over all "
      "views,\n"
      "     the first merged view fixing the part frame (--poses axis: the initial poses as they "
      "are);\n"
      "     each view's pose, residual and 1-sigma, and the loop closure before/after, are "
      "reported;\n"
      "     a view that is missing or does not fit (no overlap, a wrong table angle, the part "
      "moved)\n"
      "     is left out and named with the reason;\n"
      "  3. the merged cloud: the views fused where they agree within their noise, kept apart and\n"
      "     flagged where they do not (scalars view, views_fused, sigma_mm, disagree);\n"
      "  4. with --cad: the signed C2M of the merged cloud and of each view to the CAD model, the\n"
      "     deviation painted on the CAD mesh (cad_deviation.ply, per vertex: MeshLab, "
      "CloudCompare),\n"
      "     coverage of the reachable CAD surface (the face on the table excluded) and the area no "
      "view\n"
      "     covered by reason (occluded, grazing, outside the field, too dark, not "
      "reconstructed).\n"
      "  5. unless --no-mesh: a watertight surface mesh by Poisson reconstruction of the merged "
      "cloud,\n"
      "     trimmed where no view saw the surface (mesh.ply; with --cad its C2M to the CAD), timed "
      "apart.\n"
      "Output MODEL (written atomically): report.json, summary.txt, merged.ply, mesh.ply, and with "
      "--cad\n"
      "cad_deviation.ply and cad_coverage.ply (surface samples coloured by reason). Example:\n"
      "  slshadow simulate --rig config/demo/turntable_rig.yaml --scene "
      "config/demo/turntable_scene.yaml \\\n"
      "      --patterns config/demo/patterns.yaml --views config/demo/views_12.yaml --out project\n"
      "  slshadow merge project --out model --cad config/demo/turntable_scene.yaml\n"
      "Views as independent jobs (a large project; GNU parallel or a Slurm job array): each shard\n"
      "reconstructs its views into a folder, the merge then reads them (docs/formats.md \"View\n"
      "reconstructions\"; a view reconstructed with other options or from other images is "
      "refused):\n"
      "  parallel -j 2 slshadow merge project --reconstructions recon --reconstruct-only "
      "--threads 1 --shard {}/4 ::: 0 1 2 3\n"
      "  slshadow merge project --reconstructions recon --out model --cad "
      "config/demo/turntable_scene.yaml",
      argv[0]};
  std::string project, out_dir, cad_path, mode = "stereo", poses = "registered";
  bool overwrite = false, quiet = false;
  multiview::ProjectMergeOptions options;
  app.add_option("PROJECT", project, "multi-view project folder (project.json, views/<name>/)")
      ->required();
  app.add_option("--out", out_dir,
                 "output model folder (must not exist unless --overwrite); required unless "
                 "--reconstruct-only");
  std::string reconstructions, shard_text = "0/1";
  bool reconstruct_only = false;
  app.add_option("--reconstructions", reconstructions,
                 "folder of the views' reconstructions (DIR/<view>/: cloud, dark pixels, the "
                 "options): views stored there are read instead of reconstructed, the others "
                 "reconstructed and written there; a second merge with other registration, "
                 "fusion or CAD options then skips step 1");
  app.add_flag("--reconstruct-only", reconstruct_only,
               "step 1 only: reconstruct this shard's views into --reconstructions and stop "
               "(views already stored with the same images and options are skipped)");
  int threads = 0;
  app.add_option("--threads", threads,
                 "threads for OpenCV, TBB and Ceres (default: SLURM_CPUS_PER_TASK when set, else "
                 "all cores); give each shard the cores it was allocated");
  app.add_option("--shard", shard_text,
                 "with --reconstruct-only, I/N: shard I (0-based) of N of the complete views in "
                 "project order, contiguous blocks; SLURM_ARRAY_TASK_ID / COUNT are not read")
      ->capture_default_str();
  app.add_option("--cad", cad_path,
                 "the part's CAD model in the part frame: a mesh (.stl/.ply/.obj), or a scene "
                 "(.yaml/.json) whose meshes are the part at table angle 0");
  app.add_option("--mode", mode, "reconstruction: stereo (both cameras) | projector (first camera)")
      ->capture_default_str()
      ->check(CLI::IsMember({"stereo", "projector"}));
  app.add_option("--poses", poses,
                 "registered: the initial poses refined by pairwise ICP and the pose graph | "
                 "axis: the turntable axis and table angles as they are (no registration)")
      ->capture_default_str()
      ->check(CLI::IsMember({"registered", "axis"}));
  app.add_option("--initial-gate-mm", options.registration.initial_gate_mm,
                 "bound on the initial poses' error where views overlap, mm (pairing and ICP)")
      ->capture_default_str();
  app.add_option("--max-departure-deg", options.registration.max_initial_departure_deg,
                 "a table view whose registered pose departs from its table angle's by more is "
                 "left out, deg (0: no check)")
      ->capture_default_str();
  app.add_option("--max-departure-mm", options.registration.max_initial_departure_mm,
                 "the same bound on the displacement of the view's centroid, mm (0: no check)")
      ->capture_default_str();
  app.add_option("--degenerate-ratio", options.registration.icp_degenerate_ratio,
                 "hold a pair's ICP directions whose eigenvalue is below this share of the largest "
                 "at the table's relative pose (table pairs; such a pair must pass the free-space "
                 "check, --max-seen-through; 0: off, such pairs slide and are rejected)")
      ->capture_default_str();
  app.add_option("--hold-gate-sigmas", options.registration.icp_hold_gate_sigmas,
                 "hold only pairs that would slide: a table pair registered without the hold "
                 "keeps its own result where it converged within this many prior sigmas of the "
                 "table's relative pose along its weak directions (0: always hold)")
      ->capture_default_str();
  app.add_option("--max-seen-through", options.registration.max_seen_through,
                 "a pair that held a direction at the table's prior is rejected when more than "
                 "this share of either view's points lie where the other view saw through (a "
                 "wrong table angle; 1: no check)")
      ->capture_default_str();
  app.add_option("--hand-spread-blocks", options.registration.hand_spread_blocks,
                 "a hand view's 1-sigma from its weak pairs re-solved with each of this many "
                 "blocks of their overlap left out; wider than --max-departure-deg / -mm: left "
                 "out (0: the pose graph's covariance only)")
      ->capture_default_str();
  app.add_option("--max-pairs-per-view", options.registration.max_pairs_per_view,
                 "each view is paired with at most this many overlapping views, those looking "
                 "from the nearest directions")
      ->capture_default_str();
  app.add_option("--icp-points", options.registration.icp_points,
                 "source points per pair in the pairwise ICP")
      ->capture_default_str();
  app.add_option("--icp-table-share", options.registration.icp_table_share,
                 "share of a table view's ICP points drawn where they fix the table angle (walls "
                 "facing along the turn, far from the axis), the rest evenly strided (0: strided "
                 "only)")
      ->capture_default_str();
  app.add_flag("--icp-table-angles,!--no-icp-table-angles", options.registration.icp_table_angles,
               "with --icp-table-share: the turntable axis from the evenly strided sample, then "
               "the table angles re-fitted (the axis held) from the sample with the table share "
               "(default; --no-icp-table-angles: everything from the one sample)");
  app.add_flag("--icp-table-normals-only,!--no-icp-table-normals-only",
               options.registration.icp_table_normals_only,
               "with --icp-table-angles: the --icp-normal-neighbors normals on the table sample "
               "only, the axis from the reconstruction's normals (default; "
               "--no-icp-table-normals-only: on every ICP sample)");
  app.add_option("--icp-normal-neighbors", options.registration.icp_normal_neighbors,
                 "k of the PCA normals the pairwise ICP uses instead of the reconstruction's "
                 "(with sensor noise those are several degrees off; 0: the reconstruction's)")
      ->capture_default_str();
  bool six_dof = false;
  app.add_flag("--six-dof", six_dof,
               "pose graph with six free unknowns per view, also for table views (default: the "
               "turntable model, one angle per table view about one fitted axis)");
  app.add_option("--max-points-per-view", options.max_points_per_view,
                 "keep at most this many points of each view (every s-th cell; 0: all)")
      ->capture_default_str();
  app.add_option("--threshold-mm", options.cad.threshold_mm, "inlier threshold of the coverage, mm")
      ->capture_default_str();
  app.add_option("--grazing-deg", options.cad.grazing_deg,
                 "incidence beyond which the CAD surface counts as grazing, deg")
      ->capture_default_str();
  app.add_option(
         "--table-crop-mm", options.table_crop_mm,
         "views on the table (table views and hand placements with placed_on_table): drop points "
         "less than this above the table plane (negative: keep all)")
      ->capture_default_str();
  bool no_mesh = false;
  app.add_flag("--no-mesh", no_mesh, "do not build the surface mesh (mesh.ply)");
  app.add_option("--mesh-depth", options.mesh_options.depth,
                 "Poisson octree depth of the mesh (finest cell: the cloud's extent / 2^depth)")
      ->capture_default_str();
  app.add_option("--mesh-trim-mm", options.mesh_options.trim_distance_mm,
                 "mesh vertices farther than this from every merged point are trimmed, mm (0: 2 x "
                 "the larger of the finest cell and the cloud's point spacing)")
      ->capture_default_str();
  AddFusionOptions(&app, &options.registration);
  app.add_flag("--overwrite", overwrite, "replace an existing output folder");
  app.add_flag("--quiet", quiet, "do not print the summary");
  bool no_html = false;
  app.add_flag("--no-html", no_html,
               "do not write MODEL/report.html (the self-contained page of the model; slshadow "
               "report MODEL writes it later)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  options.mode = ReconstructModeFromString(mode);
  options.poses = multiview::PoseSourceFromString(poses);
  options.reconstructions = reconstructions;
  if (const int budget = ResolveThreadBudget(threads); budget > 0) SetThreadBudget(budget);
  if (reconstruct_only) {
    SLSHADOW_THROW_IF(reconstructions.empty(),
                      "--reconstruct-only: needs --reconstructions DIR (where the views go)");
    SLSHADOW_THROW_IF(!out_dir.empty(), "--reconstruct-only: --out ", out_dir,
                      " would not be written; the merge is a second command");
    const Shard shard = ParseShard(shard_text, "--shard");
    const multiview::ReconstructShardSummary summary = multiview::ReconstructProjectShard(
        project, options, shard, [quiet](const std::string& name, size_t k, size_t n) {
          if (!quiet) std::printf("[%zu/%zu] %s\n", k + 1, n, name.c_str());
          std::fflush(stdout);
        });
    if (!quiet)
      std::printf("shard %d/%d: %s-> %s\n", shard.index, shard.count, summary.Brief().c_str(),
                  reconstructions.c_str());
    return 0;
  }
  SLSHADOW_THROW_IF(out_dir.empty(),
                    "--out: required (the model folder), unless --reconstruct-only");
  SLSHADOW_THROW_IF(shard_text != "0/1", "--shard ", shard_text,
                    ": only with --reconstruct-only (the merge reads every view)");
  options.mesh = !no_mesh;
  options.registration.turntable_model = !six_dof;
  std::optional<TriangleMesh> cad;
  if (!cad_path.empty()) {
    const std::filesystem::path p(cad_path);
    const std::string ext = p.extension().string();
    cad = (ext == ".yaml" || ext == ".yml" || ext == ".json") ? multiview::PartSurface(LoadScene(p))
                                                              : ReadMesh(p);
    SLSHADOW_THROW_IF(cad->empty(), cad_path, ": --cad: the CAD model has no triangles");
  }
  const multiview::ProjectMergeResult result =
      multiview::MergeProject(project, cad ? &*cad : nullptr, options);
  multiview::WriteModel(result, cad ? &*cad : nullptr, out_dir, overwrite, !no_html);
  if (!quiet) std::printf("%s-> %s\n", result.Summary().c_str(), out_dir.c_str());
  return 0;
}

}  // namespace slshadow::app
