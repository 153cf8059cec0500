// Soak: 10 000 patterns, stereo, through the real sequencer and writer, with a test projector
// whose latency is sometimes longer than the sequencer assumes (its frames then show the
// previous pattern) and test cameras that drop frames and deliver some late. Oracle: each test
// camera's own record of what was on screen when it took a frame. Fixed seeds.
#include <random>

#include <gtest/gtest.h>

#include "capture/sequencer.h"
#include "patterns/codec.h"
#include "tests/capture/test_devices.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::capture {
namespace {
namespace fs = std::filesystem;

TEST(SequencerSoak, TenThousandPatternsNoFrameUnderTheWrongPatternEveryDropAccountedFor) {
  slshadow::testing::TempDir dir;
  Rig rig;
  rig.name = "soak";
  rig.cameras.push_back({"left", CameraModel(64, 48, 60, 60, 31.5, 23.5), Rigid3d()});
  rig.cameras.push_back({"right", CameraModel(64, 48, 60, 60, 31.5, 23.5),
                         Rigid3d(Eigen::Quaterniond::Identity(), {-80, 0, 0})});
  rig.projector = RigDevice{"projector", CameraModel(64, 32, 50, 50, 31.5, 15.5), Rigid3d()};
  PatternSpec spec;
  spec.kind = PatternKind::kGrayCode;
  spec.projector_width = 64;
  spec.projector_height = 32;
  const auto patterns = GeneratePatterns(spec);

  doubles::TestProjector projector(64, 32);
  // 5 % of pattern switches take 30 ms although the sequencer waits 0 (it learns of it only from
  // the frames); a fixed hash of the switch number, so the run is reproducible.
  int64_t slow_switches = 0, last_request = -1;
  projector.latency_for = [&](int) {
    const uint64_t h = static_cast<uint64_t>(projector.requests()) * 0x9E3779B97F4A7C15ull;
    const bool slow = (h >> 40) % 100 < 5;
    if (slow && projector.requests() != last_request) {
      ++slow_switches;
      last_request = projector.requests();
    }
    return std::chrono::microseconds(slow ? 30000 : 0);
  };
  doubles::TestCameraOptions lo, ro;
  lo.noise = ro.noise = 2;
  lo.seed = 11;
  ro.seed = 12;
  ro.serial = "TEST-1";
  ro.gain = 0.8;
  ro.offset = 12;
  ro.first_frame_id = 65000;
  lo.drop_probability = ro.drop_probability = 0.005;
  lo.late_probability = ro.late_probability = 0.005;
  doubles::TestCamera left(projector, lo), right(projector, ro);
  const std::vector<CaptureCamera> cameras = {{"left", &left, {}, std::chrono::milliseconds(50)},
                                              {"right", &right, {}, std::chrono::milliseconds(50)}};
  SequencerOptions options;
  options.progress = false;
  options.sleep_until = projector.Sleeper();
  options.retry_backoff = std::chrono::milliseconds(20);
  options.max_retries = 5;
  options.writer.encoding = ImageEncoding::kPgm;
  options.writer.durable = false;

  const int kPatterns = 10000;
  int captured = 0, captures = 0, wrong = 0, retries = 0;
  // Frame ids are compared within one capture run: frames lost before a run's first grabbed
  // frame leave no gap in it (they are timeouts all the same).
  std::map<const doubles::TestCamera*, int64_t> lost_before_first;
  std::map<std::string, CameraCaptureStats> total;
  while (captured < kPatterns) {
    const fs::path out = dir / ("set" + std::to_string(captures++));
    std::map<const doubles::TestCamera*, int64_t> start;
    for (const auto* cam : {&left, &right}) start[cam] = cam->triggers();
    const CaptureSummary s = Capture(rig, spec, cameras, projector, out, options);
    ASSERT_TRUE(s.complete);
    for (const auto* cam : {&left, &right}) {
      for (int64_t t = start[cam]; cam->lost_triggers().count(t); ++t) ++lost_before_first[cam];
    }
    retries += s.retries;
    const ImageSet set = ImageSet::Open(out);
    for (const auto& r : set.records()) {
      const doubles::TestCamera& cam = r.camera == "left" ? left : right;
      const int shown = cam.ShownFor(*r.frame_id);
      wrong += shown != r.pattern_index;
      ASSERT_LE(
          cv::norm(set.Load(r.camera, r.pattern_index),
                   cam.RenderClean(patterns[static_cast<size_t>(r.pattern_index)]), cv::NORM_INF),
          2.5)
          << r.camera << " pattern " << r.pattern_index << " (showed " << shown << ")";
    }
    for (const auto& [name, c] : s.cameras) {
      CameraCaptureStats& t = total[name];
      t.timeouts += c.timeouts;
      t.missing_frame_ids += c.missing_frame_ids;
      t.stale += c.stale;
      t.not_complementary += c.not_complementary;
      t.frames_stored += c.frames_stored;
    }
    captured += s.patterns;
    fs::remove_all(out);
  }
  std::printf(
      "soak: %d patterns in %d captures, %d retries, %lld slow switches; left: %lld dropped, %lld "
      "late, "
      "%lld timeouts, %lld missing ids, %lld stale, %lld not complementary; right: %lld dropped, "
      "%lld late, "
      "%lld timeouts, %lld missing ids, %lld stale, %lld not complementary\n",
      captured, captures, retries, static_cast<long long>(slow_switches),
      static_cast<long long>(left.dropped()), static_cast<long long>(left.late()),
      static_cast<long long>(total["left"].timeouts),
      static_cast<long long>(total["left"].missing_frame_ids),
      static_cast<long long>(total["left"].stale),
      static_cast<long long>(total["left"].not_complementary),
      static_cast<long long>(right.dropped()), static_cast<long long>(right.late()),
      static_cast<long long>(total["right"].timeouts),
      static_cast<long long>(total["right"].missing_frame_ids),
      static_cast<long long>(total["right"].stale),
      static_cast<long long>(total["right"].not_complementary));
  EXPECT_EQ(wrong, 0);
  EXPECT_GE(captured, kPatterns);
  // The faults really happened...
  EXPECT_GT(slow_switches, 100);
  EXPECT_GT(left.dropped() + right.dropped(), 50);
  EXPECT_GT(left.late() + right.late(), 50);
  // ... and every one is accounted for: each drop and each late frame was a timeout, and each is a
  // frame id never grabbed (a late frame is flushed before the retry).
  for (const auto* cam : {&left, &right}) {
    const CameraCaptureStats& t = total[cam == &left ? "left" : "right"];
    EXPECT_EQ(t.timeouts, cam->dropped() + cam->late());
    EXPECT_EQ(t.missing_frame_ids + lost_before_first[cam], cam->dropped() + cam->flushed());
    EXPECT_EQ(cam->flushed(), cam->late());
    EXPECT_EQ(t.frames_stored, captured);
  }
  EXPECT_GT(total["left"].stale + total["left"].not_complementary, 0);
}

}  // namespace
}  // namespace slshadow::capture
