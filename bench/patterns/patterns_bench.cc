// Decode throughput of slshadow's codecs against OpenCV's GrayCodePattern::decode on the same
// camera images, in one run (docs/benchmarks.md, "Pattern decoding"). Camera 1920x1200, projector
// 1920x1080, standard view (patterns/synthetic.h) with noise sigma 1. Throughput is counted in
// camera pixels decoded per second, per camera (items_per_second).
//
//   build-patterns/bench/patterns/patterns_bench --benchmark_repetitions=5
//       --benchmark_report_aggregates_only=true   (one command line)
#include <benchmark/benchmark.h>

#include <map>
#include <string>

#include <opencv2/structured_light.hpp>

#include "patterns/codec.h"
#include "patterns/synthetic.h"

namespace slshadow {
namespace {

constexpr int kCamW = 1920, kCamH = 1200, kProjW = 1920, kProjH = 1080;

PatternSpec PhaseSpec() {
  PatternSpec s;
  s.kind = PatternKind::kPhaseShift;
  s.projector_width = kProjW;
  s.projector_height = kProjH;
  s.phase_steps = 4;
  s.period_px = 16;
  return s;
}

PatternSpec GraySpec() {
  PatternSpec s;
  s.kind = PatternKind::kGrayCode;
  s.projector_width = kProjW;
  s.projector_height = kProjH;
  s.opencv_order = true;
  return s;
}

PatternSpec MultiSpec() {
  PatternSpec s;
  s.kind = PatternKind::kMultiFrequency;
  s.projector_width = kProjW;
  s.projector_height = kProjH;
  s.phase_steps = 4;
  s.periods_px = {2100.0 / 70, 2100.0 / 64, 2100.0 / 59};
  return s;
}

const std::vector<cv::Mat>& Images(const PatternSpec& spec) {
  static std::map<std::string, std::vector<cv::Mat>> cache;
  const std::string key = PatternSpecToJson(spec).dump();
  auto it = cache.find(key);
  if (it == cache.end()) {
    CameraSimOptions sim;
    sim.noise_sigma = 1.0;
    it = cache.emplace(key, SimulateStandardView(spec, kCamW, kCamH, sim)).first;
  }
  return it->second;
}

void Report(benchmark::State& state, int64_t pixels_per_iteration) {
  state.SetItemsProcessed(state.iterations() * pixels_per_iteration);
}

void BM_Slshadow_Decode(benchmark::State& state, const PatternSpec& spec) {
  const auto& images = Images(spec);
  DecodeOptions options;
  options.parallel = state.range(0) != 0;
  for (auto _ : state) {
    ProjectorMap map = DecodePatterns(spec, images, options);
    benchmark::DoNotOptimize(map.proj_x.data);
  }
  Report(state, int64_t{kCamW} * kCamH);
}

// OpenCV's decode needs two cameras (it matches them through the projector): both are given the
// same images, so one call decodes 2 x 1920x1200 camera pixels.
void BM_OpenCv_GrayCodePattern_decode(benchmark::State& state) {
  const auto& images = Images(GraySpec());
  cv::structured_light::GrayCodePattern::Params params;
  params.width = kProjW;
  params.height = kProjH;
  const cv::Ptr<cv::structured_light::GrayCodePattern> graycode =
      cv::structured_light::GrayCodePattern::create(params);
  graycode->setWhiteThreshold(4);
  graycode->setBlackThreshold(12);
  const size_t n = graycode->getNumberOfPatternImages();
  std::vector<cv::Mat> codes(images.begin(), images.begin() + static_cast<std::ptrdiff_t>(n));
  const std::vector<std::vector<cv::Mat>> pattern = {codes, codes};
  const std::vector<cv::Mat> white = {images[n], images[n]}, black = {images[n + 1], images[n + 1]};
  for (auto _ : state) {
    cv::Mat disparity;
    const bool ok = graycode->decode(pattern, disparity, black, white,
                                     cv::structured_light::DECODE_3D_UNDERWORLD);
    benchmark::DoNotOptimize(ok);
  }
  Report(state, 2 * int64_t{kCamW} * kCamH);
}

// OpenCV's per-pixel core alone (shadow mask + getProjPixel), one camera: its decode without the
// disparity step.
void BM_OpenCv_GrayCodePattern_getProjPixel(benchmark::State& state) {
  const auto& images = Images(GraySpec());
  cv::structured_light::GrayCodePattern::Params params;
  params.width = kProjW;
  params.height = kProjH;
  const auto graycode = cv::structured_light::GrayCodePattern::create(params);
  graycode->setWhiteThreshold(4);
  const size_t n = graycode->getNumberOfPatternImages();
  std::vector<cv::Mat> codes(images.begin(), images.begin() + static_cast<std::ptrdiff_t>(n));
  const cv::Mat& white = images[n];
  const cv::Mat& black = images[n + 1];
  for (auto _ : state) {
    int64_t decoded = 0;
    cv::Point proj;
    for (int y = 0; y < kCamH; ++y) {
      for (int x = 0; x < kCamW; ++x) {
        if (white.at<uint8_t>(y, x) - black.at<uint8_t>(y, x) <= 12) continue;
        decoded += !graycode->getProjPixel(codes, x, y, proj);
      }
    }
    benchmark::DoNotOptimize(decoded);
  }
  Report(state, int64_t{kCamW} * kCamH);
}

// Arg 1: rows in parallel (cv::parallel_for_), wall-clock time; arg 0: one thread, CPU time
// (robust on a loaded machine: the per-core throughput).
BENCHMARK_CAPTURE(BM_Slshadow_Decode, gray_code_phase_shift, PhaseSpec())
    ->ArgName("parallel")
    ->Arg(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_Slshadow_Decode, gray_code_phase_shift, PhaseSpec())
    ->ArgName("parallel")
    ->Arg(0)
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Slshadow_Decode, gray_code_opencv_order, GraySpec())
    ->ArgName("parallel")
    ->Arg(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_Slshadow_Decode, gray_code_opencv_order, GraySpec())
    ->ArgName("parallel")
    ->Arg(0)
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Slshadow_Decode, multi_frequency, MultiSpec())
    ->ArgName("parallel")
    ->Arg(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(BM_Slshadow_Decode, multi_frequency, MultiSpec())
    ->ArgName("parallel")
    ->Arg(0)
    ->Unit(benchmark::kMillisecond);
// OpenCV runs on one thread: CPU time.
BENCHMARK(BM_OpenCv_GrayCodePattern_decode)->Unit(benchmark::kMillisecond)->Iterations(2);
BENCHMARK(BM_OpenCv_GrayCodePattern_getProjPixel)->Unit(benchmark::kMillisecond)->Iterations(3);

}  // namespace
}  // namespace slshadow

BENCHMARK_MAIN();
