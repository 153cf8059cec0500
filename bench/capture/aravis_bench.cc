// Throughput of the Aravis backend over loopback (docs/benchmarks.md, "Capture: GigE Vision"):
// 1920x1200 Mono8 free-run frames from in-process GV fake cameras through real GVSP, 1000 frames
// per run, one camera and two at once. Runs inside a private network namespace like the tests.
//
//   build/bench/capture/aravis_bench --benchmark_repetitions=3 --benchmark_report_aggregates_only
//
// Arguments: packet size in bytes, the camera's free-run rate in frames/s, socket buffer. Counters:
// fps (complete frames per second, first to last), lost (frames served but not delivered complete:
// damaged or lost whole), bad (complete frames whose content differs from what was served; checked
// on every 25th frame).
#include <benchmark/benchmark.h>

#include <atomic>
#include <chrono>
#include <thread>

#include "capture/aravis_camera.h"
#include "tests/capture/fake_gv_camera.h"

namespace slshadow::capture {
namespace {

constexpr int kFrames = 1000;
constexpr int kWidth = 1920, kHeight = 1200;

struct RunResult {
  double seconds = 0;
  int ok = 0, damaged = 0, timeouts = 0, bad = 0;
  uint64_t missing = 0;
};

cv::Mat TestImage(int salt) {
  cv::Mat image(kHeight, kWidth, CV_8UC1);
  cv::RNG rng(1000 + salt);
  rng.fill(image, cv::RNG::UNIFORM, 0, 256);
  return image;
}

// Grabs kFrames complete-or-not frames after a first one; times first to last.
RunResult Receive(Camera& camera, const cv::Mat& served) {
  RunResult r;
  camera.Start();
  Frame first = camera.Grab(std::chrono::milliseconds(3000));
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < kFrames; ++i) {
    const Frame frame = camera.Grab(std::chrono::milliseconds(1000));
    if (frame.ok()) {
      ++r.ok;
      if (i % 25 == 0 && cv::norm(frame.image, served, cv::NORM_INF) != 0) ++r.bad;
    } else if (frame.status == FrameStatus::kTimeout) {
      ++r.timeouts;
    } else {
      ++r.damaged;
    }
  }
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  camera.Stop();
  r.missing = camera.Statistics().missing_frames;
  (void)first;
  return r;
}

std::unique_ptr<Camera> OpenFullFrame(const std::string& address, int packet_size,
                                      int socket_buffer) {
  auto camera = OpenAravisCamera(AravisOpenOptions{.device = address, .n_buffers = 16});
  CameraSettings s;
  s.pixel_format = PixelFormat::kMono8;
  s.roi = Roi{0, 0, kWidth, kHeight};
  s.trigger = TriggerMode::kFreeRun;
  s.packet_size_bytes = packet_size;
  s.socket_buffer_bytes = socket_buffer;
  camera->Configure(s);
  return camera;
}

void Report(benchmark::State& state, const std::vector<RunResult>& runs) {
  double fps = 1e9;
  double lost = 0, bad = 0;
  for (const auto& r : runs) {
    fps = std::min(fps, r.ok / r.seconds);  // the slower camera of a pair
    lost += static_cast<double>(r.damaged + r.missing);
    bad += r.bad;
  }
  state.counters["fps"] = fps;
  state.counters["lost"] = lost;
  state.counters["bad"] = bad;
}

void BM_OneCamera(benchmark::State& state) {
  const std::string reason = testing::SkipReasonWithoutPrivateNetwork();
  if (!reason.empty()) {
    state.SkipWithError(reason.c_str());
    return;
  }
  const cv::Mat served = TestImage(1);
  testing::FakeGvCamera fake({.address = "127.0.0.2",
                              .frame_rate_hz = static_cast<double>(state.range(1)),
                              .keep_served = 0});
  fake.SetFill([&served](const testing::FakeFrameRequest&) { return served; });
  auto camera = OpenFullFrame(fake.address(), static_cast<int>(state.range(0)),
                              static_cast<int>(state.range(2)));
  for (auto _ : state) {
    const RunResult r = Receive(*camera, served);
    state.SetIterationTime(r.seconds);
    Report(state, {r});
  }
}

void BM_TwoCameras(benchmark::State& state) {
  const std::string reason = testing::SkipReasonWithoutPrivateNetwork();
  if (!reason.empty()) {
    state.SkipWithError(reason.c_str());
    return;
  }
  const cv::Mat served_left = TestImage(1), served_right = TestImage(2);
  const double rate = static_cast<double>(state.range(1));
  testing::FakeGvCamera left(
      {.address = "127.0.0.2", .serial = "LEFT", .frame_rate_hz = rate, .keep_served = 0});
  testing::FakeGvCamera right(
      {.address = "127.0.0.3", .serial = "RIGHT", .frame_rate_hz = rate, .keep_served = 0});
  left.SetFill([&](const testing::FakeFrameRequest&) { return served_left; });
  right.SetFill([&](const testing::FakeFrameRequest&) { return served_right; });
  const int packet = static_cast<int>(state.range(0)),
            socket_buffer = static_cast<int>(state.range(2));
  auto cam_left = OpenFullFrame(left.address(), packet, socket_buffer);
  auto cam_right = OpenFullFrame(right.address(), packet, socket_buffer);
  for (auto _ : state) {
    RunResult l, r;
    std::thread other([&] { r = Receive(*cam_right, served_right); });
    l = Receive(*cam_left, served_left);
    other.join();
    state.SetIterationTime(std::max(l.seconds, r.seconds));
    Report(state, {l, r});
  }
}

// Arguments: packet size (bytes), free-run rate asked of the camera (240/s is the goal; 1000/s
// means as fast as it can send), socket buffer (0: one frame, Aravis's automatic size).
BENCHMARK(BM_OneCamera)
    ->Args({1400, 1000, 0})
    ->Args({8192, 240, 0})
    ->Args({8192, 1000, 0})
    ->Iterations(1)
    ->UseManualTime()
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_TwoCameras)
    ->Args({8192, 240, 0})
    ->Args({8192, 240, 4 << 20})
    ->Args({8192, 1000, 4 << 20})
    ->Iterations(1)
    ->UseManualTime()
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace slshadow::capture

int main(int argc, char** argv) {
  slshadow::testing::RunInPrivateNetwork(argc, argv);
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
