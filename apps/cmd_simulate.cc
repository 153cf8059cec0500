// slshadow simulate --rig RIG --scene SCENE --patterns SPEC --out DIR
#include <CLI/CLI.hpp>
#include <cstdio>

#include "apps/commands.h"
#include "core/error.h"
#include "core/rig.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "sim/scene.h"
#include "sim/simulate.h"
#include "workflows/multiview/virtual_project.h"
#include "workflows/pipeline/scan_pipeline.h"

namespace slshadow::app {

int RunSimulate(int argc, char** argv) {
  CLI::App app{
      "Virtual scan: ray-cast the rig over a scene and write the ImageSet a real capture would "
      "write\n"
      "(docs/formats.md: \"Scene YAML\", \"Simulator ground truth\").\n\n"
      "Every camera of RIG sees every projector image of SPEC projected onto SCENE: one geometry "
      "pass\n"
      "per camera (Embree: hit point, normal, projector coordinate through the projector's "
      "distortion,\n"
      "shadow ray), then per image DN = exposure * full_scale * (ambient * albedo + albedo * cos_p "
      "*\n"
      "(d_ref / d_p)^2 * I) and the scene's optional layers (supersampling, defocus, gamma, "
      "vignetting,\n"
      "ambient, EMVA 1288 noise, fill factor; all off unless the scene enables them).\n\n"
      "Output DIR (written atomically): manifest.json with source \"virtual\" and the scan's "
      "provenance (scene,\n"
      "simulator options: docs/formats.md \"Scan provenance\") in `extra.provenance`,\n"
      "<camera>/NNNN.<png|pgm|tiff> images, and ground_truth/<camera>/ with depth, 3D points (rig "
      "frame,\n"
      "mm), normals, true projector coordinates, shadow/visibility masks, object ids and the "
      "visible\n"
      "surface as surface.ply. Units: mm, px. Example:\n"
      "  slshadow simulate --rig config/demo/rig.yaml --scene config/demo/scene.yaml \\\n"
      "      --patterns config/patterns/graycode_phase.yaml --out scan_virtual --encoding pgm\n\n"
      "With --views VIEWS.yaml (docs/formats.md \"Views YAML\"), a multi-view scan: the scene "
      "turned "
      "about the\nrig's turntable axis to each view's table angle (hand-placed views: placed at "
      "their part_from_rig_guess)\nand scanned into a project folder OUT (docs/formats.md "
      "\"Multi-view project\"): OUT/project.json and one\nImageSet per view in OUT/views/<name>/ "
      "(no ground truth). --resume renders only the views missing.",
      argv[0]};
  std::string rig_path, scene_path, patterns_path, out_dir, encoding = "png";
  bool overwrite = false, no_ground_truth = false, quiet = false;
  app.add_option("--rig", rig_path,
                 "rig file (.yaml/.json, docs/formats.md \"Rig YAML\"); needs a projector")
      ->required();
  app.add_option("--scene", scene_path, "scene file (.yaml/.json, docs/formats.md \"Scene YAML\")")
      ->required();
  app.add_option("--patterns", patterns_path,
                 "pattern spec (.yaml/.json, docs/formats.md \"Pattern spec\"), e.g. "
                 "config/patterns/graycode_phase.yaml; "
                 "its projector size must match the rig's projector")
      ->required();
  app.add_option("--out", out_dir, "output ImageSet folder (must not exist unless --overwrite)")
      ->required();
  app.add_option("--encoding", encoding,
                 "image encoding: png (portable, ~10-25 ms per 1920x1200 image), pgm (raw, fastest "
                 "lossless) or tiff")
      ->capture_default_str()
      ->check(CLI::IsMember({"png", "pgm", "tiff"}));
  app.add_flag("--overwrite", overwrite, "replace an existing output folder");
  app.add_flag("--no-ground-truth", no_ground_truth,
               "skip ground_truth/ (images and manifest only; the ground-truth maps are then not "
               "computed either, "
               "about a quarter less ray-casting time)");
  app.add_flag("--quiet", quiet, "do not print the timing summary");
  std::string views_path;
  bool resume = false;
  app.add_option(
      "--views", views_path,
      "views file (docs/formats.md \"Views YAML\"): write a multi-view project at --out");
  app.add_flag("--resume", resume,
               "with --views: continue the project at --out (missing views only)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  const Rig rig = LoadRig(rig_path);
  const Scene scene = LoadScene(scene_path);
  const PatternSpec spec = LoadPatternSpec(patterns_path);
  if (!views_path.empty()) {
    SLSHADOW_THROW_IF(overwrite,
                      "--overwrite: not with --views (use --resume to continue a project)");
    multiview::VirtualProjectOptions project_options;
    project_options.encoding = ImageEncodingFromString(encoding);
    project_options.resume = resume;
    project_options.rig_what = rig_path;
    project_options.spec_what = patterns_path;
    if (!quiet) {
      project_options.on_view = [](const std::string& name, size_t, bool rendered) {
        std::printf("view %s: %s\n", name.c_str(), rendered ? "rendered" : "kept (complete)");
        std::fflush(stdout);
      };
    }
    const multiview::VirtualProjectSummary summary = multiview::SimulateProject(
        scene, rig, spec, multiview::LoadViews(views_path), out_dir, project_options);
    if (!quiet)
      std::printf("simulate --views: %s -> %s\n%s\n", scene_path.c_str(), out_dir.c_str(),
                  summary.BriefReport().c_str());
    return 0;
  }
  SLSHADOW_THROW_IF(resume, "--resume: only with --views");
  SimulateOptions options;
  options.writer.encoding = ImageEncodingFromString(encoding);
  options.writer.overwrite = overwrite;
  options.write_ground_truth = !no_ground_truth;
  const SimulateSummary summary =
      pipeline::SimulateFromSpec(scene, rig, spec, patterns_path, rig_path, out_dir, options);
  if (!quiet)
    std::printf("simulate: %s -> %s\n%s\n", scene_path.c_str(), out_dir.c_str(),
                summary.BriefReport().c_str());
  return 0;
}

}  // namespace slshadow::app
