// `slshadow calibrate turntable`: the turntable axis from a board on the table seen at several
// commanded angles (calib/turntable.h), written into the rig file's `turntable:`. Registered on
// `slshadow calibrate`'s parser by apps/cmd_calibrate.cc; kept in its own file.
#pragma once

#include <string>
#include <vector>

namespace CLI {
class App;
}  // namespace CLI

namespace slshadow::app {

struct CalibrateTurntableCommand {
  CLI::App* command = nullptr;  // the subcommand, after Register
  std::string rig;
  std::string target;
  std::vector<std::string> images;
  std::vector<double> angles_deg;
  std::string out;
  std::string loss = "none";
  double loss_scale_px = 1.0;
  double max_rms_px = 1.0;

  // Adds the `turntable` subcommand and its options to `calibrate`.
  void Register(CLI::App* calibrate);
  // Runs it (after parsing): reads the rig, the target and the images, calibrates, prints the
  // axis with its 1-sigma and the per-view residuals, writes --out atomically. Returns 0; throws
  // slshadow::Error on bad input.
  int Run() const;
};

}  // namespace slshadow::app
