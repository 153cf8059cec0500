#include "core/image_set.h"
#include "core/enum_names.h"

#include <fcntl.h>
#include <sys/uio.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <map>
#include <optional>

#include <opencv2/core/utility.hpp>

#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/image_io.h"

namespace slshadow {
namespace fs = std::filesystem;

constexpr EnumName<ImageSource> kImageSourceNames[] = {{ImageSource::kDevice, "device"},
                                                       {ImageSource::kVirtual, "virtual"},
                                                       {ImageSource::kReplay, "replay"}};

std::string ToString(ImageSource value) { return EnumToString(value, kImageSourceNames); }

ImageSource ImageSourceFromString(const std::string& name) {
  return EnumFromString("image source", name, kImageSourceNames);
}

namespace {

ImageSource SourceFromConfig(const ConfigNode& node) {
  return EnumFromConfig(node, kImageSourceNames);
}

const char* Extension(ImageEncoding e) {
  switch (e) {
    case ImageEncoding::kPng:
      return ".png";
    case ImageEncoding::kPgm:
      return ".pgm";
    case ImageEncoding::kTiff:
      return ".tif";
  }
  return ".png";
}

void CheckImage(const cv::Mat& image, const RigDevice& camera, const std::string& what,
                int bit_depth) {
  SLSHADOW_THROW_IF(image.channels() != 1, what, ": expected a single-channel (grey) image, got ",
                    image.channels(), " channels");
  const int depth = image.depth() == CV_8U ? 8 : image.depth() == CV_16U ? 16 : 0;
  SLSHADOW_THROW_IF(depth == 0, what, ": expected 8- or 16-bit unsigned pixels");
  SLSHADOW_THROW_IF(bit_depth != 0 && depth != bit_depth, what, ": bit depth is ", depth,
                    ", the manifest says ", bit_depth);
  SLSHADOW_THROW_IF(image.cols != camera.model.width || image.rows != camera.model.height, what,
                    ": wrong image size ", image.cols, "x", image.rows, ", camera '", camera.name,
                    "' is ", camera.model.width, "x", camera.model.height);
}

nlohmann::json RecordToJson(const ImageRecord& r) {
  nlohmann::json j = {
      {"camera", r.camera},          {"pattern", r.pattern_index},   {"file", r.file},
      {"bit_depth", r.bit_depth},    {"exposure_us", r.exposure_us}, {"timestamp", r.timestamp},
      {"source", ToString(r.source)}};
  if (!r.device_serial.empty()) j["device_serial"] = r.device_serial;
  if (r.frame_id) j["frame_id"] = *r.frame_id;
  if (r.device_timestamp_ns) j["device_timestamp_ns"] = *r.device_timestamp_ns;
  if (r.retries) j["retries"] = *r.retries;
  return j;
}

// Pattern indices beyond this are bad input (a sequence of a million images is not a capture);
// the bound keeps PatternCount() and per-pattern allocations sane.
constexpr int64_t kMaxPatternIndex = 999999;

// The pixel size a PNG (IHDR) or binary PGM (P5) header declares, read without decoding, so an
// image whose header claims a size other than the camera's is refused before the decoder
// allocates for it. Empty for other formats (OpenCV's decoder then applies its own size limit).
std::optional<cv::Size> PeekImageSize(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  char head[64] = {};
  in.read(head, sizeof(head));
  const size_t n = static_cast<size_t>(in.gcount());
  const auto* u = reinterpret_cast<const unsigned char*>(head);
  if (n >= 24 && std::memcmp(head, "\x89PNG\r\n\x1a\n", 8) == 0 &&
      std::memcmp(head + 12, "IHDR", 4) == 0) {
    const auto be32 = [&](size_t at) {
      return (uint64_t{u[at]} << 24) | (uint64_t{u[at + 1]} << 16) | (uint64_t{u[at + 2]} << 8) |
             u[at + 3];
    };
    const uint64_t w = be32(16), h = be32(20);
    if (w > INT32_MAX || h > INT32_MAX) return cv::Size(-1, -1);
    return cv::Size(static_cast<int>(w), static_cast<int>(h));
  }
  if (n >= 2 && head[0] == 'P' && head[1] == '5') {
    // "P5" whitespace width whitespace height, with '#' comments to the end of a line.
    std::vector<uint64_t> values;
    for (size_t i = 2; i < n && values.size() < 2;) {
      if (head[i] == '#') {
        while (i < n && head[i] != '\n') ++i;
      } else if (std::isdigit(u[i])) {
        uint64_t v = 0;
        for (; i < n && std::isdigit(u[i]) && v < (1ull << 40); ++i)
          v = v * 10 + static_cast<uint64_t>(head[i] - '0');
        values.push_back(v);
      } else {
        ++i;
      }
    }
    if (values.size() < 2) return std::nullopt;
    if (values[0] > INT32_MAX || values[1] > INT32_MAX) return cv::Size(-1, -1);
    return cv::Size(static_cast<int>(values[0]), static_cast<int>(values[1]));
  }
  return std::nullopt;
}

// One image record of a manifest (or a capture journal line, which may carry "type"); the file
// must exist under `dir`.
ImageRecord RecordFromConfig(const ConfigNode& n, const Rig& rig, const fs::path& dir,
                             bool allow_type = false) {
  std::vector<std::string> keys = {
      "camera", "pattern",       "file",     "bit_depth",           "exposure_us", "timestamp",
      "source", "device_serial", "frame_id", "device_timestamp_ns", "retries"};
  if (allow_type) keys.push_back("type");
  n.RejectUnknownKeys(keys);
  ImageRecord r;
  r.camera = n["camera"].AsString();
  if (rig.CameraIndex(r.camera) < 0)
    n["camera"].Fail("no camera of this name in the manifest's rig");
  const int64_t pattern = n["pattern"].AsInt();
  if (pattern < 0 || pattern > kMaxPatternIndex) {
    n["pattern"].Fail("pattern index must be 0.." + std::to_string(kMaxPatternIndex));
  }
  r.pattern_index = static_cast<int>(pattern);
  r.file = n["file"].AsString();
  const fs::path file(r.file);
  if (file.is_absolute() || r.file.find("..") != std::string::npos) {
    n["file"].Fail("must be a path relative to the ImageSet folder, without '..'");
  }
  std::error_code ec;
  if (!fs::is_regular_file(dir / file, ec))
    n["file"].Fail("image file not found in " + dir.string());
  r.bit_depth = static_cast<int>(n.GetInt("bit_depth", 8));
  if (r.bit_depth != 8 && r.bit_depth != 16) n["bit_depth"].Fail("must be 8 or 16");
  r.exposure_us = n.GetDouble("exposure_us", 0.0);
  if (r.exposure_us < 0) n["exposure_us"].Fail("must be >= 0");
  r.timestamp = n.GetString("timestamp", "");
  r.source = n.Has("source") ? SourceFromConfig(n["source"]) : ImageSource::kDevice;
  r.device_serial = n.GetString("device_serial", "");
  const auto non_negative = [&](const char* key) -> std::optional<uint64_t> {
    if (!n.Has(key)) return std::nullopt;
    const int64_t v = n[key].AsInt();
    if (v < 0) n[key].Fail("must be >= 0");
    return static_cast<uint64_t>(v);
  };
  r.frame_id = non_negative("frame_id");
  r.device_timestamp_ns = non_negative("device_timestamp_ns");
  if (const auto retries = non_negative("retries")) {
    if (*retries > 1000000) n["retries"].Fail("must be 0..1000000");
    r.retries = static_cast<int>(*retries);
  }
  return r;
}

}  // namespace

constexpr EnumName<ImageEncoding> kImageEncodingNames[] = {{ImageEncoding::kPng, "png"},
                                                           {ImageEncoding::kPgm, "pgm"},
                                                           {ImageEncoding::kTiff, "tiff"},
                                                           {ImageEncoding::kTiff, "tif"}};

ImageEncoding ImageEncodingFromString(const std::string& name) {
  return EnumFromString("image encoding", name, kImageEncodingNames);
}

std::string ToString(ImageEncoding value) { return EnumToString(value, kImageEncodingNames); }

namespace {}  // namespace

cv::Mat ReadGrayImage(const fs::path& path) {
  std::error_code ec;
  SLSHADOW_THROW_IF(!fs::is_regular_file(path, ec), path.string(), ": image file not found");
  return ReadImage(path, ImageReadMode::kUnchanged);
}

void WriteGrayImage(const fs::path& path, const cv::Mat& image, int png_compression) {
  SLSHADOW_THROW_IF(image.channels() != 1 || (image.depth() != CV_8U && image.depth() != CV_16U),
                    path.string(),
                    ": cannot write image: ", path.extension() == ".pgm" ? "PGM" : "this writer",
                    " takes 8- or 16-bit single-channel images");
  WriteImage(path, image, ImageWriteOptions{png_compression});
}

ImageSet ImageSet::Open(const fs::path& dir) {
  std::error_code ec;
  SLSHADOW_THROW_IF(!fs::is_directory(dir, ec), dir.string(),
                    ": not an ImageSet folder (no such directory)");
  const fs::path manifest_path = dir / "manifest.json";
  const ConfigNode root = ConfigNode::LoadFile(manifest_path);
  root.RejectUnknownKeys({"format", "version", "created", "rig", "patterns", "images", "extra"});
  if (root["format"].AsString() != "slshadow-imageset")
    root["format"].Fail("expected \"slshadow-imageset\"");
  if (root["version"].AsInt() != kFormatVersion) {
    root["version"].Fail("unsupported ImageSet version (this slshadow reads version 1)");
  }
  ImageSet set;
  set.dir_ = dir;
  set.created_ = root.GetString("created", "");
  set.rig_ = RigFromConfig(root["rig"]);
  set.patterns_ = root["patterns"].json();
  if (root.Has("extra")) set.extra_ = root["extra"].json();
  const auto images = root["images"];
  std::map<std::pair<std::string, int>, size_t> seen;
  for (size_t i = 0; i < images.size(); ++i) {
    const auto n = images.at(i);
    ImageRecord r = RecordFromConfig(n, set.rig_, dir);
    if (!seen.emplace(std::make_pair(r.camera, r.pattern_index), i).second) {
      n.Fail("duplicate image for camera '" + r.camera + "', pattern " +
             std::to_string(r.pattern_index));
    }
    set.records_.push_back(std::move(r));
  }
  return set;
}

std::vector<std::string> ImageSet::CameraNames() const {
  std::vector<std::string> names;
  for (const auto& c : rig_.cameras) {
    for (const auto& r : records_) {
      if (r.camera == c.name) {
        names.push_back(c.name);
        break;
      }
    }
  }
  return names;
}

int ImageSet::PatternCount() const {
  int n = 0;
  for (const auto& r : records_) n = std::max(n, r.pattern_index + 1);
  return n;
}

const ImageRecord* ImageSet::Find(const std::string& camera, int pattern_index) const {
  for (const auto& r : records_) {
    if (r.camera == camera && r.pattern_index == pattern_index) return &r;
  }
  return nullptr;
}

cv::Mat ImageSet::Load(const std::string& camera, int pattern_index) const {
  const ImageRecord* r = Find(camera, pattern_index);
  SLSHADOW_THROW_IF(r == nullptr, (dir_ / "manifest.json").string(), ": no image for camera '",
                    camera, "', pattern ", pattern_index);
  const fs::path path = dir_ / r->file;
  const RigDevice& device = rig_.Camera(camera);
  if (const auto size = PeekImageSize(path);
      size && (size->width != device.model.width || size->height != device.model.height)) {
    SLSHADOW_THROW(path.string(), ": wrong image size ", size->width, "x", size->height,
                   " in its header, camera '", camera, "' is ", device.model.width, "x",
                   device.model.height);
  }
  cv::Mat image = ReadGrayImage(path);
  CheckImage(image, device, path.string(), r->bit_depth);
  return image;
}

std::vector<cv::Mat> ImageSet::LoadCamera(const std::string& camera) const {
  const int n = PatternCount();
  // Every pattern must be there before anything is allocated for n of them.
  std::vector<bool> present(static_cast<size_t>(n), false);
  for (const auto& r : records_) {
    if (r.camera == camera) present[static_cast<size_t>(r.pattern_index)] = true;
  }
  for (int i = 0; i < n; ++i) {
    SLSHADOW_THROW_IF(!present[static_cast<size_t>(i)], (dir_ / "manifest.json").string(),
                      ": no image for camera '", camera, "', pattern ", i,
                      " (the manifest has patterns up to ", n - 1, ")");
  }
  std::vector<cv::Mat> images(n);
  std::vector<std::string> errors(n);
  cv::parallel_for_(cv::Range(0, n), [&](const cv::Range& range) {
    for (int i = range.start; i < range.end; ++i) {
      try {
        images[i] = Load(camera, i);
      } catch (const Error& e) {
        errors[i] = e.what();
      }
    }
  });
  for (const auto& e : errors) SLSHADOW_THROW_IF(!e.empty(), e);
  return images;
}

ImageSetWriter::ImageSetWriter(fs::path dir, Rig rig, nlohmann::json patterns,
                               ImageSetWriterOptions options)
    : dir_(std::move(dir)),
      rig_(std::move(rig)),
      patterns_(std::move(patterns)),
      options_(options) {
  rig_.Check(dir_.string() + " (rig)");
  SLSHADOW_THROW_IF(patterns_.is_null(), dir_.string(),
                    ": patterns: an ImageSet needs its pattern specification");
  std::error_code ec;
  SLSHADOW_THROW_IF(fs::exists(dir_, ec) && !options_.overwrite, dir_.string(),
                    ": already exists (choose another folder or pass --overwrite)");
  SLSHADOW_THROW_IF(options_.png_compression < 0 || options_.png_compression > 9,
                    "png_compression: must be 0..9 (got ", options_.png_compression, ")");
  staging_ = TemporarySibling(dir_);
  fs::create_directories(staging_, ec);
  SLSHADOW_THROW_IF(ec, staging_.string(), ": cannot create folder: ", ec.message());
  for (const auto& c : rig_.cameras) fs::create_directories(staging_ / c.name, ec);
}

ImageSetWriter::~ImageSetWriter() {
  if (!committed_) {
    std::error_code ec;
    fs::remove_all(staging_, ec);
  }
}

void ImageSetWriter::Add(const std::string& camera, int pattern_index, const cv::Mat& image,
                         double exposure_us, ImageSource source, const std::string& timestamp) {
  SLSHADOW_THROW_IF(committed_, dir_.string(), ": ImageSet already committed");
  const RigDevice& device = rig_.Camera(camera);
  SLSHADOW_THROW_IF(pattern_index < 0, "pattern index must be >= 0 (got ", pattern_index, ")");
  char name[32];
  std::snprintf(name, sizeof(name), "%04d", pattern_index);
  ImageRecord r;
  r.camera = camera;
  r.pattern_index = pattern_index;
  r.file = camera + "/" + name + Extension(options_.encoding);
  CheckImage(image, device, dir_.string() + "/" + r.file, 0);
  r.bit_depth = image.depth() == CV_16U ? 16 : 8;
  r.exposure_us = exposure_us;
  r.timestamp = timestamp.empty() ? UtcTimestamp() : timestamp;
  r.source = source;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& other : records_) {
      SLSHADOW_THROW_IF(other.camera == camera && other.pattern_index == pattern_index,
                        dir_.string(), ": duplicate image for camera '", camera, "', pattern ",
                        pattern_index);
    }
    records_.push_back(r);
  }
  WriteGrayImage(staging_ / r.file, image, options_.png_compression);
}

