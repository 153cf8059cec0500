// Real data through the capture path: ../shared/data/kamino-procam-graycode pose 0 (a real
// camera's 42 Gray-code frames, see its README), made into an ImageSet and played by the replay
// camera through the sequencer (with validation on: no false alarm on real frames) and through
// `slshadow capture` with a devices file. The captured files are the recorded pixels bit for bit
// and reconstruct to the same cloud as the original files (the values of
// tests/reconstruct/reconstruct_image_set_test.cc).
#include <cstdio>
#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/core/persistence.hpp>

#include "capture/replay_camera.h"
#include "capture/sequencer.h"
#include "core/image_set.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct_image_set.h"
#include "tests/capture/test_devices.h"
#include "tests/testing/kamino_rig.h"
#include "tests/testing/run_cli.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::capture {
namespace {
namespace fs = std::filesystem;

using slshadow::testing::KaminoDir;
using slshadow::testing::KaminoRig;

TEST(ReplayKamino, CapturedFilesAreTheRecordedPixelsAndReconstructAsTheOriginals) {
  if (!fs::exists(KaminoDir() / "capture_0")) GTEST_SKIP() << "no shared data at " << KaminoDir();
  slshadow::testing::TempDir dir;
  const fs::path spec_path =
      slshadow::testing::SourceDir() / "config/patterns/kamino_opencv_graycode.yaml";
  const PatternSpec spec = LoadPatternSpec(spec_path);
  const Rig rig = KaminoRig();
  std::vector<cv::Mat> originals;
  {
    ImageSetWriter writer(dir / "recorded", rig, PatternSpecToJson(spec));
    for (int k = 0; k < spec.NumImages(); ++k) {
      char name[32];
      std::snprintf(name, sizeof(name), "graycode_%02d.png", k);
      originals.push_back(ReadGrayImage(KaminoDir() / "capture_0" / name));
      writer.Add("camera", k, originals.back(), 0, ImageSource::kDevice);
    }
    writer.Commit();
  }

  // 1. Library: replay camera + sequencer, validation on (a projector double of the recorded
  //    projector's size: the replay serves what was recorded under each pattern).
  doubles::TestProjector projector(1024, 768);
  ReplayCameraOptions replay_options;
  replay_options.first_frame_id = 65500;  // wraps to 1 within the 42 frames
  ReplayCamera camera(dir / "recorded", replay_options);
  SequencerOptions options;
  options.progress = false;
  options.sleep_until = projector.Sleeper();
  const CaptureSummary s =
      Capture(rig, spec, {{"camera", &camera, {}, std::chrono::milliseconds(100)}}, projector,
              dir / "replayed", options);
  ASSERT_TRUE(s.complete);
  EXPECT_EQ(s.retries, 0);  // no false alarm on real frames
  const CameraCaptureStats& c = s.cameras.at("camera");
  EXPECT_EQ(c.stale + c.not_complementary + c.damaged + c.timeouts, 0);
  EXPECT_EQ(c.missing_frame_ids, 0);  // 65535 -> 1 is not a drop
  // The 20 Gray pairs were judged against white and black (they come last here).
  std::printf("kamino pose 0: lowest complementary share of a Gray pair %.4f\n",
              c.min_complementary_share);
  EXPECT_EQ(c.pair_checks, 20);
  EXPECT_GE(c.min_complementary_share, options.validation.min_complementary);
  const ImageSet replayed = ImageSet::Open(dir / "replayed");
  ASSERT_EQ(replayed.records().size(), originals.size());
  for (int k = 0; k < spec.NumImages(); ++k) {
    const cv::Mat back = replayed.Load("camera", k);
    ASSERT_EQ(back.type(), CV_8UC1);
    EXPECT_EQ(cv::norm(back, originals[static_cast<size_t>(k)], cv::NORM_INF), 0.0)
        << "pattern " << k;
    const ImageRecord* r = replayed.Find("camera", k);
    EXPECT_EQ(r->source, ImageSource::kReplay);
    EXPECT_EQ(r->frame_id, static_cast<uint64_t>((65500 + k - 1) % 65535 + 1));
    EXPECT_EQ(r->device_serial, "replay-camera");
  }

  // 2. The command line: a devices file with the replay backend and no projector.
  {
    std::ofstream(dir / "devices.yaml")
        << "format: slshadow-devices\nversion: 1\ncameras:\n"
           "  - name: camera\n    backend: replay\n    imageset: recorded\n"
           "projector:\n  backend: none\n";
    std::ofstream out(dir / "rig.json");
    out << RigToJson(rig).dump(1);
  }
  ASSERT_EQ(
      slshadow::testing::RunCli({"capture", "--rig", (dir / "rig.json").string(), "--devices",
                                 (dir / "devices.yaml").string(), "--patterns", spec_path.string(),
                                 "--out", (dir / "cli").string(), "--quiet"}),
      0);
  const ImageSet cli = ImageSet::Open(dir / "cli");
  for (int k = 0; k < spec.NumImages(); ++k) {
    EXPECT_EQ(cv::norm(cli.Load("camera", k), originals[static_cast<size_t>(k)], cv::NORM_INF), 0.0)
        << "pattern " << k;
  }
  EXPECT_EQ(cli.extra()["devices"], (dir / "devices.yaml").string());

  // 3. Reconstruction of the captured set equals that of the original files.
  ImageSetReconstructOptions ro;
  const ImageSetReconstruction a = ReconstructFromImages(rig, spec, {{"camera", originals}}, ro);
  const ImageSetReconstruction b = ReconstructImageSet(replayed, ro);
  // The valid pixels of capture_0: a regression value, which tests/reconstruct/
  // reconstruct_image_set_test.cc checks against a pixel-by-pixel recount of the decoder's rules.
  EXPECT_EQ(a.summaries.at(0).decode_status[0], 996162);
  EXPECT_EQ(b.summaries.at(0).decode_status, a.summaries.at(0).decode_status);
  ASSERT_EQ(a.cloud.points.size(), b.cloud.points.size());
  EXPECT_GT(b.cloud.points.size(), 450000u);
  for (size_t i = 0; i < a.cloud.points.size(); ++i)
    ASSERT_EQ(a.cloud.points[i], b.cloud.points[i]) << i;
}

}  // namespace
}  // namespace slshadow::capture
