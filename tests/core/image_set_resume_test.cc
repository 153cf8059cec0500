// ResumableImageSetWriter: a capture interrupted at any point (between records, after an image
// was written but before it was journaled, with a torn last journal line) and then resumed gives
// the same manifest records and the same image bytes as one that was never interrupted.
#include <fstream>
#include <functional>
#include <sstream>

#include <gtest/gtest.h>

#include "core/error.h"
#include "core/file_util.h"
#include "core/image_set.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {
namespace fs = std::filesystem;

Rig SmallRig() {
  Rig rig;
  rig.name = "small";
  rig.cameras.push_back({"left", CameraModel(64, 48, 60, 60, 31.5, 23.5, -0.1), Rigid3d()});
  rig.cameras.push_back(
      {"right", CameraModel(64, 48, 61, 61, 32, 24),
       Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitY())),
               {-100, 0, 10})});
  rig.projector = RigDevice{"projector", CameraModel(32, 20, 30, 30, 16, 10), Rigid3d()};
  return rig;
}

const nlohmann::json kSpec = {
    {"kind", "gray_code"}, {"projector_width", 32}, {"projector_height", 20}};
constexpr int kPatterns = 7;

// The k-th record of a capture, taken in sequencer order (pattern-major, cameras in rig order),
// with its provenance and a deterministic host timestamp.
struct Shot {
  ImageRecord record;
  cv::Mat image;
};
Shot MakeShot(int k) {
  Shot s;
  s.record.camera = k % 2 ? "right" : "left";
  s.record.pattern_index = k / 2;
  s.record.exposure_us = 2500;
  s.record.timestamp = "2026-11-24T10:00:" + std::to_string(10 + k) + ".000Z";
  s.record.source = ImageSource::kDevice;
  s.record.device_serial = k % 2 ? "SN-R" : "SN-L";
  s.record.frame_id = static_cast<uint64_t>(65530 + k / 2) % 65535 + 1;  // wraps through 65535 -> 1
  s.record.device_timestamp_ns = 1000000ull * static_cast<uint64_t>(k);
  s.record.retries = k % 3;
  s.image = cv::Mat(48, 64, k % 4 == 3 ? CV_16UC1 : CV_8UC1);
  cv::RNG rng(static_cast<uint64_t>(100 + k));
  rng.fill(s.image, cv::RNG::UNIFORM, 0, s.image.depth() == CV_8U ? 256 : 65536);
  return s;
}
constexpr int kShots = 2 * kPatterns;

std::string Bytes(const fs::path& p) { return ReadTextFile(p); }

// Records and image bytes of a committed set (the manifest's "created" differs by design).
void ExpectSameSet(const fs::path& a, const fs::path& b) {
  const ImageSet sa = ImageSet::Open(a), sb = ImageSet::Open(b);
  ASSERT_EQ(sa.records().size(), sb.records().size());
  for (size_t i = 0; i < sa.records().size(); ++i) {
    EXPECT_EQ(sa.records()[i], sb.records()[i]) << "record " << i;
    EXPECT_EQ(Bytes(a / sa.records()[i].file), Bytes(b / sb.records()[i].file))
        << sa.records()[i].file;
  }
  EXPECT_EQ(sa.extra(), sb.extra());
  // Only the manifest remains: no journal, no staging header, no temporary images.
  size_t files = 0;
  for (const auto& e : fs::recursive_directory_iterator(b)) files += e.is_regular_file();
  EXPECT_EQ(files, sb.records().size() + 1);
}

void CaptureAll(const fs::path& out) {
  ResumableImageSetWriter w(out, SmallRig(), kSpec, {.encoding = ImageEncoding::kPng});
  for (int k = 0; k < kShots; ++k) w.Add(MakeShot(k).record, MakeShot(k).image);
  w.SetExtra({{"capture", "test"}});
  w.Commit();
}

// Continues a staged capture as the sequencer does: every (camera, pattern) not finished.
void Resume(const fs::path& out, int* taken = nullptr) {
  ResumableImageSetWriter w(out, SmallRig(), kSpec,
                            {.encoding = ImageEncoding::kPng, .resume = true});
  EXPECT_TRUE(w.resumed());
  int n = 0;
  for (int k = 0; k < kShots; ++k) {
    const Shot s = MakeShot(k);
    if (w.Has(s.record.camera, s.record.pattern_index)) continue;
    w.Add(s.record, s.image);
    ++n;
  }
  if (taken) *taken = n;
  w.SetExtra({{"capture", "test"}});
  w.Commit();
}

