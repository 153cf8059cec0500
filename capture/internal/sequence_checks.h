// Internal to capture/: the pieces of frame validation the acquisition sequencers share (the
// Show-and-trigger sequencer in sequencer.cc, the pattern-sequence capture in
// pattern_sequence_capture.cc): what a pattern sequence predicts (SequenceModel), per-camera
// references, sampled pixel checks, and small record helpers. Not a public API.
#pragma once

#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include <nlohmann/json.hpp>

#include "capture/camera.h"
#include "capture/sequencer.h"
#include "core/image_set.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"

namespace slshadow::capture::internal {

// CPU time of the calling thread, seconds.
double ThreadCpuSeconds();
// ISO 8601 UTC with milliseconds ("now" for a zero time point).
std::string FormatUtc(std::chrono::system_clock::time_point tp);
// Largest value of a pixel format (255, 4095, 65535).
double FullScale(PixelFormat f);
// The ImageSet source of a camera backend ("replay", "sim", else a device).
ImageSource SourceOf(const std::string& backend);
// The validation sampling stride for a camera of `width` x `height` pixels: stride_px when set,
// else about target_samples samples.
int SampleStride(const ValidationOptions& validation, int width, int height);
// The cameras of a capture: at least one, each with a device, a camera name of the rig, a
// positive grab timeout, none twice; throws slshadow::Error naming the camera.
void CheckCaptureCameras(const Rig& rig, const std::vector<CaptureCamera>& cameras);
// Stops every camera when it goes out of scope (errors ignored: the capture's own error wins).
class CamerasStopper {
 public:
  explicit CamerasStopper(const std::vector<CaptureCamera>& cameras) : cameras_(cameras) {}
  ~CamerasStopper();
  CamerasStopper(const CamerasStopper&) = delete;
  CamerasStopper& operator=(const CamerasStopper&) = delete;

 private:
  const std::vector<CaptureCamera>& cameras_;
};
// The ImageSet record of an accepted frame of pattern k (exposure: the frame's, else the
// configured one).
ImageRecord RecordOf(const CaptureCamera& camera, const CameraInfo& info,
                     const CameraSettings& settings, int k, const Frame& frame, int retries);
// A camera's entry in a capture's start note (journaled session).
nlohmann::json CameraNote(const CameraInfo& info, const CameraSettings& settings,
                          double exposure_us);
// Journals a capture run's end note (the summary, `failure`, `storage_error`), then throws the
// storage error or the failure, each naming the staging folder to resume; returns when both are
// empty.
void EndSession(ResumableImageSetWriter& writer, const CaptureSummary& summary,
                const std::string& failure, const std::string& storage_error);

// What the pattern sequence predicts, computed once per capture.
struct SequenceModel {
  std::vector<FrameInfo> frames;
  std::vector<double> expected_change;  // [k]: min over an 8x8 tile grid of the share of projector
                                        // pixels whose level changes by half the range from k-1
  struct Group {
    int first = 0, size = 1;
    bool pair = false;     // Gray bit + inverse, or white + black: taken and checked as a whole
    bool opening = false;  // white, black and the first Gray pair as one group (see CheckGroup)
  };
  std::vector<Group> groups;
  std::vector<int> group_of;          // pattern -> group index
  std::vector<int> reference_frames;  // white, black; or the first phase steps
  bool white_black = false;
  bool references_last = false;  // white and black after the Gray pairs (OpenCV order)

