// slshadow compare CLOUD REFERENCE --out DIR [...]
#include <CLI/CLI.hpp>
#include <cstdio>

#include "apps/commands.h"
#include "compare/report.h"
#include "core/point_cloud.h"
#include "core/rig.h"
#include "report/html_report.h"

namespace slshadow::app {

int RunCompare(int argc, char** argv) {
  CLI::App app{
      "Compare a point cloud against a reference and write a report folder.\n\n"
      "CLOUD is a .ply point cloud (mm). REFERENCE is a mesh (.stl, .obj, or .ply with faces) or "
      "a\n"
      "point cloud (.ply without faces). With a mesh, each point's deviation is its signed "
      "distance\n"
      "to the nearest triangle (+ outside, C2M); with a cloud, its distance to the nearest "
      "reference\n"
      "point (C2C, CloudCompare's definition, optionally with a local plane or quadric model).\n"
      "Statistics (mean, std, RMS, median, p95, max of |deviation|; inliers / outliers at the\n"
      "threshold; coverage = share of the reference surface reached by inlier points) go to\n"
      "DIR/report.json (docs/formats.md \"Comparison report\"), DIR/summary.txt, "
      "DIR/histogram.png,\n"
      "DIR/deviation_map.png and DIR/compared.ply (registered cloud with a 'deviation' scalar "
      "field\n"
      "and colours; opens in CloudCompare), and DIR/report.html: all of it in one self-contained "
      "page\n"
      "(3D view of the deviations, tables, charts; opens from the file, no network). The folder "
      "is\n"
      "replaced atomically when complete.",
      argv[0]};
  std::string cloud_path, reference_path, out_dir, method = "none", local_model = "none", view_rig,
                                                   view_camera;
  compare::CompareOptions options;
  compare::ReportOptions report;
  size_t mesh_samples = 200000;
  bool no_overwrite = false;
  app.add_option("CLOUD", cloud_path, "compared point cloud (.ply, mm)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("REFERENCE", reference_path, "reference mesh (.stl/.obj/.ply) or cloud (.ply)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--out", out_dir, "report folder (created or replaced)")->required();
  app.add_option("--register", method,
                 "none: the clouds share a frame; icp: point-to-plane ICP from the identity; "
                 "global+icp: FPFH + RANSAC coarse alignment, then ICP")
      ->check(CLI::IsMember({"none", "icp", "global+icp"}))
      ->capture_default_str();
  app.add_option("--threshold-mm", options.threshold_mm, "inlier threshold on |deviation|, mm")
      ->capture_default_str();
  app.add_option("--color-range-mm", options.color_range_mm,
                 "colour range of the deviation map, histogram and PLY colours, +-mm (0: the 99th "
                 "percentile of |deviation|)")
      ->capture_default_str();
  app.add_option(
         "--local-model", local_model,
         "C2C only: none, or a least-squares plane / quadric fitted on the nearest reference "
         "point's neighbours; the distance is min(nearest, model) as in CloudCompare")
      ->check(CLI::IsMember({"none", "plane", "quadric"}))
      ->capture_default_str();
  app.add_option("--local-model-neighbors", options.c2c.local_model_neighbors,
                 "neighbours for the local model (0: 6 for a plane, 12 for a quadric)")
      ->capture_default_str();
  app.add_option("--max-distance-mm", options.c2c.max_distance_mm,
                 "C2C only: points farther than this get this distance (0: unlimited)")
      ->capture_default_str();
  app.add_option("--coverage-radius-mm", options.coverage_radius_mm,
                 "a reference sample is covered when an inlier lies this close "
                 "(0: max(threshold, 3 x median point spacing))")
      ->capture_default_str();
  app.add_option("--mesh-samples", mesh_samples,
                 "area-uniform samples of a mesh reference (coverage, registration)")
      ->capture_default_str();
  app.add_flag("--m3c2", options.m3c2,
               "also compute M3C2 distances along normals with LoD95 (scalar fields)");
  app.add_option("--m3c2-radius-mm", options.m3c2_options.projection_radius_mm,
                 "M3C2 cylinder radius, mm")
      ->capture_default_str();
  app.add_option("--m3c2-depth-mm", options.m3c2_options.max_depth_mm,
                 "M3C2 cylinder half-length, mm")
      ->capture_default_str();
  app.add_option("--registration-error-mm", options.m3c2_options.registration_error_mm,
                 "registration error added inside M3C2's LoD95, mm")
      ->capture_default_str();
  app.add_option(
      "--view-rig", view_rig,
      "render the deviation map from a camera of this rig (rig frame = the cloud's frame); "
      "default: a view fitted to the cloud");
  app.add_option("--view-camera", view_camera,
                 "camera name in --view-rig (default: the first camera)");
  std::string artefacts;
  app.add_option(
         "--artefacts", artefacts,
         "artefact file (YAML, docs/formats.md \"Artefact file\"): also report the VDI/VDE 2634-2 "
         "figures PF, PS, SD, F of its spheres, ball bars and flats")
      ->check(CLI::ExistingFile);
  app.add_flag("--no-overwrite", no_overwrite,
               "fail instead of replacing an existing report folder");
  bool no_html = false;
  ::slshadow::report::HtmlOptions html;
  app.add_flag("--no-html", no_html,
               "do not write report.html (the self-contained page of the result; slshadow report "
               "DIR writes it later)");
  app.add_option("--html-max-points", html.max_points,
                 "points drawn in report.html's 3D view (a fixed-seed uniform sample; the figures "
                 "use every point)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  options.registration.method = compare::RegistrationMethodFromString(method);
  options.c2c.local_model = compare::LocalModelFromString(local_model);
  report.overwrite = !no_overwrite;
  if (!no_html) report.before_commit = ::slshadow::report::HtmlWriter(html);
  if (!view_rig.empty()) {
    const Rig rig = LoadRig(view_rig);
    const RigDevice& cam = view_camera.empty() ? rig.cameras.front() : rig.Camera(view_camera);
    report.view = compare::ViewCamera{cam.model, cam.cam_from_rig};
  }
  if (!artefacts.empty()) options.artefacts = compare::LoadArtefactSpec(artefacts);
  options.Check();
  const PointCloud cloud = ReadPly(cloud_path);
  const compare::Reference reference = compare::LoadReference(reference_path, mesh_samples);
  const compare::CompareResult result =
      compare::CompareAndReport(cloud, reference, options, out_dir, report, cloud_path);
  std::printf("%sreport: %s\n", result.Summary().c_str(), out_dir.c_str());
  return 0;
}

}  // namespace slshadow::app
