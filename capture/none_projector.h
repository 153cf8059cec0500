// NoneProjector: no projector at all, for cameras-only stills (calibration boards under room
// light) and for replaying a recorded capture. Show() returns at once. The sequencer cannot check
// frames against patterns nobody shows (Info().width == 0): it refuses to run validated unless
// every camera replays a recording (whose frames hold the sequence and are checked as live ones).
#pragma once

#include "capture/projector.h"

namespace slshadow::capture {

class NoneProjector : public Projector {
 public:
  explicit NoneProjector(std::chrono::microseconds latency = std::chrono::microseconds(0))
      : latency_(latency) {}
  ProjectorInfo Info() const override { return {"none", "", 0, 0, 0}; }
  void Load(const std::vector<cv::Mat>& images) override {
    size_ = static_cast<int>(images.size());
  }
  std::chrono::steady_clock::time_point Show(int index) override;
  std::chrono::steady_clock::time_point ShowBlack() override {
    return std::chrono::steady_clock::now();
  }
  std::chrono::microseconds Latency() const override { return latency_; }
  void SetLatency(std::chrono::microseconds latency) override { latency_ = latency; }
  int size() const override { return size_; }

 private:
  std::chrono::microseconds latency_;
  int size_ = 0;
};

}  // namespace slshadow::capture
