#include "workflows/pipeline/bench.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>

#include <unistd.h>

#include <nlohmann/json.hpp>
#include <opencv2/structured_light.hpp>

#include "compare/compare.h"
#include "compare/distances.h"
#include "core/error.h"
#include "core/kdtree.h"
#include "core/rig.h"
#include "core/stage_meter.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct.h"
#include "sim/scene.h"
#include "sim/scene_surface.h"
#include "sim/simulate.h"
#include "workflows/pipeline/c2m_peer_py.h"
#include "workflows/pipeline/scan_pipeline.h"

namespace slshadow::pipeline {
namespace {

struct Timing {
  double wall_s = 0;
  double cpu_s = 0;
};

// Runs `work` n times; returns the run with the median wall time (and its index in `median_run`).
Timing Median(int n, const std::function<void()>& work, int* median_run = nullptr) {
  std::vector<std::pair<Timing, int>> runs;
  for (int i = 0; i < n; ++i) {
    const double cpu0 = ProcessCpuSeconds();
    const auto t0 = std::chrono::steady_clock::now();
    work();
    runs.push_back({{std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
                     ProcessCpuSeconds() - cpu0},
                    i});
  }
  std::sort(runs.begin(), runs.end(),
            [](const auto& a, const auto& b) { return a.first.wall_s < b.first.wall_s; });
  if (median_run) *median_run = runs[runs.size() / 2].second;
  return runs[runs.size() / 2].first;
}

// Adds a stage's wall and CPU seconds to the entry named `name` of `stages` (appended when new).
void AddStage(std::vector<BenchStage>* stages, const std::string& name, double wall_s,
              double cpu_s) {
  for (auto& s : *stages) {
    if (s.name == name) {
      s.wall_s += wall_s;
      s.cpu_s += cpu_s;
      return;
    }
  }
  stages->push_back({name, wall_s, cpu_s});
}

// The per-stage times of a reconstruction.
void AddStages(std::vector<BenchStage>* stages, const ReconstructSummary& s) {
  AddStage(stages, "rays", s.rays_s, s.rays_cpu_s);
  if (s.mode == ReconstructMode::kStereo) AddStage(stages, "match", s.match_s, s.match_cpu_s);
  AddStage(stages, "triangulate", s.triangulate_s, s.triangulate_cpu_s);
  AddStage(stages, "filters", s.filter_s, s.filter_cpu_s);
  AddStage(stages, "normals+cloud", s.normals_s, s.normals_cpu_s);
}

BenchEntry MakeEntry(const std::string& name, const std::string& what) {
  BenchEntry e;
  e.name = name;
  e.what = what;
  return e;
}

bool Wanted(const BenchOptions& options, const std::string& name) {
  return options.only.empty() ||
         std::find(options.only.begin(), options.only.end(), name) != options.only.end();
}

// The number after "key": in a one-line JSON object (the peer script's output); 0 when absent.
double JsonNumber(const std::string& json, const std::string& key) {
  const auto at = json.find("\"" + key + "\":");
  return at == std::string::npos ? 0.0 : std::atof(json.c_str() + at + key.size() + 3);
}

// Open3D's RaycastingScene on the same cloud and mesh (bench/c2m_peer/open3d_c2m.py, compiled in),
// run by Debian's python3 where python3-open3d lives. Returns the script's JSON line, or "" with
// `why` set when the peer cannot run.
// With `mesh` null, the C2C peer: `points` against `reference`.
std::string RunOpen3dPeer(const std::vector<Eigen::Vector3d>& points, const TriangleMesh* mesh,
                          const std::vector<Eigen::Vector3d>* reference, int reps,
                          std::string* why) {
  namespace fs = std::filesystem;
  const std::string python = fs::exists("/usr/bin/python3") ? "/usr/bin/python3" : "python3";
  const fs::path dir =
      fs::temp_directory_path() / ("slshadow_bench_c2m_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  auto write = [&](const std::string& name, const void* data, size_t bytes) {
    std::ofstream f(dir / name, std::ios::binary);
    f.write(static_cast<const char*>(data), static_cast<std::streamsize>(bytes));
  };
  std::ofstream(dir / "open3d_c2m.py") << kOpen3dC2mPy;
  write("points.f64", points.data(), points.size() * sizeof(Eigen::Vector3d));
  std::string args;
  if (mesh) {
    write("vertices.f64", mesh->vertices.data(), mesh->vertices.size() * sizeof(Eigen::Vector3d));
    std::vector<uint32_t> tris;
    for (const auto& t : mesh->triangles) {
      for (int k = 0; k < 3; ++k) tris.push_back(static_cast<uint32_t>(t[k]));
    }
    write("triangles.u32", tris.data(), tris.size() * sizeof(uint32_t));
    args = (dir / "points.f64").string() + " " + (dir / "vertices.f64").string() + " " +
           (dir / "triangles.u32").string();
  } else {
    write("reference.f64", reference->data(), reference->size() * sizeof(Eigen::Vector3d));
    args = "c2c " + (dir / "points.f64").string() + " " + (dir / "reference.f64").string();
  }
  const std::string cmd = python + " " + (dir / "open3d_c2m.py").string() + " " + args + " " +
                          std::to_string(reps) + " > " + (dir / "out.json").string() + " 2> " +
                          (dir / "err.txt").string();
  const int status = std::system(cmd.c_str());
  std::stringstream out, err;
  out << std::ifstream(dir / "out.json").rdbuf();
  err << std::ifstream(dir / "err.txt").rdbuf();
  std::error_code ec;
  fs::remove_all(dir, ec);
  if (status != 0) {
    *why = err.str().empty() ? "the Open3D peer failed (exit status " + std::to_string(status) + ")"
                             : err.str();
    while (!why->empty() && why->back() == '\n') why->pop_back();
    return "";
  }
  return out.str();
}

// CloudCompare's own compute time (its log's "[computeApproxDistances] Time" + "[ComputeDistances]
// Time", file loading excluded) for `-C2C_DIST` of `points` against `reference`, headless, `reps`
// runs; the median run's seconds and its mean distance. Returns false with `why` set when
// CloudCompare is absent or fails.
bool RunCloudComparePeer(const std::vector<Eigen::Vector3d>& points,
                         const std::vector<Eigen::Vector3d>& reference, int reps, double* seconds,
                         double* mean_mm, std::string* why) {
  namespace fs = std::filesystem;
  if (std::system("command -v CloudCompare > /dev/null 2>&1") != 0) {
    *why = "CloudCompare not installed (apt-get install cloudcompare)";
    return false;
  }
  const fs::path dir =
      fs::temp_directory_path() / ("slshadow_bench_cc_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  PlyWriteOptions f;
  f.double_positions = false;  // CloudCompare keeps float coordinates
  PointCloud cloud;
  cloud.points = points;
  WritePly(dir / "compared.ply", cloud, f);
  cloud.points = reference;
  WritePly(dir / "reference.ply", cloud, f);
  cloud = PointCloud();
  const std::string cmd =
      "cd '" + dir.string() +
      "' && QT_QPA_PLATFORM=offscreen CloudCompare -SILENT -NO_TIMESTAMP -AUTO_SAVE OFF "
      "-O compared.ply -O reference.ply -C2C_DIST > cc.log 2>&1";
  std::vector<std::pair<double, double>> runs;  // seconds, mean distance
  for (int i = 0; i < reps; ++i) {
    const int status = std::system(cmd.c_str());
    std::stringstream text;
    text << std::ifstream(dir / "cc.log").rdbuf();
    const std::string log = text.str();
    double s = 0, mean = 0;
    bool timed = false;
    for (const char* key : {"[computeApproxDistances] Time: ", "[ComputeDistances] Time: "}) {
      const auto at = log.find(key);
      if (at != std::string::npos) {
        s += std::atof(log.c_str() + at + std::strlen(key));
        timed = true;
      }
    }
    const auto at = log.find("Mean distance = ");
    if (at != std::string::npos) mean = std::atof(log.c_str() + at + 16);
    if (status != 0 || !timed) {
      *why = "CloudCompare failed (exit status " + std::to_string(status) +
             "); its log: " + (dir / "cc.log").string();
      return false;  // the folder is kept for the log
    }
    runs.push_back({s, mean});
  }
  std::error_code ec;
  fs::remove_all(dir, ec);
  std::sort(runs.begin(), runs.end());
  *seconds = runs[runs.size() / 2].first;
  *mean_mm = runs[runs.size() / 2].second;
  return true;
}

}  // namespace

void BenchOptions::Check() const {
  SLSHADOW_THROW_IF(repetitions < 1 || repetitions > 100, "--repetitions: must be 1..100 (got ",
                    repetitions, ")");
  for (const auto& name : only) {
    SLSHADOW_THROW_IF(
        name != "simulate" && name != "decode" && name != "reconstruct" && name != "compare",
        "--only: unknown entry '", name, "' (entries: simulate, decode, reconstruct, compare)");
  }
}

std::vector<BenchEntry> RunBench(const BenchOptions& options) {
  options.Check();
  const Rig rig = LoadRigOrDemo("");
  const Scene scene = LoadSceneOrDemo("", ".");
  const PatternSpec spec = LoadPatternSpecOrDemo("");
  const std::vector<cv::Mat> projector_images = GeneratePatterns(spec);
  const int reps = options.repetitions;
  const double camera_mpix = rig.cameras[0].model.width * rig.cameras[0].model.height / 1e6;
  std::vector<BenchEntry> entries;

  std::vector<std::vector<cv::Mat>> images;
  std::vector<GeometryBuffer> geometry;
  {
    BenchEntry e = MakeEntry("simulate", "render 2 cameras x " + std::to_string(spec.NumImages()) +
                                             " patterns, demo part");
    SimulateSummary summary;
    const Timing t = Median(Wanted(options, "simulate") ? reps : 1, [&] {
      geometry.clear();
      images = RenderScan(scene, rig, projector_images, &geometry, &summary);
    });
    if (Wanted(options, "simulate")) {
      e.median_wall_s = t.wall_s;
      e.cpu_s = t.cpu_s;
      e.throughput = static_cast<double>(summary.primary_rays + summary.shadow_rays) / 1e6 /
                     summary.geometry_seconds;
      e.unit = "Mrays/s (geometry pass, primary + shadow rays)";
      e.what += " (primary rays only: " +
                std::to_string(static_cast<int>(summary.PrimaryMraysPerSecond() + 0.5)) + " M/s)";
      entries.push_back(e);
    }
  }

  const std::string left = rig.cameras[0].name, right = rig.cameras[1].name;
  std::vector<ProjectorMap> maps(2);
  if (Wanted(options, "decode")) {
    BenchEntry e = MakeEntry("decode", "DecodePatterns, 2 cameras, " +
                                           std::to_string(spec.NumImages()) + " images each");
    const Timing t = Median(reps, [&] {
      for (int c = 0; c < 2; ++c) maps[c] = DecodePatterns(spec, images[c]);
    });
    e.median_wall_s = t.wall_s;
    e.cpu_s = t.cpu_s;
    e.throughput = 2 * camera_mpix / t.wall_s;
    e.unit = "MPix/s";
    if (options.with_opencv) {
      // The same camera viewing OpenCV's own Gray-code sequence, rendered by the simulator.
      PatternSpec gray;
      gray.kind = PatternKind::kGrayCode;
      gray.projector_width = spec.projector_width;
      gray.projector_height = spec.projector_height;
      gray.opencv_order = true;
      const auto gray_images = RenderScan(scene, rig, GeneratePatterns(gray))[0];
      cv::structured_light::GrayCodePattern::Params params;
      params.width = gray.projector_width;
      params.height = gray.projector_height;
      const auto graycode = cv::structured_light::GrayCodePattern::create(params);
      const size_t n = graycode->getNumberOfPatternImages();
      const std::vector<cv::Mat> codes(gray_images.begin(),
                                       gray_images.begin() + static_cast<std::ptrdiff_t>(n));
      const cv::Mat& white = gray_images[n];
      const cv::Mat& black = gray_images[n + 1];
      const Timing p = Median(std::min(reps, 3), [&] {
        int64_t decoded = 0;
        cv::Point proj;
        for (int y = 0; y < white.rows; ++y) {
          for (int x = 0; x < white.cols; ++x) {
            if (white.at<uint8_t>(y, x) - black.at<uint8_t>(y, x) <= 12) continue;
            decoded += !graycode->getProjPixel(codes, x, y, proj);
          }
        }
        if (decoded < 0) std::abort();  // keeps the loop
      });
      e.peer = "OpenCV GrayCodePattern getProjPixel, 1 camera";
      e.peer_median_wall_s = p.wall_s;
      e.peer_throughput = camera_mpix / p.wall_s;
      e.ratio = e.throughput / e.peer_throughput;
    }
    entries.push_back(e);
  } else {
    for (int c = 0; c < 2; ++c) maps[c] = DecodePatterns(spec, images[c]);
  }

  Reconstruction stereo;
  if (Wanted(options, "reconstruct")) {
    BenchEntry e = MakeEntry("reconstruct",
                             "decode + triangulate 2 cameras (camera-projector), 2 x 1920x1200");
    std::vector<std::vector<BenchStage>> run_stages;
    int median_run = 0;
    const Timing t = Median(
        reps,
        [&] {
          std::vector<BenchStage> stages;
          for (int c = 0; c < 2; ++c) {
            const double cpu0 = ProcessCpuSeconds();
            const auto t0 = std::chrono::steady_clock::now();
            const ProjectorMap map = DecodePatterns(spec, images[c]);
            AddStage(&stages, "decode",
                     std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
                     ProcessCpuSeconds() - cpu0);
            AddStages(&stages, ReconstructWithProjector(rig, rig.cameras[c].name, map).summary);
          }
          run_stages.push_back(std::move(stages));
        },
        &median_run);
    e.stages = run_stages[static_cast<size_t>(median_run)];
    e.median_wall_s = t.wall_s;
    e.cpu_s = t.cpu_s;
    e.throughput = 2 * camera_mpix / t.wall_s;
    e.unit = "MPix/s";
    entries.push_back(e);
    // The same with the two cameras concurrently, one task each: OpenCV runs the loops nested in a
    // parallel region serially, so each camera's decode and reconstruction run on one core without
    // the parallel loops' serial parts and joins (ReconstructFromImages still runs them in turn).
    BenchEntry ec =
        MakeEntry("reconstruct", "the same, the 2 cameras concurrently (one core each)");
    const Timing tc = Median(reps, [&] {
      cv::parallel_for_(cv::Range(0, 2), [&](const cv::Range& r) {
        for (int c = r.start; c < r.end; ++c) {
          const ProjectorMap map = DecodePatterns(spec, images[static_cast<size_t>(c)]);
          ReconstructWithProjector(rig, rig.cameras[static_cast<size_t>(c)].name, map);
        }
      });
    });
    ec.median_wall_s = tc.wall_s;
    ec.cpu_s = tc.cpu_s;
    ec.throughput = 2 * camera_mpix / tc.wall_s;
    ec.unit = "MPix/s";
    entries.push_back(ec);
    BenchEntry s = MakeEntry("reconstruct", "stereo left-right from decoded maps");
    run_stages.clear();
    const Timing ts = Median(
        reps,
        [&] {
          stereo = ReconstructStereo(rig, left, right, maps[0], maps[1]);
          run_stages.emplace_back();
          AddStages(&run_stages.back(), stereo.summary);
        },
        &median_run);
    s.stages = run_stages[static_cast<size_t>(median_run)];
    s.median_wall_s = ts.wall_s;
    s.cpu_s = ts.cpu_s;
    s.throughput = static_cast<double>(stereo.summary.points) / 1e6 / ts.wall_s;
    s.unit = "Mpoints/s";
    entries.push_back(s);
  }

  if (Wanted(options, "compare")) {
    if (stereo.cloud.empty()) stereo = ReconstructStereo(rig, left, right, maps[0], maps[1]);
    const TriangleMesh truth = SceneMeshSurface(scene);
    const compare::Reference reference = compare::ReferenceFromMesh(truth, "demo part");
    BenchEntry e =
        MakeEntry("compare", "C2M of the stereo cloud (" + std::to_string(stereo.cloud.size()) +
                                 " points) to the part mesh");
    const Timing t =
        Median(reps, [&] { compare::Compare(stereo.cloud, reference, compare::CompareOptions{}); });
    e.median_wall_s = t.wall_s;
    e.cpu_s = t.cpu_s;
    e.throughput = static_cast<double>(stereo.cloud.size()) / 1e6 / t.wall_s;
    e.unit = "Mpoints/s";
    entries.push_back(e);
    // The signed distances alone (hierarchy build + queries), the work Open3D's peer does.
    BenchEntry c = MakeEntry("compare", "signed C2M alone (CloudToMesh: hierarchy + queries)");
    double mean_abs = 0;
    const Timing tc = Median(reps, [&] {
      const compare::C2MResult r = compare::CloudToMesh(stereo.cloud.points, truth);
      double sum = 0;
      for (const double d : r.signed_distances_mm) sum += std::abs(d);
      mean_abs = sum / static_cast<double>(r.signed_distances_mm.size());
    });
    c.median_wall_s = tc.wall_s;
    c.cpu_s = tc.cpu_s;
    c.throughput = static_cast<double>(stereo.cloud.size()) / 1e6 / tc.wall_s;
    c.unit = "Mpoints/s";
    if (options.with_open3d) {
      std::string why;
      const std::string json = RunOpen3dPeer(stereo.cloud.points, &truth, nullptr, reps, &why);
      if (json.empty()) {
        std::fprintf(stderr, "bench: C2M peer skipped: %s\n", why.c_str());
      } else {
        char what[256];
        std::snprintf(
            what, sizeof(what),
            "Open3D RaycastingScene compute_signed_distance, scene + query (CPU %.3f s; unsigned "
            "compute_distance %.3f s, CPU %.3f s; mean |d| %.4f mm, slshadow %.4f mm)",
            JsonNumber(json, "signed_cpu_s"), JsonNumber(json, "unsigned_s"),
            JsonNumber(json, "unsigned_cpu_s"), JsonNumber(json, "signed_mean_abs_mm"), mean_abs);
        c.peer = what;
        c.peer_median_wall_s = JsonNumber(json, "signed_s");
        c.peer_throughput = static_cast<double>(stereo.cloud.size()) / 1e6 / c.peer_median_wall_s;
        c.ratio = c.throughput / c.peer_throughput;
      }
    }
    entries.push_back(c);
    // No CloudCompare C2M peer: its -C2M_DIST on this cloud (78 % of the points 1 mm to 170 mm from
    // the part mesh) took 607 s in one run (docs/benchmarks/log/2026-11-24-compare.md).

    // C2C, about 1 M -> 1 M: the stereo cloud's even-indexed points against its odd-indexed ones.
    std::vector<Eigen::Vector3d> even, odd;
    for (size_t i = 0; i < stereo.cloud.size(); ++i)
      (i % 2 ? odd : even).push_back(stereo.cloud.points[i]);
    BenchEntry cc = MakeEntry(
        "compare", "C2C " + std::to_string(even.size()) + " -> " + std::to_string(odd.size()) +
                       " points (stereo cloud, even to odd points; kd-tree + queries)");
    double c2c_mean = 0;
    const Timing t2 = Median(reps, [&] {
      const KdTree tree(odd);
      const compare::C2CResult r = compare::CloudToCloud(even, tree);
      double sum = 0;
      for (const double d : r.distances_mm) sum += d;
      c2c_mean = sum / static_cast<double>(r.distances_mm.size());
    });
    cc.median_wall_s = t2.wall_s;
    cc.cpu_s = t2.cpu_s;
    cc.throughput = static_cast<double>(even.size()) / 1e6 / t2.wall_s;
    cc.unit = "Mpoints/s";
    if (options.with_open3d) {
      std::string why;
      const std::string json = RunOpen3dPeer(even, nullptr, &odd, reps, &why);
      if (json.empty()) {
        std::fprintf(stderr, "bench: C2C peer skipped: %s\n", why.c_str());
      } else {
        char what[256];
        std::snprintf(what, sizeof(what),
                      "Open3D PointCloud compute_point_cloud_distance (CPU %.3f s; mean d %.5f mm, "
                      "slshadow %.5f mm)",
                      JsonNumber(json, "c2c_cpu_s"), JsonNumber(json, "c2c_mean_mm"), c2c_mean);
        cc.peer = what;
        cc.peer_median_wall_s = JsonNumber(json, "c2c_s");
        cc.peer_throughput = static_cast<double>(even.size()) / 1e6 / cc.peer_median_wall_s;
        cc.ratio = cc.throughput / cc.peer_throughput;
      }
    }
    entries.push_back(cc);
    if (options.with_cloudcompare) {
      double cc_s = 0, cc_mean = 0;
      std::string why;
      if (!RunCloudComparePeer(even, odd, std::min(reps, 3), &cc_s, &cc_mean, &why)) {
        std::fprintf(stderr, "bench: CloudCompare C2C peer skipped: %s\n", why.c_str());
      } else {
        BenchEntry m = cc;
        m.what = "C2C " + std::to_string(even.size()) + " -> " + std::to_string(odd.size()) +
                 " points, against CloudCompare";
        char what[256];
        std::snprintf(what, sizeof(what),
                      "CloudCompare -C2C_DIST, its logged compute time, median of %d (mean d %.5f "
                      "mm, slshadow %.5f mm)",
                      std::min(reps, 3), cc_mean, c2c_mean);
        m.peer = what;
        m.peer_median_wall_s = cc_s;
        m.peer_throughput = static_cast<double>(even.size()) / 1e6 / cc_s;
        m.ratio = m.throughput / m.peer_throughput;
        entries.push_back(m);
      }
    }
  }
  return entries;
}

std::string FormatBench(const std::vector<BenchEntry>& entries) {
  std::string out = "entry        median wall (s)  CPU (s)  throughput            what\n";
  char buf[512];
  for (const auto& e : entries) {
    std::snprintf(buf, sizeof(buf), "%-12s %15.3f  %7.3f  %8.2f %-12s %s\n", e.name.c_str(),
                  e.median_wall_s, e.cpu_s, e.throughput, e.unit.c_str(), e.what.c_str());
    out += buf;
    if (!e.peer.empty()) {
      std::snprintf(
          buf, sizeof(buf), "  peer       %15.3f           %8.2f %-12s %s -> slshadow is %.1fx\n",
          e.peer_median_wall_s, e.peer_throughput, e.unit.c_str(), e.peer.c_str(), e.ratio);
      out += buf;
    }
    for (const auto& stage : e.stages) {
      std::snprintf(buf, sizeof(buf), "  %-14s %13.3f  %7.3f\n", stage.name.c_str(), stage.wall_s,
                    stage.cpu_s);
      out += buf;
    }
  }
  return out;
}

std::string BenchToJson(const std::vector<BenchEntry>& entries, const BenchOptions& options) {
  nlohmann::ordered_json json = {
      {"format", "slshadow-bench"}, {"version", 1}, {"repetitions", options.repetitions}};
  json["entries"] = nlohmann::ordered_json::array();
  for (const auto& e : entries) {
    nlohmann::ordered_json entry = {{"name", e.name},
                                    {"what", e.what},
                                    {"median_wall_s", e.median_wall_s},
                                    {"cpu_s", e.cpu_s},
                                    {"throughput", e.throughput},
                                    {"unit", e.unit},
                                    {"peer", e.peer},
                                    {"peer_median_wall_s", e.peer_median_wall_s},
                                    {"peer_throughput", e.peer_throughput},
                                    {"ratio", e.ratio}};
    entry["stages"] = nlohmann::ordered_json::array();
    for (const auto& stage : e.stages) {
      entry["stages"].push_back(
          {{"name", stage.name}, {"wall_s", stage.wall_s}, {"cpu_s", stage.cpu_s}});
    }
    json["entries"].push_back(std::move(entry));
  }
  return json.dump(2) + "\n";
}

}  // namespace slshadow::pipeline
