// Speed of decode + reconstruct on a 2 x 1920x1200 phase-shift + Gray-code ImageSet held in memory
// (image file decoding excluded): the demo rig looking at a plane, images rendered without the
// simulator by warping GeneratePatterns output through the analytic plane mapping.
//
//   build-*/bench/reconstruct/reconstruct_bench --benchmark_repetitions=5
//   (add --benchmark_report_aggregates_only=true for medians only)
#include <benchmark/benchmark.h>

#include <map>

#include <opencv2/calib3d.hpp>

#include "patterns/synthetic.h"
#include "reconstruct/ray_cache.h"
#include "reconstruct/reconstruct_image_set.h"
#include "tests/reconstruct/analytic_scene.h"

namespace slshadow {
namespace {

struct Fixture {
  Rig rig;
  PatternSpec spec;
  std::map<std::string, std::vector<cv::Mat>> images;
  std::map<std::string, ProjectorMap> maps;

  Fixture() {
    rig = LoadRig(std::filesystem::path(SLSHADOW_SOURCE_DIR) / "config/demo/rig.yaml");
    spec.kind = PatternKind::kPhaseShift;
    spec.projector_width = rig.projector->model.width;
    spec.projector_height = rig.projector->model.height;
    spec.phase_steps = 4;
    spec.period_px = 16;
    const std::vector<cv::Mat> patterns = GeneratePatterns(spec);
    const Eigen::Vector3d n = Eigen::Vector3d(0.1, -0.12, -1.0).normalized();
    for (const auto& cam : rig.cameras) {
      const auto view =
          testing::RenderAnalytic(rig, cam, testing::Plane(n, n.dot(Eigen::Vector3d(0, 0, 520))));
      CameraSimOptions sim;
      sim.noise_sigma = 1.0;
      images[cam.name] = SimulateCameraImages(patterns, view.map.proj_x, view.map.proj_y, sim);
      maps[cam.name] = DecodePatterns(spec, images[cam.name]);
    }
  }
};

const Fixture& GetFixture() {
  static const Fixture fixture;
  return fixture;
}

void BM_Decode2Cameras(benchmark::State& state) {
  const Fixture& f = GetFixture();
  for (auto _ : state) {
    for (const auto& [name, images] : f.images)
      benchmark::DoNotOptimize(DecodePatterns(f.spec, images));
  }
  state.counters["MPix/s"] =
      benchmark::Counter(2 * 1920 * 1200 / 1e6, benchmark::Counter::kIsIterationInvariantRate);
}

void BM_TriangulateProjector2Cameras(benchmark::State& state) {
  const Fixture& f = GetFixture();
  ReconstructOptions options;
  options.method = static_cast<TriangulationMethod>(state.range(0));
  int64_t points = 0;
  for (auto _ : state) {
    points = 0;
    for (const auto& cam : f.rig.cameras)
      points +=
          ReconstructWithProjector(f.rig, cam.name, f.maps.at(cam.name), options).summary.points;
  }
  state.counters["points"] = static_cast<double>(points);
  state.SetLabel(ToString(options.method));
}

void BM_TriangulateStereo(benchmark::State& state) {
  const Fixture& f = GetFixture();
  ReconstructOptions options;
  options.method = static_cast<TriangulationMethod>(state.range(0));
  int64_t points = 0;
  for (auto _ : state)
    points =
        ReconstructStereo(f.rig, "left", "right", f.maps.at("left"), f.maps.at("right"), options)
            .summary.points;
  state.counters["points"] = static_cast<double>(points);
  state.SetLabel(ToString(options.method));
}

// The whole job of `slshadow reconstruct` after the image files are read: decode both cameras,
// triangulate, filter, normals, merged cloud.
void BM_DecodeAndReconstruct(benchmark::State& state) {
  const Fixture& f = GetFixture();
  ImageSetReconstructOptions options;
  options.mode = static_cast<ReconstructMode>(state.range(0));
  int64_t points = 0;
  for (auto _ : state)
    points =
        static_cast<int64_t>(ReconstructFromImages(f.rig, f.spec, f.images, options).cloud.size());
  state.counters["points"] = static_cast<double>(points);
  state.SetLabel(ToString(options.mode));
}

// Peer: OpenCV on the same correspondences of both cameras (valid decoded pixels): undistort the
// camera and projector points (cv::undistortPoints) and triangulate them (cv::triangulatePoints,
// linear DLT), no gates, filters or normals.
struct OpenCvInput {
  std::vector<cv::Mat> cam_pts, proj_pts;  // CV_64FC2, one per camera
  std::vector<cv::Mat> k_cam, d_cam, p_cam;
  cv::Mat k_proj, d_proj, p_proj;
};

const OpenCvInput& GetOpenCvInput() {
  static const OpenCvInput in = [] {
    const Fixture& f = GetFixture();
    OpenCvInput in;
    auto k = [](const CameraModel& m) -> cv::Mat {
      return cv::Mat((cv::Mat_<double>(3, 3) << m.fx(), 0, m.cx(), 0, m.fy(), m.cy(), 0, 0, 1));
    };
    auto d = [](const CameraModel& m) -> cv::Mat {
      return cv::Mat((cv::Mat_<double>(1, 5) << m.params[4], m.params[5], m.params[6], m.params[7],
                      m.params[8]));
    };
    auto p = [](const Rigid3d& pose) {
      cv::Mat out(3, 4, CV_64F);
      const Eigen::Matrix4d m = pose.ToMatrix();
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 4; ++c) out.at<double>(r, c) = m(r, c);
      }
      return out;
    };
    in.k_proj = k(f.rig.projector->model);
    in.d_proj = d(f.rig.projector->model);
    in.p_proj = p(f.rig.projector->cam_from_rig);
    for (const auto& cam : f.rig.cameras) {
      const ProjectorMap& map = f.maps.at(cam.name);
      std::vector<cv::Point2d> c, q;
      for (int v = 0; v < map.height(); ++v) {
        for (int u = 0; u < map.width(); ++u) {
          if (map.status.at<uint8_t>(v, u) != 0) continue;
          c.emplace_back(u, v);
          q.emplace_back(map.proj_x.at<float>(v, u), map.proj_y.at<float>(v, u));
        }
      }
      in.cam_pts.push_back(cv::Mat(c, true).reshape(2, 1));
      in.proj_pts.push_back(cv::Mat(q, true).reshape(2, 1));
      in.k_cam.push_back(k(cam.model));
      in.d_cam.push_back(d(cam.model));
      in.p_cam.push_back(p(cam.cam_from_rig));
    }
    return in;
  }();
  return in;
}

