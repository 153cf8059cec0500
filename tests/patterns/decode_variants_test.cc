// The sequence variants of the pattern spec (Gray bits without inverse, shifted Gray code, the
// shifted code alone, phase offset and direction, explicit frame order, extra Gray bits, one coded
// axis), each generated,
// rendered through a known camera-to-projector map (patterns/synthetic.h, no simulator) and
// decoded against that map. The oracle for "as accurate as today's codecs" is the default
// phase_shift spec decoded from the same view: the same accuracy bounds and no fewer valid pixels.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <functional>
#include <numbers>
#include <string>

#include "core/error.h"
#include "patterns/codec.h"
#include "patterns/synthetic.h"

namespace slshadow {
namespace {

constexpr int kCamW = 320, kCamH = 240;

PatternSpec PhaseSpec() {
  PatternSpec s;
  s.kind = PatternKind::kPhaseShift;
  s.projector_width = 400;
  s.projector_height = 300;
  s.phase_steps = 4;
  s.period_px = 16;
  return s;
}

struct Result {
  int64_t inside = 0, valid = 0, unwrap_errors = 0;
  double rms = 0, std = 0, max_abs = 0;
};

// Decoded coordinates against the map, over camera pixels that see the projector's interior.
Result Check(const PatternSpec& spec, const ProjectorMap& map, const cv::Mat& mx,
             const cv::Mat& my) {
  Result r;
  double sum = 0, sum2 = 0;
  int64_t n = 0;
  const double period = spec.kind == PatternKind::kGrayCode ? 1.0 : spec.PeriodsPx()[0];
  for (int v = 0; v < mx.rows; ++v) {
    for (int u = 0; u < mx.cols; ++u) {
      const double x = mx.at<double>(v, u), y = my.at<double>(v, u);
      if (!(x > 0.5 && x < spec.projector_width - 1.5 && y > 0.5 &&
            y < spec.projector_height - 1.5))
        continue;
      ++r.inside;
      if (map.status.at<uint8_t>(v, u) != 0) continue;
      ++r.valid;
      for (int axis = 0; axis < 2; ++axis) {
        if (!spec.Codes(axis)) {
          EXPECT_TRUE(std::isnan((axis == 0 ? map.proj_x : map.proj_y).at<float>(v, u)));
          continue;
        }
        const double truth = axis == 0 ? x : y;
        const double decoded = (axis == 0 ? map.proj_x : map.proj_y).at<float>(v, u);
        // Gray code: the projector pixel containing the point, or a decoded edge (half-integer).
        const double e =
            spec.kind == PatternKind::kGrayCode
                ? (decoded == std::floor(decoded) ? decoded - std::round(truth)
                                                  : (std::fabs(decoded - truth) <= 0.5 ? 0.0 : 1.0))
                : decoded - truth;
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
    const double mean = sum / static_cast<double>(n);
    r.rms = std::sqrt(sum2 / static_cast<double>(n));
    r.std = std::sqrt(std::max(0.0, r.rms * r.rms - mean * mean));
  }
  return r;
}

Result RenderAndDecode(const PatternSpec& spec, const CameraSimOptions& sim) {
  cv::Mat mx, my;
  const auto images = SimulateStandardView(spec, kCamW, kCamH, sim, &mx, &my);
  return Check(spec, DecodePatterns(spec, images), mx, my);
}

struct Variant {
  std::string name;
  std::function<void(PatternSpec&)> apply;
};

std::vector<Variant> Variants() {
  return {
      {"no_inverse_phase_mean", [](PatternSpec& s) { s.gray_inverse = false; }},
      {"no_inverse_white_black",
       [](PatternSpec& s) {
         s.gray_inverse = false;
         s.white_black = true;
       }},
      {"white_black_with_inverse", [](PatternSpec& s) { s.white_black = true; }},
      {"shifted", [](PatternSpec& s) { s.gray_code = GrayCodeVariant::kShifted; }},
      {"shifted_no_inverse",
       [](PatternSpec& s) {
         s.gray_code = GrayCodeVariant::kShifted;
         s.gray_inverse = false;
       }},
      // The shifted code alone (no frames of floor(x / P)), with inverse pairs.
      {"shifted_only", [](PatternSpec& s) { s.gray_code = GrayCodeVariant::kShiftedOnly; }},
      // The sequence of issue 31: columns only, 4 phase steps, then the 5 bits of the shifted
      // code without inverse (9 frames).
      {"shifted_only_no_inverse_one_axis",
       [](PatternSpec& s) {
         s.code_y = false;
         s.gray_code = GrayCodeVariant::kShiftedOnly;
         s.gray_inverse = false;
       }},
      // With a phase offset (the code's edges stay where they are; the phase moves).
      {"shifted_only_offset",
       [](PatternSpec& s) {
         s.gray_code = GrayCodeVariant::kShiftedOnly;
         s.phase_offset_rad = 1.0;
       }},
      // The sequence of issue 14: cos(2 pi c / P - pi + 2 pi i / N), 12 steps, Gray bits without
      // inverse, one more Gray bit than the axis needs.
      {"offset_direction_12_steps_extra_bit",
       [](PatternSpec& s) {
         s.phase_steps = 12;
         s.phase_offset_rad = -std::numbers::pi;
         s.phase_direction = -1;
         s.gray_inverse = false;
         s.gray_bits = 7;
       }},
      {"one_axis_shifted_offset",
       [](PatternSpec& s) {
         s.code_y = false;
         s.gray_code = GrayCodeVariant::kShifted;
         s.phase_offset_rad = 1.0;
       }},
      {"reversed_frame_order",
       [](PatternSpec& s) {
         s.gray_inverse = false;
         const auto frames = s.Frames();
         for (auto it = frames.rbegin(); it != frames.rend(); ++it)
           s.frame_order.push_back(it->Name());
       }},
  };
}

class PhaseVariant : public ::testing::TestWithParam<size_t> {
 protected:
  PatternSpec Spec() const {
    PatternSpec s = PhaseSpec();
    Variants()[GetParam()].apply(s);
    s.Check();
    return s;
  }
};

TEST_P(PhaseVariant, NoiseFreeDecodesLikeTheDefaultCodec) {
  const PatternSpec spec = Spec();
  for (int depth : {8, 16}) {
    CameraSimOptions sim;
    sim.bit_depth = depth;
    const Result baseline = RenderAndDecode(PhaseSpec(), sim);
    const Result r = RenderAndDecode(spec, sim);
    std::printf(
        "%s %d-bit: rms %.4f px (default %.4f), max %.4f px, valid %lld/%lld (default %lld)\n",
        Variants()[GetParam()].name.c_str(), depth, r.rms, baseline.rms, r.max_abs,
        static_cast<long long>(r.valid), static_cast<long long>(r.inside),
        static_cast<long long>(baseline.valid));
    EXPECT_EQ(r.unwrap_errors, 0);
    EXPECT_LE(r.rms, 0.01);
    EXPECT_LE(r.max_abs, 0.05);
    EXPECT_GE(r.valid, r.inside);  // every pixel inside the projector decodes
    EXPECT_GE(r.valid, baseline.valid);
  }
}

TEST_P(PhaseVariant, GammaBlurAndNoiseGiveNoUnwrappingErrors) {
  const PatternSpec spec = Spec();
  CameraSimOptions sim;
  sim.gamma = 1.8;
  sim.blur_sigma_px = 1.0;
  sim.noise_sigma = 1.0;
  sim.seed = 5;
  const Result baseline = RenderAndDecode(PhaseSpec(), sim);
  const Result r = RenderAndDecode(spec, sim);
  std::printf("%s gamma/blur/noise: rms %.4f px (default %.4f), valid %lld/%lld (default %lld)\n",
              Variants()[GetParam()].name.c_str(), r.rms, baseline.rms,
              static_cast<long long>(r.valid), static_cast<long long>(r.inside),
              static_cast<long long>(baseline.valid));
  EXPECT_EQ(r.unwrap_errors, 0);
  EXPECT_GT(r.valid, 0.99 * r.inside);
  EXPECT_LT(r.rms, 0.5);
}

TEST_P(PhaseVariant, NoiseGivesThePredictedPhaseStandardDeviation) {
  const PatternSpec spec = Spec();
  CameraSimOptions sim;
  sim.gain = 0.7;
  sim.noise_sigma = 2.0;
  sim.seed = 11;
  sim.bit_depth = 16;
  const Result r = RenderAndDecode(spec, sim);
  // sigma_phi = sigma / (B sqrt(N / 2)) radians, B = gain * 127.5 grey levels.
  const double predicted_px = sim.noise_sigma /
                              (sim.gain * 127.5 * std::sqrt(spec.phase_steps / 2.0)) *
                              spec.period_px / (2 * std::numbers::pi);
  std::printf("%s N=%d: phase std %.5f px, predicted %.5f px\n",
              Variants()[GetParam()].name.c_str(), spec.phase_steps, r.std, predicted_px);
  EXPECT_EQ(r.unwrap_errors, 0);
  EXPECT_GE(r.valid, r.inside * 999 / 1000);
  EXPECT_LT(r.std, 1.2 * predicted_px);
  EXPECT_GT(r.std, predicted_px / 1.2);
}

INSTANTIATE_TEST_SUITE_P(Variants, PhaseVariant, ::testing::Range<size_t>(0, Variants().size()),
                         [](const auto& info) { return Variants()[info.param].name; });

// Permuting the frames and the images alike changes nothing: the decoder finds frames by role.
TEST(DecodeVariants, FrameOrderIsAPermutationOfTheSameDecode) {
  for (PatternKind kind :
       {PatternKind::kGrayCode, PatternKind::kPhaseShift, PatternKind::kMultiFrequency}) {
    PatternSpec spec = PhaseSpec();
    spec.kind = kind;
    spec.periods_px = {400.0 / 26, 400.0 / 24, 400.0 / 22.3};
    CameraSimOptions sim;
    sim.noise_sigma = 2;
    const auto images = SimulateStandardView(spec, kCamW, kCamH, sim);
    const ProjectorMap reference = DecodePatterns(spec, images);
    // Reverse, then swap neighbours: a permutation unlike the default order.
    std::vector<size_t> order(images.size());
    for (size_t i = 0; i < order.size(); ++i) order[i] = order.size() - 1 - i;
    for (size_t i = 0; i + 1 < order.size(); i += 2) std::swap(order[i], order[i + 1]);
    PatternSpec permuted = spec;
    std::vector<cv::Mat> permuted_images;
    const auto frames = spec.Frames();
    for (size_t i : order) {
      permuted.frame_order.push_back(frames[i].Name());
      permuted_images.push_back(images[i]);
    }
    permuted.Check();
    // Generation follows the order too.
    const auto generated = GeneratePatterns(spec), generated_permuted = GeneratePatterns(permuted);
    for (size_t i = 0; i < order.size(); ++i) {
      ASSERT_EQ(cv::norm(generated[order[i]], generated_permuted[i], cv::NORM_INF), 0);
    }
    const ProjectorMap map = DecodePatterns(permuted, permuted_images);
    EXPECT_EQ(cv::norm(map.status, reference.status, cv::NORM_INF), 0) << ToString(kind);
    for (const auto& [a, b] :
         {std::pair{map.proj_x, reference.proj_x}, std::pair{map.proj_y, reference.proj_y}}) {
      cv::Mat pa = a.clone(), pb = b.clone();
      cv::patchNaNs(pa, -7);
      cv::patchNaNs(pb, -7);
      EXPECT_EQ(cv::norm(pa, pb, cv::NORM_INF), 0) << ToString(kind);
    }
  }
}

// Gray code without inverse frames: bits against (white + black) / 2, the projector pixel exactly.
TEST(DecodeVariants, GrayCodeWithoutInverseIsExact) {
  for (bool opencv_order : {false, true}) {
    PatternSpec spec = PhaseSpec();
    spec.kind = PatternKind::kGrayCode;
    spec.gray_inverse = false;
    spec.opencv_order = opencv_order;
    EXPECT_EQ(spec.NumImages(), 2 + 9 + 9);
    for (double noise : {0.0, 1.0}) {
      CameraSimOptions sim;
      sim.noise_sigma = noise;
      sim.blur_sigma_px = noise > 0 ? 0.5 : 0.0;
      sim.gamma = noise > 0 ? 2.2 : 1.0;
      cv::Mat mx, my;
      const auto images = SimulateStandardView(spec, kCamW, kCamH, sim, &mx, &my);
      const Result r = Check(spec, DecodePatterns(spec, images), mx, my);
      PatternSpec with_inverse = spec;
      with_inverse.gray_inverse = true;
      const Result baseline = RenderAndDecode(with_inverse, sim);
      std::printf(
          "gray_code without inverse, noise %.0f: valid %lld/%lld (with inverse %lld), wrong %lld "
          "(with "
          "inverse %lld)\n",
          noise, static_cast<long long>(r.valid), static_cast<long long>(r.inside),
          static_cast<long long>(baseline.valid), static_cast<long long>(r.unwrap_errors),
          static_cast<long long>(baseline.unwrap_errors));
      EXPECT_EQ(r.max_abs, 0.0);
      if (noise == 0) {
        EXPECT_EQ(r.unwrap_errors, 0);
      } else {
        // As with inverse frames (decode_test.cc): noise flips a bit whose contrast is just above
        // the threshold, at a code edge: the neighbouring projector pixel, in few pixels.
        EXPECT_LT(r.unwrap_errors, r.valid / 1000);
      }
      // Half the contrast of a pattern / inverse pair: a few more pixels at edges are low contrast.
      EXPECT_GT(r.valid, 0.95 * baseline.valid);
    }
  }
}

// Multi-frequency with a phase offset and reversed steps decodes like the default.
TEST(DecodeVariants, MultiFrequencyOffsetAndDirection) {
  PatternSpec spec = PhaseSpec();
  spec.kind = PatternKind::kMultiFrequency;
  spec.periods_px = {400.0 / 26, 400.0 / 24, 400.0 / 22.3};
  spec.phase_offset_rad = 2.5;
  spec.phase_direction = -1;
  spec.phase_steps = 5;
  const Result r = RenderAndDecode(spec, {});
  EXPECT_EQ(r.unwrap_errors, 0);
  EXPECT_LE(r.rms, 0.01);
  EXPECT_GE(r.valid, r.inside);
}

// A direction or offset that does not match the projected frames is caught: decoding the sample's
// sequence as if it were the default one gives coordinates off by periods, not a silent near-miss.
TEST(DecodeVariants, WrongDirectionDoesNotDecode) {
  PatternSpec spec = PhaseSpec();
  spec.phase_steps = 12;
  spec.phase_offset_rad = -std::numbers::pi;
  spec.phase_direction = -1;
  cv::Mat mx, my;
  const auto images = SimulateStandardView(spec, kCamW, kCamH, {}, &mx, &my);
  PatternSpec wrong = spec;
  wrong.phase_direction = 1;
  const Result r = Check(wrong, DecodePatterns(wrong, images), mx, my);
  EXPECT_GT(r.rms, 1.0);
}

}  // namespace
}  // namespace slshadow
