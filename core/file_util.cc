#include "core/file_util.h"

#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstring>
#include <ctime>
#include <fstream>
#include <sstream>
#include <utility>

#include "core/error.h"

namespace slshadow {
namespace fs = std::filesystem;

std::string ReadTextFile(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) SLSHADOW_THROW(path.string(), ": file not found");
  if (fs::is_directory(path, ec)) SLSHADOW_THROW(path.string(), ": is a directory, expected a file");
  std::ifstream in(path, std::ios::binary);
  if (!in) SLSHADOW_THROW(path.string(), ": cannot open for reading: ", std::strerror(errno));
  std::ostringstream s;
  s << in.rdbuf();
  if (in.bad()) SLSHADOW_THROW(path.string(), ": read error");
  return s.str();
}

fs::path TemporarySibling(const fs::path& path) {
  static std::atomic<int> counter{0};
  fs::path tmp = path;
  tmp += ".partial-" + std::to_string(::getpid()) + "-" + std::to_string(counter++);
  return tmp;
}

void WriteFileAtomically(const fs::path& path, const std::function<void(const fs::path&)>& write) {
  std::error_code ec;
  if (path.has_parent_path()) fs::create_directories(path.parent_path(), ec);
  if (ec) SLSHADOW_THROW(path.parent_path().string(), ": cannot create directory: ", ec.message());
  const fs::path tmp = TemporarySibling(path);
  try {
    write(tmp);
  } catch (...) {
    fs::remove(tmp, ec);
    throw;
  }
  fs::rename(tmp, path, ec);
  if (ec) {
    fs::remove(tmp, ec);
    SLSHADOW_THROW(path.string(), ": cannot move finished file into place: ", ec.message());
  }
}

void WriteTextFileAtomically(const fs::path& path, const std::string& text) {
  WriteFileAtomically(path, [&](const fs::path& tmp) {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) SLSHADOW_THROW(path.string(), ": cannot open for writing: ", std::strerror(errno));
    out << text;
    out.close();
    if (!out) SLSHADOW_THROW(path.string(), ": write failed (disk full?)");
  });
}

void CommitDirectory(const fs::path& staged, const fs::path& target, bool overwrite) {
  std::error_code ec;
  fs::path old;
  if (fs::exists(target, ec)) {
    if (!overwrite) SLSHADOW_THROW(target.string(), ": already exists (pass --overwrite to replace it)");
    old = TemporarySibling(target);
    fs::rename(target, old, ec);
    if (ec) SLSHADOW_THROW(target.string(), ": cannot move the existing folder aside: ", ec.message());
  }
  fs::rename(staged, target, ec);
  if (ec) {
    if (!old.empty()) fs::rename(old, target);
    SLSHADOW_THROW(target.string(), ": cannot move finished folder into place: ", ec.message());
  }
  if (!old.empty()) fs::remove_all(old, ec);
}

StagingDirectory::StagingDirectory(std::filesystem::path target)
    : target_(std::move(target)), staging_(TemporarySibling(target_)) {
  std::error_code ec;
  std::filesystem::create_directories(staging_, ec);
  SLSHADOW_THROW_IF(ec, staging_.string(), ": cannot create folder: ", ec.message());
}

StagingDirectory::~StagingDirectory() {
  std::error_code ec;
  if (!committed_) std::filesystem::remove_all(staging_, ec);
}

void StagingDirectory::Commit(bool overwrite) {
  CommitDirectory(staging_, target_, overwrite);
  committed_ = true;
}

std::string UtcTimestamp() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  const auto ms =
      std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count() % 1000;
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[64];
  std::strftime(buf, sizeof(buf), "%Y-%m-%dT%H:%M:%S", &tm);
  char out[80];
  std::snprintf(out, sizeof(out), "%s.%03dZ", buf, static_cast<int>(ms));
  return out;
}

}  // namespace slshadow
