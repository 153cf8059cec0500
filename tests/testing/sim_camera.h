// The simulator behind the capture seams (capture/camera.h, capture/projector.h): a projector that
// only records what it shows, and cameras that render, with the simulator, the frame of the
// pattern shown at the moment they are triggered. A capture sequence run against them gives the
// images RenderScan gives (one geometry pass per camera when it is made, one pattern pass per
// frame: sim/renderer.h), so capture code is tested end to end without hardware and without
// mocking our own code.
//
//   auto shown = std::make_shared<ShownPattern>();
//   SimProjector projector(rig, shown);     projector.Load(GeneratePatterns(spec));
//   SimCamera left(scene, rig, "left", shown);
//   left.Configure(settings); left.Start();
//   projector.Show(i); left.Trigger(); capture::Frame f = left.Grab(timeout);  // pattern i
#pragma once

#include <chrono>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "capture/camera.h"
#include "capture/projector.h"
#include "core/rig.h"
#include "sim/renderer.h"
#include "sim/scene.h"

namespace slshadow::testing {

// What the projector currently shows: the loaded sequence and the index on the output (or
// black). Shared between a SimProjector and the SimCameras that look at its light. Thread-safe.
class ShownPattern {
 public:
  static constexpr int kBlack = -1;
  void Load(std::vector<cv::Mat> images);
  void Show(int index);  // an index of the loaded sequence, or kBlack
  // The index shown now and its image (a black image of the loaded size for kBlack; empty
  // before anything was loaded).
  int index() const;
  std::pair<int, cv::Mat> Current() const;
  int size() const;

 private:
  mutable std::mutex mutex_;
  std::vector<cv::Mat> images_;
  cv::Mat black_;
  int index_ = kBlack;
};

// A capture::Projector for the rig's projector that records the shown index in `shown`.
// Load checks each image (CV_8UC1, the projector's resolution) and throws slshadow::Error naming
// its index; Show throws on an index outside the loaded sequence. Latency is stored, not waited.
class SimProjector : public capture::Projector {
 public:
  SimProjector(const Rig& rig, std::shared_ptr<ShownPattern> shown);
  capture::ProjectorInfo Info() const override;
  void Load(const std::vector<cv::Mat>& images) override;
  std::chrono::steady_clock::time_point Show(int index) override;
  std::chrono::steady_clock::time_point ShowBlack() override;
  std::chrono::microseconds Latency() const override { return latency_; }
  void SetLatency(std::chrono::microseconds latency) override { latency_ = latency; }
  int size() const override { return shown_->size(); }

 private:
  int width_ = 0, height_ = 0;
  std::shared_ptr<ShownPattern> shown_;
  std::chrono::microseconds latency_{0};
};

// A capture::Camera that renders camera `camera` of `rig` viewing `scene` under the pattern
// `shown` shows when the frame is taken: in kSoftware mode at Trigger() (one frame per trigger,
// delivered by the next Grab), in kFreeRun mode at Grab(). The geometry pass runs once, in the
// constructor; a frame is one pattern pass (PatternRenderer::Render with the shown index, so the
// noise layer's seed is the one RenderScan uses; the black frame renders with index -1).
//
// Settings: pixel format Mono8 when the scene's adc_bits <= 8, else Mono12 or Mono16 (the image
// is 16-bit); full-sensor ROI only; no hardware trigger. exposure_us and gain_db scale the
// scene's exposure linearly (DN proportional to exposure time and to 10^(gain_db / 20)); unset,
// the scene's exposure_us and 0 dB. A refused setting throws slshadow::Error naming it.
// Grab: kAborted when not started, kTimeout when no frame is pending (nothing else will come).
class SimCamera : public capture::Camera {
 public:
  SimCamera(const Scene& scene, const Rig& rig, const std::string& camera,
            std::shared_ptr<const ShownPattern> shown);
  ~SimCamera() override;
  SimCamera(const SimCamera&) = delete;  // the renderer refers to the members
  SimCamera& operator=(const SimCamera&) = delete;
  capture::CameraInfo Info() const override;
  void Configure(const capture::CameraSettings& settings) override;
  capture::CameraSettings Settings() const override;
  void Start() override;
  void Stop() override;
  void Trigger() override;
  capture::Frame Grab(std::chrono::milliseconds timeout) override;
  void Flush() override;
  capture::StreamStatistics Statistics() const override;

 private:
  capture::Frame Render(int index, const cv::Mat& projector_image);

  Scene scene_;  // the scene as given; rendered_scene_ has the configured exposure
  Scene rendered_scene_;
  Rig rig_;
  int camera_index_ = 0;
  std::string camera_;
  std::shared_ptr<const ShownPattern> shown_;
  GeometryBuffer geometry_;
  std::unique_ptr<PatternRenderer> renderer_;
  capture::CameraSettings settings_;
  bool started_ = false;
  std::deque<capture::Frame> pending_;  // rendered at Trigger(), not yet grabbed
  uint64_t next_frame_id_ = 1;
  capture::StreamStatistics statistics_;
};

}  // namespace slshadow::testing
