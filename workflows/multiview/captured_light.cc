// The light a real capture records (coverage_prediction.h): the lit range and its gloss lobe and
// pixel noise from the white and black frames (WithCapturedRadiometry), the Gray bits' contrast
// per unit of lit range (WithCapturedContrast).
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <vector>

#include "compare/compare.h"
#include "core/error.h"
#include "workflows/multiview/coverage_prediction.h"
#include "workflows/multiview/internal/prediction_reasons.h"

namespace slshadow::multiview {

using internal::GlossLobe;

namespace {

// The square of a printed checkerboard (Albedo kCheckerboard, part frame) a sample at `p` lies
// on, as its index a + squares_x b (the board's outer squares start at -1 square) and its class
// (0: the corner square's parity, light on the kamino board; 1: the other); false off the board
// or within `edge_margin_mm` of a square's edge.
bool BoardSquare(const Albedo& texture, const Eigen::Vector3d& p, double edge_margin_mm,
                 int* square, int* cls) {
  const double sq = texture.square_mm;
  const int a = static_cast<int>(std::floor(p.x() / sq)) + 1;
  const int b = static_cast<int>(std::floor(p.y() / sq)) + 1;
  if (a < 0 || b < 0 || a >= texture.squares_x || b >= texture.squares_y) return false;
  const double ex = std::abs(p.x() / sq - std::round(p.x() / sq)) * sq;
  const double ey = std::abs(p.y() / sq - std::round(p.y() / sq)) * sq;
  if (std::min(ex, ey) < edge_margin_mm) return false;
  *cls = (a + b) % 2 == 0 ? 0 : 1;
  *square = a + texture.squares_x * b;
  return true;
}

// A surface sample (part frame, outward normal n) as the capture's camera sees it lit: the camera
// pixel nearest its projection; false when it faces away from the camera or the projector, or
// falls outside either device's image.
struct LitSight {
  LitSight(const RigDevice& camera, const RigDevice& projector_device, const Rigid3d& part_from_rig)
      : cam(camera),
        projector(projector_device),
        rig_from_part(part_from_rig.Inverse()),
        cam_centre(part_from_rig * camera.CenterInRig()),
        projector_centre(part_from_rig * projector_device.CenterInRig()) {}
  bool Pixel(const Eigen::Vector3d& p, const Eigen::Vector3d& n, int* u, int* v) const {
    if (n.dot(projector_centre - p) <= 0 || n.dot(cam_centre - p) <= 0) return false;
    const Eigen::Vector3d p_rig = rig_from_part * p;
    if (!projector.model.Project(projector.cam_from_rig * p_rig)) return false;
    const auto px = cam.model.Project(cam.cam_from_rig * p_rig);
    if (!px) return false;
    *u = static_cast<int>(std::lround(px->x()));
    *v = static_cast<int>(std::lround(px->y()));
    return *u >= 0 && *v >= 0 && *u < cam.model.width && *v < cam.model.height;
  }
  const RigDevice& cam;
  const RigDevice& projector;
  Rigid3d rig_from_part;
  Eigen::Vector3d cam_centre, projector_centre;
};

}  // namespace

CoveragePredictionOptions WithCapturedRadiometry(CoveragePredictionOptions options,
                                                 const TriangleMesh& part_in_part, const Rig& rig,
                                                 int camera, const Rigid3d& part_from_rig,
                                                 const cv::Mat& white, const cv::Mat& black,
                                                 double edge_margin_mm,
                                                 CapturedRadiometry* measured) {
  SLSHADOW_THROW_IF(!rig.projector, "captured radiometry: the rig '", rig.name,
                    "' has no projector");
  SLSHADOW_THROW_IF(camera < 0 || camera >= static_cast<int>(rig.cameras.size()),
                    "captured radiometry: no camera ", camera, " in the rig '", rig.name, "'");
  const RigDevice& cam = rig.cameras[static_cast<size_t>(camera)];
  const RigDevice& projector = *rig.projector;
  SLSHADOW_THROW_IF(white.type() != CV_8UC1 || black.type() != CV_8UC1 ||
                        white.size() != black.size() || white.cols != cam.model.width ||
                        white.rows != cam.model.height,
                    "captured radiometry: the white and black frames must be 8-bit grey images of "
                    "camera '",
                    cam.name, "' (", cam.model.width, " x ", cam.model.height, ")");
  SLSHADOW_THROW_IF(part_in_part.empty(), "captured radiometry: the part mesh is empty");
  const double d_ref =
      options.reference_distance_mm > 0 ? options.reference_distance_mm : rig.working_distance_mm;
  SLSHADOW_THROW_IF(!(d_ref > 0), "captured radiometry: no reference distance (the rig '", rig.name,
                    "' has no working_distance_mm)");
  const Albedo& texture = options.albedo_texture;
  const bool board = texture.kind == Albedo::Kind::kCheckerboard;
  SLSHADOW_THROW_IF(texture.IsTextured() && !board,
                    "captured radiometry: only a uniform or a checkerboard albedo is measured");
  const compare::Reference reference =
      compare::ReferenceFromMesh(part_in_part, "part", options.samples);
  const LitSight sight(cam, projector, part_from_rig);
  const Eigen::Vector3d& projector_centre = sight.projector_centre;
  const Eigen::Vector3d& cam_centre = sight.cam_centre;
  std::vector<double> ratios[2], tan2[2];  // dark, light
  std::vector<double> steps[2];            // (white - black) to the next pixel along the row
  std::vector<double> factors[2];          // the geometric factor
  std::vector<int> squares[2];             // a checkerboard's square (-1: uniform)
  for (size_t i = 0; i < reference.cloud.points.size(); ++i) {
    const Eigen::Vector3d& p = reference.cloud.points[i];
    const Eigen::Vector3d n = reference.cloud.normals[i].cast<double>();
    int cls = 1, square = -1;
    if (board && !BoardSquare(texture, p, edge_margin_mm, &square, &cls)) continue;
    int u = 0, v = 0;
    if (!sight.Pixel(p, n, &u, &v)) continue;
    const Eigen::Vector3d to_p = projector_centre - p;
    const double range = white.at<uint8_t>(v, u) - black.at<uint8_t>(v, u);
    if (u + 1 < white.cols)
      steps[cls].push_back(white.at<uint8_t>(v, u + 1) - black.at<uint8_t>(v, u + 1) - range);
    const double factor = n.dot(to_p) / to_p.norm() * d_ref * d_ref / to_p.squaredNorm();
    ratios[cls].push_back(range / factor);
    factors[cls].push_back(factor);
    squares[cls].push_back(square);
    const Eigen::Vector3d half = (to_p.normalized() + (cam_centre - p).normalized()).normalized();
    const double cos_h = std::max(1e-6, std::abs(n.dot(half)));
    tan2[cls].push_back((1 - cos_h * cos_h) / (cos_h * cos_h));
  }
  const auto median = [](std::vector<double>& v) {
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  CapturedRadiometry m;
  m.samples_dark = ratios[0].size();
  m.samples_light = ratios[1].size();
  SLSHADOW_THROW_IF(ratios[1].empty() || (board && ratios[0].empty()),
                    "captured radiometry: no sample of the part's ",
                    ratios[1].empty() ? (board ? "light squares" : "surface") : "dark squares",
                    " seen by camera '", cam.name, "' and lit by the projector");
  const int classes = board ? 2 : 1;
  // The half angles seen, and per class the medians of equal-count bins of tan^2(theta_h).
  double t2_min = std::numeric_limits<double>::infinity(), t2_max = 0;
  constexpr int kBins = 20;
  std::vector<std::array<double, 2>> bins[2];  // (median tan^2, median ratio)
  for (int c = 2 - classes; c < 2; ++c) {
    std::vector<size_t> order(ratios[c].size());
    for (size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::sort(order.begin(), order.end(),
              [&](size_t a, size_t b) { return tan2[c][a] < tan2[c][b]; });
    t2_min = std::min(t2_min, tan2[c][order.front()]);
    t2_max = std::max(t2_max, tan2[c][order.back()]);
    const size_t per = std::max<size_t>(1, order.size() / kBins);
    for (size_t b0 = 0; b0 + per <= order.size(); b0 += per) {
      std::vector<double> t, r;
      for (size_t k = b0; k < b0 + per; ++k) {
        t.push_back(tan2[c][order[k]]);
        r.push_back(ratios[c][order[k]]);
      }
      bins[c].push_back({median(t), median(r)});
    }
  }
  // Per class: ratio = rho + S lobe(alpha), least squares on the bins, alpha the best of the grid.
  double rho[2] = {0, 0}, gloss[2] = {0, 0}, alpha_of[2] = {0.1, 0.1};
  for (int c = 2 - classes; c < 2; ++c) {
    double best_sse = std::numeric_limits<double>::infinity();
    for (int k = 0; k <= 40; ++k) {
      const double alpha = 0.02 * std::pow(50.0, k / 40.0);
      double n = 0, sx = 0, sy = 0, sxx = 0, sxy = 0;
      for (const auto& b : bins[c]) {
        const double x = GlossLobe(b[0], 1 / (alpha * alpha));
        n += 1, sx += x, sy += b[1], sxx += x * x, sxy += x * b[1];
      }
      const double det = n * sxx - sx * sx;
      double s_k = det > 1e-12 * n * n ? (n * sxy - sx * sy) / det : 0;
      if (s_k < 0) s_k = 0;
      const double r_k = (sy - s_k * sx) / n;
      double sse = 0;
      for (const auto& b : bins[c]) {
        const double e = b[1] - r_k - s_k * GlossLobe(b[0], 1 / (alpha * alpha));
        sse += e * e;
      }
      if (sse < best_sse) best_sse = sse, rho[c] = r_k, gloss[c] = s_k, alpha_of[c] = alpha;
    }
  }
  // No lobe, or one that lifts the class by less than a grey level where it is measured (the 8-bit
  // steps of the frames are that large): the class's median.
  for (int c = 2 - classes; c < 2; ++c) {
    if (gloss[c] * GlossLobe(t2_min, 1 / (alpha_of[c] * alpha_of[c])) < 1) gloss[c] = 0;
    if (gloss[c] <= 0) rho[c] = median(ratios[c]);
  }
  m.range_per_factor_light = std::max(0.0, rho[1]);
  m.range_per_factor_dark = board ? std::max(0.0, rho[0]) : m.range_per_factor_light;
  m.gloss_range_light = gloss[1];
  m.gloss_range_dark = board ? gloss[0] : gloss[1];
  m.min_half_angle_deg = std::atan(std::sqrt(t2_min)) * 180 / M_PI;
  m.max_half_angle_deg = std::atan(std::sqrt(t2_max)) * 180 / M_PI;
  options.gloss = m.gloss_range_light / 255.0;
  options.gloss_dark = board ? m.gloss_range_dark / 255.0 : 0;
  m.gloss_alpha_light = alpha_of[1];
  m.gloss_alpha_dark = board ? alpha_of[0] : alpha_of[1];
  m.gloss_seen_light = gloss[1] * GlossLobe(t2_min, 1 / (alpha_of[1] * alpha_of[1]));
  m.gloss_seen_dark =
      board ? gloss[0] * GlossLobe(t2_min, 1 / (alpha_of[0] * alpha_of[0])) : m.gloss_seen_light;
  // A checkerboard's squares: each one's median offset from the fitted light (grey levels), the
  // level a square really has (its print, the light's unevenness) at the pose of these frames.
  if (board) {
    options.square_offset_dn.assign(
        static_cast<size_t>(texture.squares_x) * static_cast<size_t>(texture.squares_y), 0.0f);
    std::vector<std::vector<double>> residuals(options.square_offset_dn.size());
    for (int c = 0; c < 2; ++c) {
      const double inv_alpha_sq = 1 / (alpha_of[c] * alpha_of[c]);
      for (size_t k = 0; k < ratios[c].size(); ++k) {
        const double fitted = rho[c] + gloss[c] * GlossLobe(tan2[c][k], inv_alpha_sq);
        residuals[static_cast<size_t>(squares[c][k])].push_back((ratios[c][k] - fitted) *
                                                                factors[c][k]);
      }
    }
    for (size_t q = 0; q < residuals.size(); ++q) {
      if (residuals[q].size() >= 20)
        options.square_offset_dn[q] = static_cast<float>(median(residuals[q]));
    }
    double sum2 = 0;
    size_t n = 0;
    for (float o : options.square_offset_dn) sum2 += o * o, n += o != 0;
    m.square_offset_rms = n ? std::sqrt(sum2 / static_cast<double>(n)) : 0;
  }
  // The pixel noise of the lit range: its step to the next pixel is the difference of two
  // independent draws, sigma sqrt(2) (robust: 1.4826 x the median absolute step).
  for (int c = 2 - classes; c < 2; ++c) {
    std::vector<double> a;
    for (double d : steps[c]) a.push_back(std::abs(d));
    const double sigma = a.empty() ? 0 : 1.4826 * median(a) / std::sqrt(2.0);
    (c == 0 ? m.pixel_noise_dark : m.pixel_noise_light) = sigma;
  }
  if (!board) m.pixel_noise_dark = m.pixel_noise_light;
  // The class nearest the shadow threshold (the lower level) decides where the noise matters.
  options.pixel_noise_dn =
      m.range_per_factor_dark + m.gloss_seen_dark <= m.range_per_factor_light + m.gloss_seen_light
          ? m.pixel_noise_dark
          : m.pixel_noise_light;
  options.gloss_alpha = m.gloss_alpha_light;
  options.gloss_alpha_dark = m.gloss_alpha_dark;
  // Albedo in (0, 1]: a class read as black keeps the smallest positive albedo (too dark).
  const auto albedo = [](double range) { return std::clamp(range / 255.0, 1e-6, 1.0); };
  options.exposure_fraction = 1;
  options.reference_distance_mm = d_ref;
  if (board) {
    options.albedo_texture.dark = albedo(m.range_per_factor_dark);
    options.albedo_texture.light = albedo(m.range_per_factor_light);
  } else {
    options.albedo = albedo(m.range_per_factor_light);
  }
  if (measured) *measured = m;
  return options;
}

CoveragePredictionOptions WithCapturedContrast(CoveragePredictionOptions options,
                                               const TriangleMesh& part_in_part, const Rig& rig,
                                               int camera, const Rigid3d& part_from_rig,
                                               const PatternSpec& spec,
                                               const std::vector<cv::Mat>& images,
                                               double edge_margin_mm, CapturedContrast* measured) {
  SLSHADOW_THROW_IF(!rig.projector, "captured contrast: the rig '", rig.name, "' has no projector");
  SLSHADOW_THROW_IF(camera < 0 || camera >= static_cast<int>(rig.cameras.size()),
                    "captured contrast: no camera ", camera, " in the rig '", rig.name, "'");
  SLSHADOW_THROW_IF(spec.kind != PatternKind::kGrayCode || !spec.gray_inverse,
                    "captured contrast: the patterns must be a Gray code with inverse frames (got ",
                    ToString(spec.kind), ")");
  const std::vector<FrameInfo> frames = spec.Frames();
  SLSHADOW_THROW_IF(images.size() != frames.size(), "captured contrast: ", images.size(),
                    " images for a pattern spec of ", frames.size());
  const RigDevice& cam = rig.cameras[static_cast<size_t>(camera)];
  const RigDevice& projector = *rig.projector;
  for (const cv::Mat& im : images) {
    SLSHADOW_THROW_IF(
        im.type() != CV_8UC1 || im.cols != cam.model.width || im.rows != cam.model.height,
        "captured contrast: the images must be 8-bit grey images of camera '", cam.name, "' (",
        cam.model.width, " x ", cam.model.height, ")");
  }
  // The frames by role: [axis][bit] pattern and inverse.
  int white = -1, black = -1;
  std::array<std::vector<int>, 2> pattern, inverse;
  for (int a = 0; a < 2; ++a) {
    const int bits = spec.Codes(a) ? spec.GrayBits(a) : 0;
    pattern[static_cast<size_t>(a)].assign(static_cast<size_t>(bits), -1);
    inverse[static_cast<size_t>(a)].assign(static_cast<size_t>(bits), -1);
  }
  for (size_t f = 0; f < frames.size(); ++f) {
    const FrameInfo& fi = frames[f];
    const auto idx = static_cast<int>(f);
    if (fi.role == FrameRole::kWhite) white = idx;
    if (fi.role == FrameRole::kBlack) black = idx;
    if (fi.code != 0) continue;
    if (fi.role == FrameRole::kGrayBit)
      pattern[static_cast<size_t>(fi.axis)][static_cast<size_t>(fi.bit)] = idx;
    if (fi.role == FrameRole::kGrayBitInverse)
      inverse[static_cast<size_t>(fi.axis)][static_cast<size_t>(fi.bit)] = idx;
  }
  SLSHADOW_THROW_IF(white < 0 || black < 0, "captured contrast: no white or black frame");
  const compare::Reference reference =
      compare::ReferenceFromMesh(part_in_part, "part", options.samples);
  const Albedo& texture = options.albedo_texture;
  const bool board = texture.kind == Albedo::Kind::kCheckerboard;
  const LitSight sight(cam, projector, part_from_rig);
  // Far above the thresholds the ratio is the optics' (the stripes' edges in the pixel and the
  // blur), not the noise's.
  const double min_range = 5 * std::max(options.shadow_threshold, options.contrast_threshold);
  // The finest bits' direct light (Nayar et al.: max - min over their pattern and inverse frames,
  // patterns/codec.h SeparateDirectGlobal), per pixel.
  std::vector<double> rho;
  std::vector<PixelBitContrast> pixels;
  // Per axis and bit: the bright pixels' sum of contrast per lit range; the dim pixels' (lit below
  // min_range) sum of contrast, and their count and sum of lit range.
  // [0]: every dim pixel, [1]: those lit within 4 grey levels above the shadow threshold.
  std::array<std::vector<double>, 2> bright_ratio;
  std::array<std::array<std::vector<double>, 2>, 2> dim_contrast;
  for (size_t a = 0; a < 2; ++a) {
    bright_ratio[a].assign(pattern[a].size(), 0);
    for (auto& d : dim_contrast) d[a].assign(pattern[a].size(), 0);
  }
  std::array<size_t, 2> dim{0, 0};
  std::array<double, 2> dim_range{0, 0};
  for (size_t i = 0; i < reference.cloud.points.size(); ++i) {
    const Eigen::Vector3d& p = reference.cloud.points[i];
    const Eigen::Vector3d n = reference.cloud.normals[i].cast<double>();
    int square = -1, cls = 1;
    if (board && !BoardSquare(texture, p, edge_margin_mm, &square, &cls)) continue;
    int u = 0, v = 0;
    if (!sight.Pixel(p, n, &u, &v)) continue;
    const auto at = [&](int f) {
      return static_cast<double>(images[static_cast<size_t>(f)].at<uint8_t>(v, u));
    };
    const double range = at(white) - at(black);
    if (range < min_range) {
      // A dim pixel: its bits' contrast against its lit range.
      if (range <= 0) continue;
      // At the shadow threshold (where the contrast test decides) or anywhere dim.
      const size_t at_threshold =
          range >= options.shadow_threshold && range < options.shadow_threshold + 4 ? 1 : 0;
      for (size_t t = 0; t <= at_threshold; ++t) {
        ++dim[t];
        dim_range[t] += range;
        for (size_t a = 0; a < 2; ++a) {
          for (size_t k = 0; k < pattern[a].size(); ++k)
            dim_contrast[t][a][k] += std::abs(at(pattern[a][k]) - at(inverse[a][k]));
        }
      }
      continue;
    }
    double r_min = std::numeric_limits<double>::infinity();
    PixelBitContrast pixel;
    for (size_t a = 0; a < 2; ++a) {
      const int bits = static_cast<int>(pattern[a].size());
      if (bits == 0) continue;
      // The decoder's rule per axis: the weakest bit, or the second weakest where flipping the
      // weakest gives the adjacent code (the pixel at that bit's edge).
      double c1 = std::numeric_limits<double>::infinity(), c2 = c1;
      int k1 = 0;
      uint32_t code = 0, binary = 0;
      pixel.ratio[a].assign(static_cast<size_t>(bits), 0);
      for (int k = bits - 1; k >= 0; --k) {
        const double pv = at(pattern[a][static_cast<size_t>(k)]);
        const double iv = at(inverse[a][static_cast<size_t>(k)]);
        binary ^= pv > iv ? 1u : 0u;
        code |= binary << k;
        const double c = std::abs(pv - iv);
        pixel.ratio[a][static_cast<size_t>(k)] = static_cast<float>(c / range);
        bright_ratio[a][static_cast<size_t>(k)] += c / range;
        if (c < c1) {
          c2 = c1, c1 = c, k1 = k;
        } else {
          c2 = std::min(c2, c);
        }
      }
      const auto adjacent = [&](int k) {
        const uint32_t other = code ^ ((2u << k) - 1u);
        return (code > other ? code - other : other - code) == 1;
      };
      for (int k = 0; k < bits; ++k) pixel.adjacent_bits[a] |= adjacent(k) ? 1u << k : 0u;
      r_min = std::min(r_min, (adjacent(k1) ? c2 : c1) / range);
    }
    rho.push_back(r_min);
    pixels.push_back(std::move(pixel));
  }
  SLSHADOW_THROW_IF(rho.empty(), "captured contrast: no sample of the part lit above ", min_range,
                    " grey levels seen by camera '", cam.name, "'");
  std::sort(rho.begin(), rho.end());
  constexpr size_t kPixels = 2000;
  options.bit_contrasts.clear();
  for (size_t j = 0; j < std::min(kPixels, pixels.size()); ++j)
    options.bit_contrasts.push_back(pixels[j * pixels.size() / std::min(kPixels, pixels.size())]);
  // The part of a dim surface's lit range a bit's fringes do not modulate (the camera's veiling
  // glare from the bright surface around, the print's scatter; more of it the finer the bit): the
  // dim pixels' mean lit range less their mean contrast over the bright pixels' mean ratio; on the
  // pixels at the shadow threshold when there are 100, else on every dim one.
  const size_t t = 0;
  for (size_t a = 0; a < 2; ++a) {
    options.bit_global_dn[a].assign(pattern[a].size(), 0);
    if (dim[t] < 100) continue;
    const auto n_dim = static_cast<double>(dim[t]), n_bright = static_cast<double>(rho.size());
    for (size_t k = 0; k < pattern[a].size(); ++k) {
      const double ratio = bright_ratio[a][k] / n_bright;
      if (ratio > 0)
        options.bit_global_dn[a][k] =
            std::max(0.0, dim_range[t] / n_dim - dim_contrast[t][a][k] / n_dim / ratio);
    }
  }
  if (measured) {
    for (size_t a = 0; a < 2; ++a) {
      if (options.bit_global_dn[a].empty()) continue;
      measured->global_finest_dn =
          std::max(measured->global_finest_dn, options.bit_global_dn[a][0]);
      measured->global_coarsest_dn =
          std::max(measured->global_coarsest_dn, options.bit_global_dn[a].back());
    }
    measured->dim_samples = dim[0];
    measured->threshold_samples = dim[1];
    measured->samples = rho.size();
    measured->median = rho[rho.size() / 2];
    measured->p10 = rho[rho.size() / 10];
  }
  return options;
}

}  // namespace slshadow::multiview
