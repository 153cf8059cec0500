// No false alarm on realistic frames: the demo rig's simulated scan with every optical and sensor
// layer on (config/scenes/layers_all.yaml: projector gamma 2.2, defocus, vignetting, ambient
// light, shot and read noise, 12-bit data in 16-bit images) of the demo's phase-shift + Gray-code
// sequence, replayed through the sequencer with validation on (stale checks, the phase-step fit of
// the first period, Gray pair complementarity): every frame accepted at the first attempt, stored
// bit for bit.
#include <gtest/gtest.h>

#include "capture/replay_camera.h"
#include "capture/sequencer.h"
#include "patterns/codec.h"
#include "sim/scene.h"
#include "sim/simulate.h"
#include "tests/capture/test_devices.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::capture {
namespace {

TEST(ReplaySimulated, AllLayersDemoScanPassesValidationWithoutRetries) {
  slshadow::testing::TempDir dir;
  const auto src = slshadow::testing::SourceDir();
  const Rig rig = LoadRig(src / "config/demo/rig.yaml");
  const PatternSpec spec = LoadPatternSpec(src / "config/demo/patterns.yaml");
  SimulateOptions sim;
  sim.writer.encoding = ImageEncoding::kPgm;
  sim.write_ground_truth = false;
  SimulateScan(LoadScene(src / "config/scenes/layers_all.yaml"), rig, GeneratePatterns(spec),
               PatternSpecToJson(spec), dir / "scan", sim);

  doubles::TestProjector projector(spec.projector_width, spec.projector_height);
  ReplayCamera left(dir / "scan", ReplayCameraOptions{"left", 1, ""});
  ReplayCamera right(dir / "scan", ReplayCameraOptions{"right", 1, ""});
  CameraSettings sixteen;
  sixteen.pixel_format = PixelFormat::kMono12;
  SequencerOptions options;
  options.progress = false;
  options.sleep_until = projector.Sleeper();
  options.writer.encoding = ImageEncoding::kPgm;
  options.writer.durable = false;
  const CaptureSummary s = Capture(rig, spec,
                                   {{"left", &left, sixteen, std::chrono::milliseconds(100)},
                                    {"right", &right, sixteen, std::chrono::milliseconds(100)}},
                                   projector, dir / "replayed", options);
  ASSERT_TRUE(s.complete);
  EXPECT_EQ(s.retries, 0);
  for (const auto& [name, c] : s.cameras) {
    std::printf("%s: %lld Gray pair checks, lowest complementary share %.4f\n", name.c_str(),
                static_cast<long long>(c.pair_checks), c.min_complementary_share);
    EXPECT_EQ(c.stale + c.not_complementary, 0) << name;
    EXPECT_EQ(c.pair_checks, spec.GrayBits(0) + spec.GrayBits(1)) << name;  // every pair was judged
  }
  const ImageSet scan = ImageSet::Open(dir / "scan"), replayed = ImageSet::Open(dir / "replayed");
  for (const auto& r : scan.records()) {
    EXPECT_EQ(cv::norm(scan.Load(r.camera, r.pattern_index),
                       replayed.Load(r.camera, r.pattern_index), cv::NORM_INF),
              0.0)
        << r.camera << " " << r.pattern_index;
  }
}

}  // namespace
}  // namespace slshadow::capture
