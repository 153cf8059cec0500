// The sequencer's own cost per pattern, beyond exposure, display latency and frame transfer
// (docs/benchmarks.md, "Capture sequencer"): a stereo capture of 1920x1200 Mono8 frames of a
// Gray-code sequence for a 1280x800 projector (44 patterns), with devices that cost nothing but
// a copy of the frame (cameras serve pre-rendered frames of what the projector shows; the
// projector waits no latency), storage as PGM on a RAM disk when there is one. Counters:
//   overhead_ms   the sequencer's own time per pattern (CaptureSummary::overhead_ms_per_pattern:
//                 wall time minus the time inside Show / wait / Trigger / Grab / Flush)
//   overhead_cpu_ms the same on the sequencer thread's CPU clock (not inflated by other load)
//   pattern_ms    wall time per pattern, devices included
// Run: build/bench/capture/capture_bench --benchmark_repetitions=5 (validate:1/stride:0 is the
// default)
#include <benchmark/benchmark.h>

#include <unistd.h>
#include <filesystem>

#include <opencv2/imgproc.hpp>

#include "capture/sequencer.h"
#include "patterns/codec.h"
#include "tests/capture/test_devices.h"

namespace slshadow::capture {
namespace {
namespace fs = std::filesystem;

// Serves the pre-rendered camera image of what the projector shows; Grab copies it (the stand-in
// for the transfer).
class PrerenderedCamera : public Camera {
 public:
  PrerenderedCamera(const doubles::TestProjector& projector, std::vector<cv::Mat> renders,
                    std::string serial)
      : projector_(projector), renders_(std::move(renders)), serial_(std::move(serial)) {}
  CameraInfo Info() const override {
    return {"test", serial_, "slshadow", "prerendered", serial_, 1920, 1200, {PixelFormat::kMono8}};
  }
  void Configure(const CameraSettings& s) override { settings_ = s; }
  CameraSettings Settings() const override { return settings_; }
  void Start() override {}
  void Stop() override {}
  void Trigger() override { pending_ = projector_.visible(); }
  Frame Grab(std::chrono::milliseconds) override {
    Frame f;
    f.status = FrameStatus::kOk;
    f.image = renders_[static_cast<size_t>(pending_)].clone();
    f.frame_id = id_;
    id_ = id_ == 65535 ? 1 : id_ + 1;
    f.host_timestamp = std::chrono::system_clock::now();
    return f;
  }

 private:
  const doubles::TestProjector& projector_;
  std::vector<cv::Mat> renders_;
  std::string serial_;
  CameraSettings settings_;
  int pending_ = 0;
  uint64_t id_ = 65500;
};

void BM_SequencerStereo1920x1200(benchmark::State& state) {
  const bool validate = state.range(0) != 0;
  const int stride = static_cast<int>(state.range(1));
  PatternSpec spec;
  spec.kind = PatternKind::kGrayCode;
  spec.projector_width = 1280;
  spec.projector_height = 800;
  Rig rig;
  rig.name = "bench";
  rig.cameras.push_back({"left", CameraModel(1920, 1200, 2700, 2700, 959.5, 599.5), Rigid3d()});
  rig.cameras.push_back({"right", CameraModel(1920, 1200, 2700, 2700, 959.5, 599.5),
                         Rigid3d(Eigen::Quaterniond::Identity(), {-100, 0, 0})});
  rig.projector =
      RigDevice{"projector", CameraModel(1280, 800, 1500, 1500, 639.5, 399.5), Rigid3d()};
  std::vector<cv::Mat> projected = GeneratePatterns(spec);
  projected.push_back(cv::Mat(800, 1280, CV_8UC1, cv::Scalar(255)));
  projected.push_back(cv::Mat(800, 1280, CV_8UC1, cv::Scalar(0)));
  std::vector<cv::Mat> left_renders, right_renders;
  for (const auto& p : projected) {
    cv::Mat l, r;
    cv::resize(p, l, cv::Size(1920, 1200), 0, 0, cv::INTER_NEAREST);
    l.convertTo(l, CV_8U, 0.8, 10);  // camera gain and offset
    cv::resize(p(cv::Rect(40, 0, 1240, 800)), r, cv::Size(1920, 1200), 0, 0, cv::INTER_NEAREST);
    r.convertTo(r, CV_8U, 0.7, 14);
    left_renders.push_back(l);
    right_renders.push_back(r);
  }
  doubles::TestProjector projector(1280, 800);
  PrerenderedCamera left(projector, left_renders, "L"), right(projector, right_renders, "R");
  const std::vector<CaptureCamera> cameras = {
      {"left", &left, {}, std::chrono::milliseconds(100)},
      {"right", &right, {}, std::chrono::milliseconds(100)}};
  SequencerOptions options;
  options.progress = false;
  options.validate = validate;
  options.validation.stride_px = stride;
  options.sleep_until = projector.Sleeper();
  options.writer.encoding = ImageEncoding::kPgm;
  options.writer.durable = false;
  const fs::path root = fs::exists("/dev/shm") ? fs::path("/dev/shm") : fs::temp_directory_path();
  const fs::path out = root / ("slshadow_capture_bench_" + std::to_string(::getpid()));
  double overhead_ms = 0, overhead_cpu_ms = 0, pattern_ms = 0;
  int runs = 0;
  for (auto _ : state) {
    const CaptureSummary s = Capture(rig, spec, cameras, projector, out, options);
    if (!s.complete || s.retries != 0) state.SkipWithError("capture did not complete cleanly");
    overhead_ms += s.overhead_ms_per_pattern;
    overhead_cpu_ms += s.overhead_cpu_ms_per_pattern;
    pattern_ms += s.mean_pattern_ms;
    ++runs;
    state.PauseTiming();
    fs::remove_all(out);
    state.ResumeTiming();
  }
  state.counters["overhead_ms"] = overhead_ms / std::max(runs, 1);
  state.counters["overhead_cpu_ms"] = overhead_cpu_ms / std::max(runs, 1);
  state.counters["pattern_ms"] = pattern_ms / std::max(runs, 1);
  state.counters["patterns"] = spec.NumImages();
}
BENCHMARK(BM_SequencerStereo1920x1200)
    ->Args({1, 0})  // validation, sampling stride chosen by the sequencer (8 here)
    ->Args({1, 4})  // validation, every 4th pixel
    ->Args({0, 0})  // no validation
    ->ArgNames({"validate", "stride"})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
}  // namespace slshadow::capture

BENCHMARK_MAIN();
