// statistics_bench: compare::MedianSpacing and compare::ComputeStats on a reconstruction-sized
// cloud (1920 x 1200 pixels in scan order, ~2.1 M points: testing::ScanOrderCloud) and its ~2.1 M
// deviations, beside the methods they had before in the same run: the general median spacing
// (compare::internal::MedianSpacingByCells, still MedianSpacing's fallback) and the selection
// ComputeStats (three std::nth_element over a copy of |d|, kept here as the baseline).
// Counters: cpu_s, the process CPU seconds (all threads) per iteration.
// Run: build/bench/compare/statistics_bench
//      SLSHADOW_BENCH_CLOUD=cloud.ply build/bench/compare/statistics_bench  (also on that cloud)
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <ctime>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "compare/internal/median_spacing.h"
#include "compare/median_spacing.h"
#include "compare/statistics.h"
#include "core/point_cloud.h"
#include "core/statistics.h"
#include "tests/compare/test_shapes.h"

namespace slshadow::compare {
namespace {

const std::vector<Eigen::Vector3d>& ScanCloud() {
  static const std::vector<Eigen::Vector3d> cloud = testing::ScanOrderCloud(1920, 1200, 0.12, 33);
  return cloud;
}

const std::vector<Eigen::Vector3d>& ShuffledCloud() {
  static const std::vector<Eigen::Vector3d> cloud = [] {
    std::vector<Eigen::Vector3d> c = ScanCloud();
    std::mt19937 rng(34);
    std::shuffle(c.begin(), c.end(), rng);
    return c;
  }();
  return cloud;
}

// Signed deviations as a reconstruction's against its ground truth: 0.03 mm of noise, 2 % of
// them 40 times larger, a few non-finite.
const std::vector<double>& Deviations() {
  static const std::vector<double> d = [] {
    std::mt19937 rng(35);
    std::normal_distribution<double> normal(0, 1);
    std::vector<double> v(ScanCloud().size());
    for (double& x : v) x = 0.03 * normal(rng) * (normal(rng) > 2 ? 40 : 1);
    for (size_t i = 0; i < v.size(); i += 10007) v[i] = std::numeric_limits<double>::quiet_NaN();
    return v;
  }();
  return d;
}

// compare::ComputeStats before the radix select (the figures of |d| and the histogram; the same
// doubles).
DistanceStats SelectionStats(const std::vector<double>& distances_mm, bool is_signed,
                             double threshold_mm, int bins = 60, double range_mm = 0) {
  DistanceStats s;
  s.is_signed = is_signed;
  s.threshold_mm = threshold_mm;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  s.signed_mean_mm = s.signed_std_mm = nan;
  std::vector<double> abs_d;
  abs_d.reserve(distances_mm.size());
  double sum = 0, sum2 = 0, ssum = 0;
  for (double d : distances_mm) {
    if (!std::isfinite(d)) {
      ++s.num_invalid;
      continue;
    }
    const double a = std::abs(d);
    abs_d.push_back(a);
    sum += a;
    sum2 += a * a;
    ssum += d;
    if (a <= threshold_mm) ++s.inliers;
  }
  s.count = abs_d.size();
  s.outliers = s.count - s.inliers;
  if (s.count == 0) return s;
  const double n = static_cast<double>(s.count);
  s.mean_mm = sum / n;
  s.rms_mm = std::sqrt(sum2 / n);
  double var = 0, svar = 0;
  const double smean = ssum / n;
  for (double d : distances_mm) {
    if (!std::isfinite(d)) continue;
    var += (std::abs(d) - s.mean_mm) * (std::abs(d) - s.mean_mm);
    svar += (d - smean) * (d - smean);
  }
  s.std_mm = std::sqrt(var / n);
  if (is_signed) {
    s.signed_mean_mm = smean;
    s.signed_std_mm = std::sqrt(svar / n);
  }
  const size_t i50 = PercentileRank(abs_d.size(), 50), i95 = PercentileRank(abs_d.size(), 95),
               i99 = PercentileRank(abs_d.size(), 99);
  const auto at = [&](size_t i) { return abs_d.begin() + static_cast<std::ptrdiff_t>(i); };
  std::nth_element(abs_d.begin(), at(i50), abs_d.end());
  s.median_mm = abs_d[i50];
  std::nth_element(at(i50), at(i95), abs_d.end());
  s.p95_mm = abs_d[i95];
  std::nth_element(at(i95), at(i99), abs_d.end());
  Histogram& h = s.histogram;
  h.hi_mm = range_mm > 0 ? range_mm : std::max(abs_d[i99], 1e-6);
  s.max_mm = *std::max_element(at(i99), abs_d.end());
  h.lo_mm = is_signed ? -h.hi_mm : 0.0;
  h.counts.assign(static_cast<size_t>(bins), 0);
  const double w = h.BinWidth();
  for (double d : distances_mm) {
    if (!std::isfinite(d)) continue;
    const double v = is_signed ? d : std::abs(d);
    if (v < h.lo_mm) {
      ++h.underflow;
    } else if (v > h.hi_mm) {
      ++h.overflow;
    } else {
      ++h.counts[std::min(static_cast<size_t>((v - h.lo_mm) / w), h.counts.size() - 1)];
    }
  }
  return s;
}

// Runs f once per iteration; counters: the CPU seconds of the process per iteration and the
// value f returns (the same for the methods compared).
template <typename F>
void Run(benchmark::State& state, F&& f) {
  double cpu = 0, value = 0;
  for (auto _ : state) {
    const std::clock_t c0 = std::clock();
    value = f();
    benchmark::DoNotOptimize(value);
    cpu += static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC;
  }
  state.counters["cpu_s"] = cpu / static_cast<double>(state.iterations());
  state.counters["value"] = value;
}

void BM_MedianSpacing_Scan2M(benchmark::State& state) {
  const auto& c = ScanCloud();
  Run(state, [&] { return MedianSpacing(c); });
  state.counters["points"] = static_cast<double>(c.size());
}
void BM_MedianSpacingByCells_Scan2M(benchmark::State& state) {
  const auto& c = ScanCloud();
  Run(state, [&] { return internal::MedianSpacingByCells(c, 20000); });
}
void BM_MedianSpacing_Shuffled2M(benchmark::State& state) {
  const auto& c = ShuffledCloud();
  Run(state, [&] { return MedianSpacing(c); });
}
void BM_MedianSpacingByCells_Shuffled2M(benchmark::State& state) {
  const auto& c = ShuffledCloud();
  Run(state, [&] { return internal::MedianSpacingByCells(c, 20000); });
}
void BM_ComputeStats_2M(benchmark::State& state) {
  const auto& d = Deviations();
  Run(state, [&] { return ComputeStats(d, false, 0.1).p95_mm; });
}
void BM_SelectionStats_2M(benchmark::State& state) {
  const auto& d = Deviations();
  Run(state, [&] { return SelectionStats(d, false, 0.1).p95_mm; });
}
void BM_ComputeUnsignedAndSignedStats_2M(benchmark::State& state) {
  const auto& d = Deviations();
  Run(state, [&] { return ComputeUnsignedAndSignedStats(d, 0.1).signed_stats.p95_mm; });
}

// ComputeUnsignedAndSignedStats before: the signed SelectionStats, copied and binned again as |d|.
void BM_SelectionUnsignedAndSigned_2M(benchmark::State& state) {
  const auto& d = Deviations();
  Run(state, [&] {
    const DistanceStats s = SelectionStats(d, true, 0.1);
    DistanceStats u = s;
    u.is_signed = false;
    Histogram& h = u.histogram;
    h.lo_mm = 0.0;
    std::fill(h.counts.begin(), h.counts.end(), size_t{0});
    h.underflow = h.overflow = 0;
    const double w = h.BinWidth();
    for (double v : d) {
      if (!std::isfinite(v)) continue;
      const double a = std::abs(v);
      if (a > h.hi_mm) {
        ++h.overflow;
      } else {
        ++h.counts[std::min(static_cast<size_t>(a / w), h.counts.size() - 1)];
      }
    }
    benchmark::DoNotOptimize(h.counts.data());
    return s.p95_mm;
  });
}

constexpr int kIterations = 20;
BENCHMARK(BM_MedianSpacing_Scan2M)->Unit(benchmark::kMillisecond)->Iterations(kIterations);
BENCHMARK(BM_MedianSpacingByCells_Scan2M)->Unit(benchmark::kMillisecond)->Iterations(kIterations);
BENCHMARK(BM_MedianSpacing_Shuffled2M)->Unit(benchmark::kMillisecond)->Iterations(kIterations);
BENCHMARK(BM_MedianSpacingByCells_Shuffled2M)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(kIterations);
BENCHMARK(BM_ComputeStats_2M)->Unit(benchmark::kMillisecond)->Iterations(kIterations);
BENCHMARK(BM_SelectionStats_2M)->Unit(benchmark::kMillisecond)->Iterations(kIterations);
BENCHMARK(BM_ComputeUnsignedAndSignedStats_2M)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(kIterations);
BENCHMARK(BM_SelectionUnsignedAndSigned_2M)->Unit(benchmark::kMillisecond)->Iterations(kIterations);

}  // namespace
}  // namespace slshadow::compare

int main(int argc, char** argv) {
  using namespace slshadow::compare;
  // A cloud read from a PLY (e.g. a reconstruction `slshadow demo --out DIR` wrote).
  static std::vector<Eigen::Vector3d> file_cloud;
  if (const char* path = std::getenv("SLSHADOW_BENCH_CLOUD")) {
    file_cloud = slshadow::ReadPly(path).points;
    benchmark::RegisterBenchmark("BM_MedianSpacing_File",
                                 [](benchmark::State& state) {
                                   Run(state, [&] { return MedianSpacing(file_cloud); });
                                   state.counters["points"] =
                                       static_cast<double>(file_cloud.size());
                                 })
        ->Unit(benchmark::kMillisecond)
        ->Iterations(kIterations);
    benchmark::RegisterBenchmark(
        "BM_MedianSpacingByCells_File",
        [](benchmark::State& state) {
          Run(state, [&] { return internal::MedianSpacingByCells(file_cloud, 20000); });
        })
        ->Unit(benchmark::kMillisecond)
        ->Iterations(kIterations);
  }
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
