// Calibration speed against OpenCV on the same corners (docs/benchmarks.md, "Calibration").
//   build-*/bench/calib/calib_bench --benchmark_repetitions=5
//   --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>

#include <cstdio>

#include <opencv2/calib3d.hpp>

#include "calib/calibration.h"
#include "calib/target.h"
#include "calib/uncertainty.h"

namespace slshadow {
namespace {

const CalibrationInput& LeftInput() {
  static const CalibrationInput input = [] {
    const TargetSpec spec = LoadTargetSpec(std::string(SLSHADOW_SOURCE_DIR) +
                                           "/config/targets/opencv-stereo-chessboard.yaml");
    const auto board = BoardPoints(spec);
    CalibrationInput in;
    in.devices = {CalibrationDevice::Camera("left", 640, 480)};
    int p = 0;
    for (int i : {1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14}) {
      char name[256];
      std::snprintf(name, sizeof(name), "%s/opencv-stereo-chessboard/left%02d.jpg",
                    SLSHADOW_SHARED_DATA_DIR, i);
      const TargetDetection det = DetectTargetInFile(spec, name);
      BoardView v;
      v.pose = p++;
      for (size_t k = 0; k < det.pixels_px.size(); ++k) {
        v.points_in_board_mm.push_back(board[static_cast<size_t>(det.point_ids[k])]);
        v.pixels_px.push_back(det.pixels_px[k]);
      }
      in.views.push_back(v);
    }
    in.num_poses = p;
    return in;
  }();
  return input;
}

void BM_SlshadowCalibrateLeft(benchmark::State& state) {
  CalibrationOptions o;
  o.fix_aspect_ratio = true;
  o.compute_covariance = state.range(0) != 0;
  double rms = 0;
  for (auto _ : state) rms = Calibrate(LeftInput(), o).summary.rms_px;
  state.counters["rms_px"] = rms;
}
BENCHMARK(BM_SlshadowCalibrateLeft)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

void BM_OpenCvCalibrateCameraLeft(benchmark::State& state) {
  std::vector<std::vector<cv::Point3f>> obj;
  std::vector<std::vector<cv::Point2f>> img;
  for (const auto& v : LeftInput().views) {
    obj.emplace_back();
    img.emplace_back();
    for (size_t i = 0; i < v.pixels_px.size(); ++i) {
      obj.back().emplace_back(static_cast<float>(v.points_in_board_mm[i].x()),
                              static_cast<float>(v.points_in_board_mm[i].y()), 0.f);
      img.back().emplace_back(static_cast<float>(v.pixels_px[i].x()),
                              static_cast<float>(v.pixels_px[i].y()));
    }
  }
  double rms = 0;
  for (auto _ : state) {
    cv::Mat k = cv::Mat::eye(3, 3, CV_64F), d;
    std::vector<cv::Mat> r, t;
    rms = cv::calibrateCamera(obj, img, cv::Size(640, 480), k, d, r, t, cv::CALIB_FIX_ASPECT_RATIO);
  }
  state.counters["rms_px"] = rms;
}
BENCHMARK(BM_OpenCvCalibrateCameraLeft)->Unit(benchmark::kMillisecond);

void BM_UncertaintyMap640x480(benchmark::State& state) {
  CalibrationOptions o;
  o.fix_aspect_ratio = true;
  const CalibrationResult r = Calibrate(LeftInput(), o);
  for (auto _ : state)
    benchmark::DoNotOptimize(
        ProjectionUncertaintyMap(r.devices[0].model, r.intrinsics_covariance[0], 16).median);
}
BENCHMARK(BM_UncertaintyMap640x480)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace slshadow

BENCHMARK_MAIN();
