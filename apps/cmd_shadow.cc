// slshadow shadow REAL --part PART --out DIR [...] (REAL: an ImageSet or a multi-view project)
#include <CLI/CLI.hpp>
#include <cstdio>

#include "apps/commands.h"
#include "core/error.h"
#include "core/rig.h"
#include "workflows/multiview/project_shadow.h"
#include "workflows/twin/twin.h"

namespace slshadow::app {

int RunShadowCommand(int argc, char** argv) {
  CLI::App app{
      "The digital shadow of a real scan: reconstruct it, place the part in the rig, fit the "
      "twin's\n"
      "physics from the real images (a layer only when the images need it), re-scan the twin\n"
      "virtually with the same rig, patterns and exposure, compare images and clouds, and name "
      "what\n"
      "the differences point to (calibration, projector response, defocus, multipath, a wrong "
      "frame,\n"
      "or the part itself), or say the scan is consistent with the model.\n\n"
      "PART is a mesh (.stl/.ply/.obj, mm, albedo 0.8) or a scene file (.yaml) whose objects are "
      "the\n"
      "part in its own frame (e.g. a plane with a printed checkerboard). Writes DIR/report.json\n"
      "(docs/formats.md \"Shadow report\"), DIR/summary.txt, DIR/maps/*.png, DIR/clouds/*.ply.\n\n"
      "REAL may also be a multi-view turntable project (slshadow scan): every view against its\n"
      "twin at the pose the turntable gives it (--pose is then the part at table angle 0), the\n"
      "diagnosis across views (the turntable axis off, the angle scale off, the part slipped\n"
      "between two views), and the merged real scan against the merged twin on the CAD surface;\n"
      "DIR/views/<name>/ holds each view's report (docs/formats.md \"Multi-view shadow report\").\n"
      "Give the part with what turns with it (e.g. a scene with the part and the table disc).",
      argv[0]};
  std::string image_set, part_path, out_dir, rig_path;
  std::vector<double> pose;
  bool fixed_pose = false, no_fit = false, overwrite = false, no_clouds = false;
  twin::ShadowOptions options;
  app.add_option("REAL", image_set,
                 "the real scan (ImageSet folder) or a multi-view project (folder with "
                 "project.json)")
      ->required()
      ->check(CLI::ExistingDirectory);
  app.add_option("--part", part_path, "the part: mesh (.stl/.ply/.obj) or scene (.yaml)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--out", out_dir, "report folder")->required();
  app.add_option("--rig", rig_path,
                 "rig file to use instead of the ImageSet's own (e.g. a later calibration)")
      ->check(CLI::ExistingFile);
  app.add_option("--pose", pose,
                 "rig_from_part as rx ry rz (Rodrigues, rad) tx ty tz (mm): ICP starts here")
      ->expected(6);
  app.add_flag("--fixed-pose", fixed_pose,
               "use --pose as it is (no ICP), e.g. a plane whose in-plane pose ICP cannot see");
  app.add_option("--min-fitness", options.min_fitness,
                 "credible pose: share of the cloud within 1 mm of the part")
      ->capture_default_str();
  app.add_option("--max-rmse-mm", options.max_rmse_mm, "credible pose: RMS of those distances, mm")
      ->capture_default_str();
  app.add_option("--shadow-threshold", options.decode.shadow_threshold,
                 "decoding: minimum white - black, 8-bit levels")
      ->capture_default_str();
  app.add_option("--contrast-threshold", options.decode.contrast_threshold,
                 "decoding: minimum bit contrast, 8-bit levels")
      ->capture_default_str();
  app.add_option(
         "--calibration-field-px", options.diagnose.calibration_field_px,
         "diagnosis: a smooth projector-coordinate field above this RMS is a calibration error")
      ->capture_default_str();
  app.add_flag("--no-physics-fit", no_fit, "keep the part file's radiometry; fit no layer");
  app.add_flag("--no-clouds", no_clouds, "do not write the clouds");
  app.add_flag("--overwrite", overwrite, "replace an existing report folder");
  bool no_html = false;
  AddHtmlOptions(&app, &no_html, &options.html);
  AddStrictOptions(&app, &options.strict);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  if (!pose.empty())
    options.rig_from_part = Rigid3d(QuaternionFromRotationVector({pose[0], pose[1], pose[2]}),
                                    {pose[3], pose[4], pose[5]});
  SLSHADOW_THROW_IF(fixed_pose && pose.empty(), "--fixed-pose: needs --pose");
  options.refine_pose = !fixed_pose;
  options.fit_physics = !no_fit;
  options.overwrite = overwrite;
  options.write_clouds = !no_clouds;
  options.write_html = !no_html;
  std::optional<Rig> rig;
  if (!rig_path.empty()) rig = LoadRig(rig_path);
  if (std::filesystem::exists(std::filesystem::path(image_set) / "project.json")) {
    const twin::ShadowPart part = multiview::LoadTurntablePart(part_path);
    SLSHADOW_THROW_IF(fixed_pose, "--fixed-pose: a multi-view project refines every view's pose");
    multiview::ProjectShadowOptions project_options;
    project_options.rig_from_part0 = options.rig_from_part;
    project_options.view = options;
    project_options.on_view = [](const std::string& name, size_t i, size_t n) {
      std::fprintf(stderr, "view %zu/%zu: %s\n", i + 1, n, name.c_str());
    };
    const multiview::ProjectShadowResult result = multiview::RunProjectShadow(
        image_set, part, project_options, out_dir, rig ? &*rig : nullptr);
    std::printf("%sreport: %s\n", result.Summary().c_str(), out_dir.c_str());
    return 0;
  }
  const twin::ShadowPart part = twin::LoadShadowPart(part_path);
  const twin::ShadowResult result =
      twin::RunShadow(image_set, part, options, out_dir, rig ? &*rig : nullptr);
  std::printf("%sreport: %s%s\n", result.Summary().c_str(), out_dir.c_str(),
              no_html ? "" : " (open report.html in a browser)");
  return 0;
}

}  // namespace slshadow::app
