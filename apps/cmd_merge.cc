// slshadow merge PROJECT --out MODEL [--cad MESH|SCENE]
#include <CLI/CLI.hpp>
#include <cstdio>

#include "apps/commands.h"
#include "core/error.h"
#include "core/mesh.h"
#include "sim/scene.h"
#include "workflows/multiview/project_merge.h"
#include "workflows/multiview/turntable_scene.h"

namespace slshadow::app {

int RunMerge(int argc, char** argv) {
  CLI::App app{
      "Merge a multi-view project (slshadow simulate --views, slshadow scan --views; "
      "docs/formats.md\n"
      "\"Multi-view project\") into one model in the part frame (the rig frame at table angle 0):\n"
      "  1. every complete view is reconstructed like any scan, one view's images in memory at a "
      "time;\n"
      "  2. each view's pose from the rig's turntable axis and its commanded table angle "
      "(hand-placed\n"
      "     views from their part_from_rig_guess); views missing or without a pose are left out, "
      "named;\n"
      "  3. the merged cloud (scalars view, quality);\n"
      "  4. with --cad: the signed C2M of the merged cloud and of each view to the CAD model, the\n"
      "     deviation painted on the CAD mesh (cad_deviation.ply, per vertex: MeshLab, "
      "CloudCompare),\n"
      "     coverage of the reachable CAD surface (the face on the table excluded) and the area no "
      "view\n"
      "     covered by reason (occluded, grazing, outside the field, not reconstructed).\n"
      "Output MODEL (written atomically): report.json, summary.txt, merged.ply, and with --cad\n"
      "cad_deviation.ply and cad_coverage.ply (surface samples coloured by reason). Example:\n"
      "  slshadow simulate --rig config/demo/turntable_rig.yaml --scene "
      "config/demo/turntable_scene.yaml \\\n"
      "      --patterns config/demo/patterns.yaml --views config/demo/views_12.yaml --out project\n"
      "  slshadow merge project --out model --cad config/demo/turntable_scene.yaml",
      argv[0]};
  std::string project, out_dir, cad_path, mode = "stereo";
  bool overwrite = false, quiet = false;
  multiview::ProjectMergeOptions options;
  app.add_option("PROJECT", project, "multi-view project folder (project.json, views/<name>/)")
      ->required();
  app.add_option("--out", out_dir, "output model folder (must not exist unless --overwrite)")
      ->required();
  app.add_option("--cad", cad_path,
                 "the part's CAD model in the part frame: a mesh (.stl/.ply/.obj), or a scene "
                 "(.yaml/.json) whose meshes are the part at table angle 0");
  app.add_option("--mode", mode, "reconstruction: stereo (both cameras) | projector (first camera)")
      ->capture_default_str()
      ->check(CLI::IsMember({"stereo", "projector"}));
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
         "table views: drop points less than this above the table plane (negative: keep all)")
      ->capture_default_str();
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
