#include "reconstruct/reconstruct.h"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <sstream>

#include "core/statistics.h"

namespace slshadow {

namespace {

std::string Percent(int64_t part, int64_t whole) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.1f%%",
                whole > 0 ? 100.0 * static_cast<double>(part) / static_cast<double>(whole) : 0.0);
  return buf;
}

// The values of ranks k0 and k1 (0-based, ascending) of finite `values`, exactly as
// std::nth_element would give them, by one radix pass: a histogram of the top 16 bits of the
// order-preserving integer key of each float locates the bucket holding each rank, and only the
// values of those buckets (a few thousand of millions for residuals) are then ordered.
inline uint32_t SortKey(float v) {
  uint32_t bits;
  std::memcpy(&bits, &v, sizeof(bits));
  return (bits & 0x80000000u) ? ~bits : (bits | 0x80000000u);
}

std::pair<float, float> SelectRanks(std::vector<float>& values, size_t k0, size_t k1) {
  constexpr int kBuckets = 1 << 16;
  std::vector<uint32_t> hist(kBuckets, 0);
  for (float v : values) ++hist[SortKey(v) >> 16];
  auto locate = [&](size_t k, size_t* rank_in_bucket) {
    size_t below = 0;
    for (int b = 0; b < kBuckets; ++b) {
      if (below + hist[static_cast<size_t>(b)] > k) {
        *rank_in_bucket = k - below;
        return static_cast<uint32_t>(b);
      }
      below += hist[static_cast<size_t>(b)];
    }
    *rank_in_bucket = 0;
    return static_cast<uint32_t>(kBuckets - 1);
  };
  size_t r0 = 0, r1 = 0;
  const uint32_t b0 = locate(k0, &r0), b1 = locate(k1, &r1);
  std::vector<float> c0, c1;
  c0.reserve(hist[b0]);
  if (b1 != b0) c1.reserve(hist[b1]);
  for (float v : values) {
    const uint32_t b = SortKey(v) >> 16;
    if (b == b0)
      c0.push_back(v);
    else if (b == b1)
      c1.push_back(v);
  }
  std::vector<float>& d1 = b1 == b0 ? c0 : c1;
  std::nth_element(c0.begin(), c0.begin() + static_cast<std::ptrdiff_t>(r0), c0.end());
  const float v0 = c0[r0];
  std::nth_element(d1.begin(), d1.begin() + static_cast<std::ptrdiff_t>(r1), d1.end());
  return {v0, d1[r1]};
}

}  // namespace

ResidualStats ComputeResidualStats(std::vector<float>& values) {
  values.erase(
      std::remove_if(values.begin(), values.end(), [](float v) { return !std::isfinite(v); }),
      values.end());
  ResidualStats s;
  s.count = static_cast<int64_t>(values.size());
  if (values.empty()) return s;
  double sum2 = 0, mx = 0;
  for (float v : values) {
    sum2 += static_cast<double>(v) * v;
    mx = std::max(mx, static_cast<double>(v));
  }
  s.rms = std::sqrt(sum2 / static_cast<double>(values.size()));
  s.max = mx;
  const size_t n = values.size();
  const size_t km = PercentileRank(n, 50);  // core/statistics.h: nearest rank
  const size_t kp = PercentileRank(n, 95);
  const auto ranked = SelectRanks(values, km, kp);
  s.median = ranked.first;
  s.p95 = ranked.second;
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
