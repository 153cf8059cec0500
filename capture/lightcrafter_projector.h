// The LightCrafter 4500 as the sequencer's projector in video mode: the DLPC350 is switched to
// video mode over USB (sequence stopped, mode read back, firmware version kept for Info), and
// the patterns are shown on its HDMI input by another projector (a window on that output), to
// which Load / Show / ShowBlack / latency are delegated. Pattern-sequence mode (the device's own
// timing and TRIG_OUT driving the cameras) is programmed through dlpc350::Client::Program; the
// sequencer side of it (grab-only, frames matched by count) is not built yet.
#pragma once

#include <memory>

#include "capture/devices.h"
#include "capture/lightcrafter_protocol.h"
#include "capture/projector.h"

namespace slshadow::capture {

class LightCrafterProjector : public Projector {
 public:
  // Takes the USB link and the HDMI output; throws slshadow::Error naming the device when it does
  // not take video mode.
  LightCrafterProjector(std::unique_ptr<dlpc350::Transport> transport, std::unique_ptr<Projector> hdmi_output);

  ProjectorInfo Info() const override;
  void Load(const std::vector<cv::Mat>& images) override { output_->Load(images); }
  std::chrono::steady_clock::time_point Show(int index) override { return output_->Show(index); }
  std::chrono::steady_clock::time_point ShowBlack() override { return output_->ShowBlack(); }
  std::chrono::microseconds Latency() const override { return output_->Latency(); }
  void SetLatency(std::chrono::microseconds latency) override { output_->SetLatency(latency); }
  int size() const override { return output_->size(); }

  dlpc350::Client& client() { return client_; }
  const dlpc350::FirmwareVersion& firmware() const { return firmware_; }

 private:
  std::unique_ptr<dlpc350::Transport> transport_;
  std::unique_ptr<Projector> output_;
  dlpc350::Client client_;
  dlpc350::FirmwareVersion firmware_;
};

// devices.yaml `backend: lightcrafter`: the only LightCrafter on USB, in video mode, its HDMI
// output a window on `display` (as for `backend: window`). Errors are prefixed with the entry.
std::unique_ptr<Projector> OpenLightCrafterProjector(const ProjectorEntry& entry,
                                                     std::unique_ptr<Projector> hdmi_output);

}  // namespace slshadow::capture
