#include "core/file_util.h"

#include <fcntl.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <climits>
#include <csignal>
#include <cstddef>
#include <cstdint>

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
  if (fs::is_directory(path, ec))
    SLSHADOW_THROW(path.string(), ": is a directory, expected a file");
  std::ifstream in(path, std::ios::binary);
  if (!in) SLSHADOW_THROW(path.string(), ": cannot open for reading: ", std::strerror(errno));
  std::ostringstream s;
  s << in.rdbuf();
  if (in.bad()) SLSHADOW_THROW(path.string(), ": read error");
  return s.str();
}

// ---------------------------------------------------------------------------------------------
// Unfinished outputs and interrupts. The registry is a fixed array of slots the signal handler can
// read without locks or allocation: a slot is free (0), being filled (1) or holds a path (2).

namespace {

constexpr int kSlots = 512;
struct UnfinishedSlot {
  std::atomic<int> state{0};
  char path[PATH_MAX];
};
UnfinishedSlot g_unfinished[kSlots];
std::atomic<int> g_critical{0};        // CommitDirectory swaps in progress
std::atomic<int> g_pending_signal{0};  // a signal held back by a swap

void RememberUnfinished(const fs::path& path) {
  std::error_code ec;
  const std::string abs = fs::absolute(path, ec).string();
  if (ec || abs.size() >= PATH_MAX) return;
  for (auto& slot : g_unfinished) {
    int expected = 0;
    if (slot.state.compare_exchange_strong(expected, 1)) {
      std::memcpy(slot.path, abs.c_str(), abs.size() + 1);
      slot.state.store(2);
      return;
    }
  }
  // All slots taken: this output is then not removed on an interrupt (still never moved into
  // place).
}

void ForgetUnfinished(const fs::path& path) {
  std::error_code ec;
  const std::string abs = fs::absolute(path, ec).string();
  for (auto& slot : g_unfinished) {
    if (slot.state.load() == 2 && abs == slot.path) slot.state.store(0);
  }
}

// Removes a file or a folder tree with async-signal-safe calls only (openat, getdents64, unlinkat).
void RemoveTreeSignalSafe(int dir_fd, const char* name, int depth) {
  if (::unlinkat(dir_fd, name, 0) == 0 || errno == ENOENT) return;
  if (depth > 32) return;
  const int fd = ::openat(dir_fd, name, O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
  if (fd < 0) return;
  for (int pass = 0; pass < 3; ++pass) {  // other threads may still be adding files
    alignas(8) char buf[2048];
    for (;;) {
      const long n = ::syscall(SYS_getdents64, fd, buf, sizeof(buf));
      if (n <= 0) break;
      for (long off = 0; off < n;) {
        struct Dirent64 {
          uint64_t ino;
          int64_t off;
          unsigned short reclen;
          unsigned char type;
          char name[1];
        };
        const auto* d = reinterpret_cast<const Dirent64*>(buf + off);
        const char* child = buf + off + offsetof(Dirent64, name);
        if (!(child[0] == '.' && (child[1] == '\0' || (child[1] == '.' && child[2] == '\0')))) {
          RemoveTreeSignalSafe(fd, child, depth + 1);
        }
        off += d->reclen;
      }
    }
    if (::unlinkat(dir_fd, name, AT_REMOVEDIR) == 0 || errno == ENOENT) break;
    ::lseek(fd, 0, SEEK_SET);
  }
  ::close(fd);
}

void WriteSignalSafe(const char* text) {
  size_t n = 0;
  while (text[n] != '\0') ++n;
  while (n > 0) {
    const ssize_t w = ::write(STDERR_FILENO, text, n);
    if (w <= 0) return;
    text += w;
    n -= static_cast<size_t>(w);
  }
}

void CleanUpAndReraise(int sig) {
  for (auto& slot : g_unfinished) {
    if (slot.state.load() == 2) RemoveTreeSignalSafe(AT_FDCWD, slot.path, 0);
  }
  WriteSignalSafe(
      sig == SIGINT
          ? "slshadow: interrupted (SIGINT): unfinished outputs removed, existing files untouched\n"
          : "slshadow: terminated (SIGTERM): unfinished outputs removed, existing files "
            "untouched\n");
  ::signal(sig, SIG_DFL);
  ::raise(sig);
}

void OnInterrupt(int sig) {
  if (g_critical.load() > 0) {
    g_pending_signal.store(sig);
    return;
  }
  CleanUpAndReraise(sig);
}

// Holds SIGINT / SIGTERM (when InstallInterruptCleanup's handler is in place) until the scope ends.
class HoldInterrupts {
 public:
  HoldInterrupts() { ++g_critical; }
  ~HoldInterrupts() {
    if (--g_critical == 0) {
      const int sig = g_pending_signal.exchange(0);
      if (sig != 0) CleanUpAndReraise(sig);
    }
  }
  HoldInterrupts(const HoldInterrupts&) = delete;
  HoldInterrupts& operator=(const HoldInterrupts&) = delete;
};

}  // namespace

void InstallInterruptCleanup() {
  struct sigaction action {};
  action.sa_handler = OnInterrupt;
  sigemptyset(&action.sa_mask);
  action.sa_flags = SA_RESTART;
  ::sigaction(SIGINT, &action, nullptr);
  ::sigaction(SIGTERM, &action, nullptr);
}

fs::path TemporarySibling(const fs::path& path) {
  static std::atomic<int> counter{0};
  fs::path tmp = path;
  tmp += ".partial-" + std::to_string(::getpid()) + "-" + std::to_string(counter++);
  RememberUnfinished(tmp);
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
    ForgetUnfinished(tmp);
    throw;
  }
  fs::rename(tmp, path, ec);
  if (ec) {
    fs::remove(tmp, ec);
    SLSHADOW_THROW(path.string(), ": cannot move finished file into place: ", ec.message());
  }
  ForgetUnfinished(tmp);
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
  const HoldInterrupts hold;  // the existing target is never left moved aside
  std::error_code ec;
  fs::path old;
  if (fs::exists(target, ec)) {
    if (!overwrite)
      SLSHADOW_THROW(target.string(), ": already exists (pass --overwrite to replace it)");
    old = TemporarySibling(target);
    fs::rename(target, old, ec);
    if (ec)
      SLSHADOW_THROW(target.string(), ": cannot move the existing folder aside: ", ec.message());
  }
  fs::rename(staged, target, ec);
  if (ec) {
    if (!old.empty()) fs::rename(old, target);
    SLSHADOW_THROW(target.string(), ": cannot move finished folder into place: ", ec.message());
  }
  ForgetUnfinished(staged);
  if (!old.empty()) {
    fs::remove_all(old, ec);
    ForgetUnfinished(old);
  }
}

