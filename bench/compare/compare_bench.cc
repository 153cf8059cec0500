// compare_bench: C2C 1 M -> 1 M (against CloudCompare's C2C in the same run when it is
// installed), C2M 1 M points -> 80 k triangles, registration of 200 k points (global + ICP).
// Run: build-*/bench/compare/compare_bench   (docs/benchmarks.md "compare")
#include <benchmark/benchmark.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <random>
#include <regex>
#include <sstream>
#include <vector>

#include <unistd.h>

#include "compare/distances.h"
#include "compare/registration.h"
#include "core/kdtree.h"
#include "core/point_cloud.h"
#include "tests/compare/test_shapes.h"

namespace slshadow::compare {
namespace {

namespace fs = std::filesystem;

// The test part (100 mm), 1 M points each, independent samples, 0.05 mm noise on the compared one,
// rounded to float so that CloudCompare reads the same coordinates.
const PointCloud& Cloud(int which) {
  static const std::vector<PointCloud> clouds = [] {
    std::vector<PointCloud> c(2);
    for (int i = 0; i < 2; ++i) {
      c[static_cast<size_t>(i)].points =
          testing::SamplePart(1000000, 100.0, 81 + static_cast<unsigned>(i));
      std::mt19937 rng(91);
      std::normal_distribution<double> g(0.0, 0.05);
      for (auto& p : c[static_cast<size_t>(i)].points) {
        if (i == 0) p.z() += g(rng);
        for (int k = 0; k < 3; ++k) {
          volatile float f = static_cast<float>(p[k]);  // see cloudcompare_test.cc
          p[k] = f;
        }
      }
    }
    return c;
  }();
  return clouds[static_cast<size_t>(which)];
}

// Wall seconds of kd-tree build + queries; *cpu_s (when given) the process CPU seconds (all
// threads).
double Ours(const PointCloud& compared, const PointCloud& reference, double* mean,
            double* cpu_s = nullptr) {
  const std::clock_t c0 = std::clock();
  const auto t0 = std::chrono::steady_clock::now();
  const KdTree tree(reference.points);
  const C2CResult r = CloudToCloud(compared.points, tree);
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (cpu_s) *cpu_s = static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC;
  double sum = 0;
  for (double d : r.distances_mm) sum += d;
  *mean = sum / static_cast<double>(r.distances_mm.size());
  return s;
}

void BM_C2C_1M(benchmark::State& state) {
  const PointCloud& a = Cloud(0);
  const PointCloud& b = Cloud(1);
  double mean = 0, cpu = 0, cpu_total = 0;
  for (auto _ : state) {
    const double s = Ours(a, b, &mean, &cpu);
    cpu_total += cpu;
    state.SetIterationTime(s);
  }
  state.counters["mean_mm"] = mean;
  state.counters["process_cpu_s"] = cpu_total / static_cast<double>(state.iterations());
}
BENCHMARK(BM_C2C_1M)->UseManualTime()->Unit(benchmark::kMillisecond)->Iterations(5);

// CloudCompare's own compute time (approximate + exact distances, from its log; file loading
// excluded) against ours on the same files, alternating in each iteration.
void BM_C2C_1M_vs_CloudCompare(benchmark::State& state) {
  if (std::system("command -v CloudCompare > /dev/null 2>&1") != 0) {
    state.SkipWithError("CloudCompare not installed");
    return;
  }
  const fs::path dir = fs::temp_directory_path() / ("compare_bench_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  PlyWriteOptions f;
  f.double_positions = false;
  WritePly(dir / "a.ply", Cloud(0), f);
  WritePly(dir / "b.ply", Cloud(1), f);
  double ours_total = 0, cc_total = 0, mean = 0, cc_mean = 0;
  int n = 0;
  for (auto _ : state) {
    const double ours = Ours(Cloud(0), Cloud(1), &mean);
    const std::string cmd =
        "cd '" + dir.string() +
        "' && QT_QPA_PLATFORM=offscreen CloudCompare -SILENT -NO_TIMESTAMP -C_EXPORT_FMT PLY "
        "-O a.ply -O b.ply -C2C_DIST > cc.log 2>&1";
    if (std::system(cmd.c_str()) != 0) {
      state.SkipWithError("CloudCompare failed");
      break;
    }
    std::ifstream log(dir / "cc.log");
    std::stringstream text;
    text << log.rdbuf();
    const std::string s = text.str();
    double cc = 0;
    const std::regex time_re(R"(\[(computeApproxDistances|ComputeDistances)\] Time: ([0-9.]+) s)");
    for (auto it = std::sregex_iterator(s.begin(), s.end(), time_re); it != std::sregex_iterator();
         ++it) {
      cc += std::stod((*it)[2]);
    }
    std::smatch m;
    if (std::regex_search(s, m, std::regex(R"(Mean distance = ([0-9.eE+-]+))")))
      cc_mean = std::stod(m[1]);
    ours_total += ours;
    cc_total += cc;
    ++n;
    state.SetIterationTime(ours);
  }
  fs::remove_all(dir);
  if (n == 0) return;
  state.counters["ours_s"] = ours_total / n;
  state.counters["cloudcompare_s"] = cc_total / n;
  state.counters["cc_over_ours"] = cc_total / ours_total;
  state.counters["mean_mm"] = mean;
  state.counters["cc_mean_mm"] = cc_mean;
}
BENCHMARK(BM_C2C_1M_vs_CloudCompare)->UseManualTime()->Unit(benchmark::kMillisecond)->Iterations(3);

void BM_C2M_1M(benchmark::State& state) {
  const TriangleMesh mesh = testing::IcoSphere(50.0, 6);  // 81920 triangles
  std::vector<Eigen::Vector3d> pts;
  std::mt19937 rng(92);
  std::normal_distribution<double> g;
  for (int i = 0; i < 1000000; ++i)
    pts.push_back((50.0 + 0.1 * g(rng)) * Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized());
  for (auto _ : state) {
    const C2MResult r = CloudToMesh(pts, mesh);
    benchmark::DoNotOptimize(r.signed_distances_mm.data());
  }
}
BENCHMARK(BM_C2M_1M)->UseRealTime()->Unit(benchmark::kMillisecond)->Iterations(3);

void BM_Register_200k(benchmark::State& state) {
  const auto reference = testing::SamplePart(200000, 100.0, 31);
  const Rigid3d cloud_from_reference(
      Eigen::Quaterniond(
          Eigen::AngleAxisd(20.0 * M_PI / 180.0, Eigen::Vector3d(1, 2, 3).normalized())),
      Eigen::Vector3d(6.0, -6.4, 4.8));
  auto cloud = testing::SamplePart(200000, 100.0, 32);
  std::mt19937 rng(33);
  std::normal_distribution<double> noise(0.0, 0.1);
  for (auto& p : cloud)
    p = cloud_from_reference * (p + Eigen::Vector3d(noise(rng), noise(rng), noise(rng)));
  RegistrationResult r;
  for (auto _ : state) {
    r = Register(cloud, reference, {}, RegistrationOptions{});
  }
  const Rigid3d err = r.reference_from_cloud * cloud_from_reference;
  state.counters["rot_err_deg"] = RotationDifferenceDeg(err, Rigid3d());
  state.counters["trans_err_mm"] = err.translation.norm();
  state.counters["fitness"] = r.fitness;
  state.counters["icp_iterations"] = r.icp_iterations;
}
BENCHMARK(BM_Register_200k)->UseRealTime()->Unit(benchmark::kMillisecond)->Iterations(5);

}  // namespace
}  // namespace slshadow::compare

BENCHMARK_MAIN();
