// The sequencer with test cameras that render what a test projector shows (tests/capture/
// test_devices.h): every stored frame is the one of its pattern (the camera's own record of what
// was on screen is the oracle), a lagging projector is caught and retried or failed with the
// pattern and camera named, drops and late frames are accounted for, frame ids that wrap are not
// drops, a capture stopped or failed at any point resumes to the same records and bytes as an
// uninterrupted one, and the exposure assistant puts the brightest lit pixels below saturation.
#include "capture/sequencer.h"

#include <atomic>
#include <cstdio>
#include <sstream>

#include <gtest/gtest.h>

#include "capture/none_projector.h"
#include "core/error.h"
#include "core/file_util.h"
#include "patterns/codec.h"
#include "tests/capture/test_devices.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::capture {
namespace {
namespace fs = std::filesystem;
using doubles::TestCamera;
using doubles::TestCameraOptions;
using doubles::TestProjector;

Rig StereoRig() {
  Rig rig;
  rig.name = "stereo";
  rig.cameras.push_back({"left", CameraModel(64, 48, 60, 60, 31.5, 23.5), Rigid3d()});
  rig.cameras.push_back({"right", CameraModel(64, 48, 60, 60, 31.5, 23.5),
                         Rigid3d(Eigen::Quaterniond::Identity(), {-80, 0, 0})});
  rig.projector = RigDevice{"projector", CameraModel(64, 32, 50, 50, 31.5, 15.5), Rigid3d()};
  return rig;
}

PatternSpec GraySpec() {
  PatternSpec spec;
  spec.kind = PatternKind::kGrayCode;
  spec.projector_width = 64;
  spec.projector_height = 32;
  return spec;  // white, black, 6 column pairs, 5 row pairs: 24 images
}

PatternSpec PhaseSpec() {
  PatternSpec spec;
  spec.kind = PatternKind::kPhaseShift;
  spec.projector_width = 64;
  spec.projector_height = 32;
  spec.period_px = 8;
  return spec;
}

struct Stereo {
  TestProjector projector{64, 32};
  TestCamera left, right;
  std::vector<CaptureCamera> cameras;
  explicit Stereo(TestCameraOptions l = {}, TestCameraOptions r = Right())
      : left(projector, l), right(projector, r) {
    cameras = {{"left", &left, {}, std::chrono::milliseconds(100)},
               {"right", &right, {}, std::chrono::milliseconds(100)}};
  }
  static TestCameraOptions Right() {
    TestCameraOptions o;
    o.serial = "TEST-1";
    o.gain = 0.8;
    o.offset = 12;
    o.seed = 2;
    return o;
  }
  TestCamera& Camera(const std::string& name) { return name == "left" ? left : right; }
};

SequencerOptions Options(TestProjector& projector) {
  SequencerOptions o;
  o.progress = false;
  o.sleep_until = projector.Sleeper();
  o.retry_backoff = std::chrono::milliseconds(20);
  o.writer.encoding = ImageEncoding::kPgm;
  o.writer.durable = false;
  return o;
}

// Every stored frame was taken while its pattern was on screen, and equals the clean render of it
// (within the noise).
void ExpectEveryFrameOfItsPattern(const fs::path& dir, Stereo& rig, const PatternSpec& spec,
                                  double noise = 0) {
  const ImageSet set = ImageSet::Open(dir);
  const auto patterns = GeneratePatterns(spec);
  ASSERT_EQ(set.records().size(), 2 * patterns.size());
  for (const auto& r : set.records()) {
    TestCamera& cam = rig.Camera(r.camera);
    ASSERT_TRUE(r.frame_id.has_value());
    EXPECT_EQ(cam.ShownFor(*r.frame_id), r.pattern_index)
        << r.camera << " pattern " << r.pattern_index;
    const cv::Mat clean = cam.RenderClean(patterns[static_cast<size_t>(r.pattern_index)]);
    EXPECT_LE(cv::norm(set.Load(r.camera, r.pattern_index), clean, cv::NORM_INF), noise + 0.5)
        << r.camera << " pattern " << r.pattern_index;
  }
}

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(FrameIdTracker, WrapIsNotADropAndGapsAreCounted) {
  FrameIdTracker t;
  for (uint64_t id : {65533u, 65534u, 65535u, 1u, 2u}) EXPECT_EQ(t.Next(id), 0) << id;
  EXPECT_EQ(t.missing(), 0);
  EXPECT_EQ(t.Next(4), 1);          // 3 missing
  EXPECT_EQ(t.Next(65534), 65529);  // 5..65533 missing (a long outage)
  EXPECT_EQ(t.Next(2), 2);          // 65535 and 1 missing across the wrap
  EXPECT_EQ(t.Next(0), 0);          // invalid id
  EXPECT_EQ(t.invalid(), 1);
  EXPECT_EQ(t.missing(), 1 + 65529 + 2);
  FrameIdTracker wide;  // 64-bit ids (USB3 Vision) count up without wrapping
  wide.Next(70000);
  EXPECT_EQ(wide.Next(70003), 2);
}

TEST(Sequencer, StereoCaptureStoresEveryFrameUnderItsPatternWithProvenance) {
  slshadow::testing::TempDir dir;
  TestCameraOptions l;
  l.first_frame_id = 65530;  // wraps within the capture
  Stereo rig(l);
  const CaptureSummary s = Capture(StereoRig(), GraySpec(), rig.cameras, rig.projector, dir / "set",
                                   Options(rig.projector));
  EXPECT_TRUE(s.complete);
  EXPECT_EQ(s.images_total, 48);
  EXPECT_EQ(s.images_stored, 48);
  EXPECT_EQ(s.retries, 0);
  for (const auto& name : {"left", "right"}) {
    const CameraCaptureStats& c = s.cameras.at(name);
    EXPECT_EQ(c.frames_grabbed, 24);
    EXPECT_EQ(c.missing_frame_ids, 0) << name;  // 65535 -> 1 is not a drop
    EXPECT_EQ(c.stale + c.not_complementary + c.timeouts + c.damaged, 0);
  }
  ExpectEveryFrameOfItsPattern(dir / "set", rig, GraySpec());
  const ImageSet set = ImageSet::Open(dir / "set");
  const ImageRecord* r = set.Find("left", 6);
  EXPECT_EQ(r->device_serial, "TEST-0");
  EXPECT_EQ(r->frame_id, 1u);  // 65530 + 6 wrapped
  EXPECT_EQ(r->retries, 0);
  EXPECT_EQ(set.Find("right", 0)->device_serial, "TEST-1");
  EXPECT_EQ(set.extra()["capture"]["sessions"].size(), 2u);  // start and end note
  EXPECT_EQ(set.extra()["capture"]["sessions"][1]["cameras"]["left"]["frames_stored"], 24);
  // The end note, written just before the commit, says the session ended with every image.
  EXPECT_EQ(set.extra()["capture"]["sessions"][1]["complete"], true);
  EXPECT_TRUE(s.validated);
  EXPECT_NE(s.BriefReport().find("0 stale, 0 not complementary"), std::string::npos);
}

// No projector shows the patterns: a coded capture with live cameras is refused before anything
// is staged, unless validation is switched off; then the report prints no counters of checks that
// did not run, and the manifest says validate: false.
TEST(Sequencer, NoProjectorRefusesAValidatedCaptureAndReportsNoChecksWithout) {
  slshadow::testing::TempDir dir;
  Stereo rig;
  NoneProjector none;
  SequencerOptions o = Options(rig.projector);
  const std::string error =
      ErrorOf([&] { Capture(StereoRig(), GraySpec(), rig.cameras, none, dir / "set", o); });
  EXPECT_NE(error.find("projector (backend 'none') shows none of the pattern spec's 24 patterns"),
            std::string::npos)
      << error;
  EXPECT_NE(error.find("--no-validate"), std::string::npos) << error;
  EXPECT_FALSE(fs::exists(dir / "set"));
  EXPECT_FALSE(fs::exists(dir / "set.partial"));

  // The test cameras film what their test projector shows: one grey still for the whole capture,
  // as an Aravis fake camera shows one image.
  rig.projector.Load({cv::Mat(32, 64, CV_8UC1, cv::Scalar(128))});
  rig.projector.Show(0);
  o.validate = false;
  const CaptureSummary s = Capture(StereoRig(), GraySpec(), rig.cameras, none, dir / "set", o);
  ASSERT_TRUE(s.complete);
  EXPECT_FALSE(s.validated);
  const std::string report = s.BriefReport();
  EXPECT_EQ(report.find("stale"), std::string::npos) << report;
  EXPECT_EQ(report.find("complementary"), std::string::npos) << report;
  EXPECT_NE(report.find("frames not checked against the patterns"), std::string::npos) << report;
  EXPECT_NE(report.find("complete: 48 of 48 images"), std::string::npos) << report;
  const ImageSet set = ImageSet::Open(dir / "set");
  EXPECT_EQ(set.records().size(), 48u);
  const nlohmann::json& sessions = set.extra()["capture"]["sessions"];
  ASSERT_EQ(sessions.size(), 2u);
  EXPECT_EQ(sessions[0]["validate"], false);
  EXPECT_EQ(sessions[1]["validated"], false);
  EXPECT_EQ(sessions[1]["complete"], true);
}

TEST(Sequencer, LaggingProjectorIsCaughtAndRetriedGrayAndPhase) {
  for (const PatternSpec& spec : {GraySpec(), PhaseSpec()}) {
    SCOPED_TRACE(ToString(spec.kind));
    slshadow::testing::TempDir dir;
    Stereo rig;
    rig.projector.true_latency = std::chrono::milliseconds(30);  // the sequencer assumes 0
    const CaptureSummary s =
        Capture(StereoRig(), spec, rig.cameras, rig.projector, dir / "set", Options(rig.projector));
    EXPECT_TRUE(s.complete);
    ExpectEveryFrameOfItsPattern(dir / "set", rig, spec);
    EXPECT_GT(s.retries, 0);
    EXPECT_GT(s.cameras.at("left").stale + s.cameras.at("left").not_complementary, 0);
    const ImageSet set = ImageSet::Open(dir / "set");
    int retried = 0;
    for (const auto& r : set.records()) retried += r.retries.value_or(0) > 0;
    EXPECT_GT(retried, 0);
  }
}

// The closed-loop late-projector scenario without X (tests/capture/closed_loop_test.cc
// LateProjectorNeverStoresAWrongFrame): every Show reaches the screen 40 ms after it returns,
// the sequencer is told 0, and the display queues Shows like a real one (a re-Show while another
// is pending brings the older pattern back first). Every stored frame must be of its pattern; the
// capture learns the latency (>= 40 ms, in the manifest) and stops queueing Shows.
TEST(Sequencer, LateDisplayThatQueuesShowsNeverStoresAWrongFrame) {
  for (const PatternSpec& spec : {GraySpec(), PhaseSpec()})
    for (const double noise : {0.0, 2.0}) {
      SCOPED_TRACE(::testing::Message() << ToString(spec.kind) << ", noise " << noise);
      slshadow::testing::TempDir dir;
      TestCameraOptions l, r = Stereo::Right();
      l.noise = r.noise = noise;
      Stereo rig(l, r);
      rig.projector.true_latency = std::chrono::milliseconds(40);  // the sequencer assumes 0
      SequencerOptions o = Options(rig.projector);
      o.max_retries = 8;
      const CaptureSummary s =
          Capture(StereoRig(), spec, rig.cameras, rig.projector, dir / "set", o);
      EXPECT_TRUE(s.complete);
      ExpectEveryFrameOfItsPattern(dir / "set", rig, spec, noise);
      EXPECT_GT(s.retries, 0);
      EXPECT_GE(s.learned_latency_us, 40000);
      EXPECT_LE(s.learned_latency_us, 40000 + 8 * 20000);
      const ImageSet set = ImageSet::Open(dir / "set");
      EXPECT_EQ(set.extra()["capture"]["learned_latency_us"].get<double>(), s.learned_latency_us);
      std::printf(
          "%s, noise %.0f: %d retries, learned latency %.0f ms, at most %d Shows pending at once\n",
          ToString(spec.kind).c_str(), noise, s.retries, s.learned_latency_us / 1000,
          rig.projector.max_pending());
    }
}

TEST(Sequencer, StaleFramesAtEveryPatternAreCaughtWithNoise) {
  // One pattern at a time is late: whichever it is, nothing is stored under the wrong pattern.
  for (const PatternSpec& spec : {GraySpec(), PhaseSpec()})
    for (int lagging = 0; lagging < spec.NumImages(); ++lagging) {
      SCOPED_TRACE(::testing::Message() << ToString(spec.kind) << ", lagging pattern " << lagging);
      slshadow::testing::TempDir dir;
      TestCameraOptions l, r = Stereo::Right();
      l.noise = r.noise = 2;
      Stereo rig(l, r);
      rig.projector.latency_for = [&](int index) {
        return std::chrono::microseconds(index == lagging ? 30000 : 0);
      };
      const CaptureSummary s = Capture(StereoRig(), spec, rig.cameras, rig.projector, dir / "set",
                                       Options(rig.projector));
      EXPECT_TRUE(s.complete);
      ExpectEveryFrameOfItsPattern(dir / "set", rig, spec, 2);
    }
}

TEST(Sequencer, StaleFramesAreCaughtWhenWhiteAndBlackComeLast) {
  // OpenCV order: the references come last, so a stale frame after a coarse pattern change is
  // only found when the pairs are judged against them at the end, and taken again.
  PatternSpec spec = GraySpec();
  spec.opencv_order = true;
  for (int lagging = 0; lagging < spec.NumImages(); ++lagging) {
    SCOPED_TRACE(::testing::Message() << "lagging pattern " << lagging);
    slshadow::testing::TempDir dir;
    TestCameraOptions l, r = Stereo::Right();
    l.noise = r.noise = 2;
    Stereo rig(l, r);
    rig.projector.latency_for = [&](int index) {
      return std::chrono::microseconds(index == lagging ? 30000 : 0);
    };
    const CaptureSummary s =
        Capture(StereoRig(), spec, rig.cameras, rig.projector, dir / "set", Options(rig.projector));
    EXPECT_TRUE(s.complete);
    EXPECT_GT(s.retries, 0);
    ExpectEveryFrameOfItsPattern(dir / "set", rig, spec, 2);
  }
}

TEST(Sequencer, ProjectorThatNeverSwitchesFailsNamingPatternAndCameraThenResumes) {
  slshadow::testing::TempDir dir;
  const fs::path out = dir / "set";
  {
    Stereo rig;
    rig.projector.latency_for = [](int index) {
      return std::chrono::microseconds(index == 9 ? 3600000000ll : 0);
    };
    const std::string e = ErrorOf([&] {
      Capture(StereoRig(), GraySpec(), rig.cameras, rig.projector, out, Options(rig.projector));
    });
    EXPECT_NE(e.find("capture failed after 4 attempts: pattern 9 (gray_x_bit2_inv), camera 'left': "
                     "frame nearly equal "
                     "to pattern 8 (gray_x_bit2)"),
              std::string::npos)
        << e;
    EXPECT_NE(e.find("camera 'right'"), std::string::npos) << e;
    EXPECT_NE(e.find("continue with --resume"), std::string::npos) << e;
  }
  EXPECT_TRUE(fs::exists(ResumableImageSetWriter::StagingDirFor(out)));
  Stereo rig;
  SequencerOptions o = Options(rig.projector);
  o.writer.resume = true;
  const CaptureSummary s = Capture(StereoRig(), GraySpec(), rig.cameras, rig.projector, out, o);
  EXPECT_TRUE(s.complete);
  EXPECT_TRUE(s.resumed);
  EXPECT_EQ(s.images_before, 16);  // patterns 0..7 of both cameras
  EXPECT_EQ(s.images_stored, 32);
}

TEST(Sequencer, DropsAndLateFramesAreRetriedAndAccountedFor) {
  slshadow::testing::TempDir dir;
  TestCameraOptions l, r = Stereo::Right();
  l.drop_triggers = {3, 10};
  l.late_triggers = {6};
  r.drop_triggers = {10, 17};
  Stereo rig(l, r);
  const CaptureSummary s = Capture(StereoRig(), GraySpec(), rig.cameras, rig.projector, dir / "set",
                                   Options(rig.projector));
  EXPECT_TRUE(s.complete);
  ExpectEveryFrameOfItsPattern(dir / "set", rig, GraySpec());
  EXPECT_EQ(s.cameras.at("left").timeouts, 3);
  EXPECT_EQ(s.cameras.at("right").timeouts, 2);
  // Every drop and every late (flushed) frame is an id never grabbed; the other camera's frames of
  // a retried round are grabbed, so they leave no gap.
  EXPECT_EQ(s.cameras.at("left").missing_frame_ids, rig.left.dropped() + rig.left.flushed());
  EXPECT_EQ(rig.left.dropped() + rig.left.flushed(), 3);
  EXPECT_EQ(s.cameras.at("right").missing_frame_ids, 2);
  EXPECT_EQ(s.retries, 4);  // rounds 3, 6, 10 (both), 17
}

// Interrupt (stop flag, a lost camera) at several points; the resumed capture equals an
// uninterrupted one record for record and byte for byte.
TEST(Sequencer, ResumeAfterInterruptionEqualsUninterruptedCapture) {
  slshadow::testing::TempDir dir;
  const auto options = [](TestProjector& projector, bool resume) {
    SequencerOptions o = Options(projector);
    o.writer.encoding = ImageEncoding::kPng;
    o.writer.durable = true;
    o.writer.resume = resume;
    return o;
  };
  const auto deterministic = [](TestCameraOptions o) {
    o.ids_follow_pattern = true;
    o.noise = 2;
    return o;
  };
  {
    Stereo rig(deterministic({}), deterministic(Stereo::Right()));
    ASSERT_TRUE(Capture(StereoRig(), GraySpec(), rig.cameras, rig.projector, dir / "reference",
                        options(rig.projector, false))
                    .complete);
  }
  const ImageSet reference = ImageSet::Open(dir / "reference");
  for (int stop_after : {1, 2, 3, 7, 16, 23}) {
    for (bool lost_camera : {false, true}) {
      SCOPED_TRACE(::testing::Message() << "after " << stop_after << " trigger rounds, "
                                        << (lost_camera ? "lost camera" : "stop"));
      const fs::path out =
          dir / ("set" + std::to_string(stop_after) + (lost_camera ? "lost" : "stop"));
      {
        std::atomic<bool> stop{false};
        TestCameraOptions r = deterministic(Stereo::Right());
        if (lost_camera) r.abort_after_triggers = stop_after;
        Stereo rig(deterministic({}), r);
        rig.left.on_trigger = [&](int64_t n) {
          if (!lost_camera && n == stop_after) stop = true;
        };
        SequencerOptions o = options(rig.projector, false);
        o.stop = &stop;
        if (lost_camera) {
          EXPECT_NE(ErrorOf([&] {
                      Capture(StereoRig(), GraySpec(), rig.cameras, rig.projector, out, o);
                    }).find("camera 'right': frame aborted (device lost)"),
                    std::string::npos);
        } else {
          const CaptureSummary s =
              Capture(StereoRig(), GraySpec(), rig.cameras, rig.projector, out, o);
          EXPECT_TRUE(s.interrupted);
          EXPECT_FALSE(s.complete);
        }
      }
      EXPECT_FALSE(fs::exists(out));
      Stereo rig(deterministic({}), deterministic(Stereo::Right()));
      const CaptureSummary s = Capture(StereoRig(), GraySpec(), rig.cameras, rig.projector, out,
                                       options(rig.projector, true));
      ASSERT_TRUE(s.complete);
      EXPECT_GT(s.images_stored, 0);
      const ImageSet set = ImageSet::Open(out);
      ASSERT_EQ(set.records().size(), reference.records().size());
      for (size_t i = 0; i < set.records().size(); ++i) {
        EXPECT_EQ(set.records()[i], reference.records()[i]) << i;
        EXPECT_EQ(ReadTextFile(out / set.records()[i].file),
                  ReadTextFile(dir / "reference" / reference.records()[i].file));
      }
      EXPECT_EQ(set.extra()["capture"]["sessions"].size(),
                4u);  // two runs, a start and an end note each
    }
  }
}

TEST(Sequencer, AutoExposurePutsTheBrightestLitPixelsBelowSaturation) {
  for (bool sixteen : {false, true}) {
    SCOPED_TRACE(sixteen ? "Mono16" : "Mono8");
    slshadow::testing::TempDir dir;
    TestCameraOptions l, r = Stereo::Right();
    l.gain = 3.0;  // saturated at the starting 10 ms: 8 + 3 x 255
    r.gain = 0.2;  // dim: 12 + 0.2 x 255
    l.sixteen_bit = r.sixteen_bit = sixteen;
    Stereo rig(l, r);
    for (auto& c : rig.cameras)
      c.settings.pixel_format = sixteen ? PixelFormat::kMono16 : PixelFormat::kMono8;
    SequencerOptions o = Options(rig.projector);
    o.auto_exposure = true;
    const CaptureSummary s =
        Capture(StereoRig(), GraySpec(), rig.cameras, rig.projector, dir / "set", o);
    ASSERT_TRUE(s.complete);
    const ImageSet set = ImageSet::Open(dir / "set");
    const double full = sixteen ? 65535 : 255;
    for (const auto& name : {"left", "right"}) {
      const double chosen = s.auto_exposure_us.at(name);
      EXPECT_EQ(set.extra()["capture"]["auto_exposure_us"][name].get<double>(), chosen);
      EXPECT_EQ(set.Find(name, 0)->exposure_us, chosen);
      double hi = 0;
      cv::minMaxLoc(set.Load(name, 0), nullptr, &hi);  // the white frame: uniformly lit
      EXPECT_GE(hi / full, 0.85 - 0.08 - 0.01) << name << " exposure " << chosen;
      EXPECT_LE(hi / full, 0.85 + 0.08 + 0.01) << name << " exposure " << chosen;
    }
  }
}

TEST(Sequencer, PosesGoToTheLayoutCalibrateRigReads) {
  slshadow::testing::TempDir dir;
  Stereo rig;
  std::istringstream enter("\n\n\n");
  std::ostringstream prompt;
  const PosesSummary s = CapturePoses(StereoRig(), GraySpec(), rig.cameras, rig.projector,
                                      dir / "poses", 3, Options(rig.projector), enter, prompt);
  EXPECT_FALSE(s.interrupted);
  ASSERT_EQ(s.poses.size(), 3u);
  for (int p = 0; p < 3; ++p) {
    EXPECT_EQ(ImageSet::Open(PoseDir(dir / "poses", p)).records().size(), 48u);
  }
  EXPECT_NE(prompt.str().find("pose 3 of 3: place the board, then press Enter"), std::string::npos);
  // Run again with more poses: the three complete ones are skipped; end of input stops cleanly.
  std::istringstream one("\n");
  const PosesSummary again = CapturePoses(StereoRig(), GraySpec(), rig.cameras, rig.projector,
                                          dir / "poses", 5, Options(rig.projector), one, prompt);
  EXPECT_EQ(again.skipped, 3);
  EXPECT_EQ(again.poses.size(), 1u);
  EXPECT_TRUE(again.interrupted);
  EXPECT_TRUE(fs::exists(PoseDir(dir / "poses", 3) / "manifest.json"));
}

TEST(Sequencer, BadArgumentsAreNamed) {
  slshadow::testing::TempDir dir;
  Stereo rig;
  auto cams = rig.cameras;
  cams[1].name = "centre";
  EXPECT_NE(ErrorOf([&] {
              Capture(StereoRig(), GraySpec(), cams, rig.projector, dir / "a",
                      Options(rig.projector));
            }).find("the rig 'stereo' has no camera 'centre'"),
            std::string::npos);
  SequencerOptions o = Options(rig.projector);
  o.max_retries = -1;
  EXPECT_NE(ErrorOf([&] {
              Capture(StereoRig(), GraySpec(), rig.cameras, rig.projector, dir / "b", o);
            }).find("max_retries"),
            std::string::npos);
  // A camera delivering another size than the rig says is damaged, retried, then named.
  TestCameraOptions small;
  small.width = 32;
  Stereo wrong(small);
  EXPECT_NE(ErrorOf([&] {
              Capture(StereoRig(), GraySpec(), wrong.cameras, wrong.projector, dir / "c",
                      Options(wrong.projector));
            })
                .find("pattern 0 (white), camera 'left': frame of 32x48, 8-bit; the rig camera is "
                      "64x48, Mono8"),
            std::string::npos);
}

}  // namespace
}  // namespace slshadow::capture
