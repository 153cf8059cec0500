// Test doubles for hardware we do not have in unit tests: a projector that "shows" images (with
// an injectable latency, behaving like a real display pipeline), and
// cameras that render what that projector shows (nearest-neighbour, gain, offset, exposure,
// saturation, seeded noise) with injectable drops (a frame never delivered, its id used up) and
// late frames (delivered after the grab timed out). The sequencer and the writer under test are
// the real code. Real-protocol tests (Aravis fake cameras, an SDL window under Xvfb) live in
// the backends' own test files.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <random>
#include <set>

#include "capture/camera.h"
#include "capture/projector.h"

namespace slshadow::capture::doubles {

// Time is virtual: Show() returns the projector's clock, and the sequencer waits through
// SleepUntil() (SequencerOptions::sleep_until), which only moves that clock. Like a real display
// pipeline (an HDMI projector, testing::DelayedProjector), every Show is queued: a Show issued at
// time s with latency L (`latency_for(index)` at the time of the Show, or true_latency) is on
// screen from s + L until a later-issued Show takes effect. Shows issued while an earlier one is
// still pending are all shown in turn, so a sequencer that re-shows while its latency estimate is
// too low sees earlier patterns come back. Deterministic, and as fast as the machine.
class TestProjector : public Projector {
 public:
  TestProjector(int width, int height) : width_(width), height_(height) {}
  ProjectorInfo Info() const override { return {"test", "test", width_, height_, 60}; }
  void Load(const std::vector<cv::Mat>& images) override {
    images_ = images;
    black_ = cv::Mat(height_, width_, CV_8UC1, cv::Scalar(0));
  }
  std::chrono::steady_clock::time_point Show(int index) override {
    ++shows_;
    if (index != requested_) {
      requested_ = index;
      ++requests_;
    }
    const auto latency = latency_for ? latency_for(index) : true_latency;
    pending_.push_back({now_ + latency, index});
    Update();
    max_pending_ = std::max(max_pending_, static_cast<int>(pending_.size()));
    return now_;
  }
  std::chrono::steady_clock::time_point ShowBlack() override {
    visible_ = requested_ = -1;
    pending_.clear();
    return now_;
  }
  std::chrono::microseconds Latency() const override { return latency_; }
  void SetLatency(std::chrono::microseconds latency) override { latency_ = latency; }
  int size() const override { return static_cast<int>(images_.size()); }

  void SleepUntil(std::chrono::steady_clock::time_point t) {
    if (t > now_) now_ = t;
    Update();
  }
  std::function<void(std::chrono::steady_clock::time_point)> Sleeper() {
    return [this](std::chrono::steady_clock::time_point t) { SleepUntil(t); };
  }
  // What is on "screen" now: the loaded image, or black before anything was shown.
  const cv::Mat& Visible() const {
    return visible_ < 0 ? black_ : images_[static_cast<size_t>(visible_)];
  }
  int visible() const { return visible_; }
  int64_t shows() const { return shows_; }
  int64_t requests() const {
    return requests_;
  }  // Show calls that asked for another pattern than the last one
  int pending() const { return static_cast<int>(pending_.size()); }  // Shows not yet on screen
  int max_pending() const {
    return max_pending_;
  }  // most Shows ever waiting at once (1 + a re-Show queued behind)

  std::chrono::microseconds true_latency{0};
  std::function<std::chrono::microseconds(int index)> latency_for;  // overrides true_latency

