// Rendered, then decoded with patterns/, projector coordinates equal the simulator's ground
// truth: Gray code exactly (integer codes; edge midpoints within half a pixel), phase shift
// within 0.02 px RMS noise-free. "Noise-free" includes quantisation: the phase test renders
// 16-bit images (measured 0.004 px RMS); 8-bit quantisation alone gives ~0.018 px RMS on the
// dark table of the demo scene, checked against 0.03 px.
#include <cmath>
#include <numbers>

#include <gtest/gtest.h>

#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "sim/simulate.h"
#include "tests/sim/sim_test_util.h"

namespace slshadow {
namespace {

struct Comparison {
  int64_t lit = 0;          // ground truth lit
  int64_t decoded = 0;      // decoded valid among lit
  int64_t wrong = 0;        // decoded valid but off by more than the codec's tolerance
  double sum_sq = 0;        // squared error (both axes) over decoded
  int64_t false_valid = 0;  // decoded valid where ground truth says not lit
  int64_t edge = 0;         // phase codecs: axis values in the projector's outer half pixel
  int64_t samples = 0;      // axis values compared (coded axes of decoded pixels, minus edge)
};

Comparison Compare(const ProjectorMap& decoded, const ProjectorMap& truth, double tolerance_px,
                   bool gray, int truth_width, int truth_height) {
  Comparison c;
  for (int y = 0; y < truth.height(); ++y) {
    for (int x = 0; x < truth.width(); ++x) {
      const bool lit = truth.status.at<uint8_t>(y, x) == static_cast<uint8_t>(PixelStatus::kValid);
      const bool valid =
          decoded.status.at<uint8_t>(y, x) == static_cast<uint8_t>(PixelStatus::kValid);
      if (!lit) {
        c.false_valid += valid;
        continue;
      }
      ++c.lit;
      if (!valid) continue;
      ++c.decoded;
      for (int axis = 0; axis < 2; ++axis) {
        if (!(axis == 0 ? decoded.has_x : decoded.has_y)) continue;  // one coded axis
        const float d = (axis == 0 ? decoded.proj_x : decoded.proj_y).at<float>(y, x);
        const float t = (axis == 0 ? truth.proj_x : truth.proj_y).at<float>(y, x);
        double err = d - t;
        const int size = axis == 0 ? truth_width : truth_height;
        if (!gray && (t < 0 || t > size - 1)) {
          // The outer half of the projector's edge pixels: the lookup is that pixel's value (no
          // neighbour to interpolate with), so the fringe is flat there and the phase reads the
          // pixel centre. Not a decoding error; left out.
          ++c.edge;
          continue;
        }
        if (gray) {
          // Integer codes are the projector pixel containing the point: d == round(t), unless t
          // sits on a pixel edge (within float rounding); half-integers are decoded edges.
          const bool integer = d == std::round(d);
          const double frac = t - std::floor(t);
          if (integer && std::abs(frac - 0.5) > 1e-3) {
            err = d - std::round(t);
          } else {
            err = std::abs(err) <= 0.5 + 1e-3 ? 0.0 : err;
          }
        }
        c.sum_sq += err * err;
        ++c.samples;
        c.wrong += std::abs(err) > tolerance_px;
      }
    }
  }
  return c;
}

class DecodeGroundTruthTest : public ::testing::Test {
 protected:
  void Run(const PatternSpec& spec, double tolerance_px, double max_rms_px, bool gray,
           int adc_bits = 8) {
    const Rig rig = testing::SmallDemoRig(4);
    Scene scene = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
    scene.radiometry.adc_bits = adc_bits;
    std::vector<GeometryBuffer> geometry;
    const auto images = RenderScan(scene, rig, GeneratePatterns(spec), &geometry);
    for (size_t cam = 0; cam < rig.cameras.size(); ++cam) {
      const ProjectorMap decoded = DecodePatterns(spec, images[cam]);
      const Comparison c = Compare(decoded, geometry[cam].projector, tolerance_px, gray,
                                   spec.projector_width, spec.projector_height);
      const double rms = std::sqrt(c.sum_sq / std::max<double>(static_cast<double>(c.samples), 1));
      std::printf(
          "%s camera %zu: %lld lit, %lld decoded, %lld wrong, RMS %.4f px, %lld decoded outside "
          "light\n",
          ToString(spec.kind).c_str(), cam, static_cast<long long>(c.lit),
          static_cast<long long>(c.decoded), static_cast<long long>(c.wrong), rms,
          static_cast<long long>(c.false_valid));
      EXPECT_GT(c.lit, rig.cameras[cam].model.width * rig.cameras[cam].model.height / 3);
      EXPECT_GT(c.decoded, c.lit * 95 / 100) << "nearly every lit pixel decodes";
      EXPECT_EQ(c.wrong, 0);
      EXPECT_LE(rms, max_rms_px);
    }
  }
};

TEST_F(DecodeGroundTruthTest, GrayCodeIsExact) {
  PatternSpec spec;
  spec.kind = PatternKind::kGrayCode;
  spec.projector_width = 320;
  spec.projector_height = 200;
  Run(spec, 0.0, 0.0, true);
}

TEST_F(DecodeGroundTruthTest, PhaseShiftWithinTwoHundredthsOfAPixel) {
  PatternSpec spec;
  spec.kind = PatternKind::kPhaseShift;
  spec.projector_width = 320;
  spec.projector_height = 200;
  spec.phase_steps = 4;
  spec.period_px = 16;
  Run(spec, 0.1, 0.02, false, 16);
}

TEST_F(DecodeGroundTruthTest, PhaseShiftEightBit) {
  PatternSpec spec;
  spec.kind = PatternKind::kPhaseShift;
  spec.projector_width = 320;
  spec.projector_height = 200;
  spec.phase_steps = 4;
  spec.period_px = 16;
  Run(spec, 0.25, 0.03, false, 8);
}

// The sequence variants of the pattern spec, rendered by the simulator: each decodes to the ground
// truth within the bounds of the default phase shift above (16-bit: 0.1 px worst, 0.02 px RMS).
TEST_F(DecodeGroundTruthTest, PhaseShiftVariantsWithinTwoHundredthsOfAPixel) {
  PatternSpec base;
  base.kind = PatternKind::kPhaseShift;
  base.projector_width = 320;
  base.projector_height = 200;
  base.phase_steps = 4;
  base.period_px = 16;
  PatternSpec no_inverse = base;  // Gray bits against the mean of the phase frames
  no_inverse.gray_inverse = false;
  PatternSpec shifted = base;  // two Gray codes, k1 = floor(x / P), k2 = floor(x / P + 1/2)
  shifted.gray_code = GrayCodeVariant::kShifted;
  shifted.gray_inverse = false;
  shifted.white_black = true;
  PatternSpec sample =
      base;  // 12 steps, cos(2 pi x / P - pi + 2 pi s / N), one axis, 7 bits, no inverse
  sample.phase_steps = 12;
  sample.period_px = 10;  // 32 periods across 320 px (6 bits needed, 7 projected)
  sample.phase_offset_rad = -std::numbers::pi;
  sample.phase_direction = -1;
  sample.code_y = false;
  sample.gray_inverse = false;
  sample.gray_bits = 7;
  for (const PatternSpec& spec : {no_inverse, shifted, sample}) {
    SCOPED_TRACE(PatternSpecToJson(spec).dump());
    Run(spec, 0.1, 0.02, false, 16);
  }
}

}  // namespace
}  // namespace slshadow
