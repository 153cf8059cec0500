#include "sim/renderer.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <mutex>
#include <optional>
#include <type_traits>
#include <utility>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include <cstdlib>
#include <new>

#include <tbb/blocked_range2d.h>
#include <tbb/parallel_for.h>
#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "sim/internal/pattern_kernels.h"
#include "sim/pooled_mats.h"
#include "sim/sensor_noise.h"

namespace slshadow {
namespace {

// Bilinear lookup with clamping at the borders.
inline float Bilinear(const float* img, int w, int h, float x, float y) {
  const float fx0 = std::floor(x), fy0 = std::floor(y);
  const float fx = x - fx0, fy = y - fy0;
  const int x0 = std::clamp(static_cast<int>(fx0), 0, w - 1),
            x1 = std::clamp(static_cast<int>(fx0) + 1, 0, w - 1);
  const int y0 = std::clamp(static_cast<int>(fy0), 0, h - 1),
            y1 = std::clamp(static_cast<int>(fy0) + 1, 0, h - 1);
  const float* r0 = img + static_cast<size_t>(y0) * w;
  const float* r1 = img + static_cast<size_t>(y1) * w;
  return (1 - fy) * ((1 - fx) * r0[x0] + fx * r0[x1]) + fy * ((1 - fx) * r1[x0] + fx * r1[x1]);
}

inline float Nearest(const float* img, int w, int h, float x, float y) {
  const int xi = std::clamp(static_cast<int>(std::lround(x)), 0, w - 1);
  const int yi = std::clamp(static_cast<int>(std::lround(y)), 0, h - 1);
  return img[static_cast<size_t>(yi) * w + xi];
}

// Levels 0, s/(K-1), ..., s for a maximum sigma s (empty when s is negligible).
std::vector<double> SigmaLevels(double max_sigma) {
  if (!(max_sigma > 0.05)) return {};
  const int k = std::clamp(static_cast<int>(std::ceil(max_sigma / 0.5)) + 1, 2, 8);
  std::vector<double> levels(static_cast<size_t>(k));
  for (int i = 0; i < k; ++i) levels[static_cast<size_t>(i)] = max_sigma * i / (k - 1);
  return levels;
}

cv::Mat Blur(const cv::Mat& image, double sigma) {
  if (sigma <= 0) return image;
  cv::Mat out;
  cv::GaussianBlur(image, out, cv::Size(0, 0), sigma, sigma, cv::BORDER_REPLICATE);
  return out;
}

}  // namespace

PatternRenderer::PatternRenderer(const Scene& scene, const Rig& rig, int camera_index,
                                 const GeometryBuffer& geometry)
    : scene_(scene), geometry_(geometry), camera_index_(camera_index) {
  SLSHADOW_THROW_IF(!rig.projector, "rig '", rig.name,
                    "' has no projector: the simulator needs one");
  projector_width_ = rig.projector->model.width;
  projector_height_ = rig.projector->model.height;
  full_scale_dn_ = std::ldexp(1.0, scene.radiometry.adc_bits) - 1;
  const SceneLayers& l = scene.layers;
  response_.resize(256);
  for (int v = 0; v < 256; ++v) {
    double r = v / 255.0;
    if (l.response_enabled)
      r = l.response_lut.empty() ? std::pow(r, l.gamma) : l.response_lut[static_cast<size_t>(v)];
    response_[static_cast<size_t>(v)] = static_cast<float>(r);
  }
  linear_response_ = !l.response_enabled;
  const CameraModel& model = rig.cameras[static_cast<size_t>(camera_index)].model;
  if (l.vignetting_enabled) {
    // Smooth in the image: evaluated on an 8-pixel grid and interpolated bilinearly.
    constexpr int kStep = 8;
    const int gw = model.width / kStep + 2, gh = model.height / kStep + 2;
    cv::Mat grid(gh, gw, CV_32FC1);
    for (int j = 0; j < gh; ++j) {
      for (int i = 0; i < gw; ++i) {
        const auto xy = model.UndistortToNormalized(Eigen::Vector2d(i * kStep, j * kStep));
        // Outside the region where undistortion converges: treat as the image corner's value.
        const double r2 = xy ? xy->squaredNorm() : 0.0;
        double v;
        if (l.vignetting_cos4) {
          v = 1.0 / ((1 + r2) * (1 + r2));
        } else {
          const auto& a = l.vignetting_coefficients;
          v = 1 + a[0] * r2 + a[1] * r2 * r2 + a[2] * r2 * r2 * r2;
        }
        grid.at<float>(j, i) = static_cast<float>(std::max(0.0, v));
      }
    }
    vignetting_ = cv::Mat(model.height, model.width, CV_32FC1);
    for (int y = 0; y < model.height; ++y) {
      for (int x = 0; x < model.width; ++x) {
        vignetting_.at<float>(y, x) =
            Bilinear(grid.ptr<float>(), gw, gh, static_cast<float>(x) / kStep,
                     static_cast<float>(y) / kStep);
      }
    }
  }
  if (l.camera_defocus.enabled) {
    cv::Mat sigma(model.height, model.width, CV_32FC1, cv::Scalar(0));
    double max_sigma = 0;
    for (int y = 0; y < model.height; ++y) {
      for (int x = 0; x < model.width; ++x) {
        const float d = geometry.depth_mm.at<float>(y, x);
        const double s = std::isfinite(d) ? l.camera_defocus.SigmaPx(model.fx(), d) : 0.0;
        sigma.at<float>(y, x) = static_cast<float>(s);
        max_sigma = std::max(max_sigma, s);
      }
    }
    camera_sigmas_ = SigmaLevels(max_sigma);
    if (!camera_sigmas_.empty()) {
      // Background pixels (no surface) stay sharp: sigma 0.
      camera_level_ = sigma * ((camera_sigmas_.size() - 1) / max_sigma);
    }
  }
  if (l.projector_defocus.enabled && !geometry.proj_sigma_px.empty()) {
    const float max_sigma =
        *std::max_element(geometry.proj_sigma_px.begin(), geometry.proj_sigma_px.end());
    projector_sigmas_ = SigmaLevels(max_sigma);
  }
}

cv::Mat PatternRenderer::RenderIrradiance(const cv::Mat& projector_image) const {
  return RenderIrradianceBatch({projector_image})[0];
}

std::vector<cv::Mat> PatternRenderer::RenderIrradianceBatch(
    const std::vector<cv::Mat>& images) const {
  const int batch = static_cast<int>(images.size());
  SLSHADOW_THROW_IF(batch < 1 || batch > kMaxBatch, "pattern batch must hold 1..", kMaxBatch,
                    " images (got ", batch, ")");
  for (const cv::Mat& projector_image : images) {
    SLSHADOW_THROW_IF(
        projector_image.type() != CV_8UC1 || projector_image.cols != projector_width_ ||
            projector_image.rows != projector_height_ || !projector_image.isContinuous(),
        "projector image must be 8-bit single-channel ", projector_width_, "x", projector_height_,
        " (got type ", projector_image.type(), ", ", projector_image.cols, "x",
        projector_image.rows, ")");
  }
  const SceneLayers& l = scene_.layers;
  const int pw = projector_width_, ph = projector_height_;
  // Float intensity images through the response curve, unless the response is linear and no
  // projector blur is needed (then lookups read the 8-bit images directly).
  const bool direct = linear_response_ && projector_sigmas_.empty();
  // The batch is interleaved per projector pixel ([pixel][image]) so one lookup reads all images
  // of the batch from the same cache lines.
  const size_t n_proj = static_cast<size_t>(pw) * ph;
  std::vector<uint8_t> inter8;              // direct path
  std::vector<std::vector<float>> inter_f;  // [blur level][pixel * batch + image]
  if (direct) {
    inter8.resize(n_proj * batch);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n_proj, 4096),
                      [&](const tbb::blocked_range<size_t>& r) {
                        for (int k = 0; k < batch; ++k) {
                          const uint8_t* src = images[static_cast<size_t>(k)].ptr<uint8_t>();
                          for (size_t i = r.begin(); i < r.end(); ++i)
                            inter8[i * batch + k] = src[i];
                        }
                      });
  } else {
    const size_t n_levels = std::max<size_t>(1, projector_sigmas_.size());
    inter_f.assign(n_levels, std::vector<float>(n_proj * batch));
    tbb::parallel_for(0, batch, [&](int k) {
      cv::Mat intensity(ph, pw, CV_32FC1);
      for (int y = 0; y < ph; ++y) {
        const uint8_t* src = images[static_cast<size_t>(k)].ptr<uint8_t>(y);
        float* dst = intensity.ptr<float>(y);
        for (int x = 0; x < pw; ++x) dst[x] = response_[src[x]];
      }
      for (size_t lv = 0; lv < n_levels; ++lv) {
        const cv::Mat level =
            projector_sigmas_.empty() ? intensity : Blur(intensity, projector_sigmas_[lv]);
        const float* src = level.ptr<float>();
        float* dst = inter_f[lv].data();
        for (size_t i = 0; i < n_proj; ++i) dst[i * batch + k] = src[i];
      }
    });
  }
  const int w = geometry_.width, h = geometry_.height;
  const int spp = geometry_.samples_per_axis * geometry_.samples_per_axis;
  const float scale =
      static_cast<float>(scene_.radiometry.exposure_fraction * full_scale_dn_ / spp);
  const float ambient = static_cast<float>(l.ambient);
  const bool bilinear = scene_.radiometry.bilinear_lookup;
  const bool fill = l.fill_factor < 1;
  const float half_side = static_cast<float>(std::sqrt(l.fill_factor) / 2);
  const int top_level =
      projector_sigmas_.empty() ? 0 : static_cast<int>(projector_sigmas_.size()) - 1;
  const float level_scale =
      projector_sigmas_.empty() ? 0.0f : static_cast<float>(top_level / projector_sigmas_.back());
  std::vector<cv::Mat> out(static_cast<size_t>(batch));
  for (auto& m : out) m.create(h, w, CV_32FC1);
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 4), [&](const tbb::blocked_range<int>& r) {
    float acc[kMaxBatch];
    for (int y = r.begin(); y < r.end(); ++y) {
      const float* vig = vignetting_.empty() ? nullptr : vignetting_.ptr<float>(y);
      for (int x = 0; x < w; ++x) {
        for (int k = 0; k < batch; ++k) acc[k] = 0;
        const size_t i0 = (static_cast<size_t>(y) * w + x) * spp;
        for (int s = 0; s < spp; ++s) {
          const size_t i = i0 + s;
          const float f = geometry_.factor[i];
          const float base = ambient * geometry_.albedo[i];
          if (!(f > 0)) {
            for (int k = 0; k < batch; ++k) acc[k] += base;
            continue;
          }
          const float u = geometry_.proj_x[i], t = geometry_.proj_y[i];
          // Bilinear weights, shared by every image of the batch; clamped at the borders.
          const auto bilinear_at = [&] {
            const float fx0 = std::floor(u), fy0 = std::floor(t);
            const int x0 = std::clamp(static_cast<int>(fx0), 0, pw - 1),
                      x1 = std::clamp(static_cast<int>(fx0) + 1, 0, pw - 1);
            const int y0 = std::clamp(static_cast<int>(fy0), 0, ph - 1),
                      y1 = std::clamp(static_cast<int>(fy0) + 1, 0, ph - 1);
            return std::array<size_t, 4>{(static_cast<size_t>(y0) * pw + x0) * batch,
                                         (static_cast<size_t>(y0) * pw + x1) * batch,
                                         (static_cast<size_t>(y1) * pw + x0) * batch,
                                         (static_cast<size_t>(y1) * pw + x1) * batch};
          };
          const auto bilinear_weights = [&] {
            const float ax = u - std::floor(u), ay = t - std::floor(t);
            return std::array<float, 4>{(1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay};
          };
          // base + gain x the blurred images at the point's blur (bilinear between the two nearest
          // blur levels).
          const auto add_blurred = [&](float base_light, float gain) {
            const auto [i00, i01, i10, i11] = bilinear_at();
            const auto [w00, w01, w10, w11] = bilinear_weights();
            int l0 = 0, l1 = 0;
            float a = 0;
            if (top_level > 0) {
              const float lv = geometry_.proj_sigma_px[i] * level_scale;
              l0 = std::min(static_cast<int>(lv), top_level);
              l1 = std::min(l0 + 1, top_level);
              a = lv - l0;
            }
            const float* p0 = inter_f[static_cast<size_t>(l0)].data();
            const float* p1 = inter_f[static_cast<size_t>(l1)].data();
            for (int k = 0; k < batch; ++k) {
              const float v0 =
                  w00 * p0[i00 + k] + w01 * p0[i01 + k] + w10 * p0[i10 + k] + w11 * p0[i11 + k];
              const float v1 =
                  w00 * p1[i00 + k] + w01 * p1[i01 + k] + w10 * p1[i10 + k] + w11 * p1[i11 + k];
              acc[k] += base_light + gain * ((1 - a) * v0 + a * v1);
            }
          };
          if (fill || !bilinear) {
            // Pixel-exact: the projector pixel containing the point (dark in the fill gaps).
            const int xi = std::clamp(static_cast<int>(std::lround(u)), 0, pw - 1);
            const int yi = std::clamp(static_cast<int>(std::lround(t)), 0, ph - 1);
            const bool lit = !fill || (std::abs(u - std::round(u)) <= half_side &&
                                       std::abs(t - std::round(t)) <= half_side);
            const size_t idx = (static_cast<size_t>(yi) * pw + xi) * batch;
            float g = lit ? f : 0.0f;
            if (top_level > 0) {
              // Projector blur: the pixel grid (its steps and fill gaps) keeps the Gaussian
              // transfer of its 1-px period, exp(-2 pi^2 sigma^2); the rest of the light is the
              // blurred image, smooth, at the fill factor's share of the pixel area.
              const float sigma = geometry_.proj_sigma_px[i];
              const float grid = std::exp(-2 * static_cast<float>(M_PI * M_PI) * sigma * sigma);
              g *= grid;
              add_blurred(base, f * (1 - grid) * static_cast<float>(l.fill_factor));
              const float* p = inter_f[0].data() + idx;
              for (int k = 0; k < batch; ++k) acc[k] += g * p[k];
              continue;
            }
            if (direct) {
              for (int k = 0; k < batch; ++k) acc[k] += base + g * (1.0f / 255) * inter8[idx + k];
            } else {
              const float* p = inter_f[0].data() + idx;
              for (int k = 0; k < batch; ++k) acc[k] += base + g * p[k];
            }
            continue;
          }
          const auto [i00, i01, i10, i11] = bilinear_at();
          const auto [w00, w01, w10, w11] = bilinear_weights();
          if (direct) {
            const float g = f * (1.0f / 255);
            const uint8_t* p = inter8.data();
            for (int k = 0; k < batch; ++k) {
              acc[k] += base + g * (w00 * p[i00 + k] + w01 * p[i01 + k] + w10 * p[i10 + k] +
                                    w11 * p[i11 + k]);
            }
          } else {
            add_blurred(base, f);
          }
        }
        const float m = scale * (vig ? vig[x] : 1.0f);
        for (int k = 0; k < batch; ++k) out[static_cast<size_t>(k)].ptr<float>(y)[x] = acc[k] * m;
      }
    }
  });
  if (!camera_sigmas_.empty()) {
    tbb::parallel_for(0, batch, [&](int k) {
      out[static_cast<size_t>(k)] = ApplyCameraDefocus(out[static_cast<size_t>(k)]);
    });
  }
  return out;
}

