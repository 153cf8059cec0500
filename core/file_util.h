// File helpers that keep the promise "nothing already written is lost or half-written": every
// output is written to a temporary sibling and renamed into place only when complete.
#pragma once

#include <chrono>
#include <filesystem>
#include <functional>
#include <string>

namespace slshadow {

// Reads a whole file; throws slshadow::Error naming the file when it cannot be read.
std::string ReadTextFile(const std::filesystem::path& path);

// Calls write(temporary_path), then renames the temporary file onto `path`. If write throws, the
// temporary file is removed and `path` is untouched. Creates missing parent directories.
void WriteFileAtomically(const std::filesystem::path& path,
                         const std::function<void(const std::filesystem::path&)>& write);

// Writes `text` to `path` atomically.
void WriteTextFileAtomically(const std::filesystem::path& path, const std::string& text);

// A unique temporary sibling name of `path` ("<name>.partial-<pid>-<n>"). The name is
// remembered as unfinished output until CommitDirectory or WriteFileAtomically moves it into place:
// an interrupt (InstallInterruptCleanup) removes whatever exists under an unfinished name.
std::filesystem::path TemporarySibling(const std::filesystem::path& path);

// Installs handlers for SIGINT and SIGTERM that remove every unfinished output (files and folders
// under TemporarySibling names not yet moved into place), print one line to stderr and end the
// process by the same signal (exit status 128 + signal in a shell). A signal arriving while a
// finished folder replaces an existing one (CommitDirectory) is held until the swap is done, so
// the existing folder is never lost. Called once by the command line's Main.
void InstallInterruptCleanup();

// Replaces directory `target` by the complete directory `staged` (a sibling): an existing target
// is moved aside, the staged one renamed in, and the old one removed. Throws when target exists
// and `overwrite` is false.
void CommitDirectory(const std::filesystem::path& staged, const std::filesystem::path& target,
                     bool overwrite);

// A folder built under a temporary sibling name of `target` and moved into place by Commit()
// (CommitDirectory); destroyed uncommitted, it is removed with everything in it, so an error
// midway leaves nothing half-written. The constructor creates the folder (throws naming it).
class StagingDirectory {
 public:
  explicit StagingDirectory(std::filesystem::path target);
  ~StagingDirectory();
  StagingDirectory(const StagingDirectory&) = delete;
  StagingDirectory& operator=(const StagingDirectory&) = delete;
  const std::filesystem::path& path() const { return staging_; }
  void Commit(bool overwrite);

 private:
  std::filesystem::path target_, staging_;
  bool committed_ = false;
};

// The current UTC time as ISO 8601 with milliseconds, e.g. "2026-11-22T06:30:00.123Z".
std::string UtcTimestamp();
// The same for a given time.
std::string UtcTimestamp(std::chrono::system_clock::time_point time);

}  // namespace slshadow