TEST(ResumableImageSetWriter, UninterruptedCaptureReadsBackWithProvenance) {
  testing::TempDir dir;
  CaptureAll(dir / "set");
  EXPECT_FALSE(fs::exists(ResumableImageSetWriter::StagingDirFor(dir / "set")));
  const ImageSet set = ImageSet::Open(dir / "set");
  ASSERT_EQ(set.records().size(), static_cast<size_t>(kShots));
  for (int k = 0; k < kShots; ++k) {
    const Shot s = MakeShot(k);
    const ImageRecord* r = set.Find(s.record.camera, s.record.pattern_index);
    ASSERT_NE(r, nullptr);
    EXPECT_EQ(r->device_serial, s.record.device_serial);
    EXPECT_EQ(r->frame_id, s.record.frame_id);
    EXPECT_EQ(r->device_timestamp_ns, s.record.device_timestamp_ns);
    EXPECT_EQ(r->retries, s.record.retries);
    EXPECT_EQ(r->timestamp, s.record.timestamp);
    EXPECT_EQ(cv::norm(set.Load(s.record.camera, s.record.pattern_index), s.image, cv::NORM_INF),
              0.0);
  }
}

TEST(ResumableImageSetWriter, ResumeAfterInterruptionAtEveryPointEqualsUninterrupted) {
  testing::TempDir dir;
  CaptureAll(dir / "reference");
  for (int stop = 0; stop <= kShots; ++stop) {
    SCOPED_TRACE(::testing::Message() << "interrupted after " << stop << " records");
    const fs::path out = dir / ("set" + std::to_string(stop));
    {
      ResumableImageSetWriter w(out, SmallRig(), kSpec, {.encoding = ImageEncoding::kPng});
      EXPECT_FALSE(w.resumed());
      for (int k = 0; k < stop; ++k) w.Add(MakeShot(k).record, MakeShot(k).image);
    }  // "Ctrl-C": destroyed without Commit
    EXPECT_TRUE(fs::is_directory(ResumableImageSetWriter::StagingDirFor(out)));
    EXPECT_FALSE(fs::exists(out));
    int taken = 0;
    Resume(out, &taken);
    EXPECT_EQ(taken, kShots - stop);
    ExpectSameSet(dir / "reference", out);
  }
}

TEST(ResumableImageSetWriter, TornJournalLineAndUnjournaledImageAreTakenAgain) {
  testing::TempDir dir;
  CaptureAll(dir / "reference");
  for (int stop : {0, 1, 6, kShots - 1}) {
    SCOPED_TRACE(::testing::Message() << "crash after " << stop << " records");
    const fs::path out = dir / ("set" + std::to_string(stop));
    const fs::path staging = ResumableImageSetWriter::StagingDirFor(out);
    {
      ResumableImageSetWriter w(out, SmallRig(), kSpec, {.encoding = ImageEncoding::kPng});
      for (int k = 0; k < stop; ++k) w.Add(MakeShot(k).record, MakeShot(k).image);
    }
    // A crash while storing record `stop`: an image of it is in place (a wrong one here), a
    // temporary file lies around, and its journal line was torn mid-write.
    const Shot next = MakeShot(stop);
    char name[32];
    std::snprintf(name, sizeof(name), "%04d", next.record.pattern_index);
    const std::string file = next.record.camera + "/" + name + ".png";
    WriteGrayImage(staging / file, cv::Mat(48, 64, CV_8UC1, cv::Scalar(7)));
    WriteGrayImage(staging / (next.record.camera + "/." + name + ".tmp.png"),
                   cv::Mat(48, 64, CV_8UC1, cv::Scalar(9)));
    {
      std::ofstream journal(staging / "journal.jsonl", std::ios::app);
      journal << R"({"type":"image","camera":")" << next.record.camera << R"(","pattern":)"
              << next.record.pattern_index << R"(,"file":")" << file << R"(","bit_de)";
    }
    {
      ResumableImageSetWriter w(out, SmallRig(), kSpec,
                                {.encoding = ImageEncoding::kPng, .resume = true});
      EXPECT_EQ(w.Records().size(), static_cast<size_t>(stop));
      EXPECT_FALSE(w.Has(next.record.camera, next.record.pattern_index));
    }
    // The torn line was cut off: the journal ends with a complete line.
    const std::string journal = ReadTextFile(staging / "journal.jsonl");
    EXPECT_TRUE(journal.empty() || journal.back() == '\n');
    int taken = 0;
    Resume(out, &taken);
    EXPECT_EQ(taken, kShots - stop);
    ExpectSameSet(dir / "reference", out);
  }
}

