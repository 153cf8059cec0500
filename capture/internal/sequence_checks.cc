#include "capture/internal/sequence_checks.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>

#include "core/error.h"
#include "core/file_util.h"

namespace slshadow::capture::internal {

double ThreadCpuSeconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

std::string FormatUtc(std::chrono::system_clock::time_point tp) {
  return tp.time_since_epoch().count() == 0 ? UtcTimestamp() : UtcTimestamp(tp);
}

double FullScale(PixelFormat f) {
  switch (f) {
    case PixelFormat::kMono8:
      return 255;
    case PixelFormat::kMono12:
      return 4095;
    case PixelFormat::kMono16:
      return 65535;
  }
  return 255;
}

ImageSource SourceOf(const std::string& backend) {
  if (backend == "replay") return ImageSource::kReplay;
  if (backend == "sim") return ImageSource::kVirtual;
  return ImageSource::kDevice;
}

int SampleStride(const ValidationOptions& validation, int width, int height) {
  return validation.stride_px > 0
             ? validation.stride_px
             : std::max(1, static_cast<int>(std::sqrt(static_cast<double>(width) * height /
                                                      validation.target_samples)));
}

void CheckCaptureCameras(const Rig& rig, const std::vector<CaptureCamera>& cameras) {
  SLSHADOW_THROW_IF(cameras.empty(), "capture: no cameras");
  for (size_t i = 0; i < cameras.size(); ++i) {
    const CaptureCamera& c = cameras[i];
    SLSHADOW_THROW_IF(c.camera == nullptr, "capture: camera '", c.name, "' has no device");
    SLSHADOW_THROW_IF(rig.CameraIndex(c.name) < 0, "capture: the rig '", rig.name,
                      "' has no camera '", c.name, "'");
    SLSHADOW_THROW_IF(c.grab_timeout.count() <= 0, "capture: camera '", c.name,
                      "': grab timeout must be > 0");
    for (size_t j = 0; j < i; ++j) {
      SLSHADOW_THROW_IF(cameras[j].name == c.name, "capture: camera '", c.name, "' given twice");
    }
  }
}

CamerasStopper::~CamerasStopper() {
  for (const auto& c : cameras_) {
    try {
      c.camera->Stop();
    } catch (...) {}
  }
}

ImageRecord RecordOf(const CaptureCamera& camera, const CameraInfo& info,
                     const CameraSettings& settings, int k, const Frame& frame, int retries) {
  ImageRecord r;
  r.camera = camera.name;
  r.pattern_index = k;
  r.exposure_us = frame.exposure_us > 0 ? frame.exposure_us : settings.exposure_us.value_or(0);
  r.timestamp = FormatUtc(frame.host_timestamp);
  r.source = SourceOf(info.backend);
  r.device_serial = info.serial;
  if (frame.frame_id != 0) r.frame_id = frame.frame_id;
  if (frame.device_timestamp_ns != 0) r.device_timestamp_ns = frame.device_timestamp_ns;
  r.retries = retries;
  return r;
}

nlohmann::json CameraNote(const CameraInfo& info, const CameraSettings& settings,
                          double exposure_us) {
  return {{"backend", info.backend},
          {"id", info.id},
          {"serial", info.serial},
          {"model", info.model},
          {"vendor", info.vendor},
          {"exposure_us", exposure_us},
          {"pixel_format", ToString(settings.pixel_format)},
          {"trigger", ToString(settings.trigger)}};
}

void EndSession(ResumableImageSetWriter& writer, const CaptureSummary& summary,
                const std::string& failure, const std::string& storage_error) {
  nlohmann::json end_note = summary.ToJson();
  // The note is written before the commit, so summary.complete (committed) is still false here:
  // the note says whether this session ended with every image captured (the commit follows).
  end_note["complete"] = failure.empty() && storage_error.empty() && !summary.interrupted &&
                         summary.images_before + summary.images_stored >= summary.images_total;
  end_note["ended"] = UtcTimestamp();
  if (!failure.empty()) end_note["failure"] = failure;
  if (!storage_error.empty()) end_note["storage_error"] = storage_error;
  try {
    writer.AppendSession(end_note);
  } catch (const Error&) {
    // The records are what matters; a lost note is not worth hiding the real error.
  }
  SLSHADOW_THROW_IF(!storage_error.empty(), storage_error, " (the capture is staged in ",
                    writer.staging_dir().string(), "; continue it with --resume)");
  SLSHADOW_THROW_IF(!failure.empty(), failure, " (", summary.images_before + summary.images_stored,
                    " of ", summary.images_total, " images are staged in ",
                    writer.staging_dir().string(), "; fix the cause and continue with --resume)");
}

namespace {

template <typename T>
struct Sampler {
  static double ChangedShare(const cv::Mat& f, const cv::Mat& prev, const References& refs,
                             double lit_threshold, double abs_threshold, int stride, int* samples) {
    int64_t count = 0, changed = 0;
    if (!refs.samples.empty()) {
      const uchar* a = f.data;
      const uchar* b = prev.data;
      const size_t sa = f.step[0], sb = prev.step[0];
      for (const auto& p : refs.samples) {
        const float va = reinterpret_cast<const T*>(a + static_cast<size_t>(p.y) * sa)[p.x];
        const float vb = reinterpret_cast<const T*>(b + static_cast<size_t>(p.y) * sb)[p.x];
        changed += std::abs(va - vb) >= p.quarter;
      }
      *samples = static_cast<int>(refs.samples.size());
      return static_cast<double>(changed) / static_cast<double>(refs.samples.size());
    }
    const bool refs_ready = refs.ready();
    ForEachSample(f.rows, f.cols, stride, [&](int y, int x) {
      const double d =
          std::abs(static_cast<double>(f.at<T>(y, x)) - static_cast<double>(prev.at<T>(y, x)));
      if (refs_ready) {
        const double contrast = refs.white.at<float>(y, x) - refs.black.at<float>(y, x);
        if (contrast < lit_threshold) return;
        ++count;
        changed += d >= 0.25 * contrast;
      } else {
        ++count;
        changed += d >= abs_threshold;
      }
    });
    *samples = static_cast<int>(count);
    return count ? static_cast<double>(changed) / static_cast<double>(count) : 0.0;
  }
  // Share of pixels decisive in both frames (a quarter of the contrast away from the middle)
  // that lie on opposite sides of it.
  static double ComplementaryShare(const cv::Mat& p, const cv::Mat& q, const References& refs,
                                   double lit_threshold, int stride, int* samples) {
    int64_t count = 0, opposite = 0;
    if (!refs.samples.empty()) {
      const size_t sp = p.step[0], sq = q.step[0];
      for (const auto& r : refs.samples) {
        const float da =
            reinterpret_cast<const T*>(p.data + static_cast<size_t>(r.y) * sp)[r.x] - r.mid;
        const float db =
            reinterpret_cast<const T*>(q.data + static_cast<size_t>(r.y) * sq)[r.x] - r.mid;
        if (std::abs(da) < r.quarter || std::abs(db) < r.quarter) continue;
        ++count;
        opposite += (da > 0) != (db > 0);
      }
      *samples = static_cast<int>(count);
      return count ? static_cast<double>(opposite) / static_cast<double>(count) : 1.0;
    }
    ForEachSample(p.rows, p.cols, stride, [&](int y, int x) {
      const double w = refs.white.at<float>(y, x), k = refs.black.at<float>(y, x);
      const double contrast = w - k;
      if (contrast < lit_threshold) return;
      const double mid = 0.5 * (w + k);
      const double da = p.at<T>(y, x) - mid, db = q.at<T>(y, x) - mid;
      if (std::abs(da) < 0.25 * contrast || std::abs(db) < 0.25 * contrast) return;
      ++count;
      opposite += (da > 0) != (db > 0);
    });
    *samples = static_cast<int>(count);
    return count ? static_cast<double>(opposite) / static_cast<double>(count) : 1.0;
  }
};

}  // namespace

double ChangedShare(const cv::Mat& f, const cv::Mat& prev, const References& refs,
                    double lit_threshold, double abs_threshold, int stride, int* samples) {
  return f.depth() == CV_8U ? Sampler<uint8_t>::ChangedShare(f, prev, refs, lit_threshold,
                                                             abs_threshold, stride, samples)
                            : Sampler<uint16_t>::ChangedShare(f, prev, refs, lit_threshold,
                                                              abs_threshold, stride, samples);
}

double ComplementaryShare(const cv::Mat& p, const cv::Mat& q, const References& refs,
                          double lit_threshold, int stride, int* samples) {
  return p.depth() == CV_8U
             ? Sampler<uint8_t>::ComplementaryShare(p, q, refs, lit_threshold, stride, samples)
             : Sampler<uint16_t>::ComplementaryShare(p, q, refs, lit_threshold, stride, samples);
}

double LitShare(const References& refs, double lit_threshold, int stride) {
  int64_t count = 0, lit = 0;
  ForEachSample(refs.white.rows, refs.white.cols, stride, [&](int y, int x) {
    ++count;
    lit += refs.white.at<float>(y, x) - refs.black.at<float>(y, x) >= lit_threshold;
  });
  return count ? static_cast<double>(lit) / static_cast<double>(count) : 0.0;
}

}  // namespace slshadow::capture::internal
