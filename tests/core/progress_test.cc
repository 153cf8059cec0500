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

// An observer installed on a thread sees the Progress objects constructed there (also when they
// advance from other threads), with `done` rising from call to call and ending at the total; a
// Progress constructed on another thread or after the scope ends is not seen; print=false keeps
// stderr clean while the observer still sees every step.
TEST(Progress, ObserverSeesItsThreadsWorkInOrder) {
  std::vector<std::pair<std::string, int64_t>> seen;
  const std::string err = StderrOf("1", [&seen] {
    {
      ScopedProgressObserver observer(
          [&seen](const std::string& task, int64_t done, int64_t total) {
            EXPECT_EQ(total, 4000);
            seen.emplace_back(task, done);
          });
      Progress p("render", 4000, false);
      std::vector<std::thread> threads;
      for (int t = 0; t < 4; ++t) {
        threads.emplace_back([&p] {
          for (int i = 0; i < 500; ++i) p.Advance(2);
        });
      }
      for (auto& t : threads) t.join();
      std::thread other([] {
        Progress q("elsewhere", 1, false);
        q.Advance();
      });
      other.join();
    }
    Progress after("after", 1, false);
    after.Advance();
  });
  EXPECT_EQ(err, "");
  ASSERT_FALSE(seen.empty());
  for (size_t i = 0; i < seen.size(); ++i) {
    EXPECT_EQ(seen[i].first, "render");
    if (i > 0) {
      EXPECT_GT(seen[i].second, seen[i - 1].second);
    }
  }
  EXPECT_EQ(seen.back().second, 4000);
}

TEST(Progress, NestedObserversRestoreTheOuterOne) {
  int outer = 0, inner = 0;
  ScopedProgressObserver a([&outer](const std::string&, int64_t, int64_t) { ++outer; });
  {
    ScopedProgressObserver b([&inner](const std::string&, int64_t, int64_t) { ++inner; });
    Progress p("inner", 2, false);
    p.Advance(2);
  }
  Progress q("outer", 3, false);
  q.Advance();
  q.Advance();
  EXPECT_EQ(inner, 1);
  EXPECT_EQ(outer, 2);
}

}  // namespace
}  // namespace slshadow