 private:
  struct Pending {
    std::chrono::steady_clock::time_point effective;
    int index;
  };
  // The latest-issued Show that has taken effect is on screen; it and every Show issued before it
  // leave the queue.
  void Update() {
    for (size_t i = pending_.size(); i-- > 0;) {
      if (pending_[i].effective <= now_) {
        visible_ = pending_[i].index;
        pending_.erase(pending_.begin(), pending_.begin() + static_cast<std::ptrdiff_t>(i) + 1);
        break;
      }
    }
  }
  int width_, height_;
  std::vector<cv::Mat> images_;
  cv::Mat black_;
  int requested_ = -1, visible_ = -1, max_pending_ = 0;
  std::chrono::steady_clock::time_point now_{std::chrono::hours(1)};
  std::deque<Pending> pending_;
  int64_t shows_ = 0, requests_ = 0;
  std::chrono::microseconds latency_{0};
};

struct TestCameraOptions {
  std::string serial = "TEST-0";
  int width = 64, height = 48;
  double gain = 1.0, offset = 8;  // level = offset + gain * projector level * exposure / 10000 us
  double noise = 0;               // uniform noise amplitude (grey levels)
  uint64_t seed = 1;
  uint64_t first_frame_id = 65400;  // GigE Vision ids: 16-bit, wrap 65535 -> 1
  bool ids_follow_pattern =
      false;  // frame id and host time = functions of the pattern (deterministic records)
  bool sixteen_bit = false;  // Mono16: level x 256
  double drop_probability = 0, late_probability = 0;
  std::set<int64_t> drop_triggers, late_triggers;  // by trigger count (0-based)
  int64_t abort_after_triggers = -1;               // the camera disappears: Grab returns kAborted
};

class TestCamera : public Camera {
 public:
  TestCamera(const TestProjector& projector, TestCameraOptions options)
      : projector_(projector),
        options_(std::move(options)),
        rng_(options_.seed),
        next_id_(options_.first_frame_id) {
    settings_.exposure_us = 10000;
  }
  CameraInfo Info() const override {
    CameraInfo info;
    info.backend = "test";
    info.id = options_.serial;
    info.vendor = "slshadow";
    info.model = "test camera";
    info.serial = options_.serial;
    info.sensor_width = options_.width;
    info.sensor_height = options_.height;
    info.pixel_formats = {PixelFormat::kMono8, PixelFormat::kMono16};
    return info;
  }
  void Configure(const CameraSettings& settings) override {
    settings.Check(options_.serial);
    const auto exposure = settings.exposure_us ? settings.exposure_us : settings_.exposure_us;
    settings_ = settings;
    settings_.exposure_us = exposure;
  }
  CameraSettings Settings() const override { return settings_; }
  void Start() override { started_ = true; }
  void Stop() override {
    started_ = false;
    queue_.clear();
  }
  void ExpectPattern(int index) override { expected_pattern_ = index; }
  void Trigger() override {
    const int64_t t = triggers_++;
    if (options_.abort_after_triggers >= 0 && t >= options_.abort_after_triggers) return;
    const uint64_t id =
        options_.ids_follow_pattern
            ? Wrap(options_.first_frame_id + static_cast<uint64_t>(expected_pattern_))
            : next_id_;
    next_id_ = Wrap(next_id_ + 1);
    const bool drop = options_.drop_triggers.count(t) || Chance(options_.drop_probability);
    const bool late =
        !drop && (options_.late_triggers.count(t) || Chance(options_.late_probability));
    if (drop || late) lost_triggers_.insert(t);
    if (drop) {
      ++dropped_;
      return;
    }
    Pending p;
    p.frame = Render(id);
    p.shown = projector_.visible();
    p.late = late;
    queue_.push_back(std::move(p));
  }
  Frame Grab(std::chrono::milliseconds) override {
    Frame f;
    if (options_.abort_after_triggers >= 0 && triggers_ > options_.abort_after_triggers) {
      f.status = FrameStatus::kAborted;
      f.message = "device lost";
      return f;
    }
    if (queue_.empty()) {
      f.status = FrameStatus::kTimeout;
      return f;
    }
    if (queue_.front().late) {  // arrives just after this timeout
      queue_.front().late = false;
      ++late_;
      f.status = FrameStatus::kTimeout;
      return f;
    }
    Pending p = std::move(queue_.front());
    queue_.pop_front();
    shown_of_id_[p.frame.frame_id] = p.shown;
    return p.frame;
  }
  void Flush() override {
    flushed_ += static_cast<int64_t>(queue_.size());
    queue_.clear();
  }

