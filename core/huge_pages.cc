#include "core/huge_pages.h"

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>

#ifdef __GLIBC__
#include <gnu/libc-version.h>
#endif
#include <unistd.h>

namespace slshadow {
namespace {

constexpr const char* kTunable = "glibc.malloc.hugetlb";
constexpr const char* kSwitch = "SLSHADOW_HUGE_PAGES";

bool Disabled() {
  const char* v = std::getenv(kSwitch);
  return v && std::strcmp(v, "0") == 0;
}

std::optional<std::string> TunablesForThisProcess(std::string* reason) {
  int major = 0, minor = 0;
  GlibcVersion(&major, &minor);
  return HugePageTunables(std::getenv("GLIBC_TUNABLES"), KernelThpMode(), major, minor, Disabled(),
                          reason);
}

}  // namespace

std::string KernelThpMode() {
  std::ifstream in("/sys/kernel/mm/transparent_hugepage/enabled");
  std::stringstream text;
  text << in.rdbuf();
  return SelectedThpMode(text.str());
}

void GlibcVersion(int* major, int* minor) {
  *major = *minor = 0;
#ifdef __GLIBC__
  std::sscanf(gnu_get_libc_version(), "%d.%d", major, minor);
#endif
}

std::string SelectedThpMode(const std::string& text) {
  const size_t open = text.find('['), close = text.find(']', open);
  if (open == std::string::npos || close == std::string::npos) return "";
  return text.substr(open + 1, close - open - 1);
}

std::optional<std::string> HugePageTunables(const char* tunables, const std::string& thp_mode,
                                            int glibc_major, int glibc_minor, bool disabled,
                                            std::string* reason) {
  std::string why;
  const std::string current = tunables ? tunables : "";
  if (disabled) {
    why = std::string(kSwitch) + "=0";
  } else if (current.find(kTunable) != std::string::npos) {
    why = "GLIBC_TUNABLES sets " + std::string(kTunable) + " already";
  } else if (thp_mode != "madvise") {
    why = thp_mode.empty() ? "the kernel's transparent huge page mode is unknown"
                           : "the kernel's transparent huge pages are '" + thp_mode + "'";
  } else if (glibc_major < 2 || (glibc_major == 2 && glibc_minor < 35)) {
    why = "glibc " + std::to_string(glibc_major) + "." + std::to_string(glibc_minor) + " has no " +
          kTunable + " (2.35 on)";
  }
  if (!why.empty()) {
    if (reason) *reason = why;
    return std::nullopt;
  }
  return (current.empty() ? "" : current + ":") + kTunable + "=1";
}

void ReexecWithHugePages(char** argv) {
  const std::optional<std::string> tunables = TunablesForThisProcess(nullptr);
  if (!tunables || !argv || !argv[0]) return;
  if (setenv("GLIBC_TUNABLES", tunables->c_str(), 1) != 0) return;
  execv("/proc/self/exe", argv);
  // Not re-executed (no /proc, say): run as we are, and say so in --version.
  unsetenv("GLIBC_TUNABLES");
}

std::string HugePagesStatus() {
  const std::string mode = KernelThpMode();
  if (mode == "always") {
    return "memory: large buffers on transparent huge pages (the kernel's mode is 'always')";
  }
  const char* tunables = std::getenv("GLIBC_TUNABLES");
  const std::string set = std::string(kTunable) + "=1";
  if (tunables && std::string(tunables).find(set) != std::string::npos && mode == "madvise") {
    return "memory: malloc on transparent huge pages (GLIBC_TUNABLES " + set + ")";
  }
  std::string reason;
  if (TunablesForThisProcess(&reason)) reason = "the program was not re-executed";
  return "memory: malloc on 4 KiB pages (" + reason + ")";
}

}  // namespace slshadow
