// capture::CapturePatternSequence's matching rules, deterministic: a scripted projector (the
// device's clock) and scripted hardware-triggered cameras whose frames carry exactly the
// timestamps a run would give them, with the faults placed where a test wants them: a missed
// trigger, a frame lost in transport, a missing first frame that cannot be placed, a late first
// frame that the count anchors, a spurious trigger, a damaged frame, and a rerun that completes the
// set. Oracle: the pattern the error names, and which patterns (from which run) were stored.
// The timing-dependent whole loop is tests/capture/pattern_sequence_capture_test.cc.
#include "capture/pattern_sequence_capture.h"

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/error.h"
#include "core/image_set.h"
#include "patterns/pattern_spec.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::capture {
namespace {

namespace fs = std::filesystem;
using std::chrono::milliseconds;
using SysClock = std::chrono::system_clock;
constexpr auto kPeriod = std::chrono::microseconds(10000);

// One frame of a scripted run: the pattern whose trigger produced it (its slot), how long after
// that trigger it arrives at the host, its status and whether the transport skipped a frame id.
struct Shot {
  int slot = 0;
  milliseconds latency{2};
  FrameStatus status = FrameStatus::kOk;
  bool id_gap = false;
};

// The device's clock, shared by the scripted projector and cameras.
struct DeviceRun {
  int index = -1;
  SysClock::time_point start;
};

class ScriptedProjector : public SequenceProjector {
 public:
  explicit ScriptedProjector(DeviceRun* run) : run_(run) {}
  ProjectorInfo Info() const override { return {"scripted", "scripted", 64, 40, 100}; }
  void Load(const std::vector<cv::Mat>& images) override {
    loaded = static_cast<int>(images.size());
  }
  SysClock::time_point Start() override {
    ++run_->index;
    run_->start = SysClock::now();
    return run_->start;
  }
  void Stop() override {}
  std::chrono::microseconds FramePeriod() const override { return kPeriod; }
  void CheckAlive() override { SLSHADOW_THROW_IF(gone, "scripted projector: gone"); }
  int loaded = 0;
  bool gone = false;

 private:
  DeviceRun* run_;
};

class ScriptedCamera : public Camera {
 public:
  ScriptedCamera(const DeviceRun* run, int width, int height, std::vector<std::vector<Shot>> runs)
      : run_(run), width_(width), height_(height), runs_(std::move(runs)) {}
  CameraInfo Info() const override {
    return {"scripted", "cam", "", "", "S1", width_, height_, {}};
  }
  void Configure(const CameraSettings& s) override { settings_ = s; }
  CameraSettings Settings() const override { return settings_; }
  void Start() override {}
  void Stop() override {}
  void Trigger() override {}
  Frame Grab(milliseconds) override {
    if (served_run_ != run_->index) {  // the projector started another run
      served_run_ = run_->index;
      next_ = 0;
    }
    if (run_->index < 0 || next_ >= runs_.at(static_cast<size_t>(run_->index)).size()) {
      return {FrameStatus::kTimeout, "scripted: no frame", {}};
    }
    const Shot& s = runs_[static_cast<size_t>(run_->index)][next_++];
    frame_id_ += s.id_gap ? 2 : 1;
    Frame f;
    f.status = s.status;
    f.message = s.status == FrameStatus::kOk ? "" : "scripted damage";
    const auto edge = run_->start + s.slot * kPeriod;
    f.host_timestamp = std::chrono::time_point_cast<SysClock::duration>(edge + s.latency);
    f.device_timestamp_ns =
        s.status == FrameStatus::kOk
            ? static_cast<uint64_t>(1000000000000 + run_->index * 1000000000LL +
                                    std::chrono::nanoseconds(s.slot * kPeriod).count())
            : 0;
    f.frame_id = s.status == FrameStatus::kOk ? frame_id_ : 0;
    // The image says which pattern it shows, so the stored set tells whether a frame was shifted.
    if (s.status == FrameStatus::kOk)
      f.image = cv::Mat(height_, width_, CV_8UC1, cv::Scalar(s.slot + 1));
    return f;
  }

 private:
  const DeviceRun* run_;
  int width_, height_;
  std::vector<std::vector<Shot>> runs_;
  CameraSettings settings_;
  size_t next_ = 0;
  int served_run_ = -1;
  uint64_t frame_id_ = 100;
};

std::vector<Shot> Clean(int n) {
  std::vector<Shot> shots;
  for (int k = 0; k < n; ++k) shots.push_back({k});
  return shots;
}

class PatternSequenceFaults : public ::testing::Test {
 protected:
  void SetUp() override {
    rig_.name = "scripted";
    RigDevice cam;
    cam.name = "left";
    cam.model.width = 32;
    cam.model.height = 20;
    cam.model.params[CameraModel::kFx] = cam.model.params[CameraModel::kFy] = 30;
    cam.model.params[CameraModel::kCx] = 15.5;
    cam.model.params[CameraModel::kCy] = 9.5;
    rig_.cameras.push_back(cam);
    spec_.kind = PatternKind::kGrayCode;
    spec_.projector_width = 64;
    spec_.projector_height = 40;
    spec_.Check();
    n_ = spec_.NumImages();
  }

