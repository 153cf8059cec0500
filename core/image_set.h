// ImageSet: one folder holding a structured-light capture, real or virtual, with everything
// needed to decode and reconstruct it (DESIGN.md: "real and virtual produce the same ImageSet").
//
//   DIR/manifest.json   versioned manifest: rig, pattern spec, one record per image
//   DIR/<camera>/<file> 8- or 16-bit single-channel images, lossless (PNG, PGM or TIFF)
//
// The manifest format is documented in docs/formats.md ("ImageSet manifest"). Images are loaded
// lazily, on request, and checked against the rig's image size and the recorded bit depth.
#pragma once

#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/rig.h"

namespace slshadow {

enum class ImageSource { kDevice, kVirtual, kReplay };
std::string ToString(ImageSource source);                    // "device", "virtual", "replay"
ImageSource ImageSourceFromString(const std::string& name);  // throws slshadow::Error

struct ImageRecord {
  std::string camera;      // a camera name of the rig
  int pattern_index = 0;   // index into the pattern sequence, 0-based
  std::string file;        // path relative to the ImageSet folder
  int bit_depth = 8;       // 8 or 16
  double exposure_us = 0;  // exposure time, microseconds (0 when unknown)
  std::string timestamp;   // ISO 8601 UTC (device captures: host clock at arrival), or empty
  ImageSource source = ImageSource::kDevice;
  // Device provenance, optional (written to the manifest only when set): the camera's serial,
  // its frame counter (GigE Vision: 16-bit, wraps, 0 invalid), its own clock, and how many
  // times the pattern was re-acquired before this frame was accepted.
  std::string device_serial;  // empty: unknown
  std::optional<uint64_t> frame_id;
  std::optional<uint64_t> device_timestamp_ns;
  std::optional<int> retries;
  bool operator==(const ImageRecord&) const = default;
};

class ImageSet {
 public:
  static constexpr int kFormatVersion = 1;

  // Reads and validates DIR/manifest.json. Throws slshadow::Error naming the manifest and the
  // field on any missing or malformed entry, an unknown camera, a duplicate (camera, pattern)
  // pair or a missing image file. Images are not decoded here.
  static ImageSet Open(const std::filesystem::path& dir);

  const std::filesystem::path& dir() const { return dir_; }
  const Rig& rig() const { return rig_; }
  // The pattern specification as stored (see patterns/ for its schema).
  const nlohmann::json& patterns() const { return patterns_; }
  // Free-form provenance: device settings for real captures, scene and layers for virtual ones.
  const nlohmann::json& extra() const { return extra_; }
  const std::string& created() const { return created_; }
  const std::vector<ImageRecord>& records() const { return records_; }

  // Cameras that have images, in rig order.
  std::vector<std::string> CameraNames() const;
  // Number of patterns: 1 + the largest pattern index.
  int PatternCount() const;
  const ImageRecord* Find(const std::string& camera, int pattern_index) const;

  // Decodes one image (CV_8UC1 or CV_16UC1). Throws slshadow::Error naming the file when it is
  // missing, unreadable, not single-channel, of another bit depth than recorded or of another
  // size than the rig's camera.
  cv::Mat Load(const std::string& camera, int pattern_index) const;
  // All patterns of one camera, in pattern order, decoded in parallel. Throws if one is missing.
  std::vector<cv::Mat> LoadCamera(const std::string& camera) const;

 private:
  std::filesystem::path dir_;
  Rig rig_;
  nlohmann::json patterns_;
  nlohmann::json extra_;
  std::string created_;
  std::vector<ImageRecord> records_;
};

// Lossless image encodings an ImageSetWriter can use.
enum class ImageEncoding {
  kPng,  // portable, compressed (png_compression); the slowest to write
  kPgm,  // raw binary PGM (P5): a memcpy, the fastest lossless option; 16-bit big-endian
  kTiff  // uncompressed TIFF
};
ImageEncoding ImageEncodingFromString(const std::string& name);  // throws on unknown names
std::string ToString(ImageEncoding encoding);                    // "png", "pgm", "tiff"

struct ImageSetWriterOptions {
  ImageEncoding encoding = ImageEncoding::kPng;
  int png_compression = 1;  // 0..9; 1 is fast and still lossless
  bool overwrite = false;   // replace an existing folder when committing
};

// Writes an ImageSet into a temporary sibling folder; Commit() writes the manifest and renames
// the folder into place, so a reader never sees a half-written ImageSet. A writer destroyed
// without Commit() removes its temporary folder. Add() is thread-safe.
class ImageSetWriter {
 public:
  ImageSetWriter(std::filesystem::path dir, Rig rig, nlohmann::json patterns,
                 ImageSetWriterOptions options = {});
  ~ImageSetWriter();
  ImageSetWriter(const ImageSetWriter&) = delete;
  ImageSetWriter& operator=(const ImageSetWriter&) = delete;

  // Encodes and writes one image (CV_8UC1 or CV_16UC1, the camera's size). Throws on a wrong
  // size, type, unknown camera or duplicate (camera, pattern).
  void Add(const std::string& camera, int pattern_index, const cv::Mat& image, double exposure_us,
           ImageSource source, const std::string& timestamp = "");
  void SetExtra(nlohmann::json extra) { extra_ = std::move(extra); }
  // The folder being written (a temporary sibling of the final folder until Commit()).
  const std::filesystem::path& staging_dir() const { return staging_; }
  void Commit();