StagingDirectory::StagingDirectory(std::filesystem::path target)
    : target_(std::move(target)), staging_(TemporarySibling(target_)) {
  std::error_code ec;
  std::filesystem::create_directories(staging_, ec);
  SLSHADOW_THROW_IF(ec, staging_.string(), ": cannot create folder: ", ec.message());
}

StagingDirectory::~StagingDirectory() {
  std::error_code ec;
  if (!committed_) {
    std::filesystem::remove_all(staging_, ec);
    ForgetUnfinished(staging_);
  }
}

void StagingDirectory::Commit(bool overwrite) {
  CommitDirectory(staging_, target_, overwrite);
  committed_ = true;
}

std::string UtcTimestamp() { return UtcTimestamp(std::chrono::system_clock::now()); }

std::string UtcTimestamp(std::chrono::system_clock::time_point time) {
  const std::time_t t = std::chrono::system_clock::to_time_t(time);
  const auto ms =
      std::chrono::duration_cast<std::chrono::milliseconds>(time.time_since_epoch()).count() % 1000;
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[64];
  std::strftime(buf, sizeof(buf), "%Y-%m-%dT%H:%M:%S", &tm);
  char out[80];
  std::snprintf(out, sizeof(out), "%s.%03dZ", buf, static_cast<int>(ms));
  return out;
}

}  // namespace slshadow