void ImageSetWriter::Commit() {
  std::lock_guard<std::mutex> lock(mutex_);
  SLSHADOW_THROW_IF(committed_, dir_.string(), ": ImageSet already committed");
  std::sort(records_.begin(), records_.end(), [&](const ImageRecord& a, const ImageRecord& b) {
    const int ca = rig_.CameraIndex(a.camera), cb = rig_.CameraIndex(b.camera);
    return ca != cb ? ca < cb : a.pattern_index < b.pattern_index;
  });
  nlohmann::json m;
  m["format"] = "slshadow-imageset";
  m["version"] = ImageSet::kFormatVersion;
  m["created"] = UtcTimestamp();
  m["rig"] = RigToJson(rig_);
  m["patterns"] = patterns_;
  m["images"] = nlohmann::json::array();
  for (const auto& r : records_) m["images"].push_back(RecordToJson(r));
  if (!extra_.is_null()) m["extra"] = extra_;
  WriteTextFileAtomically(staging_ / "manifest.json", m.dump(1) + "\n");
  CommitDirectory(staging_, dir_, options_.overwrite);
  committed_ = true;
}

// ---------------------------------------------------------------------------------------------
// ResumableImageSetWriter

namespace {

constexpr const char* kStagingHeader = "staging.json";
constexpr const char* kJournal = "journal.jsonl";

void FsyncPath(const fs::path& path, bool directory) {
  const int fd = ::open(path.c_str(), (directory ? O_RDONLY | O_DIRECTORY : O_RDONLY) | O_CLOEXEC);
  SLSHADOW_THROW_IF(fd < 0, path.string(), ": cannot open to sync: ", std::strerror(errno));
  const int rc = ::fsync(fd);
  const int error = errno;
  ::close(fd);
  SLSHADOW_THROW_IF(rc != 0, path.string(), ": fsync failed: ", std::strerror(error));
}

std::string EncodingName(ImageEncoding e) {
  switch (e) {
    case ImageEncoding::kPng:
      return "png";
    case ImageEncoding::kPgm:
      return "pgm";
    case ImageEncoding::kTiff:
      return "tiff";
  }
  return "png";
}

std::string RecordFileName(const std::string& camera, int pattern_index, ImageEncoding encoding) {
  char name[32];
  std::snprintf(name, sizeof(name), "%04d", pattern_index);
  return camera + "/" + name + Extension(encoding);
}

}  // namespace