TEST(ResumableImageSetWriter, ZeroFilledJournalTailIsCutButDamageInTheMiddleIsRefused) {
  testing::TempDir dir;
  const fs::path out = dir / "set", staging = ResumableImageSetWriter::StagingDirFor(out);
  {
    ResumableImageSetWriter w(out, SmallRig(), kSpec);
    for (int k = 0; k < 3; ++k) w.Add(MakeShot(k).record, MakeShot(k).image);
    w.AppendSession({{"note", "first"}});
  }
  {
    std::ofstream(staging / "journal.jsonl", std::ios::app) << std::string(40, '\0') << "\n"
                                                            << std::string(9, '\0');
  }
  {
    ResumableImageSetWriter w(out, SmallRig(), kSpec, {.resume = true});
    EXPECT_EQ(w.Records().size(), 3u);
    ASSERT_EQ(w.Sessions().size(), 1u);
    EXPECT_EQ(w.Sessions()[0]["note"], "first");
    w.Add(MakeShot(3).record, MakeShot(3).image);
  }
  std::string text = ReadTextFile(staging / "journal.jsonl");
  text.replace(text.find("\"type\":\"image\""), 14, "\"type\":\"imag\xff");
  WriteTextFileAtomically(staging / "journal.jsonl", text);
  std::string message;
  try {
    ResumableImageSetWriter w(out, SmallRig(), kSpec, {.resume = true});
  } catch (const Error& e) {
    message = e.what();
  }
  EXPECT_NE(
      message.find("journal.jsonl: line 1: unreadable journal line followed by readable ones"),
      std::string::npos)
      << message;
}

TEST(ResumableImageSetWriter, ALaterRecordReplacesAnEarlierOneAcrossSessions) {
  testing::TempDir dir;
  const fs::path out = dir / "set";
  Shot a = MakeShot(0), b = MakeShot(0);
  b.image = MakeShot(2).image;
  b.record.retries = 5;
  {
    ResumableImageSetWriter w(out, SmallRig(), kSpec);
    w.Add(a.record, a.image);
    w.Add(b.record, b.image);
    EXPECT_EQ(w.Records().size(), 1u);
  }
  ResumableImageSetWriter w(out, SmallRig(), kSpec, {.resume = true});
  ASSERT_EQ(w.Records().size(), 1u);
  EXPECT_EQ(w.Records()[0].retries, 5);
  EXPECT_EQ(cv::norm(w.Load("left", 0), b.image, cv::NORM_INF), 0.0);
}

TEST(ResumableImageSetWriter, RefusesToLoseOrMixAStagedCapture) {
  testing::TempDir dir;
  const fs::path out = dir / "set";
  {
    ResumableImageSetWriter w(out, SmallRig(), kSpec);
    w.Add(MakeShot(0).record, MakeShot(0).image);
  }
  const auto error_of = [](const std::function<void()>& f) -> std::string {
    try {
      f();
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  };
  // Without --resume the staged frames would be lost.
  EXPECT_NE(error_of([&] {
              ResumableImageSetWriter(out, SmallRig(), kSpec);
            }).find("continue it with --resume"),
            std::string::npos);
  Rig other = SmallRig();
  other.cameras[1].model = CameraModel(64, 48, 70, 70, 32, 24);
  EXPECT_NE(error_of([&] {
              ResumableImageSetWriter(out, other, kSpec, {.resume = true});
            }).find("cannot resume: the staged capture was started with another rig"),
            std::string::npos);
  nlohmann::json spec = kSpec;
  spec["projector_width"] = 64;
  EXPECT_NE(error_of([&] {
              ResumableImageSetWriter(out, SmallRig(), spec, {.resume = true});
            }).find("another pattern spec"),
            std::string::npos);
  EXPECT_NE(error_of([&] {
              ResumableImageSetWriter(out, SmallRig(), kSpec,
                                      {.encoding = ImageEncoding::kPgm, .resume = true});
            }).find("image encoding 'png', this run asks for 'pgm'"),
            std::string::npos);
  // The staged capture survived every refusal.
  ResumableImageSetWriter w(out, SmallRig(), kSpec, {.resume = true});
  EXPECT_EQ(w.Records().size(), 1u);
  // --resume with nothing staged starts a fresh capture.
  ResumableImageSetWriter fresh(dir / "other", SmallRig(), kSpec, {.resume = true});
  EXPECT_FALSE(fresh.resumed());
}

}  // namespace
}  // namespace slshadow
