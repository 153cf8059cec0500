#include "patterns/synthetic.h"

#include <cmath>
#include <numbers>

#include <opencv2/imgproc.hpp>

#include "core/error.h"
#include "patterns/codec.h"

namespace slshadow {

void CameraSimOptions::Check() const {
  const char* p = "camera simulation: ";
  SLSHADOW_THROW_IF(!std::isfinite(offset), p, "offset: must be finite (got ", offset, ")");
  SLSHADOW_THROW_IF(!std::isfinite(gain) || gain < 0, p, "gain: must be >= 0 (got ", gain, ")");
  SLSHADOW_THROW_IF(!std::isfinite(gamma) || gamma <= 0, p, "gamma: must be > 0 (got ", gamma, ")");
  SLSHADOW_THROW_IF(!std::isfinite(blur_sigma_px) || blur_sigma_px < 0, p,
                    "blur_sigma_px: must be >= 0 (got ", blur_sigma_px, ")");
  SLSHADOW_THROW_IF(!std::isfinite(noise_sigma) || noise_sigma < 0, p,
                    "noise_sigma: must be >= 0 (got ", noise_sigma, ")");
  SLSHADOW_THROW_IF(bit_depth != 8 && bit_depth != 16, p, "bit_depth: must be 8 or 16 (got ",
                    bit_depth, ")");
  SLSHADOW_THROW_IF(!gain_map.empty() && gain_map.type() != CV_32FC1, p,
                    "gain_map: must be CV_32FC1");
  SLSHADOW_THROW_IF(!offset_map.empty() && offset_map.type() != CV_32FC1, p,
                    "offset_map: must be CV_32FC1");
}

std::vector<cv::Mat> SimulateStandardView(const PatternSpec& spec, int width, int height,
                                          const CameraSimOptions& options, cv::Mat* map_x,
                                          cv::Mat* map_y) {
  SLSHADOW_THROW_IF(width < 2 || height < 2,
                    "camera simulation: camera size must be at least 2x2 (got ", width, "x", height,
                    ")");
  const double a = 10 * std::numbers::pi / 180;
  const double s = 0.8 * spec.projector_width / width;  // projector px per camera px
  const cv::Matx33d centre_cam(1, 0, -width / 2.0, 0, 1, -height / 2.0, 0, 0, 1);
  const cv::Matx33d view(s * std::cos(a), -s * std::sin(a), 0, s * std::sin(a), s * std::cos(a), 0,
                         0.05 / width, 0.02 / height, 1);
  const cv::Matx33d to_proj(1, 0, spec.projector_width / 2.0, 0, 1, spec.projector_height / 2.0, 0,
                            0, 1);
  cv::Mat mx, my;
  HomographyMaps(to_proj * view * centre_cam, width, height, &mx, &my);
  std::vector<cv::Mat> images = SimulateCameraImages(GeneratePatterns(spec), mx, my, options);
  if (map_x) *map_x = mx;
  if (map_y) *map_y = my;
  return images;
}

void HomographyMaps(const cv::Matx33d& h, int width, int height, cv::Mat* map_x, cv::Mat* map_y) {
  *map_x = cv::Mat(height, width, CV_64FC1);
  *map_y = cv::Mat(height, width, CV_64FC1);
  for (int v = 0; v < height; ++v) {
    for (int u = 0; u < width; ++u) {
      const double w = h(2, 0) * u + h(2, 1) * v + h(2, 2);
      map_x->at<double>(v, u) = (h(0, 0) * u + h(0, 1) * v + h(0, 2)) / w;
      map_y->at<double>(v, u) = (h(1, 0) * u + h(1, 1) * v + h(1, 2)) / w;
    }
  }
}

std::vector<cv::Mat> SimulateCameraImages(const std::vector<cv::Mat>& projector_images,
                                          const cv::Mat& map_x_in, const cv::Mat& map_y_in,
                                          const CameraSimOptions& options) {
  options.Check();
  SLSHADOW_THROW_IF(map_x_in.size() != map_y_in.size() || map_x_in.empty(),
                    "camera simulation: map_x and map_y must be non-empty and of one size");
  cv::Mat map_x, map_y;
  map_x_in.convertTo(map_x, CV_64F);
  map_y_in.convertTo(map_y, CV_64F);
  const int width = map_x.cols, height = map_x.rows;
  SLSHADOW_THROW_IF(!options.gain_map.empty() && options.gain_map.size() != map_x.size(),
                    "camera simulation: gain_map must have the camera's size");
  SLSHADOW_THROW_IF(!options.offset_map.empty() && options.offset_map.size() != map_x.size(),
                    "camera simulation: offset_map must have the camera's size");
  std::vector<cv::Mat> out(projector_images.size());
  // Projector response lookup table.
  std::vector<double> response(256);
  for (int v = 0; v < 256; ++v)
    response[static_cast<size_t>(v)] = 255.0 * std::pow(v / 255.0, options.gamma);

  for (size_t i = 0; i < projector_images.size(); ++i) {
    const cv::Mat& proj = projector_images[i];
    SLSHADOW_THROW_IF(proj.type() != CV_8UC1, "camera simulation: projector image ", i,
                      " must be CV_8UC1");
    const int pw = proj.cols, ph = proj.rows;
    cv::Mat level(height, width, CV_32FC1);
    cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& range) {
      for (int v = range.start; v < range.end; ++v) {
        const double* mx = map_x.ptr<double>(v);
        const double* my = map_y.ptr<double>(v);
        float* dst = level.ptr<float>(v);
        const float* gm = options.gain_map.empty() ? nullptr : options.gain_map.ptr<float>(v);
        const float* om = options.offset_map.empty() ? nullptr : options.offset_map.ptr<float>(v);
        for (int u = 0; u < width; ++u) {
          const double x = mx[u], y = my[u];
          double s = 0;
          if (x >= -0.5 && x <= pw - 0.5 && y >= -0.5 && y <= ph - 0.5) {
            const double xc = std::clamp(x, 0.0, pw - 1.0), yc = std::clamp(y, 0.0, ph - 1.0);
            const int x0 = std::min(static_cast<int>(xc), pw - 2 < 0 ? 0 : pw - 2);
            const int y0 = std::min(static_cast<int>(yc), ph - 2 < 0 ? 0 : ph - 2);
            const double tx = xc - x0, ty = yc - y0;
            const uint8_t* r0 = proj.ptr<uint8_t>(y0);
            const uint8_t* r1 = proj.ptr<uint8_t>(std::min(y0 + 1, ph - 1));
            const int x1 = std::min(x0 + 1, pw - 1);
            const double top = (1 - tx) * response[r0[x0]] + tx * response[r0[x1]];
            const double bottom = (1 - tx) * response[r1[x0]] + tx * response[r1[x1]];
            s = (1 - ty) * top + ty * bottom;
          }
          const double gain = gm ? gm[u] : options.gain;
          const double offset = om ? om[u] : options.offset;
          dst[u] = static_cast<float>(offset + gain * s);
        }
      }
    });
    if (options.blur_sigma_px > 0) {
      cv::GaussianBlur(level, level, cv::Size(0, 0), options.blur_sigma_px, options.blur_sigma_px,
                       cv::BORDER_REPLICATE);
    }
    const double scale = options.bit_depth == 8 ? 1.0 : 257.0;
    const double max_level = options.bit_depth == 8 ? 255.0 : 65535.0;
    cv::Mat image(height, width, options.bit_depth == 8 ? CV_8UC1 : CV_16UC1);
    cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& range) {
      for (int v = range.start; v < range.end; ++v) {
        // One generator per (seed, image, row): deterministic whatever the thread split.
        cv::RNG rng(options.seed * 0x9E3779B97F4A7C15ull + i * 0x100000001B3ull +
                    static_cast<uint64_t>(v) + 1);
        const float* src = level.ptr<float>(v);
        for (int u = 0; u < width; ++u) {
          double c = src[u];
          if (options.noise_sigma > 0) c += rng.gaussian(options.noise_sigma);
          const double q = std::clamp(std::floor(c * scale + 0.5), 0.0, max_level);
          if (options.bit_depth == 8) {
            image.ptr<uint8_t>(v)[u] = static_cast<uint8_t>(q);
          } else {
            image.ptr<uint16_t>(v)[u] = static_cast<uint16_t>(q);
          }
        }
      }
    });
    out[i] = image;
  }
  return out;
}

}  // namespace slshadow
