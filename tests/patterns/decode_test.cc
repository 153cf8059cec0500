// Decoding against analytic ground truth: camera images are generated patterns warped through a
// known camera-to-projector map (a homography or a smooth analytic map), with bilinear sampling
// of the projector image, optionally with gamma, blur, noise and per-pixel gain / ambient.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <numbers>

#include "core/config.h"
#include "core/error.h"
#include "patterns/codec.h"
#include "patterns/synthetic.h"

namespace slshadow {
namespace {

constexpr int kCamW = 320, kCamH = 240;
constexpr int kProjW = 400, kProjH = 300;

// A rotated, scaled, slightly perspective view of the middle of the projector image.
void HomographyView(cv::Mat* mx, cv::Mat* my) {
  const double a = 10 * std::numbers::pi / 180, s = 1.05;
  const cv::Matx33d centre_cam(1, 0, -kCamW / 2.0, 0, 1, -kCamH / 2.0, 0, 0, 1);
  const cv::Matx33d rot(s * std::cos(a), -s * std::sin(a), 0, s * std::sin(a), s * std::cos(a), 0,
                        2e-4, 1e-4, 1);
  const cv::Matx33d to_proj(1, 0, kProjW / 2.0, 0, 1, kProjH / 2.0, 0, 0, 1);
  HomographyMaps(to_proj * rot * centre_cam, kCamW, kCamH, mx, my);
}

// A smooth non-projective map (a wavy surface seen from the side).
void WavyView(cv::Mat* mx, cv::Mat* my) {
  *mx = cv::Mat(kCamH, kCamW, CV_64FC1);
  *my = cv::Mat(kCamH, kCamW, CV_64FC1);
  for (int v = 0; v < kCamH; ++v) {
    for (int u = 0; u < kCamW; ++u) {
      mx->at<double>(v, u) = 200 + 1.1 * (u - 160.0) + 6 * std::sin(2 * std::numbers::pi * v / 120);
      my->at<double>(v, u) =
          150 + 0.97 * (v - 120.0) + 4 * std::sin(2 * std::numbers::pi * u / 150);
    }
  }
}

PatternSpec Spec(PatternKind kind) {
  PatternSpec s;
  s.kind = kind;
  s.projector_width = kProjW;
  s.projector_height = kProjH;
  s.phase_steps = 4;
  s.period_px = 16;
  s.periods_px = {400.0 / 26, 400.0 / 24, 400.0 / 22.3};  // P123 = 571 px > 400
  return s;
}

bool Inside(double x, double y) {
  return x > 0.5 && x < kProjW - 1.5 && y > 0.5 && y < kProjH - 1.5;
}

struct GrayResult {
  int64_t inside = 0, valid = 0, wrong = 0, valid_outside = 0, edges = 0;
  double max_error = 0;  // projector pixels
};

// `border`: camera pixels to skip at the image edges (blur there replicates the edge pixel, which
// no real camera does).
GrayResult CheckGrayExact(const ProjectorMap& map, const cv::Mat& mx, const cv::Mat& my,
                          int border = 0) {
  GrayResult r;
  for (int v = border; v < kCamH - border; ++v) {
    for (int u = border; u < kCamW - border; ++u) {
      const double x = mx.at<double>(v, u), y = my.at<double>(v, u);
      const bool valid = map.status.at<uint8_t>(v, u) == 0;
      if (!Inside(x, y)) {
        r.valid_outside += valid && !(x > -0.5 && x < kProjW - 0.5 && y > -0.5 && y < kProjH - 0.5);
        continue;
      }
      ++r.inside;
      if (!valid) continue;
      ++r.valid;
      const float px = map.proj_x.at<float>(v, u), py = map.proj_y.at<float>(v, u);
      // Integer results must be the projector pixel containing the point; half-integer ones (a
      // pixel on an edge, DecodeOptions::gray_edge_midpoint) that edge, within 0.05 px.
      const auto error = [&](double decoded, double truth) {
        const bool half = decoded != std::floor(decoded);
        r.edges += half;
        const double e = half ? std::fabs(decoded - truth) : std::fabs(decoded - std::round(truth));
        return half && e <= 0.05 ? 0.0 : e;
      };
      const double ex = error(px, x), ey = error(py, y);
      r.wrong += ex != 0 || ey != 0;
      r.max_error = std::max(r.max_error, std::max(ex, ey));
    }
  }
  return r;
}

TEST(DecodeGrayCode, NoiseFreeDecodesEveryValidPixelExactly) {
  cv::Mat mx, my;
  HomographyView(&mx, &my);
  const PatternSpec spec = Spec(PatternKind::kGrayCode);
  for (int depth : {8, 16}) {
    for (bool edges : {false, true}) {
      CameraSimOptions sim;
      sim.bit_depth = depth;
      DecodeOptions options;
      options.gray_edge_midpoint = edges;
      const ProjectorMap map =
          DecodePatterns(spec, SimulateCameraImages(GeneratePatterns(spec), mx, my, sim), options);
      EXPECT_TRUE(map.has_x && map.has_y);
      const GrayResult r = CheckGrayExact(map, mx, my);
      SCOPED_TRACE(::testing::Message() << depth << "-bit, edges " << edges << ": valid " << r.valid
                                        << "/" << r.inside << ", on edges " << r.edges);
      EXPECT_EQ(r.wrong, 0);
      EXPECT_EQ(r.valid_outside, 0);
      if (edges) {
        // A pixel that sees a projector pixel edge (bit contrast < threshold) decodes to the edge.
        EXPECT_GT(r.edges, 0);
        EXPECT_GT(r.valid, 0.999 * r.inside);
      } else {
        // Only pixels within ~1% of a projector pixel edge are rejected.
        EXPECT_EQ(r.edges, 0);
        EXPECT_GT(r.valid, 0.95 * r.inside);
      }
      const auto counts = map.CountByStatus();
      EXPECT_EQ(counts[static_cast<int>(PixelStatus::kSaturated)], 0);
      EXPECT_EQ(counts[static_cast<int>(PixelStatus::kCodeError)], 0);
      EXPECT_GT(counts[static_cast<int>(PixelStatus::kShadow)],
                0);  // the corners see outside the projector
    }
  }
}

TEST(DecodeGrayCode, GammaBlurNoiseAndVaryingAlbedoKeepValidPixelsExact) {
  cv::Mat mx, my;
  WavyView(&mx, &my);
  PatternSpec spec = Spec(PatternKind::kGrayCode);
  spec.opencv_order = true;
  CameraSimOptions sim;
  sim.gamma = 2.2;
  sim.blur_sigma_px = 0.5;
  sim.seed = 7;
  // Albedo from 0.25 to 1.0 and ambient from 5 to 60 grey levels across the image: a single
  // global threshold would fail here, the pattern / inverse comparison does not.
  sim.gain_map = cv::Mat(kCamH, kCamW, CV_32FC1);
  sim.offset_map = cv::Mat(kCamH, kCamW, CV_32FC1);
  for (int v = 0; v < kCamH; ++v) {
    for (int u = 0; u < kCamW; ++u) {
      sim.gain_map.at<float>(v, u) = static_cast<float>(0.25 + 0.5 * u / kCamW);
      sim.offset_map.at<float>(v, u) = static_cast<float>(5 + 45.0 * v / kCamH);
    }
  }
  for (double noise : {0.0, 1.0}) {
    sim.noise_sigma = noise;
    const ProjectorMap map =
        DecodePatterns(spec, SimulateCameraImages(GeneratePatterns(spec), mx, my, sim));
    const GrayResult r = CheckGrayExact(map, mx, my, 2);
    const auto counts = map.CountByStatus();
    SCOPED_TRACE(::testing::Message()
                 << "noise " << noise << ": valid " << r.valid << "/" << r.inside << " wrong "
                 << r.wrong << " low contrast " << counts[2] << " shadow " << counts[1]);
    if (noise == 0) {
      EXPECT_EQ(r.wrong, 0);
    } else {
      // Noise can flip a bit whose contrast is just above the threshold, i.e. at a code edge: the
      // neighbouring projector pixel, in few pixels.
      EXPECT_LE(r.max_error, 1.0);
      EXPECT_LT(r.wrong, r.valid / 1000);
    }
    EXPECT_GT(r.valid, 0.70 * r.inside);
    EXPECT_EQ(r.valid_outside, 0);
  }
}

struct PhaseResult {
  int64_t inside = 0, valid = 0, unwrap_errors = 0;
  double rms = 0, mean = 0, std = 0, max_abs = 0;
};

// Errors of the decoded coordinates against the map, over pixels inside the projector.
PhaseResult CheckPhase(const ProjectorMap& map, const cv::Mat& mx, const cv::Mat& my,
                       double period) {
  PhaseResult r;
  double sum = 0, sum2 = 0;
  int64_t n = 0;
  for (int v = 0; v < kCamH; ++v) {
    for (int u = 0; u < kCamW; ++u) {
      const double x = mx.at<double>(v, u), y = my.at<double>(v, u);
      if (!Inside(x, y)) continue;
      ++r.inside;
      if (map.status.at<uint8_t>(v, u) != 0) continue;
      ++r.valid;
      for (int axis = 0; axis < 2; ++axis) {
        const double e =
            axis == 0 ? map.proj_x.at<float>(v, u) - x : map.proj_y.at<float>(v, u) - y;
        if (std::fabs(e) > period / 2) {
          ++r.unwrap_errors;
          continue;
        }
        sum += e;
        sum2 += e * e;
        ++n;
        r.max_abs = std::max(r.max_abs, std::fabs(e));
      }
    }
  }
  if (n > 0) {
    r.mean = sum / static_cast<double>(n);
    r.rms = std::sqrt(sum2 / static_cast<double>(n));
    r.std = std::sqrt(std::max(0.0, r.rms * r.rms - r.mean * r.mean));
  }
  return r;
}

class DecodePhase : public ::testing::TestWithParam<PatternKind> {};

TEST_P(DecodePhase, NoiseFreeIsWithinOneHundredthPixelWithoutUnwrappingErrors) {
  const PatternSpec spec = Spec(GetParam());
  for (int view = 0; view < 2; ++view) {
    cv::Mat mx, my;
    view == 0 ? HomographyView(&mx, &my) : WavyView(&mx, &my);
    for (int depth : {8, 16}) {
      CameraSimOptions sim;
      sim.bit_depth = depth;
      const ProjectorMap map =
          DecodePatterns(spec, SimulateCameraImages(GeneratePatterns(spec), mx, my, sim));
      const PhaseResult r = CheckPhase(map, mx, my, spec.PeriodsPx()[0]);
      SCOPED_TRACE(::testing::Message()
                   << ToString(spec.kind) << " view " << view << " depth " << depth << ": rms "
                   << r.rms << " max " << r.max_abs << " valid " << r.valid << "/" << r.inside);
      std::printf("%s view %d %d-bit: rms %.4f px, max %.4f px, valid %lld/%lld\n",
                  ToString(spec.kind).c_str(), view, depth, r.rms, r.max_abs,
                  static_cast<long long>(r.valid), static_cast<long long>(r.inside));
      EXPECT_EQ(r.unwrap_errors, 0);
      EXPECT_LE(r.rms, 0.01);
      EXPECT_LE(r.max_abs, 0.05);
      EXPECT_GE(r.valid, r.inside);  // every pixel inside the projector decodes
    }
  }
}

TEST_P(DecodePhase, NoiseGivesThePredictedPhaseStandardDeviation) {
  PatternSpec spec = Spec(GetParam());
  cv::Mat mx, my;
  HomographyView(&mx, &my);
  for (int steps : {4, 6}) {
    spec.phase_steps = steps;
    const auto patterns = GeneratePatterns(spec);
    CameraSimOptions sim;
    sim.gain = 0.7;
    sim.noise_sigma = 2.0;
    sim.seed = 11 + static_cast<uint64_t>(steps);
    sim.bit_depth = 16;  // keeps quantisation out of the comparison
    const ProjectorMap map = DecodePatterns(spec, SimulateCameraImages(patterns, mx, my, sim));
    const double period = spec.PeriodsPx()[0];
    const PhaseResult r = CheckPhase(map, mx, my, period);
    // sigma_phi = sigma / (B sqrt(N / 2)) radians, B = gain * 127.5 grey levels.
    const double b = sim.gain * 127.5;
    const double predicted_px =
        sim.noise_sigma / (b * std::sqrt(steps / 2.0)) * period / (2 * std::numbers::pi);
    SCOPED_TRACE(::testing::Message() << ToString(spec.kind) << " N=" << steps << ": std " << r.std
                                      << " px, predicted " << predicted_px << " px");
    std::printf("%s N=%d sigma=%.1f: phase std %.5f px, predicted %.5f px, ratio %.3f\n",
                ToString(spec.kind).c_str(), steps, sim.noise_sigma, r.std, predicted_px,
                r.std / predicted_px);
    EXPECT_EQ(r.unwrap_errors, 0);
    EXPECT_GE(r.valid, r.inside * 999 / 1000);
    EXPECT_LT(r.std, 1.2 * predicted_px);
    EXPECT_GT(r.std, predicted_px / 1.2);
  }
}

INSTANTIATE_TEST_SUITE_P(Codecs, DecodePhase,
                         ::testing::Values(PatternKind::kPhaseShift, PatternKind::kMultiFrequency),
                         [](const auto& info) { return ToString(info.param); });

TEST(DecodePhaseShift, GammaAndBlurGiveNoUnwrappingErrors) {
  const PatternSpec spec = Spec(PatternKind::kPhaseShift);
  cv::Mat mx, my;
  WavyView(&mx, &my);
  CameraSimOptions sim;
  sim.gamma = 1.8;
  sim.blur_sigma_px = 1.0;
  sim.noise_sigma = 1.0;
  const ProjectorMap map =
      DecodePatterns(spec, SimulateCameraImages(GeneratePatterns(spec), mx, my, sim));
  const PhaseResult r = CheckPhase(map, mx, my, spec.period_px);
  EXPECT_EQ(r.unwrap_errors, 0);
  EXPECT_GT(r.valid, 0.99 * r.inside);
  // Gamma distorts the fringes: 4 steps see the 3rd and 5th harmonics as a periodic phase error.
  EXPECT_LT(r.rms, 0.5);
}

// Regions of a homography view with a known failure each: the decoder must flag them with the
// right reason, count them, and leave their coordinates NaN.
class DecodeFailures : public ::testing::TestWithParam<PatternKind> {};

TEST_P(DecodeFailures, AreMaskedWithTheirReason) {
  const PatternSpec spec = Spec(GetParam());
  cv::Mat mx, my;
  HomographyView(&mx, &my);
  CameraSimOptions sim;
  sim.gain_map = cv::Mat(kCamH, kCamW, CV_32FC1, cv::Scalar(0.8));
  const cv::Rect shadow(40, 60, 40, 40), saturated(120, 60, 40, 40), washed(200, 60, 40, 40),
      corrupt(20, 140, 35, 40);  // projector x in about [44, 92]
  sim.gain_map(shadow).setTo(0.0);
  sim.gain_map(saturated).setTo(3.0);
  auto images = SimulateCameraImages(GeneratePatterns(spec), mx, my, sim);
  const auto frames = spec.Frames();
  // Washed-out code: global light makes each Gray frame nearly its pair's mean.
  for (size_t i = 0; i + 1 < frames.size(); ++i) {
    if (frames[i].role != FrameRole::kGrayBit) continue;
    cv::Mat p = images[i](washed), q = images[i + 1](washed);
    cv::Mat mean = (p + q) / 2;
    mean.copyTo(p);
    mean.copyTo(q);
  }
  // Corrupted code: the x MSB pair swapped (Gray code: 9 bits, column c reads as 511 - c >= 400;
  // phase shift: 6 bits, half-period index h <= 11 reads as 63 - h > 49), or for the heterodyne
  // the P3 frames rotated by one step (a quarter-cycle error).
  if (spec.kind != PatternKind::kMultiFrequency) {
    const size_t msb =
        static_cast<size_t>(spec.kind == PatternKind::kGrayCode ? 2 : spec.phase_steps);
    cv::Mat p = images[msb](corrupt).clone();
    images[msb + 1](corrupt).copyTo(images[msb](corrupt));
    p.copyTo(images[msb + 1](corrupt));
  } else {
    std::vector<cv::Mat> p3;
    for (size_t i = 0; i < frames.size(); ++i) {
      if (frames[i].role == FrameRole::kPhase && frames[i].axis == 0 && frames[i].frequency == 2) {
        p3.push_back(images[i](corrupt).clone());
      }
    }
    for (size_t i = 0, k = 0; i < frames.size(); ++i) {
      if (frames[i].role == FrameRole::kPhase && frames[i].axis == 0 && frames[i].frequency == 2) {
        p3[(k++ + 1) % p3.size()].copyTo(images[i](corrupt));
      }
    }
  }
  const ProjectorMap map = DecodePatterns(spec, images);
  const auto share = [&](const cv::Rect& rect, PixelStatus status) {
    return cv::countNonZero(map.status(rect) == static_cast<int>(status)) /
           static_cast<double>(rect.area());
  };
  EXPECT_EQ(share(shadow, PixelStatus::kShadow), 1.0);
  EXPECT_EQ(share(saturated, PixelStatus::kSaturated), 1.0);
  if (spec.kind != PatternKind::kMultiFrequency) {
    EXPECT_EQ(share(washed, PixelStatus::kLowContrast), 1.0);
  }
  // Gray code: pixels on a projector pixel edge are low contrast first (about 3%).
  EXPECT_GT(share(corrupt, PixelStatus::kCodeError), 0.9);
  EXPECT_EQ(share(corrupt, PixelStatus::kValid), 0.0);
  const auto counts = map.CountByStatus();
  EXPECT_GE(counts[static_cast<int>(PixelStatus::kShadow)], shadow.area());
  EXPECT_EQ(counts[static_cast<int>(PixelStatus::kSaturated)], saturated.area());
  int64_t total = 0;
  for (int64_t c : counts) total += c;
  EXPECT_EQ(total, int64_t{kCamW} * kCamH);
  // Coordinates are finite exactly where the status is valid.
  for (int v = 0; v < kCamH; ++v) {
    for (int u = 0; u < kCamW; ++u) {
      const bool valid = map.status.at<uint8_t>(v, u) == 0;
      ASSERT_EQ(std::isfinite(map.proj_x.at<float>(v, u)), valid);
      ASSERT_EQ(std::isfinite(map.proj_y.at<float>(v, u)), valid);
      ASSERT_TRUE(std::isfinite(map.quality.at<float>(v, u)));
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Codecs, DecodeFailures,
                         ::testing::Values(PatternKind::kGrayCode, PatternKind::kPhaseShift,
                                           PatternKind::kMultiFrequency),
                         [](const auto& info) { return ToString(info.param); });

TEST(Decode, OneAxisLeavesTheOtherNaN) {
  PatternSpec spec = Spec(PatternKind::kPhaseShift);
  spec.code_y = false;
  cv::Mat mx, my;
  HomographyView(&mx, &my);
  const ProjectorMap map =
      DecodePatterns(spec, SimulateCameraImages(GeneratePatterns(spec), mx, my, {}));
  EXPECT_TRUE(map.has_x);
  EXPECT_FALSE(map.has_y);
  EXPECT_EQ(cv::countNonZero(map.proj_y == map.proj_y), 0);  // all NaN
  EXPECT_GT(map.CountByStatus()[0], kCamW * kCamH / 2);
}

TEST(Decode, ParallelEqualsSerial) {
  const PatternSpec spec = Spec(PatternKind::kPhaseShift);
  cv::Mat mx, my;
  WavyView(&mx, &my);
  CameraSimOptions sim;
  sim.noise_sigma = 3;
  const auto images = SimulateCameraImages(GeneratePatterns(spec), mx, my, sim);
  DecodeOptions serial;
  serial.parallel = false;
  const ProjectorMap a = DecodePatterns(spec, images), b = DecodePatterns(spec, images, serial);
  EXPECT_EQ(cv::norm(a.status, b.status, cv::NORM_INF), 0);
  cv::Mat ax, bx;
  cv::patchNaNs(ax = a.proj_x.clone(), -1);
  cv::patchNaNs(bx = b.proj_x.clone(), -1);
  EXPECT_EQ(cv::norm(ax, bx, cv::NORM_INF), 0);
}

// Decoding is per pixel: a crop of odd width (vector tails, non-continuous ROI views) decodes to
// the same values as the same pixels of the full image, for every codec and bit depth.
TEST(Decode, OddWidthCropsEqualTheFullImage) {
  cv::Mat mx, my;
  WavyView(&mx, &my);
  for (PatternKind kind :
       {PatternKind::kGrayCode, PatternKind::kPhaseShift, PatternKind::kMultiFrequency}) {
    for (int depth : {8, 16}) {
      const PatternSpec spec = Spec(kind);
      CameraSimOptions sim;
      sim.noise_sigma = 2;
      sim.bit_depth = depth;
      const auto images = SimulateCameraImages(GeneratePatterns(spec), mx, my, sim);
      const cv::Rect crop(7, 3, 301, 200);  // 301 = 18 * 16 + 13
      std::vector<cv::Mat> views;
      for (const auto& im : images) views.push_back(im(crop));
      const ProjectorMap full = DecodePatterns(spec, images), part = DecodePatterns(spec, views);
      SCOPED_TRACE(::testing::Message() << ToString(kind) << " " << depth << "-bit");
      EXPECT_EQ(cv::norm(full.status(crop), part.status, cv::NORM_INF), 0);
      EXPECT_EQ(cv::norm(full.quality(crop), part.quality, cv::NORM_INF), 0);
      for (const auto& [a, b] :
           {std::pair{full.proj_x(crop), part.proj_x}, std::pair{full.proj_y(crop), part.proj_y}}) {
        cv::Mat fa = a.clone(), fb = b.clone();
        cv::patchNaNs(fa, -7);
        cv::patchNaNs(fb, -7);
        EXPECT_EQ(cv::norm(fa, fb, cv::NORM_INF), 0);
      }
      EXPECT_GT(part.CountByStatus()[0], crop.area() / 2);
    }
  }
}

TEST(Decode, RejectsBadInput) {
  const PatternSpec spec = Spec(PatternKind::kGrayCode);
  std::vector<cv::Mat> images(static_cast<size_t>(spec.NumImages()),
                              cv::Mat(8, 8, CV_8UC1, cv::Scalar(0)));
  EXPECT_NO_THROW(DecodePatterns(spec, images));
  auto few = images;
  few.pop_back();
  EXPECT_THROW(DecodePatterns(spec, few), Error);
  auto mixed = images;
  mixed[3] = cv::Mat(8, 8, CV_16UC1, cv::Scalar(0));
  EXPECT_THROW(DecodePatterns(spec, mixed), Error);
  auto sizes = images;
  sizes[5] = cv::Mat(8, 9, CV_8UC1, cv::Scalar(0));
  EXPECT_THROW(DecodePatterns(spec, sizes), Error);
  auto color = images;
  for (auto& m : color) m = cv::Mat(8, 8, CV_8UC3, cv::Scalar(0));
  EXPECT_THROW(DecodePatterns(spec, color), Error);
  DecodeOptions bad;
  bad.shadow_threshold = -1;
  EXPECT_THROW(DecodePatterns(spec, images, bad), Error);
  bad = {};
  bad.unwrap_tolerance_cycles = 0.7;
  EXPECT_THROW(bad.Check(), Error);
  bad = {};
  bad.saturation_level = 0;
  EXPECT_THROW(bad.Check(), Error);
}

TEST(Decode, TwelveBitDataIn16BitImagesWithFullScale) {
  const PatternSpec spec = Spec(PatternKind::kGrayCode);
  cv::Mat mx, my;
  HomographyView(&mx, &my);
  auto images = SimulateCameraImages(GeneratePatterns(spec), mx, my, {});  // 8-bit
  for (auto& im : images) im.convertTo(im, CV_16U, 16.0);                  // 12-bit levels 0..4080
  DecodeOptions options;
  options.full_scale = 4095;
  const ProjectorMap map = DecodePatterns(spec, images, options);
  const GrayResult r = CheckGrayExact(map, mx, my);
  EXPECT_EQ(r.wrong, 0);
  EXPECT_GT(r.valid, 0.95 * r.inside);
  // The saturation level follows the full scale: 4095 is saturated.
  for (auto& im : images) im(cv::Rect(100, 100, 10, 10)).setTo(4095);
  EXPECT_EQ(DecodePatterns(spec, images, options)
                .CountByStatus()[static_cast<int>(PixelStatus::kSaturated)],
            100);
}

TEST(Atan2Cycles, MatchesStdAtan2) {
  double worst = 0;
  for (int i = 0; i < 100000; ++i) {
    const double angle = 2 * std::numbers::pi * i / 100000.0;
    for (double radius : {1e-3, 1.0, 3e4}) {
      const float y = static_cast<float>(radius * std::sin(angle)),
                  x = static_cast<float>(radius * std::cos(angle));
      double expected =
          std::atan2(static_cast<double>(y), static_cast<double>(x)) / (2 * std::numbers::pi);
      if (expected < 0) expected += 1;
      double d = std::fabs(Atan2Cycles(y, x) - expected);
      d = std::min(d, 1 - d);  // 0 and 1 are the same angle
      worst = std::max(worst, d);
    }
  }
  EXPECT_LT(worst, 2e-6);
  const float f = Atan2Cycles(-1e-30f, 1.0f);
  EXPECT_TRUE(f >= 0.0f && f < 1.0f);
}

// Options as files: every field written is read back (JSON and YAML), unknown keys and bad
// values are refused naming the file and the field.
TEST(DecodeOptionsFile, RoundTripsEveryFieldAndRejectsUnknownKeys) {
  DecodeOptions o;
  o.shadow_threshold = 7.5;
  o.contrast_threshold = 2.25;
  o.saturation_level = 4000;
  o.full_scale = 4095;
  o.gray_edge_midpoint = false;
  o.unwrap_tolerance_cycles = 0.2;
  o.parallel = false;
  const nlohmann::json j = DecodeOptionsToJson(o);
  for (const ConfigNode& node : {ConfigNode::FromJson(j, "decode.json"),
                                 ConfigNode::ParseYaml(JsonToYaml(j), "decode.yaml")}) {
    const DecodeOptions r = DecodeOptionsFromConfig(node);
    EXPECT_EQ(r.shadow_threshold, o.shadow_threshold);
    EXPECT_EQ(r.contrast_threshold, o.contrast_threshold);
    EXPECT_EQ(r.saturation_level, o.saturation_level);
    EXPECT_EQ(r.full_scale, o.full_scale);
    EXPECT_EQ(r.gray_edge_midpoint, o.gray_edge_midpoint);
    EXPECT_EQ(r.unwrap_tolerance_cycles, o.unwrap_tolerance_cycles);
    EXPECT_EQ(r.parallel, o.parallel);
    EXPECT_EQ(DecodeOptionsToJson(r), j);
  }
  // Missing fields keep their defaults.
  EXPECT_EQ(DecodeOptionsToJson(
                DecodeOptionsFromConfig(ConfigNode::FromJson(nlohmann::json::object(), "d.json"))),
            DecodeOptionsToJson(DecodeOptions{}));
  nlohmann::json typo = j;
  typo["shadow_treshold"] = 3;
  try {
    DecodeOptionsFromConfig(ConfigNode::FromJson(typo, "d.json"));
    FAIL() << "unknown key accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("shadow_treshold"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("d.json"), std::string::npos) << e.what();
  }
  nlohmann::json bad = j;
  bad["unwrap_tolerance_cycles"] = 0.9;
  try {
    DecodeOptionsFromConfig(ConfigNode::FromJson(bad, "d.json"));
    FAIL() << "bad value accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("unwrap_tolerance_cycles"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("d.json"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace slshadow
