// Test doubles standing for hardware we do not have, built on the real X server:
//  - XScreenCamera: a "physical camera watching the screen": each frame is a read-back of a
//    region of the X screen (XScreenReader) at the moment of the trigger (software trigger) or at
//    the camera's own frame clock (free-run).
//  - DelayedProjector: a projector whose light comes `delay` after Show() returns (a display with
//    input lag): Show hands the image to a worker that shows it on the wrapped projector later.
#pragma once

#include <chrono>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <thread>

#include "capture/camera.h"
#include "capture/projector.h"
#include "capture/x11_screen.h"

namespace slshadow::testing {

using capture::Camera;
using capture::CameraInfo;
using capture::CameraSettings;
using capture::Frame;
using capture::FrameStatus;
using capture::PixelFormat;
using capture::Projector;
using capture::ProjectorInfo;
using capture::TriggerMode;
using capture::XScreenReader;

class XScreenCamera : public Camera {
 public:
  XScreenCamera(const std::string& display, const cv::Rect& region,
                std::chrono::microseconds frame_period = std::chrono::milliseconds(10))
      : screen_(display), region_(region), period_(frame_period) {}
  CameraInfo Info() const override {
    CameraInfo info;
    info.backend = "x-screen";
    info.id = screen_.display_name();
    info.sensor_width = region_.width;
    info.sensor_height = region_.height;
    info.pixel_formats = {PixelFormat::kMono8};
    return info;
  }
  void Configure(const CameraSettings& settings) override { settings_ = settings; }
  CameraSettings Settings() const override { return settings_; }
  void Start() override { next_tick_ = std::chrono::steady_clock::now(); }
  void Stop() override { pending_.clear(); }
  void Trigger() override {
    if (settings_.trigger != TriggerMode::kSoftware) return;
    std::lock_guard<std::mutex> lock(mutex_);
    pending_.push_back(Take());
  }
  Frame Grab(std::chrono::milliseconds) override {
    std::lock_guard<std::mutex> lock(mutex_);
    if (settings_.trigger == TriggerMode::kSoftware) {
      if (pending_.empty()) return Frame{FrameStatus::kTimeout, "no trigger", {}, 0, 0, {}, 0};
      Frame f = pending_.front();
      pending_.pop_front();
      return f;
    }
    next_tick_ += period_;
    std::this_thread::sleep_until(next_tick_);
    return Take();
  }
  void Flush() override {
    std::lock_guard<std::mutex> lock(mutex_);
    pending_.clear();
    next_tick_ = std::chrono::steady_clock::now();
  }

 private:
  Frame Take() {
    Frame f;
    f.status = FrameStatus::kOk;
    f.image = screen_.ReadGrey(region_);
    f.frame_id = ++frame_id_;
    f.host_timestamp = std::chrono::system_clock::now();
    return f;
  }
  XScreenReader screen_;
  cv::Rect region_;
  std::chrono::microseconds period_;
  CameraSettings settings_;
  std::mutex mutex_;
  std::deque<Frame> pending_;
  uint64_t frame_id_ = 0;
  std::chrono::steady_clock::time_point next_tick_;
};

class DelayedProjector : public Projector {
 public:
  DelayedProjector(Projector& inner, std::chrono::microseconds delay)
      : inner_(inner), delay_(delay) {
    worker_ = std::thread([this] { Work(); });
  }
  ~DelayedProjector() override {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      quit_ = true;
    }
    cv_.notify_all();
    worker_.join();
  }
  ProjectorInfo Info() const override { return inner_.Info(); }
  // Waits until every Show already handed over has reached the wrapped projector.
  void Load(const std::vector<cv::Mat>& images) override {
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait(lock, [&] { return queue_.empty() && !busy_; });
    inner_.Load(images);
  }
  std::chrono::steady_clock::time_point Show(int index) override { return Post(index); }
  std::chrono::steady_clock::time_point ShowBlack() override { return Post(-1); }
  std::chrono::microseconds Latency() const override { return inner_.Latency(); }
  void SetLatency(std::chrono::microseconds latency) override { inner_.SetLatency(latency); }
  int size() const override { return inner_.size(); }

 private:
  std::chrono::steady_clock::time_point Post(int index) {
    const auto now = std::chrono::steady_clock::now();
    {
      std::lock_guard<std::mutex> lock(mutex_);
      queue_.push_back({now + delay_, index});
    }
    cv_.notify_all();
    return now;
  }
  void Work() {
    std::unique_lock<std::mutex> lock(mutex_);
    while (true) {
      cv_.wait(lock, [&] { return quit_ || !queue_.empty(); });
      if (queue_.empty()) return;
      const auto [due, index] = queue_.front();
      queue_.pop_front();
      busy_ = true;
      lock.unlock();
      std::this_thread::sleep_until(due);
      if (index < 0)
        inner_.ShowBlack();
      else
        inner_.Show(index);
      lock.lock();
      busy_ = false;
      cv_.notify_all();
    }
  }
  Projector& inner_;
  std::chrono::microseconds delay_;
  std::thread worker_;
  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<std::pair<std::chrono::steady_clock::time_point, int>> queue_;
  bool quit_ = false;
  bool busy_ = false;
};

}  // namespace slshadow::testing