cv::Mat PatternRenderer::ApplyCameraDefocus(const cv::Mat& image) const {
  const int w = image.cols, h = image.rows;
  std::vector<cv::Mat> blurred;
  for (double sgm : camera_sigmas_) blurred.push_back(Blur(image, sgm));
  cv::Mat mixed(h, w, CV_32FC1);
  const int top = static_cast<int>(blurred.size()) - 1;
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const tbb::blocked_range<int>& r) {
    for (int y = r.begin(); y < r.end(); ++y) {
      for (int x = 0; x < w; ++x) {
        const float lv = camera_level_.at<float>(y, x);
        const int l0 = std::min(static_cast<int>(lv), top), l1 = std::min(l0 + 1, top);
        const float a = lv - l0;
        mixed.at<float>(y, x) = (1 - a) * blurred[static_cast<size_t>(l0)].at<float>(y, x) +
                                a * blurred[static_cast<size_t>(l1)].at<float>(y, x);
      }
    }
  });
  return mixed;
}

PatternBatch::PatternBatch(std::vector<cv::Mat> images) : images_(std::move(images)) {
  SLSHADOW_THROW_IF(images_.empty(), "a pattern batch needs at least one projector image");
  for (const cv::Mat& m : images_) {
    SLSHADOW_THROW_IF(m.type() != CV_8UC1 || m.size() != images_[0].size() || !m.isContinuous(),
                      "projector images of a batch must be 8-bit single-channel, continuous, all ",
                      images_[0].cols, "x", images_[0].rows, " (got type ", m.type(), ", ", m.cols,
                      "x", m.rows, ")");
  }
}

