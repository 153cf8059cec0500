// Large buffers on transparent huge pages, for the command line (apps/main.cc).
//
// A command allocates hundreds of MB (images, projector maps, grids, clouds) and touches each page
// once. Where the kernel's transparent huge pages are "madvise" (Debian's default), glibc's malloc
// backs all of it with 4 KiB pages, one page fault each; on a virtual machine a fault can cost
// ~9 us: `slshadow demo` took 1.7x as long as it does with huge pages
// (docs/benchmarks/log/2026-11-29-huge-pages.md). glibc's tunable glibc.malloc.hugetlb=1 (glibc
// 2.35 on) makes malloc advise the kernel to back its heap with 2 MiB pages (madvise
// MADV_HUGEPAGE), but glibc reads tunables only when a program starts: the command line therefore
// re-executes itself once, first thing, with the tunable added to GLIBC_TUNABLES (same process,
// same arguments; the environment variable SLSHADOW_HUGE_PAGES=0 turns this off).
#pragma once

#include <optional>
#include <string>

namespace slshadow {

// The GLIBC_TUNABLES value to re-execute with: `tunables` (the current value; nullptr when unset)
// with glibc.malloc.hugetlb=1 appended. Nothing when `disabled`, when `tunables` already sets
// glibc.malloc.hugetlb, when `thp_mode` (the selected word of
// /sys/kernel/mm/transparent_hugepage/enabled) is not "madvise" ("always" backs large buffers with
// huge pages already, "never" forbids them, "" unknown), or when glibc is older than 2.35. Sets
// *reason (when given) to why nothing is to be done.
std::optional<std::string> HugePageTunables(const char* tunables, const std::string& thp_mode,
                                            int glibc_major, int glibc_minor, bool disabled,
                                            std::string* reason = nullptr);

// The selected mode in the text of /sys/kernel/mm/transparent_hugepage/enabled
// ("always [madvise] never" -> "madvise"); "" when there is none.
std::string SelectedThpMode(const std::string& text);

// This machine's facts HugePageTunables judges by: the kernel's transparent huge page mode ("" when
// unknown) and glibc's version (0.0 without glibc).
std::string KernelThpMode();
void GlibcVersion(int* major, int* minor);

// Re-executes the running program (/proc/self/exe) with `argv` and GLIBC_TUNABLES as
// HugePageTunables gives it for this process; returns only when there is nothing to do or the
// re-execution failed (the program then simply runs with 4 KiB pages).
void ReexecWithHugePages(char** argv);

// One line for `slshadow --version`: whether this process's malloc uses huge pages, and if not why.
std::string HugePagesStatus();

}  // namespace slshadow
