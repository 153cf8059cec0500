#include "apps/cmd_calibrate_turntable.h"

#include <CLI/CLI.hpp>

#include <cstdio>

#include "workflows/pipeline/calibrate.h"

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
  pipeline::CalibrateTurntableRequest request;
  request.rig = rig;
  request.target = target;
  request.out = out;
  request.folders.assign(images.begin(), images.end());
  request.commanded_deg = angles_deg;
  request.options.loss = LossTypeFromString(loss);
  request.options.loss_scale_px = loss_scale_px;
  request.max_rms_px = max_rms_px;
  pipeline::CalibrateTurntableAndWrite(request, [](const std::string& text) {
    std::fputs(text.c_str(), stdout);
    std::fflush(stdout);
  });
  return 0;
}

}  // namespace slshadow::app