fs::path ResumableImageSetWriter::StagingDirFor(const fs::path& dir) {
  fs::path staging = dir.has_filename() ? dir : dir.parent_path();
  staging += ".partial";
  return staging;
}

ResumableImageSetWriter::ResumableImageSetWriter(fs::path dir, Rig rig, nlohmann::json patterns,
                                                 ResumableImageSetWriterOptions options)
    : dir_(std::move(dir)),
      rig_(std::move(rig)),
      patterns_(std::move(patterns)),
      options_(options) {
  rig_.Check(dir_.string() + " (rig)");
  SLSHADOW_THROW_IF(patterns_.is_null(), dir_.string(),
                    ": patterns: an ImageSet needs its pattern specification");
  SLSHADOW_THROW_IF(options_.png_compression < 0 || options_.png_compression > 9,
                    "png_compression: must be 0..9 (got ", options_.png_compression, ")");
  staging_ = StagingDirFor(dir_);
  std::error_code ec;
  SLSHADOW_THROW_IF(fs::exists(dir_, ec) && !options_.overwrite, dir_.string(),
                    ": already exists (choose another folder or pass --overwrite)");
  const nlohmann::json header = {{"format", "slshadow-imageset-staging"},
                                 {"version", 1},
                                 {"rig", RigToJson(rig_)},
                                 {"patterns", patterns_},
                                 {"encoding", EncodingName(options_.encoding)}};
  if (fs::exists(staging_, ec)) {
    SLSHADOW_THROW_IF(!options_.resume, staging_.string(),
                      ": an interrupted capture is staged here; continue it with --resume, or "
                      "delete the folder to "
                      "start over");
    const ConfigNode root = ConfigNode::LoadFile(staging_ / kStagingHeader);
    if (root["format"].AsString() != "slshadow-imageset-staging")
      root["format"].Fail("expected \"slshadow-imageset-staging\"");
    if (root["version"].AsInt() != 1)
      root["version"].Fail("unsupported staging version (this slshadow reads 1)");
    const std::string what =
        staging_.string() + ": cannot resume: the staged capture was started with ";
    SLSHADOW_THROW_IF(root["rig"].json() != header["rig"], what,
                      "another rig (cameras, projector or calibration differ); use the same rig "
                      "file, or delete the "
                      "folder to start over");
    SLSHADOW_THROW_IF(
        root["patterns"].json() != header["patterns"], what,
        "another pattern spec; use the same patterns file, or delete the folder to start over");
    SLSHADOW_THROW_IF(root["encoding"].AsString() != header["encoding"], what, "image encoding '",
                      root["encoding"].AsString(), "', this run asks for '",
                      EncodingName(options_.encoding), "'");
    resumed_ = true;
    LoadJournal();
  } else {
    fs::create_directories(staging_, ec);
    SLSHADOW_THROW_IF(ec, staging_.string(), ": cannot create folder: ", ec.message());
    WriteTextFileAtomically(staging_ / kStagingHeader, header.dump(1) + "\n");
  }
  for (const auto& c : rig_.cameras) {
    fs::create_directories(staging_ / c.name, ec);
    SLSHADOW_THROW_IF(ec, (staging_ / c.name).string(), ": cannot create folder: ", ec.message());
  }
  journal_fd_ =
      ::open((staging_ / kJournal).c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  SLSHADOW_THROW_IF(journal_fd_ < 0, (staging_ / kJournal).string(),
                    ": cannot open: ", std::strerror(errno));
  if (options_.durable) FsyncPath(staging_, true);
}

ResumableImageSetWriter::~ResumableImageSetWriter() {
  if (journal_fd_ >= 0) ::close(journal_fd_);
}

void ResumableImageSetWriter::LoadJournal() {
  const fs::path path = staging_ / kJournal;
  std::error_code ec;
  if (!fs::exists(path, ec)) return;
  const std::string text = ReadTextFile(path);
  // Complete lines end in '\n'. A crash can leave a torn (or zero-filled) tail: every line from the
  // first unreadable one on must be unreadable too, and is cut off; an unreadable line followed by
  // good ones is corruption, not a crash, and is refused.
  struct Line {
    size_t begin, end;
    bool ok;
    nlohmann::json json;
  };
  std::vector<Line> lines;
  for (size_t begin = 0; begin < text.size();) {
    const size_t nl = text.find('\n', begin);
    Line line{begin, nl == std::string::npos ? text.size() : nl + 1, false, {}};
    if (nl != std::string::npos) {
      line.json =
          nlohmann::json::parse(text.begin() + static_cast<std::ptrdiff_t>(begin),
                                text.begin() + static_cast<std::ptrdiff_t>(nl), nullptr, false);
      line.ok = line.json.is_object() && line.json.contains("type");
    }
    lines.push_back(std::move(line));
    begin = lines.back().end;
  }
  size_t good = lines.size();
  for (size_t i = 0; i < lines.size(); ++i) {
    if (lines[i].ok) continue;
    for (size_t j = i + 1; j < lines.size(); ++j) {
      SLSHADOW_THROW_IF(
          lines[j].ok, path.string(), ": line ", i + 1,
          ": unreadable journal line followed by readable ones (the file was edited or damaged; "
          "delete the staging folder to start over)");
    }
    good = i;
    break;
  }
  if (good < lines.size()) {
    const size_t keep = lines[good].begin;
    SLSHADOW_THROW_IF(::truncate(path.c_str(), static_cast<off_t>(keep)) != 0, path.string(),
                      ": cannot cut off the torn last line: ", std::strerror(errno));
  }
  for (size_t i = 0; i < good; ++i) {
    const ConfigNode node =
        ConfigNode::FromJson(lines[i].json, path.string(), "line " + std::to_string(i + 1));
    const std::string type = node["type"].AsString();
    if (type == "session") {
      sessions_.push_back(node["session"].json());
      continue;
    }
    if (type != "image") node["type"].Fail("expected \"image\" or \"session\"");
    if (!fs::is_regular_file(staging_ / node["file"].AsString(), ec)) continue;  // taken again
    ImageRecord r = RecordFromConfig(node, rig_, staging_, true);
    bool replaced = false;
    for (auto& other : records_) {
      if (other.camera == r.camera && other.pattern_index == r.pattern_index) {
        other = r;
        replaced = true;
      }
    }
    if (!replaced) records_.push_back(std::move(r));
  }
}

void ResumableImageSetWriter::AppendJournalLine(const std::string& line) {
  // Called with mutex_ held. One write() per line: O_APPEND keeps lines whole between threads.
  const std::string text = line + "\n";
  for (size_t done = 0; done < text.size();) {
    const ssize_t n = ::write(journal_fd_, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    SLSHADOW_THROW_IF(n <= 0, (staging_ / kJournal).string(),
                      ": cannot append: ", std::strerror(errno));
    done += static_cast<size_t>(n);
  }
  if (options_.durable) {
    SLSHADOW_THROW_IF(::fsync(journal_fd_) != 0, (staging_ / kJournal).string(),
                      ": fsync failed: ", std::strerror(errno));
  }
}

bool ResumableImageSetWriter::Has(const std::string& camera, int pattern_index) const {
  return Find(camera, pattern_index).has_value();
}

std::optional<ImageRecord> ResumableImageSetWriter::Find(const std::string& camera,
                                                         int pattern_index) const {
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& r : records_) {
    if (r.camera == camera && r.pattern_index == pattern_index) return r;
  }
  return std::nullopt;
}

std::vector<ImageRecord> ResumableImageSetWriter::Records() const {
  std::vector<ImageRecord> records;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    records = records_;
  }
  std::sort(records.begin(), records.end(), [&](const ImageRecord& a, const ImageRecord& b) {
    const int ca = rig_.CameraIndex(a.camera), cb = rig_.CameraIndex(b.camera);
    return ca != cb ? ca < cb : a.pattern_index < b.pattern_index;
  });
  return records;
}