void BM_OpenCvUndistortTriangulate2Cameras(benchmark::State& state) {
  const OpenCvInput& in = GetOpenCvInput();
  size_t points = 0;
  for (auto _ : state) {
    points = 0;
    for (size_t c = 0; c < in.cam_pts.size(); ++c) {
      cv::Mat uc, up, x;
      cv::undistortPoints(in.cam_pts[c], uc, in.k_cam[c], in.d_cam[c]);
      cv::undistortPoints(in.proj_pts[c], up, in.k_proj, in.d_proj);
      cv::triangulatePoints(in.p_cam[c], in.p_proj, uc, up, x);
      points += static_cast<size_t>(x.cols);
      benchmark::DoNotOptimize(x.data);
    }
  }
  state.counters["points"] = static_cast<double>(points);
}

// First use of a camera model: per-pixel undistortion of the whole image (cached afterwards).
void BM_RayGridColdCache(benchmark::State& state) {
  const Fixture& f = GetFixture();
  for (auto _ : state) benchmark::DoNotOptimize(ComputeRayGrid(f.rig.cameras[0].model));
}

BENCHMARK(BM_Decode2Cameras)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime();
BENCHMARK(BM_TriangulateProjector2Cameras)
    ->Arg(0)
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();
BENCHMARK(BM_TriangulateStereo)
    ->Arg(0)
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();
BENCHMARK(BM_DecodeAndReconstruct)
    ->Arg(0)
    ->Arg(1)
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();
BENCHMARK(BM_OpenCvUndistortTriangulate2Cameras)
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();
BENCHMARK(BM_RayGridColdCache)
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();

}  // namespace
}  // namespace slshadow

BENCHMARK_MAIN();
