// Ctrl-C as a stop request for a capture. While a StopOnInterrupt lives, SIGINT does not end the
// process: it raises flag(), which a capture polls through SequencerOptions::stop and answers by
// ending between frames with its staging folder resumable (CaptureSummary::interrupted). The
// destructor restores the handler that was in place (the command line's InstallInterruptCleanup,
// core/file_util.h). One per process at a time: the flag is process-wide, as a signal is.
#pragma once

#include <atomic>

namespace slshadow::capture {

class StopOnInterrupt {
 public:
  StopOnInterrupt();  // lowers the flag, then installs the handler
  ~StopOnInterrupt();
  StopOnInterrupt(const StopOnInterrupt&) = delete;
  StopOnInterrupt& operator=(const StopOnInterrupt&) = delete;

  // Raised by SIGINT; pass it as SequencerOptions::stop.
  const std::atomic<bool>* flag() const;

 private:
  void (*previous_)(int) = nullptr;
};

}  // namespace slshadow::capture
