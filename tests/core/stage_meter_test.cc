#include "core/stage_meter.h"

#include <chrono>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include <cmath>

namespace slshadow {
namespace {

#if defined(__SANITIZE_ADDRESS__)
constexpr bool kFreedMemoryLeavesTheProcess = false;
#else
constexpr bool kFreedMemoryLeavesTheProcess = true;
#endif

TEST(StageMeter, MeasuresPeakMemoryOfTheStage) {
  const double before = CurrentRssMb();
  ASSERT_GT(before, 0) << "no /proc/self/status";
  StageMeter meter("allocate");
  {
    std::vector<char> block(200u << 20, 1);  // 200 MB, touched
    volatile char sink = block[block.size() / 2];
    (void)sink;
  }
  const StageMeasurement m = meter.Stop();
  EXPECT_EQ(m.name, "allocate");
  EXPECT_GE(m.peak_rss_mb, before + 190);
  EXPECT_GT(m.cpu_s, 0) << "touching 200 MB costs CPU time";
  // A later stage that allocates little reports a small peak when the kernel lets us reset it.
  StageMeter small("small");
  const StageMeasurement s = small.Stop();
  // (Under AddressSanitizer freed blocks stay in its quarantine, so the 200 MB are still resident.)
  if (!s.peak_is_process_wide && kFreedMemoryLeavesTheProcess) {
    EXPECT_LT(s.peak_rss_mb, before + 100);
  }
  // Wall and CPU time are told apart: a stage that sleeps 30 ms lasts at least that long on the
  // wall clock (a lower bound the kernel guarantees) and spends far less CPU than wall time.
  StageMeter sleeper("sleep");
  std::this_thread::sleep_for(std::chrono::milliseconds(30));
  const StageMeasurement z = sleeper.Stop();
  EXPECT_GE(z.wall_s, 0.030);
  EXPECT_LT(z.cpu_s, 0.5 * z.wall_s);
  const std::string table = FormatStageTable({m, s});
  EXPECT_NE(table.find("allocate"), std::string::npos);
  EXPECT_NE(table.find("total"), std::string::npos);
}

// StageTimer: the CPU of work done since its start (or Restart) and never a negative time; wall
// and CPU keep growing across calls.
TEST(StageTimer, MeasuresCpuAndWallSinceItsStart) {
  StageTimer timer;
  volatile double sink = 0;
  for (int i = 0; i < 20000000; ++i) sink = sink + std::sqrt(static_cast<double>(i));
  double wall = -1, cpu = -1;
  timer.Elapsed(&wall, &cpu);
  EXPECT_GT(cpu, 0);
  EXPECT_GT(wall, 0);
  double wall2 = -1, cpu2 = -1;
  timer.Elapsed(&wall2, &cpu2);
  EXPECT_GE(wall2, wall);
  EXPECT_GE(cpu2, cpu);
  timer.Restart();
  double wall3 = -1, cpu3 = -1;
  timer.Elapsed(&wall3, &cpu3);
  EXPECT_GE(wall3, 0);
  EXPECT_GE(cpu3, 0);
  EXPECT_LT(cpu3, cpu);  // the busy loop is before the restart
}

}  // namespace
}  // namespace slshadow
