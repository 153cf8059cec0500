// A turntable turned by hand: MoveTo prints the angle to set and waits until the operator presses
// Enter; Home() asks for the zero mark. The position is the last angle the operator confirmed
// (0 when opened). A line "q", "quit" or "abort" aborts (TurntableError kAborted), and so does the
// input closing before a confirmation. With auto_confirm (scripts, `--yes`) the prompt is printed
// and taken as done at once. A move to the angle the table is already at asks nothing.
#pragma once

#include <mutex>
#include <string>

#include "capture/turntable.h"

namespace slshadow::capture {

// Where the operator is talked to: file descriptors, stdin and stderr by default.
struct ManualTurntableIo {
  int in_fd = 0;
  int out_fd = 2;
};

class ManualTurntable : public Turntable {
 public:
  explicit ManualTurntable(const TurntableConfig& config, ManualTurntableIo io = {});
  void Home() override;
  void MoveTo(double angle_deg) override;
  // kMoving while a prompt waits for the operator, else kIdle; never kFault.
  TurntableStatus Status() override;
  std::string Describe() const override;

 private:
  // Prompts "turn the table to ..." and waits for the operator; `request` names it in errors.
  void Ask(const std::string& what, const std::string& request, double angle_deg);

  TurntableConfig config_;
  ManualTurntableIo io_;
  std::mutex mutex_;  // guards position_deg_ and waiting_ (Status() from another thread)
  double position_deg_ = 0;
  bool waiting_ = false;
};

}  // namespace slshadow::capture
