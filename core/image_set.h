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
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/rig.h"

namespace slshadow {

enum class ImageSource { kDevice, kVirtual, kReplay };
std::string ToString(ImageSource source);  // "device", "virtual", "replay"

struct ImageRecord {
  std::string camera;         // a camera name of the rig
  int pattern_index = 0;      // index into the pattern sequence, 0-based
  std::string file;           // path relative to the ImageSet folder
  int bit_depth = 8;          // 8 or 16
  double exposure_us = 0;     // exposure time, microseconds (0 when unknown)
  std::string timestamp;      // ISO 8601 UTC, or empty when unknown
  ImageSource source = ImageSource::kDevice;
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
  kPng,  // portable; costs 10-25 ms per 1920x1200 image at the default level
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

// Reads / writes one single-channel 8- or 16-bit image losslessly (by extension: .png, .pgm,
// .tif/.tiff). Throws slshadow::Error naming the file on failure.
cv::Mat ReadGrayImage(const std::filesystem::path& path);
void WriteGrayImage(const std::filesystem::path& path, const cv::Mat& image, int png_compression = 1);

}  // namespace slshadow