 private:
  std::filesystem::path dir_;
  std::filesystem::path staging_;
  Rig rig_;
  nlohmann::json patterns_;
  nlohmann::json extra_;
  ImageSetWriterOptions options_;
  std::vector<ImageRecord> records_;
  std::mutex mutex_;
  bool committed_ = false;
};

struct ResumableImageSetWriterOptions {
  ImageEncoding encoding = ImageEncoding::kPng;
  int png_compression = 1;  // 0..9
  bool overwrite = false;   // replace an existing target folder at Commit()
  bool resume = false;      // continue an existing staging folder (else: refuse to touch it)
  // fsync every image, its folder and every journal line. Off only for throwaway data (tests,
  // benchmarks): a crash may then lose records the journal claims.
  bool durable = true;
};

// Writes an ImageSet so that an interrupted capture (Ctrl-C, a crash, a lost camera) can be
// continued. Layout of the deterministic staging folder `<dir>.partial/` beside the target:
//   staging.json    rig, pattern spec and encoding the capture was started with
//   journal.jsonl   append-only, one JSON object per line: {"type":"image", <image record>} or
//                   {"type":"session", "session": {...}}; a later image line for the same
//                   (camera, pattern) replaces the earlier one
//   <camera>/NNNN.<ext>
// Add() writes the image to a hidden temporary file, fsyncs it, renames it into place, fsyncs the
// folder, and only then appends and fsyncs its journal line: a record in the journal always has
// its complete image. Reopening with options.resume reads the journal (a torn last line, e.g.
// from a crash mid-write, is cut off; an image written but not journaled counts as missing),
// refuses a staging folder started for another rig, pattern spec or encoding, and continues.
// Commit() writes manifest.json (records in rig camera order, then pattern order: independent of
// the order or the session they were taken in) and renames the folder into place. The staging
// folder is never removed without Commit(). Format: docs/formats.md, "Resumable capture".
class ResumableImageSetWriter {
 public:
  // "<dir>.partial": where a capture into `dir` stages.
  static std::filesystem::path StagingDirFor(const std::filesystem::path& dir);

  // Starts a staging folder, or continues one when options.resume is set and it exists. Throws
  // slshadow::Error when the target exists (and !overwrite), when a staging folder exists and
  // !resume (it would be lost), or when the staging folder belongs to another rig / patterns.
  ResumableImageSetWriter(std::filesystem::path dir, Rig rig, nlohmann::json patterns,
                          ResumableImageSetWriterOptions options = {});
  ~ResumableImageSetWriter();
  ResumableImageSetWriter(const ResumableImageSetWriter&) = delete;
  ResumableImageSetWriter& operator=(const ResumableImageSetWriter&) = delete;

  bool resumed() const { return resumed_; }  // an existing staging folder was continued
  const std::filesystem::path& staging_dir() const { return staging_; }
  const std::filesystem::path& dir() const { return dir_; }
  const Rig& rig() const { return rig_; }

  bool Has(const std::string& camera, int pattern_index) const;
  std::optional<ImageRecord> Find(const std::string& camera, int pattern_index) const;
  // Finished records, in rig camera order then pattern order.
  std::vector<ImageRecord> Records() const;
  // A finished image, read back from the staging folder.
  cv::Mat Load(const std::string& camera, int pattern_index) const;

  // Stores one image durably (see above) and returns its record. `record` gives camera,
  // pattern_index, exposure, timestamp (empty: now), source and provenance; file and bit_depth
  // are filled in. Replaces a finished record of the same (camera, pattern). Thread-safe.
  ImageRecord Add(ImageRecord record, const cv::Mat& image);
  // Journals a note about one capture session (settings chosen, statistics); all sessions,
  // including those before a resume, are returned by Sessions().
  void AppendSession(const nlohmann::json& session);
  std::vector<nlohmann::json> Sessions() const;
  void SetExtra(nlohmann::json extra) { extra_ = std::move(extra); }
  // Writes the manifest and renames the staging folder onto the target.
  void Commit();

 private:
  void LoadJournal();
  void AppendJournalLine(const std::string& line);
  std::filesystem::path dir_, staging_;
  Rig rig_;
  nlohmann::json patterns_;
  nlohmann::json extra_;
  ResumableImageSetWriterOptions options_;
  std::vector<ImageRecord> records_;  // one per (camera, pattern)
  std::vector<nlohmann::json> sessions_;
  mutable std::mutex mutex_;
  int journal_fd_ = -1;
  bool resumed_ = false;
  bool committed_ = false;
};

// Reads / writes one single-channel 8- or 16-bit image losslessly (by extension: .png, .pgm,
// .tif/.tiff). Throws slshadow::Error naming the file on failure.
cv::Mat ReadGrayImage(const std::filesystem::path& path);
void WriteGrayImage(const std::filesystem::path& path, const cv::Mat& image,
                    int png_compression = 1);

}  // namespace slshadow