const uint8_t* PatternBatch::Interleaved() const {
  std::call_once(interleaved_once_, [this] {
    const int batch = size();
    const size_t n = images_[0].total();
    // Pooled (no page faults after the first scan); every byte written below.
    CreatePooled(interleaved_, 1, static_cast<int>(n * batch + kPadding), CV_8UC1);
    uint8_t* const inter = interleaved_.ptr<uint8_t>();
    std::fill(inter + n * batch, inter + n * batch + kPadding, uint8_t{0});
    std::vector<const uint8_t*> src(static_cast<size_t>(batch));
    for (int k = 0; k < batch; ++k)
      src[static_cast<size_t>(k)] = images_[static_cast<size_t>(k)].ptr<uint8_t>();
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, n, 16384), [&](const tbb::blocked_range<size_t>& r) {
          size_t i = r.begin();
#if defined(__x86_64__)
          if (batch >= 4) {
            // 16 projector pixels at a time: byte transposes of 16 images each, then per pixel one
            // 16-byte store per group of images. A group of fewer than 16 images spills into the
            // next pixel's bytes, which are written afterwards (pixels in order; the last spill
            // stays inside this range: i + 32 <= end).
            const int groups = (batch + 15) / 16;
            for (; i + 32 <= r.end(); i += 16) {
              __m128i a[2][16];
              for (int gi = 0; gi < groups; ++gi) {
                for (int k = 0; k < 16; ++k) {
                  const int img = gi * 16 + k;
                  a[gi][k] = img < batch ? _mm_loadu_si128(reinterpret_cast<const __m128i*>(
                                               src[static_cast<size_t>(img)] + i))
                                         : _mm_setzero_si128();
                }
                Transpose16x16(a[gi]);
              }
              for (int j = 0; j < 16; ++j) {
                uint8_t* dst = inter + (i + static_cast<size_t>(j)) * batch;
                for (int gi = 0; gi < groups; ++gi)
                  _mm_storeu_si128(reinterpret_cast<__m128i*>(dst + 16 * gi), a[gi][j]);
              }
            }
          }
#endif
          uint8_t* dst = inter + i * batch;
          for (; i < r.end(); ++i) {
            for (int k = 0; k < batch; ++k) *dst++ = src[static_cast<size_t>(k)][i];
          }
        });
  });
  return interleaved_.ptr<uint8_t>();
}

