#include "apps/cmd_calibrate_turntable.h"

#include <CLI/CLI.hpp>

#include <algorithm>
#include <cstdio>
#include <filesystem>

#include "calib/turntable.h"
#include "core/error.h"
#include "core/rig.h"

namespace slshadow::app {

void CalibrateTurntableCommand::Register(CLI::App* calibrate) {
  command = calibrate->add_subcommand(
      "turntable",
      "the turntable's axis (direction, point, angle scale, with 1-sigma) from a board on the "
      "table seen at 3+ commanded angles by the cameras of a calibrated rig");
  command->add_option("--rig", rig, "calibrated rig file (intrinsics and poses held fixed)")
      ->required();
  command
      ->add_option("--target", target,
                   "target YAML of the board standing on the table (docs/formats.md, "
                   "\"Calibration target YAML\")")
      ->required();
  command
      ->add_option("--images", images,
                   "one folder per table angle, holding one image per camera named after it "
                   "(left.png, right.png; any image extension); a camera may be missing or not "
                   "see the board, but some camera must see it in every folder")
      ->required();
  command
      ->add_option("--angles", angles_deg,
                   "commanded table angles in degrees, one per --images folder in the same "
                   "order, comma-separated (e.g. -40,-30,0,30,40); default: each folder's name "
                   "(030, -15.5, 30deg)")
      ->delimiter(',');
  command
      ->add_option("--out", out,
                   "rig file to write: the input rig with `turntable:` filled (may be --rig)")
      ->required();
  command->add_option("--loss", loss, "robust loss on point residuals: none, huber or cauchy")
      ->capture_default_str();
  command
      ->add_option("--loss-scale-px", loss_scale_px,
                   "residual (px) where the robust loss starts to bend")
      ->capture_default_str();
  command
      ->add_option("--max-rms-px", max_rms_px,
                   "warn when the fit's RMS exceeds this (the board moved on the table, a wrong "
                   "angle or a stale rig)")
      ->capture_default_str();
}

int CalibrateTurntableCommand::Run() const {
  namespace fs = std::filesystem;
  Rig rig_in = LoadRig(rig);
  const TargetSpec spec = LoadTargetSpec(target);
  std::vector<fs::path> folders(images.begin(), images.end());
  std::vector<double> angles = angles_deg;
  if (angles.empty()) {
    for (const auto& f : folders) angles.push_back(CommandedAngleFromFolderName(f));
  }
  SLSHADOW_THROW_IF(angles.size() != folders.size(), "--angles: ", angles.size(), " angle(s) for ",
                    folders.size(), " --images folder(s)");
  TurntableOptions options;
  options.loss = LossTypeFromString(loss);
  options.loss_scale_px = loss_scale_px;
  options.Check();
  std::vector<ImageCheck> checks;
  const TurntableInput input = TurntableInputFromFolders(rig_in, spec, folders, angles, &checks);
  for (const auto& c : checks) {
    if (!c.found) std::printf("note: %s: no board (%s)\n", c.label.c_str(), c.reason.c_str());
  }
  const TurntableResult result = CalibrateTurntable(input, options);
  std::printf("%s", result.FullReport().c_str());
  if (!result.converged)
    std::printf("warning: the solver did not converge (%s)\n", result.termination.c_str());
  if (result.rms_px > max_rms_px) {
    std::printf(
        "warning: RMS %.4f px is above %.4g px: did the board move on the table, is an angle "
        "wrong, or does the rig no longer fit the cameras?\n",
        result.rms_px, max_rms_px);
  }
  const TurntableAxis& a = result.axis;
  std::printf(
      "axis (rig frame, 1-sigma):\n"
      "  direction   %.6f %.6f %.6f  +- %.5f deg\n"
      "  point       %.4f %.4f %.4f mm  +- %.5f mm (perpendicular to the axis)\n"
      "  angle scale %.7f  +- %.2g (true degrees per commanded degree)\n"
      "  offset      0 deg (by definition: angles count from the table at commanded 0)\n",
      a.direction_in_rig.x(), a.direction_in_rig.y(), a.direction_in_rig.z(), a.sigma_direction_deg,
      a.point_in_rig_mm.x(), a.point_in_rig_mm.y(), a.point_in_rig_mm.z(), a.sigma_point_mm,
      a.angle_scale, a.sigma_angle_scale);
  rig_in.turntable = a;
  SaveRig(rig_in, out);
  std::printf("wrote %s\n", out.c_str());
  return 0;
}

}  // namespace slshadow::app
