// Direct / global separation against synthetic images with a known direct gain and a known
// global component: a high-frequency pattern lighting half the scene adds g/2 everywhere, the
// white frame g and the black frame nothing; ambient light adds to every frame.
#include <gtest/gtest.h>

#include "core/error.h"
#include "patterns/codec.h"
#include "patterns/synthetic.h"

namespace slshadow {
namespace {

constexpr int kW = 240, kH = 180;

void View(cv::Mat* mx, cv::Mat* my) {
  // 1.3 projector px per camera px: the finest stripes (2 px) stay resolved.
  HomographyMaps(cv::Matx33d(1.3, 0.05, 20, -0.04, 1.3, 15, 0, 0, 1), kW, kH, mx, my);
}

TEST(SeparateDirectGlobal, GrayCodeRecoversDirectAndGlobal) {
  PatternSpec spec;
  spec.kind = PatternKind::kGrayCode;
  spec.projector_width = 400;
  spec.projector_height = 300;
  cv::Mat mx, my;
  View(&mx, &my);
  CameraSimOptions sim;
  sim.gain = 0.6;      // direct: 0.6 * 255 = 153 grey levels under full white
  sim.offset = 10;     // ambient
  sim.bit_depth = 16;  // keeps rounding small
  auto images = SimulateCameraImages(GeneratePatterns(spec), mx, my, sim);
  const double g = 40;  // global light under full white, 8-bit levels
  const auto frames = spec.Frames();
  for (size_t i = 0; i < images.size(); ++i) {
    const double add = frames[i].role == FrameRole::kWhite   ? g
                       : frames[i].role == FrameRole::kBlack ? 0
                                                             : g / 2;
    images[i] += cv::Scalar(add * 257);
  }
  const DirectGlobal dg = SeparateDirectGlobal(spec, images, 2);
  // Away from the image border, where some pixels straddle stripe edges (bilinear sampling).
  const cv::Rect inner(10, 10, kW - 20, kH - 20);
  cv::Mat direct = dg.direct(inner) / 257, global = dg.global(inner) / 257;
  // Pixels exactly on a stripe edge see half lit in every fine frame: take the median.
  std::vector<float> d(direct.begin<float>(), direct.end<float>()),
      gl(global.begin<float>(), global.end<float>());
  std::nth_element(d.begin(), d.begin() + static_cast<long>(d.size() / 2), d.end());
  std::nth_element(gl.begin(), gl.begin() + static_cast<long>(gl.size() / 2), gl.end());
  EXPECT_NEAR(d[d.size() / 2], 0.6 * 255, 0.5);
  EXPECT_NEAR(gl[gl.size() / 2], g, 0.5);
}

TEST(SeparateDirectGlobal, PhaseShiftRecoversDirectAndGlobalPlusAmbient) {
  PatternSpec spec;
  spec.kind = PatternKind::kPhaseShift;
  spec.projector_width = 400;
  spec.projector_height = 300;
  spec.phase_steps = 4;
  // Bilinear sampling of the projector image attenuates a sinusoid of period P by up to
  // cos(pi / P): P = 40 keeps that below 0.3%.
  spec.period_px = 40;
  cv::Mat mx, my;
  View(&mx, &my);
  CameraSimOptions sim;
  sim.gain = 0.6;
  sim.offset = 10;
  sim.bit_depth = 16;
  auto images = SimulateCameraImages(GeneratePatterns(spec), mx, my, sim);
  const double g = 40;
  for (auto& im : images) im += cv::Scalar(g / 2 * 257);
  const DirectGlobal dg = SeparateDirectGlobal(spec, images);
  const cv::Rect inner(10, 10, kW - 20, kH - 20);
  // Sinusoid with amplitude 0.6 * 127.5 about 0.6 * 127.5: d = 2 B' = 153, g = 2 (A - B') = g + 2
  // ambient.
  EXPECT_NEAR(cv::mean(dg.direct(inner))[0] / 257, 0.6 * 255, 1.0);
  EXPECT_NEAR(cv::mean(dg.global(inner))[0] / 257, g + 2 * 10, 1.0);
  EXPECT_THROW(SeparateDirectGlobal(spec, {images[0]}), Error);
}

}  // namespace
}  // namespace slshadow