  // Captures with one scripted camera whose runs are `runs`; returns the error ("" when none).
  std::string Capture(std::vector<std::vector<Shot>> runs, int max_retries,
                      CaptureSummary* summary = nullptr) {
    camera_ = std::make_unique<ScriptedCamera>(&run_, 32, 20, std::move(runs));
    projector_ = std::make_unique<ScriptedProjector>(&run_);
    CameraSettings s;
    s.trigger = TriggerMode::kHardware;
    std::vector<CaptureCamera> cams = {{"left", camera_.get(), s, milliseconds(100)}};
    SequencerOptions options;
    options.writer.encoding = ImageEncoding::kPgm;
    options.writer.durable = false;
    options.writer.resume = true;
    options.progress = false;
    options.validate = false;  // the scripted images are flat: this tests the matching
    options.max_retries = max_retries;
    options.settle = std::chrono::microseconds(0);
    try {
      const CaptureSummary got =
          CapturePatternSequence(rig_, spec_, cams, *projector_, dir_.path() / "set", options);
      if (summary) *summary = got;
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  }

  // Pattern index -> the slot its stored image shows (-1: not stored).
  std::vector<int> Stored() {
    ResumableImageSetWriterOptions o;
    o.resume = true;
    o.encoding = ImageEncoding::kPgm;
    std::vector<int> shows(static_cast<size_t>(n_), -1);
    if (fs::exists(dir_.path() / "set" / "manifest.json")) {
      const ImageSet set = ImageSet::Open(dir_.path() / "set");
      for (int k = 0; k < n_; ++k)
        shows[static_cast<size_t>(k)] = set.Load("left", k).at<uint8_t>(0, 0) - 1;
      return shows;
    }
    ResumableImageSetWriter writer(dir_.path() / "set", rig_, PatternSpecToJson(spec_), o);
    for (const auto& r : writer.Records()) {
      shows[static_cast<size_t>(r.pattern_index)] =
          writer.Load("left", r.pattern_index).at<uint8_t>(0, 0) - 1;
    }
    return shows;
  }

  std::vector<int> FirstStored(int count) {
    std::vector<int> shows(static_cast<size_t>(n_), -1);
    for (int k = 0; k < count; ++k) shows[static_cast<size_t>(k)] = k;
    return shows;
  }

  slshadow::testing::TempDir dir_;
  Rig rig_;
  PatternSpec spec_;
  int n_ = 0;
  DeviceRun run_;
  std::unique_ptr<ScriptedCamera> camera_;
  std::unique_ptr<ScriptedProjector> projector_;
};

TEST_F(PatternSequenceFaults, EveryTriggerAFrameCompletesInOrder) {
  CaptureSummary s;
  EXPECT_EQ(Capture({Clean(n_)}, 0, &s), "");
  EXPECT_TRUE(s.complete);
  EXPECT_EQ(projector_->loaded, n_);
  EXPECT_EQ(Stored(), FirstStored(n_));
}

TEST_F(PatternSequenceFaults, AMissedTriggerNamesItsPatternAndKeepsThoseBefore) {
  auto shots = Clean(n_);
  shots.erase(shots.begin() + 5);
  const std::string error = Capture({shots}, 0);
  EXPECT_NE(error.find("pattern 5 ("), std::string::npos) << error;
  EXPECT_NE(error.find("the next one came 20.0 ms after pattern 4"), std::string::npos) << error;
  EXPECT_NE(error.find("missed this pattern's trigger"), std::string::npos) << error;
  EXPECT_EQ(Stored(), FirstStored(5));
}

TEST_F(PatternSequenceFaults, AFrameLostInTransportIsToldByTheFrameIdGap) {
  auto shots = Clean(n_);
  shots.erase(shots.begin() + 5);
  shots[5].id_gap = true;
  const std::string error = Capture({shots}, 0);
  EXPECT_NE(error.find("pattern 5 ("), std::string::npos) << error;
  EXPECT_NE(error.find("lost in transport (frame-id gap)"), std::string::npos) << error;
}

// Pattern 0's trigger missed: the first frame (pattern 1's) arrives after a period and the frames
// span one pattern less than the sequence: nothing can be placed, nothing is stored.
TEST_F(PatternSequenceFaults, AMissingFirstFrameThatCannotBePlacedStoresNothing) {
  auto shots = Clean(n_);
  shots.erase(shots.begin());
  const std::string error = Capture({shots}, 0);
  EXPECT_NE(error.find("pattern 0 ("), std::string::npos) << error;
  EXPECT_NE(error.find("cannot tell which pattern its first frame shows"), std::string::npos)
      << error;
  EXPECT_EQ(Stored(), FirstStored(0));
}

// A first frame later than a period (long exposure, slow link) is still pattern 0's when the
// frames span the whole sequence.
TEST_F(PatternSequenceFaults, ALateFirstFrameIsAnchoredByTheCount) {
  auto shots = Clean(n_);
  for (auto& s : shots) s.latency = milliseconds(25);
  CaptureSummary s;
  EXPECT_EQ(Capture({shots}, 0, &s), "");
  EXPECT_TRUE(s.complete);
  EXPECT_EQ(Stored(), FirstStored(n_));
}

TEST_F(PatternSequenceFaults, ASpuriousTriggerIsAFault) {
  auto shots = Clean(n_);
  shots.insert(shots.begin() + 6, Shot{5});  // a second frame of pattern 5's period
  const std::string error = Capture({shots}, 0);
  EXPECT_NE(error.find("pattern 6 ("), std::string::npos) << error;
  EXPECT_NE(error.find("a spurious trigger"), std::string::npos) << error;
  EXPECT_EQ(Stored(), FirstStored(6));
}

TEST_F(PatternSequenceFaults, ADamagedFrameIsAFaultAtItsPattern) {
  auto shots = Clean(n_);
  shots[7].status = FrameStatus::kMissingPackets;
  const std::string error = Capture({shots}, 0);
  EXPECT_NE(error.find("pattern 7 ("), std::string::npos) << error;
  EXPECT_NE(error.find("frame missing packets (scripted damage)"), std::string::npos) << error;
  EXPECT_EQ(Stored(), FirstStored(7));
}

TEST_F(PatternSequenceFaults, TheProjectorGoneIsNamedWithTheMissingFrame) {
  camera_ =
      std::make_unique<ScriptedCamera>(&run_, 32, 20, std::vector<std::vector<Shot>>{Clean(9)});
  projector_ = std::make_unique<ScriptedProjector>(&run_);
  projector_->gone = true;
  CameraSettings s;
  s.trigger = TriggerMode::kHardware;
  std::vector<CaptureCamera> cams = {{"left", camera_.get(), s, milliseconds(100)}};
  SequencerOptions options;
  options.writer.encoding = ImageEncoding::kPgm;
  options.progress = false;
  options.validate = false;
  options.max_retries = 0;
  try {
    CapturePatternSequence(rig_, spec_, cams, *projector_, dir_.path() / "set", options);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("pattern 9 ("), std::string::npos) << what;
    EXPECT_NE(what.find("its trigger never came; scripted projector: gone"), std::string::npos)
        << what;
  }
  EXPECT_EQ(Stored(), FirstStored(9));
}

// A rerun keeps the patterns of the first run and stores only the missing ones from the second.
TEST_F(PatternSequenceFaults, ARerunStoresOnlyTheMissingPatterns) {
  auto first = Clean(n_);
  first.erase(first.begin() + 5);
  CaptureSummary s;
  EXPECT_EQ(Capture({first, Clean(n_)}, 1, &s), "");
  EXPECT_TRUE(s.complete);
  EXPECT_EQ(s.retries, 1);
  EXPECT_EQ(s.cameras.at("left").missed_triggers, 1);
  EXPECT_EQ(Stored(), FirstStored(n_));
  const ImageSet set = ImageSet::Open(dir_.path() / "set");
  for (const auto& r : set.records())
    EXPECT_EQ(r.retries, r.pattern_index < 5 ? 0 : 1) << r.pattern_index;
}

TEST_F(PatternSequenceFaults, CamerasMustTakeTheHardwareTrigger) {
  camera_ =
      std::make_unique<ScriptedCamera>(&run_, 32, 20, std::vector<std::vector<Shot>>{Clean(n_)});
  projector_ = std::make_unique<ScriptedProjector>(&run_);
  std::vector<CaptureCamera> cams = {{"left", camera_.get(), CameraSettings{}, milliseconds(100)}};
  try {
    CapturePatternSequence(rig_, spec_, cams, *projector_, dir_.path() / "set", SequencerOptions{});
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(
                  "capture: camera 'left': trigger is software; with a projector that runs"),
              std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace slshadow::capture