  // The noise-free image this camera gives of projector image `proj` at its current exposure.
  cv::Mat RenderClean(const cv::Mat& proj) const { return Draw(proj, nullptr); }

  int64_t triggers() const { return triggers_; }
  int64_t dropped() const { return dropped_; }
  int64_t late() const { return late_; }
  int64_t flushed() const { return flushed_; }
  // Trigger numbers whose frame was dropped or late.
  const std::set<int64_t>& lost_triggers() const { return lost_triggers_; }
  // Which pattern the projector showed when the frame of `id` was taken.
  int ShownFor(uint64_t id) const { return shown_of_id_.at(id); }
  std::function<void(int64_t triggers)> on_trigger;  // e.g. raise a stop flag after N triggers

 private:
  struct Pending {
    Frame frame;
    int shown = -1;
    bool late = false;
  };
  static uint64_t Wrap(uint64_t id) { return (id - 1) % 65535 + 1; }
  bool Chance(double p) { return p > 0 && std::uniform_real_distribution<double>(0, 1)(rng_) < p; }

  cv::Mat Draw(const cv::Mat& proj, std::mt19937_64* rng) const {
    const double scale = settings_.exposure_us.value_or(10000) / 10000.0;
    const double full = options_.sixteen_bit ? 65535 : 255;
    cv::Mat out(options_.height, options_.width, options_.sixteen_bit ? CV_16UC1 : CV_8UC1);
    std::uniform_real_distribution<double> noise(-options_.noise, options_.noise);
    for (int y = 0; y < out.rows; ++y) {
      const uint8_t* row = proj.ptr<uint8_t>(y * proj.rows / out.rows);
      for (int x = 0; x < out.cols; ++x) {
        double v = options_.offset + options_.gain * row[x * proj.cols / out.cols] * scale;
        if (rng && options_.noise > 0) v += noise(*rng);
        if (options_.sixteen_bit) v *= 256;
        v = std::clamp(std::round(v), 0.0, full);
        if (options_.sixteen_bit) {
          out.at<uint16_t>(y, x) = static_cast<uint16_t>(v);
        } else {
          out.at<uint8_t>(y, x) = static_cast<uint8_t>(v);
        }
      }
    }
    return out;
  }

  Frame Render(uint64_t id) {
    Frame f;
    f.status = FrameStatus::kOk;
    if (options_.ids_follow_pattern) {
      std::mt19937_64 per_pattern(options_.seed * 1000003u +
                                  static_cast<uint64_t>(expected_pattern_));
      f.image = Draw(projector_.Visible(), &per_pattern);
    } else {
      f.image = Draw(projector_.Visible(), &rng_);
    }
    f.frame_id = id;
    f.exposure_us = settings_.exposure_us.value_or(0);
    const int64_t tick = options_.ids_follow_pattern ? expected_pattern_ : triggers_;
    f.device_timestamp_ns = 1000000000ull + static_cast<uint64_t>(tick) * 1000000ull;
    f.host_timestamp = std::chrono::system_clock::time_point(std::chrono::seconds(1795000000) +
                                                             std::chrono::milliseconds(tick * 20));
    if (on_trigger) on_trigger(triggers_);
    return f;
  }

  const TestProjector& projector_;
  TestCameraOptions options_;
  CameraSettings settings_;
  std::mt19937_64 rng_;
  uint64_t next_id_;
  bool started_ = false;
  int expected_pattern_ = 0;
  int64_t triggers_ = 0, dropped_ = 0, late_ = 0, flushed_ = 0;
  std::deque<Pending> queue_;
  std::map<uint64_t, int> shown_of_id_;
  std::set<int64_t> lost_triggers_;
};

}  // namespace slshadow::capture::doubles
