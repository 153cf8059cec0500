// core/progress: what reaches stderr, read back through GoogleTest's capture of file descriptor 2.
// SLSHADOW_PROGRESS decides whether anything is printed (the tests' stderr is not a terminal).
#include "core/progress.h"

#include <chrono>
#include <cstdlib>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

namespace slshadow {
namespace {

// Runs `work` with SLSHADOW_PROGRESS set to `env` and returns what it wrote to stderr.
template <typename Work>
std::string StderrOf(const char* env, Work work) {
  setenv("SLSHADOW_PROGRESS", env, 1);
  ::testing::internal::CaptureStderr();
  work();
  std::string err = ::testing::internal::GetCapturedStderr();
  unsetenv("SLSHADOW_PROGRESS");
  return err;
}

// The last "\r"-separated line: what a terminal shows at the end.
std::string LastLine(const std::string& s) { return s.substr(s.rfind('\r') + 1); }

TEST(Progress, FinalLineSaysAllStepsAndEndsTheLine) {
  const std::string err = StderrOf("1", [] {
    Progress p("decode", 4);
    for (int i = 0; i < 4; ++i) p.Advance();
  });
  ASSERT_FALSE(err.empty());
  EXPECT_EQ(err.front(), '\r') << err;  // every line overwrites the last
  EXPECT_EQ(err.back(), '\n') << err;   // the destructor ends it
  const std::string last = LastLine(err);
  EXPECT_EQ(last.rfind("decode: 100% (4/4), ", 0), 0u) << err;
  EXPECT_EQ(last.substr(last.size() - 3), " s\n") << err;
  // The step that completes the work prints however soon after the last line, and the destructor
  // prints the final line again with its newline: twice in all.
  int complete = 0;
  for (size_t at = err.find("\rdecode: 100% (4/4), "); at != std::string::npos;
       at = err.find("\rdecode: 100% (4/4), ", at + 1)) {
    ++complete;
  }
  EXPECT_EQ(complete, 2) << err;
}

TEST(Progress, DisabledPrintsNothingAndCountsStill) {
  const std::string err = StderrOf("0", [] {
    Progress p("quiet", 3);
    p.Advance(3);
    EXPECT_GE(p.ElapsedSeconds(), 0);
  });
  EXPECT_EQ(err, "");
}

TEST(Progress, NothingAdvancedPrintsNothing) {
  EXPECT_EQ(StderrOf("1", [] { Progress p("idle", 10); }), "");
}

// A step of several, a total of zero (shown as done), and many threads advancing at once: the
// final line counts every step exactly once.
TEST(Progress, StepsFromManyThreadsAreCountedOnce) {
  const std::string err = StderrOf("1", [] {
    Progress p("render", 4000);
    std::vector<std::thread> threads;
    for (int t = 0; t < 4; ++t) {
      threads.emplace_back([&p] {
        for (int i = 0; i < 500; ++i) p.Advance(2);
      });
    }
    for (auto& t : threads) t.join();
  });
  EXPECT_EQ(LastLine(err).rfind("render: 100% (4000/4000), ", 0), 0u) << LastLine(err);
  const std::string zero = StderrOf("1", [] {
    Progress p("empty", 0);
    p.Advance(0);
  });
  EXPECT_EQ(LastLine(zero).rfind("empty: 100% (0/0), ", 0), 0u) << zero;
}

// Work that stops short: a step more than 250 ms after the start prints, and the final line says
// how far it got.
TEST(Progress, WorkStoppedShortShowsItsShare) {
  const std::string err = StderrOf("1", [] {
    Progress p("merge", 8);
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    p.Advance(2);
  });
  EXPECT_EQ(err.rfind("\rmerge:  25% (2/8), ", 0), 0u) << err;
  EXPECT_EQ(LastLine(err).rfind("merge:  25% (2/8), ", 0), 0u) << err;
  EXPECT_EQ(err.back(), '\n') << err;
}

}  // namespace
}  // namespace slshadow
