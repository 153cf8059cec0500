#include "reconstruct/reconstruct.h"

#include <algorithm>
#include <cstdio>
#include <sstream>
#include <utility>

#include "core/statistics.h"

namespace slshadow {

namespace {

std::string Percent(int64_t part, int64_t whole) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.1f%%",
                whole > 0 ? 100.0 * static_cast<double>(part) / static_cast<double>(whole) : 0.0);
  return buf;
}

}  // namespace

ResidualStats ComputeResidualStats(std::vector<float> values) {
  const Summary summary = Summarize(std::move(values));  // core/statistics.h: nearest rank
  ResidualStats s;
  s.count = summary.count;
  if (s.count == 0) return s;
  s.rms = summary.rms;
  s.max = std::max(0.0, summary.max);  // as a running maximum from 0
  s.median = summary.median;
  s.p95 = summary.p95;
  return s;
}

nlohmann::json ResidualStats::ToJson() const {
  return {{"count", count}, {"median", median}, {"p95", p95}, {"max", max}, {"rms", rms}};
}

std::string ReconstructSummary::BriefReport() const {
  char buf[512];
  const CalibrationCheck& c = calibration_check;
  char check[128];
  if (!c.available) {
    std::snprintf(check, sizeof(check), "calibration check not available");
  } else {
    std::snprintf(check, sizeof(check),
                  "calibration check %s: %s systematic %.3g of %.3g projector px",
                  c.warn                          ? "WARNING"
                  : std::isfinite(c.threshold_px) ? "passed"
                                                  : "reported",
                  ToString(c.residual).c_str(), c.systematic_px, c.threshold_px);
  }
  std::snprintf(buf, sizeof(buf), "%s/%s %s-%s: %lld points of %lld cells (%s); %s; %.3f s",
                ToString(mode).c_str(), ToString(method).c_str(), camera.c_str(),
                other_device.c_str(), static_cast<long long>(points), static_cast<long long>(cells),
                Percent(points, cells).c_str(), check, total_s);
  return buf;
}

std::string ReconstructSummary::FullReport() const {
  std::ostringstream out;
  out << BriefReport() << "\n";
  out << "  grid " << grid_width << "x" << grid_height << " ("
      << (mode == ReconstructMode::kStereo ? "rectified left camera" : "camera image") << ")\n";
  out << "  cells by outcome:\n";
  for (int r = 0; r < kNumRejectReasons; ++r) {
    if (rejected[static_cast<size_t>(r)] == 0) continue;
    char line[128];
    std::snprintf(line, sizeof(line), "    %-20s %10lld  %6s\n",
                  ToString(static_cast<RejectReason>(r)).c_str(),
                  static_cast<long long>(rejected[static_cast<size_t>(r)]),
                  Percent(rejected[static_cast<size_t>(r)], cells).c_str());
    out << line;
  }
  out << "  decoder status of the camera pixels:";
  for (int k = 0; k < kNumPixelStatus; ++k) {
    out << " " << ToString(static_cast<PixelStatus>(k)) << "="
        << decode_status[static_cast<size_t>(k)];
  }
  out << "\n";
  auto stats = [&](const char* name, const ResidualStats& r, const char* unit) {
    char line[320];
    std::snprintf(line, sizeof(line), "  %-22s n=%lld median %.4g p95 %.4g rms %.4g max %.4g %s\n",
                  name, static_cast<long long>(r.count), r.median, r.p95, r.rms, r.max, unit);
    out << line;
  };
  stats("reprojection error", reprojection_error_px,
        mode == ReconstructMode::kStereo
            ? (method == TriangulationMethod::kMidpoint
                   ? "camera px (~0 by construction in stereo: no calibration evidence)"
                   : "camera px (small by construction in stereo: no calibration evidence)")
        : epipolar_error_px.count > 0
            ? "px (RMS of camera px and projector px)"
            : "px (~0 by construction with one coded axis: no calibration evidence)");
  if (epipolar_error_px.count > 0)
    stats("epipolar error", epipolar_error_px, "projector px (|signed|)");
  out << "  " << calibration_check.Message() << "\n";
  if (normal_fallbacks > 0)
    out << "  normals facing the camera (too few neighbours): " << normal_fallbacks << "\n";
  char line[256];
  std::snprintf(line, sizeof(line),
                "  time: rays %.3f s, match %.3f s, triangulate %.3f s, filters %.3f s, "
                "normals+cloud %.3f s, total %.3f s\n",
                rays_s, match_s, triangulate_s, filter_s, normals_s, total_s);
  out << line;
  std::snprintf(line, sizeof(line),
                "  CPU:  rays %.3f s, match %.3f s, triangulate %.3f s, filters %.3f s, "
                "normals+cloud %.3f s, total %.3f s\n",
                rays_cpu_s, match_cpu_s, triangulate_cpu_s, filter_cpu_s, normals_cpu_s,
                total_cpu_s);
  out << line;
  for (const auto& w : warnings) out << "  WARNING: " << w << "\n";
  return out.str();
}

nlohmann::json ReconstructSummary::ToJson() const {
  nlohmann::json rejected_json = nlohmann::json::object();
  for (int r = 1; r < kNumRejectReasons; ++r)
    rejected_json[ToString(static_cast<RejectReason>(r))] = rejected[static_cast<size_t>(r)];
  nlohmann::json decode_json = nlohmann::json::object();
  for (int k = 0; k < kNumPixelStatus; ++k)
    decode_json[ToString(static_cast<PixelStatus>(k))] = decode_status[static_cast<size_t>(k)];
  return {{"mode", ToString(mode)},
          {"method", ToString(method)},
          {"camera", camera},
          {"other_device", other_device},
          {"grid_width", grid_width},
          {"grid_height", grid_height},
          {"cells", cells},
          {"points", points},
          {"rejected", rejected_json},
          {"decode_status", decode_json},
          {"code_step_gate_px", code_step_gate_px},
          {"normal_fallbacks", normal_fallbacks},
          {"reprojection_error_px", reprojection_error_px.ToJson()},
          {"epipolar_error_px", epipolar_error_px.ToJson()},
          {"calibration_check", calibration_check.ToJson()},
          {"warnings", warnings},
          {"time_s",
           {{"rays", rays_s},
            {"match", match_s},
            {"triangulate", triangulate_s},
            {"filters", filter_s},
            {"normals", normals_s},
            {"total", total_s}}},
          {"cpu_s",
           {{"rays", rays_cpu_s},
            {"match", match_cpu_s},
            {"triangulate", triangulate_cpu_s},
            {"filters", filter_cpu_s},
            {"normals", normals_cpu_s},
            {"total", total_cpu_s}}}};
}

}  // namespace slshadow
