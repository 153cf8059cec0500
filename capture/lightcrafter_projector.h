// The LightCrafter 4500 as the sequencer's projector in video mode: the DLPC350 is switched to
// video mode over USB (sequence stopped, mode read back, firmware version kept for Info), and
// the patterns are shown on its HDMI input by another projector (a window on that output), to
// which Load / Show / ShowBlack / latency are delegated.
//
// The LightCrafter 4500 in pattern-sequence mode is a SequenceProjector
// (capture/sequence_projector.h): the DLPC350 runs the pattern LUT on its own clock and TRIG_OUT1
// pulses the cameras' trigger lines once per pattern; capture/pattern_sequence_capture.h grabs and
// matches the frames. The images come from the device's flash, which must hold the pattern sequence
// packed as dlpc350::SequenceFor lays it out: pattern i in flash image i / (24 / bit depth),
// bit-plane group i % (24 / bit depth) (TI's LightCrafter 4500 GUI builds a flash image from the
// images `slshadow patterns generate SPEC --out DIR` writes). slshadow cannot read the flash back:
// the capture's Gray-pair checks catch a flash that holds other patterns.
#pragma once

#include <memory>

#include "capture/devices.h"
#include "capture/lightcrafter_protocol.h"
#include "capture/projector.h"
#include "capture/sequence_projector.h"

namespace slshadow::capture {

class LightCrafterProjector : public Projector {
 public:
  // Takes the USB link and the HDMI output; throws slshadow::Error naming the device when it does
  // not take video mode.
  LightCrafterProjector(std::unique_ptr<dlpc350::Transport> transport,
                        std::unique_ptr<Projector> hdmi_output);

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

struct LightCrafterSequenceOptions {
  uint32_t frame_period_us = 16667;  // one pattern (and one trigger pulse) every this many us
  uint32_t exposure_us = 0;          // LED on time per pattern; 0: the whole frame period
  int bit_depth = 0;           // 1..8; 0: 1 when every image is binary (only 0 and 255), else 8
  dlpc350::TrigOut trig_out1;  // the camera trigger: polarity and edge delays
  void Check(
      const std::string& where) const;  // throws slshadow::Error naming `where` and the field
};

class LightCrafterSequenceProjector : public SequenceProjector {
 public:
  // Takes the USB link; reads the firmware version and stops any running sequence. Throws
  // slshadow::Error naming the device.
  LightCrafterSequenceProjector(std::unique_ptr<dlpc350::Transport> transport,
                                LightCrafterSequenceOptions options);

  ProjectorInfo Info() const override;
  // Stop, TRIG_OUT1, then dlpc350::Client::Program of SequenceFor(images, bit depth, internal
  // trigger, exposure, period) without repeat; throws listing the validation errors.
  void Load(const std::vector<cv::Mat>& images) override;
  std::chrono::system_clock::time_point Start() override;
  void Stop() override;
  std::chrono::microseconds FramePeriod() const override {
    return std::chrono::microseconds(options_.frame_period_us);
  }
  // Reads the display mode back: throws when the device is gone or left pattern-sequence mode.
  void CheckAlive() override;

  dlpc350::Client& client() { return client_; }
  const dlpc350::Validation& validation() const { return validation_; }  // of the last Load
  int bit_depth() const { return bit_depth_; }                           // of the last Load

 private:
  std::unique_ptr<dlpc350::Transport> transport_;
  LightCrafterSequenceOptions options_;
  dlpc350::Client client_;
  dlpc350::FirmwareVersion firmware_;
  dlpc350::Validation validation_;
  int width_ = 912, height_ = 1140;  // the DMD; the images' size after Load
  int bit_depth_ = 0;
};

// devices.yaml `backend: lightcrafter`: the only LightCrafter on USB, in video mode, its HDMI
// output a window on `display` (as for `backend: window`). Errors are prefixed with the entry.
std::unique_ptr<Projector> OpenLightCrafterProjector(const ProjectorEntry& entry,
                                                     std::unique_ptr<Projector> hdmi_output);
// devices.yaml `backend: lightcrafter` with `mode: pattern-sequence`: the LightCrafter at `usb`
// (BUS:ADDRESS; empty: the only one) with the entry's period, exposure and bit depth.
std::unique_ptr<SequenceProjector> OpenLightCrafterSequenceProjector(const ProjectorEntry& entry);

}  // namespace slshadow::capture
