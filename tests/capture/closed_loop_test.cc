// The closed loop, the capture module's strongest oracle: a whole structured-light capture through
// the real protocols, compared with the simulator.
//
//   patterns --Show--> SDL window projector --X11--> Xvfb framebuffer
//   Xvfb framebuffer --XGetImage (read back in the camera's fill callback)--> simulator render of
//     that projector image for this camera --GVSP/UDP 127.0.0.2/.3--> Aravis backend (two cameras)
//   --> ImageSet
//
// The fake cameras never see the pattern list: they render whatever is on the X screen when they
// are triggered. So the captured ImageSet equals `slshadow simulate` of the same scene and rig
// pixel for pixel only if every frame was taken of the right pattern, transferred intact and
// stored under the right (camera, pattern); and then its reconstruction equals the simulated one.
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "capture/aravis_camera.h"
#include "capture/latency.h"
#include "capture/window_projector.h"
#include "capture/x11_screen.h"
#include "core/image_set.h"
#include "core/rig.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct_image_set.h"
#include "sim/renderer.h"
#include "sim/scene.h"
#include "sim/simulate.h"
#include "tests/capture/fake_gv_camera.h"
#include "tests/capture/screen_devices.h"
#include "tests/capture/xvfb_server.h"

namespace slshadow::capture {
namespace {

namespace fs = std::filesystem;
using std::chrono::milliseconds;
using Clock = std::chrono::steady_clock;

fs::path TestDir(const std::string& name) {
  const char* tmp = std::getenv("SLSHADOW_TEST_TMP");
  fs::path dir = fs::path(tmp ? tmp : fs::temp_directory_path().string()) / ("closed_loop_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

// The demo rig at 1/scale of its resolution (same optics, coarser pixels), so a test runs in
// seconds: cameras 1920x1200 -> 480x300, projector 1280x800 -> 320x200 at scale 4.
Rig ScaledDemoRig(int scale) {
  Rig rig = LoadRig(fs::path(SLSHADOW_SOURCE_DIR) / "config/demo/rig.yaml");
  auto shrink = [scale](CameraModel& m) {
    m.width /= scale;
    m.height /= scale;
    m.params[CameraModel::kFx] /= scale;
    m.params[CameraModel::kFy] /= scale;
    m.params[CameraModel::kCx] = (m.params[CameraModel::kCx] + 0.5) / scale - 0.5;
    m.params[CameraModel::kCy] = (m.params[CameraModel::kCy] + 0.5) / scale - 0.5;
  };
  for (RigDevice& c : rig.cameras) shrink(c.model);
  shrink(rig.projector->model);
  rig.Check("scaled demo rig");
  return rig;
}

// One fake GigE Vision camera per rig camera whose fill renders, with the simulator, the
// projector image read back from the X screen at the moment the frame is taken.
class SimulatedCameraOnScreen {
 public:
  SimulatedCameraOnScreen(const Scene& scene, const Rig& rig, int camera, const GeometryBuffer& geometry,
                          const std::string& address, const cv::Rect& projector_on_screen)
      : renderer_(scene, rig, camera, geometry),
        fake_(testing::FakeGvCameraOptions{.address = address, .serial = rig.cameras[static_cast<size_t>(camera)].name}),
        rect_(projector_on_screen) {
    fake_.SetFill([this](const testing::FakeFrameRequest&) {
      const auto t0 = Clock::now();
      if (!screen_) screen_ = std::make_unique<XScreenReader>();  // on the fake camera's thread
      const cv::Mat on_screen = screen_->ReadGrey(rect_);
      const auto t1 = Clock::now();
      cv::Mat image = renderer_.Render(on_screen, 0);
      read_s_ += std::chrono::duration<double>(t1 - t0).count();
      render_s_ += std::chrono::duration<double>(Clock::now() - t1).count();
      ++fills_;
      return image;
    });
  }
  const testing::FakeGvCamera& fake() const { return fake_; }
  // Mean cost per frame of the fixture's fill: X read-back and simulator render, ms.
  std::string FillReport() const {
    char line[160];
    std::snprintf(line, sizeof line, "%d fills: X read-back %.2f ms, render %.2f ms per frame", fills_.load(),
                  1e3 * read_s_ / std::max(1, fills_.load()), 1e3 * render_s_ / std::max(1, fills_.load()));
    return line;
  }

 private:
  PatternRenderer renderer_;
  std::unique_ptr<XScreenReader> screen_;
  std::atomic<int> fills_{0};
  double read_s_ = 0, render_s_ = 0;  // written on the fake camera's thread, read after it
  testing::FakeGvCamera fake_;
  cv::Rect rect_;
};

struct CaptureStats {
  int patterns = 0;
  int retries = 0;
  double seconds = 0;
  double show_s = 0, wait_s = 0, trigger_grab_s = 0, store_s = 0;  // summed over patterns
  std::string Breakdown() const {
    char line[200];
    const double n = std::max(1, patterns);
    std::snprintf(line, sizeof line, "per pattern: Show %.2f ms (vsync), latency wait %.2f ms, trigger+grab %.2f ms, store %.2f ms",
                  1e3 * show_s / n, 1e3 * wait_s / n, 1e3 * trigger_grab_s / n, 1e3 * store_s / n);
    return line;
  }
};

// Stand-in for the sequencer (capture-seq's, not yet in this branch): for each pattern, Show,
// wait the projector's latency, trigger every camera, grab, retry a bounded number of times on a
// frame that did not arrive intact, store.
CaptureStats CaptureSequence(Projector& projector, std::vector<std::unique_ptr<Camera>>& cameras,
                             const std::vector<std::string>& names, ImageSetWriter& writer) {
  CaptureStats stats;
  const auto t0 = Clock::now();
  for (int i = 0; i < projector.size(); ++i) {
    for (int attempt = 0;; ++attempt) {
      const auto t0 = Clock::now();
      const auto shown = projector.Show(i);
      std::this_thread::sleep_until(shown + projector.Latency());
      const auto t1 = Clock::now();
      for (auto& c : cameras) c->Trigger();
      std::vector<Frame> frames;
      for (auto& c : cameras) frames.push_back(c->Grab(milliseconds(3000)));
      const auto t2 = Clock::now();
      stats.show_s += std::chrono::duration<double>(shown - t0).count();
      stats.wait_s += std::chrono::duration<double>(t1 - shown).count();
      stats.trigger_grab_s += std::chrono::duration<double>(t2 - t1).count();
      bool ok = true;
      for (const Frame& f : frames) ok = ok && f.ok();
      if (ok) {
        for (size_t c = 0; c < cameras.size(); ++c) {
          writer.Add(names[c], i, frames[c].image, frames[c].exposure_us, ImageSource::kDevice);
        }
        stats.store_s += std::chrono::duration<double>(Clock::now() - t2).count();
        break;
      }
      if (attempt == 3) throw std::runtime_error("pattern " + std::to_string(i) + ": no intact frames after 4 attempts");
      ++stats.retries;
      for (auto& c : cameras) c->Flush();
    }
    ++stats.patterns;
  }
  stats.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  return stats;
}

// Everything of one closed-loop capture: scene, rig, patterns, the simulator's ImageSet (the
// oracle), the X server and the projector window, and two fake cameras rendering the screen.
class ClosedLoop : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::string reason = testing::SkipReasonWithoutPrivateNetwork();
    if (!reason.empty()) GTEST_SKIP() << reason;
    // SLSHADOW_CLOSED_LOOP_SCALE=1: the full demo resolution (for the benchmark); default 4.
    const char* scale = std::getenv("SLSHADOW_CLOSED_LOOP_SCALE");
    rig_ = ScaledDemoRig(scale ? std::atoi(scale) : 4);
    scene_ = std::make_unique<Scene>(LoadScene(fs::path(SLSHADOW_SOURCE_DIR) / "config/demo/scene.yaml"));
    spec_ = LoadPatternSpec(fs::path(SLSHADOW_SOURCE_DIR) / "config/patterns/graycode_phase.yaml");
    spec_.projector_width = rig_.projector->model.width;
    spec_.projector_height = rig_.projector->model.height;
    spec_.Check();
    patterns_ = GeneratePatterns(spec_);
    dir_ = TestDir(::testing::UnitTest::GetInstance()->current_test_info()->name());

    // The oracle: the simulator's own scan of the same scene (what `slshadow simulate` writes).
    SimulateOptions sim_options;
    sim_options.write_ground_truth = false;
    sim_options.writer.encoding = ImageEncoding::kPgm;
    SimulateScan(*scene_, rig_, patterns_, PatternSpecToJson(spec_), dir_ / "simulated", sim_options);

    // One wide X screen: a 640-pixel wide "monitor" on the left, the projector right of it.
    const int pw = rig_.projector->model.width, ph = rig_.projector->model.height;
    xvfb_ = std::make_unique<testing::XvfbServer>(640 + pw, std::max(480, ph));
    WindowProjectorOptions wopt;
    wopt.geometry = WindowGeometry{640, 0, pw, ph};
    window_ = std::make_unique<WindowProjector>(wopt);

    simulator_ = std::make_unique<Simulator>(*scene_, rig_, TraceMode::kPacket16, /*ground_truth=*/false);
    const std::vector<std::string> addresses = {"127.0.0.2", "127.0.0.3"};
    for (int c = 0; c < 2; ++c) {
      const auto k = static_cast<size_t>(c);
      devices_.push_back(std::make_unique<SimulatedCameraOnScreen>(*scene_, rig_, c, simulator_->geometry(c), addresses[k],
                                                                   cv::Rect(640, 0, pw, ph)));
      cameras_.push_back(OpenAravisCamera(AravisOpenOptions{.device = addresses[k]}));
      CameraSettings s;
      s.trigger = TriggerMode::kSoftware;
      s.roi = Roi{0, 0, rig_.cameras[k].model.width, rig_.cameras[k].model.height};
      cameras_.back()->Configure(s);
      names_.push_back(rig_.cameras[k].name);
    }
  }

  // Captures the pattern sequence through `projector` into dir_/name and returns the ImageSet.
  ImageSet Capture(Projector& projector, const std::string& name, CaptureStats* stats) {
    projector.Load(patterns_);
    ImageSetWriterOptions wo;
    wo.encoding = ImageEncoding::kPgm;
    ImageSetWriter writer(dir_ / name, rig_, PatternSpecToJson(spec_), wo);
    for (auto& c : cameras_) c->Start();
    *stats = CaptureSequence(projector, cameras_, names_, writer);
    for (auto& c : cameras_) c->Stop();
    writer.Commit();
    std::printf("  %s\n", stats->Breakdown().c_str());
    for (const auto& d : devices_) std::printf("  fake camera %s: %s\n", d->fake().serial().c_str(), d->FillReport().c_str());
    std::printf("closed loop (%s): %d patterns x 2 cameras (%dx%d, projector %dx%d, %.0f Hz, latency %.1f ms) in %.3f s: "
                "%.1f patterns/s, %d retries\n",
                name.c_str(), stats->patterns, rig_.cameras[0].model.width, rig_.cameras[0].model.height,
                rig_.projector->model.width, rig_.projector->model.height, projector.Info().refresh_hz,
                projector.Latency().count() / 1000.0, stats->seconds, stats->patterns / stats->seconds, stats->retries);
    return ImageSet::Open(dir_ / name);
  }

  // Images of `captured` that differ from the simulated ones (camera, pattern).
  int DifferingImages(const ImageSet& captured) {
    const ImageSet simulated = ImageSet::Open(dir_ / "simulated");
    EXPECT_EQ(captured.PatternCount(), static_cast<int>(patterns_.size()));
    int differing = 0;
    for (const std::string& camera : names_) {
      for (int i = 0; i < captured.PatternCount(); ++i) {
        const cv::Mat a = captured.Load(camera, i), b = simulated.Load(camera, i);
        differing += a.type() != b.type() || cv::norm(a, b, cv::NORM_INF) != 0;
      }
    }
    return differing;
  }

  LatencyMeasurement MeasureLatency(Projector& projector) {
    LatencyOptions lopt;
    lopt.repetitions = 2;
    lopt.max_latency = milliseconds(200);
    const LatencyMeasurement latency = MeasureProjectorLatency(*cameras_[0], projector, lopt);
    std::printf("closed loop latency (left camera): %s\n", latency.BriefReport().c_str());
    return latency;
  }

  Rig rig_;
  std::unique_ptr<Scene> scene_;
  PatternSpec spec_;
  std::vector<cv::Mat> patterns_;
  fs::path dir_;
  std::unique_ptr<testing::XvfbServer> xvfb_;
  std::unique_ptr<WindowProjector> window_;
  std::unique_ptr<Simulator> simulator_;
  std::vector<std::unique_ptr<SimulatedCameraOnScreen>> devices_;
  std::vector<std::unique_ptr<Camera>> cameras_;  // destroyed before the fake cameras
  std::vector<std::string> names_;

  void TearDown() override {
    cameras_.clear();
    devices_.clear();
    window_.reset();
    xvfb_.reset();
  }
};

// Stereo capture with the measured latency: every image equals the simulation pixel for pixel,
// and so do the reconstructions (projector mode and stereo mode).
TEST_F(ClosedLoop, CaptureThroughXAndGigEVisionEqualsSimulation) {
  window_->SetLatency(MeasureLatency(*window_).latency);
  CaptureStats stats;
  const ImageSet captured = Capture(*window_, "captured", &stats);
  EXPECT_EQ(DifferingImages(captured), 0);
  const ImageSet simulated = ImageSet::Open(dir_ / "simulated");
  for (ReconstructMode mode : {ReconstructMode::kProjector, ReconstructMode::kStereo}) {
    ImageSetReconstructOptions ro;
    ro.mode = mode;
    const PointCloud a = ReconstructImageSet(captured, ro).cloud;
    const PointCloud b = ReconstructImageSet(simulated, ro).cloud;
    ASSERT_GT(a.size(), 1000u) << ToString(mode);
    ASSERT_EQ(a.size(), b.size()) << ToString(mode);
    size_t differing = 0;
    for (size_t k = 0; k < a.size(); ++k) differing += a.points[k] != b.points[k];
    EXPECT_EQ(differing, 0u) << ToString(mode);
    std::printf("reconstruction (%s): %zu points, %zu differ\n", ToString(mode), a.size(), differing);
  }
}

// The oracle sees the classic real-rig failure: a projector whose light comes 40 ms after Show
// returns, driven with latency 0, gives frames of the previous pattern, and the images differ from
// the simulation. The latency measured through the same loop is printed and positive: it is the
// wait before the trigger, so the fake camera's own trigger delay (its 1 kHz polling, GVCP) comes
// off the 40 ms, and only a trigger delay above 40 ms could make it 0.
TEST_F(ClosedLoop, StaleFramesAreSeenAndTheLatencyIsMeasured) {
  testing::DelayedProjector slow(*window_, milliseconds(40));
  slow.SetLatency(std::chrono::microseconds(0));
  CaptureStats stats;
  const int stale = DifferingImages(Capture(slow, "latency_0", &stats));
  std::printf("latency 0 with a 40 ms display: %d of %d images differ from the simulation\n", stale,
              2 * static_cast<int>(patterns_.size()));
  EXPECT_GT(stale, 0);
  EXPECT_GT(MeasureLatency(slow).latency.count(), 0);
}

}  // namespace
}  // namespace slshadow::capture

int main(int argc, char** argv) {
  slshadow::testing::RunInPrivateNetwork(argc, argv);
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