  explicit SequenceModel(const PatternSpec& spec, const std::vector<cv::Mat>& images) {
    frames = spec.Frames();
    const int n = static_cast<int>(frames.size());
    expected_change.assign(static_cast<size_t>(n), 0.0);
    const double half_range = 0.5 * (spec.intensity_max - spec.intensity_min);
    for (int k = 1; k < n; ++k) {
      expected_change[static_cast<size_t>(k)] = TileChange(
          images[static_cast<size_t>(k)], images[static_cast<size_t>(k - 1)], half_range);
    }
    group_of.assign(static_cast<size_t>(n), 0);
    for (int k = 0; k < n;) {
      Group g;
      g.first = k;
      const FrameInfo& f = frames[static_cast<size_t>(k)];
      const bool gray_pair =
          f.role == FrameRole::kGrayBit && k + 1 < n &&
          frames[static_cast<size_t>(k + 1)].role == FrameRole::kGrayBitInverse &&
          frames[static_cast<size_t>(k + 1)].axis == f.axis &&
          frames[static_cast<size_t>(k + 1)].bit == f.bit;
      const bool refs_pair = f.role == FrameRole::kWhite && k + 1 < n &&
                             frames[static_cast<size_t>(k + 1)].role == FrameRole::kBlack;
      if (gray_pair || refs_pair) {
        g.size = 2;
        g.pair = true;
      }
      for (int i = 0; i < g.size; ++i)
        group_of[static_cast<size_t>(k + i)] = static_cast<int>(groups.size());
      groups.push_back(g);
      k += g.size;
    }
    // White and black first: the white frame has no predecessor to be compared with, so it is
    // judged by the frames after it. White, black and the first Gray pair form one group.
    if (groups.size() >= 2 && frames[0].role == FrameRole::kWhite && groups[0].size == 2 &&
        groups[1].pair) {
      groups[0].size = 4;
      groups[0].opening = true;
      groups.erase(groups.begin() + 1);
      for (int i = 0; i < 4; ++i) group_of[static_cast<size_t>(i)] = 0;
      for (size_t k = 4; k < group_of.size(); ++k) --group_of[k];
    }
    // Phase first (4 or more steps): the first frame has no predecessor either; the first period's
    // steps form one group whose per-pixel sinusoid fit must hold (see CheckGroup).
    const int steps = spec.phase_steps;
    if (frames[0].role == FrameRole::kPhase && steps >= 4 &&
        static_cast<int>(frames.size()) >= steps) {
      bool same = true;
      for (int i = 0; i < steps; ++i) {
        same = same && frames[static_cast<size_t>(i)].role == FrameRole::kPhase &&
               frames[static_cast<size_t>(i)].frequency == 0 &&
               frames[static_cast<size_t>(i)].step == i;
      }
      if (same) {
        groups.erase(groups.begin(), groups.begin() + steps);
        Group g;
        g.first = 0;
        g.size = steps;
        g.pair = true;
        g.opening = true;
        groups.insert(groups.begin(), g);
        for (size_t k = 0; k < group_of.size(); ++k) {
          group_of[k] = k < static_cast<size_t>(steps) ? 0 : group_of[k] - (steps - 1);
        }
      }
    }
    if (spec.WhiteFrameIndex() >= 0 && spec.BlackFrameIndex() >= 0) {
      white_black = true;
      reference_frames = {spec.WhiteFrameIndex(), spec.BlackFrameIndex()};
      references_last = spec.WhiteFrameIndex() > 0;
    } else {
      // Phase codecs: the steps of the first frequency of the first coded axis; per pixel their
      // max and min stand in for white and black.
      for (int k = 0; k < n; ++k) {
        const FrameInfo& f = frames[static_cast<size_t>(k)];
        if (f.role == FrameRole::kPhase && f.frequency == 0 && f.axis == frames.front().axis)
          reference_frames.push_back(k);
      }
    }
  }
  std::string Name(int k) const {
    return "pattern " + std::to_string(k) + " (" + frames[static_cast<size_t>(k)].Name() + ")";
  }
  // expected_change between any two patterns (k-1 and k: the table).
  double Change(const std::vector<cv::Mat>& images, double half_range, int from, int to) const {
    if (from == to - 1) return expected_change[static_cast<size_t>(to)];
    if (from < 0 || from == to) return 0;
    return TileChange(images[static_cast<size_t>(from)], images[static_cast<size_t>(to)],
                      half_range);
  }
  static double TileChange(const cv::Mat& a, const cv::Mat& b, double half_range) {
    cv::Mat diff;
    cv::absdiff(a, b, diff);
    const cv::Mat changed = diff >= half_range;
    double worst = 1;
    for (int ty = 0; ty < 8; ++ty) {
      for (int tx = 0; tx < 8; ++tx) {
        const cv::Rect tile(tx * changed.cols / 8, ty * changed.rows / 8,
                            (tx + 1) * changed.cols / 8 - tx * changed.cols / 8,
                            (ty + 1) * changed.rows / 8 - ty * changed.rows / 8);
        if (tile.area() == 0) continue;
        worst = std::min(worst, cv::countNonZero(changed(tile)) / static_cast<double>(tile.area()));
      }
    }
    return worst;
  }
};

// Per-pixel references of one camera: white (or max) and black (or min), as float.
struct References {
  cv::Mat white, black;  // CV_32F
  // The lit sample positions (ForEachSample grid, white - black >= the lit threshold) with a
  // quarter of their contrast and their mid level, built once: the per-frame checks then read
  // only the two frames, in row order.
  struct Sample {
    int32_t y, x;
    float quarter, mid;
  };
  std::vector<Sample> samples;
  bool ready() const { return !white.empty(); }
};

// Visits every stride-th pixel in x and y, the phase of the grid changing from row to row and
// column to column (the offsets cycle through 0..stride-1), so stripes with a period near the
// stride cannot alias onto one side of every stripe.
template <typename F>
void ForEachSample(int rows, int cols, int stride, F&& f) {
  const int step =
      stride <= 2 ? 1 : (stride % 2 == 0 ? stride - 1 : stride - 2);  // coprime with stride
  int row_offset = 0;  // (i * step) % stride, kept without a division per sample
  for (int i = 0;; ++i) {
    const int y = i * stride + row_offset;
    if (y >= rows) break;
    int col_offset = i % stride;  // (j * step + i) % stride
    for (int base = 0;; base += stride) {
      const int x = base + col_offset;
      if (x >= cols) break;
      f(y, x);
      col_offset += step;
      if (col_offset >= stride) col_offset -= stride;
    }
    row_offset += step;
    if (row_offset >= stride) row_offset -= stride;
  }
}

// Share of the sampled (lit, when refs are ready) pixels that changed between two frames: by a
// quarter of the local contrast with references, else by abs_threshold. *samples: how many.
double ChangedShare(const cv::Mat& f, const cv::Mat& prev, const References& refs,
                    double lit_threshold, double abs_threshold, int stride, int* samples);
// Share of pixels decisive in both frames (a quarter of the contrast away from the middle of the
// references) that lie on opposite sides of it; 1 when none is decisive.
double ComplementaryShare(const cv::Mat& p, const cv::Mat& q, const References& refs,
                          double lit_threshold, int stride, int* samples);
// Share of the sampled pixels where white - black >= lit_threshold.
double LitShare(const References& refs, double lit_threshold, int stride);

}  // namespace slshadow::capture::internal