std::vector<cv::Mat> PatternRenderer::RenderBatch(const std::vector<cv::Mat>& images,
                                                  int first_pattern_index) const {
  return RenderBatch(PatternBatch(images), first_pattern_index);
}

std::vector<cv::Mat> PatternRenderer::RenderBatch(const PatternBatch& patterns,
                                                  int first_pattern_index) const {
  const SceneLayers& l = scene_.layers;
  const std::vector<cv::Mat>& images = patterns.images();
  const int batch = patterns.size();
  SLSHADOW_THROW_IF(batch > kMaxBatch, "pattern batch must hold 1..", kMaxBatch, " images (got ",
                    batch, ")");
  static_assert(kMaxBatch <= 32, "the fused kernels take up to 32 images");
  const bool fused = !l.response_enabled && projector_sigmas_.empty() &&
                     scene_.radiometry.bilinear_lookup && l.fill_factor >= 1 &&
                     geometry_.samples_per_axis == 1 && camera_sigmas_.empty() &&
                     !l.noise_enabled && batch <= kMaxBatch;
  if (fused) {
    const int pw = projector_width_, ph = projector_height_;
    for (const cv::Mat& m : images) {
      SLSHADOW_THROW_IF(m.type() != CV_8UC1 || m.cols != pw || m.rows != ph || !m.isContinuous(),
                        "projector image must be 8-bit single-channel ", pw, "x", ph, " (got type ",
                        m.type(), ", ", m.cols, "x", m.rows, ")");
    }
    // Interleaved once per batch object (shared by every camera of a scan).
    const uint8_t* const inter_data = patterns.Interleaved();
    const bool wide = scene_.radiometry.adc_bits > 8;
    // The batch's images as row bands of one pooled block (recycled across scans: no first-touch
    // faults after the first); each image is a continuous sub-matrix that keeps the block alive.
    cv::Mat block;
    CreatePooled(block, geometry_.height * batch, geometry_.width, wide ? CV_16UC1 : CV_8UC1);
    std::vector<cv::Mat> out(static_cast<size_t>(batch));
    for (int k = 0; k < batch; ++k)
      out[static_cast<size_t>(k)] =
          block.rowRange(k * geometry_.height, (k + 1) * geometry_.height);
    const float scale = static_cast<float>(scene_.radiometry.exposure_fraction * full_scale_dn_);
    const float ambient = static_cast<float>(l.ambient);
    const float full = static_cast<float>(full_scale_dn_);
    if (wide) {
      FusedDirectBilinear<uint16_t>(geometry_, inter_data, batch, pw, ph, ambient, scale,
                                    vignetting_, full, out);
    } else {
      FusedDirectBilinear<uint8_t>(geometry_, inter_data, batch, pw, ph, ambient, scale,
                                   vignetting_, full, out);
    }
    return out;
  }
  // The general path in chunks of at most 16 images, as before batches of 32: its float buffers
  // (one per projector blur level and one per output image) grow with the chunk.
  constexpr int kGeneralChunk = 16;
  std::vector<cv::Mat> out(images.size());
  for (int first = 0; first < batch; first += kGeneralChunk) {
    const std::vector<cv::Mat> chunk(images.begin() + first,
                                     images.begin() + std::min(first + kGeneralChunk, batch));
    const std::vector<cv::Mat> irradiance = RenderIrradianceBatch(chunk);
    tbb::parallel_for(size_t{0}, irradiance.size(), [&](size_t k) {
      out[static_cast<size_t>(first) + k] =
          Quantize(irradiance[k], first_pattern_index + first + static_cast<int>(k));
    });
  }
  return out;
}

cv::Mat PatternRenderer::Render(const cv::Mat& projector_image, int pattern_index) const {
  return RenderBatch(std::vector<cv::Mat>{projector_image}, pattern_index)[0];
}

cv::Mat PatternRenderer::Quantize(const cv::Mat& irradiance, int pattern_index) const {
  cv::Mat out;
  QuantizeIrradiance(irradiance, scene_, camera_index_, pattern_index, &out);
  return out;
}

}  // namespace slshadow
