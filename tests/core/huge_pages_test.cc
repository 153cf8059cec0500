#include "core/huge_pages.h"

#include <string>

#include <gtest/gtest.h>

namespace slshadow {
namespace {

TEST(HugePages, SelectedModeIsTheBracketedWord) {
  EXPECT_EQ(SelectedThpMode("always [madvise] never\n"), "madvise");
  EXPECT_EQ(SelectedThpMode("[always] madvise never\n"), "always");
  EXPECT_EQ(SelectedThpMode("always madvise [never]"), "never");
  EXPECT_EQ(SelectedThpMode(""), "");
  EXPECT_EQ(SelectedThpMode("always madvise never"), "");
  EXPECT_EQ(SelectedThpMode("[unterminated"), "");
}

TEST(HugePages, TunableAddedOnlyWhereItHelps) {
  std::string reason;
  // The case it is for: madvise mode, glibc 2.35 on, nothing set.
  EXPECT_EQ(HugePageTunables(nullptr, "madvise", 2, 36, false), "glibc.malloc.hugetlb=1");
  EXPECT_EQ(HugePageTunables("", "madvise", 2, 35, false), "glibc.malloc.hugetlb=1");
  EXPECT_EQ(HugePageTunables(nullptr, "madvise", 3, 0, false), "glibc.malloc.hugetlb=1");
  // Other tunables are kept.
  EXPECT_EQ(HugePageTunables("glibc.malloc.check=3", "madvise", 2, 36, false),
            "glibc.malloc.check=3:glibc.malloc.hugetlb=1");
  // Nothing to do, and why.
  EXPECT_FALSE(HugePageTunables(nullptr, "madvise", 2, 36, true, &reason));
  EXPECT_EQ(reason, "SLSHADOW_HUGE_PAGES=0");
  EXPECT_FALSE(HugePageTunables("glibc.malloc.hugetlb=0", "madvise", 2, 36, false, &reason));
  EXPECT_NE(reason.find("sets glibc.malloc.hugetlb already"), std::string::npos) << reason;
  // Already re-executed: no second time (no loop).
  EXPECT_FALSE(HugePageTunables("glibc.malloc.hugetlb=1", "madvise", 2, 36, false));
  EXPECT_FALSE(HugePageTunables(nullptr, "always", 2, 36, false, &reason));
  EXPECT_EQ(reason, "the kernel's transparent huge pages are 'always'");
  EXPECT_FALSE(HugePageTunables(nullptr, "never", 2, 36, false, &reason));
  EXPECT_EQ(reason, "the kernel's transparent huge pages are 'never'");
  EXPECT_FALSE(HugePageTunables(nullptr, "", 2, 36, false, &reason));
  EXPECT_EQ(reason, "the kernel's transparent huge page mode is unknown");
  EXPECT_FALSE(HugePageTunables(nullptr, "madvise", 2, 34, false, &reason));
  EXPECT_EQ(reason, "glibc 2.34 has no glibc.malloc.hugetlb (2.35 on)");
}

}  // namespace
}  // namespace slshadow