cv::Mat ResumableImageSetWriter::Load(const std::string& camera, int pattern_index) const {
  const auto r = Find(camera, pattern_index);
  SLSHADOW_THROW_IF(!r, staging_.string(), ": no finished image for camera '", camera,
                    "', pattern ", pattern_index);
  const fs::path path = staging_ / r->file;
  cv::Mat image = ReadGrayImage(path);
  CheckImage(image, rig_.Camera(camera), path.string(), r->bit_depth);
  return image;
}

ImageRecord ResumableImageSetWriter::Add(ImageRecord record, const cv::Mat& image) {
  SLSHADOW_THROW_IF(committed_, dir_.string(), ": ImageSet already committed");
  const RigDevice& device = rig_.Camera(record.camera);
  SLSHADOW_THROW_IF(record.pattern_index < 0, "pattern index must be >= 0 (got ",
                    record.pattern_index, ")");
  record.file = RecordFileName(record.camera, record.pattern_index, options_.encoding);
  CheckImage(image, device, dir_.string() + "/" + record.file, 0);
  record.bit_depth = image.depth() == CV_16U ? 16 : 8;
  if (record.timestamp.empty()) record.timestamp = UtcTimestamp();
  const fs::path final_path = staging_ / record.file;
  fs::path tmp = final_path.parent_path() / ("." + final_path.stem().string() + ".tmp");
  tmp += final_path.extension();
  std::error_code ec;
  WriteGrayImage(tmp, image, options_.png_compression);
  if (options_.durable) FsyncPath(tmp, false);
  fs::rename(tmp, final_path, ec);
  if (ec) {
    fs::remove(tmp, ec);
    SLSHADOW_THROW(final_path.string(), ": cannot move finished image into place: ", ec.message());
  }
  if (options_.durable) FsyncPath(final_path.parent_path(), true);
  nlohmann::json line = RecordToJson(record);
  line["type"] = "image";
  std::lock_guard<std::mutex> lock(mutex_);
  AppendJournalLine(line.dump());
  bool replaced = false;
  for (auto& other : records_) {
    if (other.camera == record.camera && other.pattern_index == record.pattern_index) {
      other = record;
      replaced = true;
    }
  }
  if (!replaced) records_.push_back(record);
  return record;
}

