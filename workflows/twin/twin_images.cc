#include "workflows/twin/internal/twin_images.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include <opencv2/core/utility.hpp>

#include "workflows/twin/internal/twin_stats.h"

namespace slshadow::twin::internal {
namespace {

float Pixel(const cv::Mat& m, int y, int x) {
  return m.depth() == CV_8U ? static_cast<float>(m.at<uint8_t>(y, x))
                            : static_cast<float>(m.at<uint16_t>(y, x));
}

}  // namespace

cv::Mat LitPartMask(const GeometryBuffer& g) {
  cv::Mat mask(g.height, g.width, CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < g.height; ++y) {
    for (int x = 0; x < g.width; ++x) {
      if (g.visibility.at<uint8_t>(y, x) == 2 && g.object_id.at<int32_t>(y, x) >= 0)
        mask.at<uint8_t>(y, x) = 255;
    }
  }
  return mask;
}

FrameAgreement CompareFrames(const PatternSpec& spec, const std::vector<FrameInfo>& frames,
                             const std::vector<cv::Mat>& rimg, const std::vector<cv::Mat>& timg,
                             const cv::Mat& mask, const GeometryBuffer& g, double fs_dn) {
  const int nf = spec.NumImages();
  FrameAgreement out;
  std::vector<nlohmann::json>& per = out.per;
  per.resize(static_cast<size_t>(nf));
  std::vector<int64_t> within(static_cast<size_t>(nf), 0);
  const double tol = 0.05 * fs_dn;
  cv::parallel_for_(cv::Range(0, nf), [&](const cv::Range& r) {
    for (int k = r.start; k < r.end; ++k) {
      double sum = 0, ss = 0;
      int64_t n = 0, in = 0;
      const cv::Mat& a = rimg[static_cast<size_t>(k)];
      const cv::Mat& b = timg[static_cast<size_t>(k)];
      const bool bytes = a.depth() == CV_8U && b.depth() == CV_8U && g.width <= 32768;
      if (bytes) {
        // Integer differences summed as integers (branch-free, vectorised): the sums of
        // integer-valued doubles below 2^53 are exact, so the figures are the same bits.
        const int tol_dn = static_cast<int>(std::floor(tol));
        int64_t isum = 0, iss = 0;
        for (int y = 0; y < g.height; ++y) {
          const uint8_t* m = mask.ptr<uint8_t>(y);
          const uint8_t* pa = a.ptr<uint8_t>(y);
          const uint8_t* pb = b.ptr<uint8_t>(y);
          int32_t rsum = 0, rss = 0, rn = 0, rin = 0;  // a row: 1920 x 255^2 < 2^31
          for (int x = 0; x < g.width; ++x) {
            const int32_t w = m[x] != 0;
            const int32_t d = (static_cast<int32_t>(pa[x]) - pb[x]) * w;
            rsum += d, rss += d * d, rn += w;
            rin += w & static_cast<int32_t>(d <= tol_dn && d >= -tol_dn);
          }
          isum += rsum, iss += rss, n += rn, in += rin;
        }
        sum = static_cast<double>(isum);
        ss = static_cast<double>(iss);
      } else {
        for (int y = 0; y < g.height; ++y) {
          const uint8_t* m = mask.ptr<uint8_t>(y);
          for (int x = 0; x < g.width; ++x) {
            if (!m[x]) continue;
            const double d = Pixel(a, y, x) - Pixel(b, y, x);
            sum += d, ss += d * d, ++n;
            if (std::abs(d) <= tol) ++in;
          }
        }
      }
      within[static_cast<size_t>(k)] = in;
      per[static_cast<size_t>(k)] = {
          {"index", k},
          {"name", frames[static_cast<size_t>(k)].Name()},
          {"mean_dn", n ? sum / static_cast<double>(n) : 0.0},
          {"rms_dn", n ? std::sqrt(ss / static_cast<double>(n)) : 0.0},
          {"within_5pct", n ? static_cast<double>(in) / static_cast<double>(n) : 0.0}};
    }
  });
  for (int k = 0; k < nf; ++k) {
    out.in_all += within[static_cast<size_t>(k)];
    out.worst = std::min(out.worst, per[static_cast<size_t>(k)]["within_5pct"].get<double>());
  }
  return out;
}

nlohmann::json CompareProjectorCoordinates(const PatternSpec& spec, const ProjectorMap& rm,
                                           const ProjectorMap& tm, const ProjectorMap& gt,
                                           const cv::Mat& mask, int64_t lit,
                                           const GeometryBuffer& g, cv::Mat* residual_map,
                                           cv::Mat* validity_map) {
  // Differences of floats, kept as floats (exact) and reserved: ~4 M values per camera
  // would otherwise be copied and page-faulted through every doubling of a vector.
  std::vector<float> real_truth, twin_truth, real_twin;
  const size_t most = static_cast<size_t>(lit) * (spec.code_x && spec.code_y ? 2 : 1);
  real_truth.reserve(most);
  twin_truth.reserve(most);
  real_twin.reserve(most);
  int64_t both = 0, real_only = 0, twin_only = 0;
  cv::Mat residual(g.height, g.width, CV_32FC1, cv::Scalar(std::nanf("")));
  cv::Mat validity(g.height, g.width, CV_8UC3, cv::Scalar(0, 0, 0));
  for (int y = 0; y < g.height; ++y) {
    for (int x = 0; x < g.width; ++x) {
      const bool rv = rm.status.at<uint8_t>(y, x) == 0, tv = tm.status.at<uint8_t>(y, x) == 0;
      if (rv && tv) ++both, validity.at<cv::Vec3b>(y, x) = {80, 200, 80};
      if (rv && !tv) ++real_only, validity.at<cv::Vec3b>(y, x) = {60, 60, 255};
      if (!rv && tv) ++twin_only, validity.at<cv::Vec3b>(y, x) = {255, 120, 60};
      if (!mask.at<uint8_t>(y, x)) continue;
      for (int axis = 0; axis < 2; ++axis) {
        if (!spec.Codes(axis)) continue;
        const float r = (axis ? rm.proj_y : rm.proj_x).at<float>(y, x);
        const float t = (axis ? tm.proj_y : tm.proj_x).at<float>(y, x);
        const float tr = (axis ? gt.proj_y : gt.proj_x).at<float>(y, x);
        if (std::isfinite(r) && std::isfinite(tr) && std::abs(r - tr) < 20)
          real_truth.push_back(r - tr);
        if (std::isfinite(t) && std::isfinite(tr) && std::abs(t - tr) < 20)
          twin_truth.push_back(t - tr);
        if (std::isfinite(r) && std::isfinite(t) && std::abs(r - t) < 20)
          real_twin.push_back(r - t);
        if (axis == (spec.code_x ? 0 : 1) && std::isfinite(r) && std::isfinite(tr))
          residual.at<float>(y, x) = r - tr;
      }
    }
  }
  *residual_map = residual;
  *validity_map = validity;
  // Outliers (|d| >= 20 px, wrong codes) are counted apart so they do not swamp the RMS.
  const SampleStats srt = ComputeSampleStats(std::move(real_truth)),
                    stt = ComputeSampleStats(std::move(twin_truth)),
                    srw = ComputeSampleStats(std::move(real_twin));
  // Per axis RMS (x, y) are pooled: RMS over both axes' residuals is what "px RMS" means
  // here.
  return {{"real_vs_truth_rms_px", srt.rms},
          {"real_vs_truth", srt.ToJson("px")},
          {"twin_vs_truth_rms_px", stt.rms},
          {"twin_vs_truth", stt.ToJson("px")},
          {"real_vs_twin_decoded_rms_px", srw.rms},
          {"real_vs_twin_decoded", srw.ToJson("px")},
          {"valid_both", both},
          {"valid_real_only", real_only},
          {"valid_twin_only", twin_only},
          {"outlier_gate_px", 20}};
}

}  // namespace slshadow::twin::internal
