// The slshadow binary re-executes itself once with glibc.malloc.hugetlb=1 (core/huge_pages.h):
// its --version line says what this process runs with. Run as the real binary, with the
// environment set per case.
#include <array>
#include <cstdio>
#include <string>

#include <gtest/gtest.h>

#include "core/huge_pages.h"

namespace {

std::string RunVersion(const std::string& env) {
  const std::string command = "env -u GLIBC_TUNABLES -u SLSHADOW_HUGE_PAGES " + env + " " +
                              SLSHADOW_BINARY + " --version 2>&1";
  FILE* pipe = popen(command.c_str(), "r");
  EXPECT_NE(pipe, nullptr) << command;
  if (!pipe) return "";
  std::string out;
  std::array<char, 256> buf;
  while (fgets(buf.data(), buf.size(), pipe)) out += buf.data();
  EXPECT_EQ(pclose(pipe), 0) << command << "\n" << out;
  return out;
}

TEST(HugePagesCli, VersionSaysWhatTheProcessRunsWith) {
  const std::string off = RunVersion("SLSHADOW_HUGE_PAGES=0");
  const std::string mode = slshadow::KernelThpMode();
  if (mode == "always") {
    EXPECT_NE(off.find("the kernel's mode is 'always'"), std::string::npos) << off;
    GTEST_SKIP() << "transparent huge pages are 'always' here: nothing to re-execute for";
  }
  EXPECT_NE(off.find("memory: malloc on 4 KiB pages (SLSHADOW_HUGE_PAGES=0)"), std::string::npos)
      << off;
  int major = 0, minor = 0;
  slshadow::GlibcVersion(&major, &minor);
  const std::string on = RunVersion("");
  const std::string other = RunVersion("GLIBC_TUNABLES=glibc.malloc.check=0");
  if (mode != "madvise" || major < 2 || (major == 2 && minor < 35)) {
    EXPECT_NE(on.find("memory: malloc on 4 KiB pages ("), std::string::npos) << on;
    GTEST_SKIP() << "transparent huge pages '" << mode << "', glibc " << major << "." << minor
                 << ": the re-execution does not apply here";
  }
  // Re-executed with the tunable, also when other tunables were set.
  for (const std::string& out : {on, other}) {
    EXPECT_NE(out.find("slshadow "), std::string::npos) << out;
    EXPECT_NE(out.find("memory: malloc on transparent huge pages (GLIBC_TUNABLES "
                       "glibc.malloc.hugetlb=1)"),
              std::string::npos)
        << out;
  }
  // A tunable the user set is left alone.
  const std::string user = RunVersion("GLIBC_TUNABLES=glibc.malloc.hugetlb=0");
  EXPECT_NE(user.find("4 KiB pages (GLIBC_TUNABLES sets glibc.malloc.hugetlb already)"),
            std::string::npos)
      << user;
}

}  // namespace