void ResumableImageSetWriter::AppendSession(const nlohmann::json& session) {
  std::lock_guard<std::mutex> lock(mutex_);
  AppendJournalLine(nlohmann::json{{"type", "session"}, {"session", session}}.dump());
  sessions_.push_back(session);
}

std::vector<nlohmann::json> ResumableImageSetWriter::Sessions() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return sessions_;
}

void ResumableImageSetWriter::Commit() {
  SLSHADOW_THROW_IF(committed_, dir_.string(), ": ImageSet already committed");
  const std::vector<ImageRecord> records = Records();
  nlohmann::json m;
  m["format"] = "slshadow-imageset";
  m["version"] = ImageSet::kFormatVersion;
  m["created"] = UtcTimestamp();
  m["rig"] = RigToJson(rig_);
  m["patterns"] = patterns_;
  m["images"] = nlohmann::json::array();
  for (const auto& r : records) m["images"].push_back(RecordToJson(r));
  if (!extra_.is_null()) m["extra"] = extra_;
  WriteTextFileAtomically(staging_ / "manifest.json", m.dump(1) + "\n");
  if (options_.durable) FsyncPath(staging_ / "manifest.json", false);
  std::lock_guard<std::mutex> lock(mutex_);
  ::close(journal_fd_);
  journal_fd_ = -1;
  // Stray temporary images of frames that never finished.
  std::error_code ec;
  for (const auto& c : rig_.cameras) {
    for (const auto& entry : fs::directory_iterator(staging_ / c.name, ec)) {
      const std::string name = entry.path().filename().string();
      if (!name.empty() && name[0] == '.' && name.find(".tmp") != std::string::npos)
        fs::remove(entry.path(), ec);
    }
  }
  CommitDirectory(staging_, dir_, options_.overwrite);
  committed_ = true;
  fs::remove(dir_ / kJournal, ec);
  fs::remove(dir_ / kStagingHeader, ec);
}

}  // namespace slshadow
