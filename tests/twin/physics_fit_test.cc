#include "workflows/twin/physics_fit.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <random>

#include <gtest/gtest.h>

#include "patterns/codec.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::twin {
namespace {

// Camera images of the demo spec (phase shift + complementary Gray code, no white / black frame)
// of a flat scene whose pixel (x, y) sees projector column x with white level W and black level B:
// I = B + (W - B) * pattern / 255.
std::vector<cv::Mat> FlatImages(const PatternSpec& spec, float w, float b) {
  const std::vector<cv::Mat> projector = GeneratePatterns(spec);
  std::vector<cv::Mat> out;
  for (const auto& p : projector) {
    cv::Mat img(64, 256, CV_8UC1);
    for (int y = 0; y < img.rows; ++y) {
      for (int x = 0; x < img.cols; ++x)
        img.at<uint8_t>(y, x) =
            cv::saturate_cast<uint8_t>(b + (w - b) * p.at<uint8_t>(y, x) / 255.0f);
    }
    out.push_back(img);
  }
  return out;
}

PatternSpec DemoSpec() {
  PatternSpec spec;
  spec.kind = PatternKind::kPhaseShift;
  spec.projector_width = 256;
  spec.projector_height = 64;
  spec.phase_steps = 4;
  spec.period_px = 16;
  spec.Check();
  return spec;
}

// Without white and black frames the levels come from the inverse pairs: each pixel is lit in
// one frame of a pair and dark in the other.
TEST(PhysicsFit, WhiteBlackFromInversePairs) {
  const PatternSpec spec = DemoSpec();
  ASSERT_LT(spec.WhiteFrameIndex(), 0);
  cv::Mat w, b;
  WhiteBlackImages(spec, FlatImages(spec, 200, 20), &w, &b);
  for (int y = 0; y < w.rows; y += 7) {
    for (int x = 0; x < w.cols; ++x) {
      ASSERT_FLOAT_EQ(w.at<float>(y, x), 200) << x;
      ASSERT_FLOAT_EQ(b.at<float>(y, x), 20) << x;
    }
  }
}

// The normalised modulation of an ideal 4-step sinusoid is 0.5 (I = 0.5 + 0.5 cos), whatever the
// order of the phase frames (two swapped give the same map).
TEST(PhysicsFit, NormalisedModulationIsOrderFree) {
  const PatternSpec spec = DemoSpec();
  std::vector<cv::Mat> images = FlatImages(spec, 230, 10);
  const cv::Mat m = NormalisedModulation(spec, images);
  double sum = 0;
  int n = 0;
  for (int y = 0; y < m.rows; ++y) {
    for (int x = 0; x < m.cols; ++x) sum += m.at<float>(y, x), ++n;
  }
  EXPECT_NEAR(sum / n, 0.5, 0.01);
  const auto frames = spec.Frames();
  int a = -1, b = -1;
  for (size_t i = 0; i < frames.size(); ++i) {
    if (frames[i].role == FrameRole::kPhase && frames[i].axis == 0 && frames[i].step == 1)
      a = static_cast<int>(i);
    if (frames[i].role == FrameRole::kPhase && frames[i].axis == 0 && frames[i].step == 2)
      b = static_cast<int>(i);
  }
  std::swap(images[static_cast<size_t>(a)], images[static_cast<size_t>(b)]);
  const cv::Mat swapped = NormalisedModulation(spec, images);
  EXPECT_EQ(cv::norm(m, swapped, cv::NORM_INF), 0.0);
}

// A twin of two flat objects of albedo 0.8 ("left") and 0.2 ("right") for the physics fit's
// synthetic cameras.
Scene TwoAlbedoTwin() {
  Scene twin;
  twin.radiometry.exposure_fraction = 0.5;
  for (const auto& [name, albedo] : {std::pair<const char*, double>{"left", 0.8}, {"right", 0.2}}) {
    SceneObject o;
    o.name = name;
    o.type = ObjectType::kPlane;
    o.albedo.value = albedo;
    twin.objects.push_back(o);
  }
  return twin;
}

// A synthetic 64 x 64 camera of TwoAlbedoTwin() for `spec`: image rows 0 .. lit_rows - 1 see the
// part lit, the left half "left", the right half "right" (both_objects) or "left" too (one
// reflectance in view). Its black frame is black(albedo) plus uniform noise of +- 0.5 DN (seeded
// by `seed`), its white frame that + 0.5 x 255 x 0.9 albedo (exposure 0.5, factor 0.9 albedo).
CameraData SyntheticCamera(const std::string& name, const PatternSpec& spec, const Scene& twin,
                           int lit_rows, bool both_objects,
                           const std::function<float(float albedo)>& black, uint32_t seed,
                           GeometryBuffer* g) {
  const int size = 64;
  g->width = g->height = size;
  g->factor = SampleBuffer(cv::Mat(1, size * size, CV_32FC1, cv::Scalar(0)));
  g->albedo = SampleBuffer(cv::Mat(1, size * size, CV_32FC1, cv::Scalar(0)));
  g->visibility = cv::Mat(size, size, CV_8UC1, cv::Scalar(0));
  g->object_id = cv::Mat(size, size, CV_32SC1, cv::Scalar(-1));
  CameraData cam;
  cam.camera = name;
  cam.geometry = g;
  cam.white = cv::Mat(size, size, CV_32FC1, cv::Scalar(0));
  cam.black = cv::Mat(size, size, CV_32FC1, cv::Scalar(0));
  std::mt19937 rng(seed);
  for (int y = 0; y < lit_rows; ++y) {
    for (int x = 0; x < size; ++x) {
      const int object = both_objects && x >= size / 2 ? 1 : 0;
      const float albedo =
          static_cast<float>(twin.objects[static_cast<size_t>(object)].albedo.value);
      const size_t i = static_cast<size_t>(y * size + x);
      g->albedo[i] = albedo;
      g->factor[i] = 0.9f * albedo;
      g->visibility.at<uint8_t>(y, x) = 2;
      g->object_id.at<int32_t>(y, x) = object;
      const float noise = static_cast<float>(rng() / 4294967296.0 - 0.5);
      cam.black.at<float>(y, x) = black(albedo) + noise;
      cam.white.at<float>(y, x) = cam.black.at<float>(y, x) + 0.5f * 255 * 0.9f * albedo;
    }
  }
  for (int i = 0; i < spec.NumImages(); ++i)
    cam.real.push_back(cv::Mat(size, size, CV_8UC1, cv::Scalar(0)));
  return cam;
}

PatternSpec GrayCodeSpec() {
  PatternSpec spec;
  spec.kind = PatternKind::kGrayCode;
  spec.projector_width = 256;
  spec.projector_height = 64;
  spec.code_y = false;
  spec.Check();
  return spec;
}

TEST(PhysicsFit, OptionsCheckNamesTheField) {
  PhysicsFitOptions o;
  o.stride_px = 0;
  try {
    o.Check();
    FAIL() << "no exception";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("stride_px"), std::string::npos) << e.what();
  }
}

// A camera sees two objects of albedo 0.8 and 0.2 side by side, lit only on image rows 0..15 of 64:
// two reflectances, so its black-level offset is observable, but the pixels span only 2 of the 8
// bands the least-squares fit needs at least 3 of (its jackknife). The fit cannot be made; the
// layer must still be there, not observable, with its reason, like every other layer.
TEST(PhysicsFit, BlackLevelLayerReportedWhenItsFitCannotBeMade) {
  PatternSpec spec;
  spec.kind = PatternKind::kGrayCode;
  spec.projector_width = 256;
  spec.projector_height = 64;
  spec.code_y = false;
  spec.Check();
  const Scene twin = TwoAlbedoTwin();
  const int size = 64, lit_rows = 16;
  GeometryBuffer g;
  g.width = g.height = size;
  g.factor = SampleBuffer(cv::Mat(1, size * size, CV_32FC1, cv::Scalar(0)));
  g.albedo = SampleBuffer(cv::Mat(1, size * size, CV_32FC1, cv::Scalar(0)));
  g.visibility = cv::Mat(size, size, CV_8UC1, cv::Scalar(0));
  g.object_id = cv::Mat(size, size, CV_32SC1, cv::Scalar(-1));
  CameraData cam;
  cam.camera = "cam";
  cam.geometry = &g;
  cam.white = cv::Mat(size, size, CV_32FC1, cv::Scalar(0));
  cam.black = cv::Mat(size, size, CV_32FC1, cv::Scalar(0));
  for (int y = 0; y < lit_rows; ++y) {
    for (int x = 0; x < size; ++x) {
      const int object = x < size / 2 ? 0 : 1;
      const float albedo =
          static_cast<float>(twin.objects[static_cast<size_t>(object)].albedo.value);
      const size_t i = static_cast<size_t>(y * size + x);
      g.albedo[i] = albedo;
      g.factor[i] = 0.9f * albedo;
      g.visibility.at<uint8_t>(y, x) = 2;
      g.object_id.at<int32_t>(y, x) = object;
      cam.black.at<float>(y, x) = 6 + 3 * albedo;
      cam.white.at<float>(y, x) = cam.black.at<float>(y, x) + 0.5f * 255 * 0.9f * albedo;
    }
  }
  for (int i = 0; i < spec.NumImages(); ++i)
    cam.real.push_back(cv::Mat(size, size, CV_8UC1, cv::Scalar(0)));
  PhysicsFitOptions options;
  options.stride_px = 1;
  const PhysicsFit fit = FitPhysics(spec, twin, {cam}, options);
  const PhysicsLayer* bl = fit.Find("black_level_cam");
  ASSERT_NE(bl, nullptr) << fit.Table();
  EXPECT_FALSE(bl->observable);
  EXPECT_FALSE(bl->kept);
  EXPECT_NE(bl->reason.find("black-level fit"), std::string::npos) << bl->reason;
  EXPECT_EQ(bl->residual_unit, "DN RMS of the black frame");
}

// A black frame lit by ambient light alone (40 DN x albedo: 32 DN on the left half, 8 on the right,
// mean 20 DN, RMS 23.3 DN): ambient is kept and its reason gives the black frame's mean, not its
// RMS (the held-out residual with ambient off, printed beside it).
TEST(PhysicsFit, AmbientReasonGivesTheBlackFrameMean) {
  const PatternSpec spec = GrayCodeSpec();
  const Scene twin = TwoAlbedoTwin();
  GeometryBuffer g;
  const CameraData cam = SyntheticCamera(
      "cam", spec, twin, 64, true, [](float albedo) { return 40 * albedo; }, 7, &g);
  PhysicsFitOptions options;
  options.stride_px = 1;
  const PhysicsFit fit = FitPhysics(spec, twin, {cam}, options);
  const PhysicsLayer* amb = fit.Find("ambient");
  ASSERT_NE(amb, nullptr) << fit.Table();
  ASSERT_TRUE(amb->kept) << amb->reason;
  EXPECT_NEAR(amb->heldout_residual_off, 23.3, 0.1);
  const std::string lead = "the black frame is lit: ";
  ASSERT_EQ(amb->reason.rfind(lead, 0), 0u) << amb->reason;
  EXPECT_NEAR(std::stod(amb->reason.substr(lead.size())), 20.0, 0.05) << amb->reason;
}

// A black-level layer that is not observable keeps the residual unit of its kind, whether another
// camera's offset is observable (b beside a) or no camera's is (c alone).
TEST(PhysicsFit, BlackLevelResidualUnitWhenNotObservable) {
  const PatternSpec spec = GrayCodeSpec();
  const Scene twin = TwoAlbedoTwin();
  const auto black = [](float albedo) { return 6 + 3 * albedo; };
  GeometryBuffer ga, gb, gc;
  PhysicsFitOptions options;
  options.stride_px = 1;
  const PhysicsFit beside = FitPhysics(spec, twin,
                                       {SyntheticCamera("a", spec, twin, 64, true, black, 1, &ga),
                                        SyntheticCamera("b", spec, twin, 64, false, black, 2, &gb)},
                                       options);
  const PhysicsFit alone =
      FitPhysics(spec, twin, {SyntheticCamera("c", spec, twin, 64, false, black, 3, &gc)}, options);
  const PhysicsLayer* a = beside.Find("black_level_a");
  const PhysicsLayer* b = beside.Find("black_level_b");
  const PhysicsLayer* c = alone.Find("black_level_c");
  ASSERT_TRUE(a && b && c) << beside.Table() << alone.Table();
  EXPECT_TRUE(a->observable);
  EXPECT_FALSE(b->observable);
  EXPECT_FALSE(c->observable);
  EXPECT_EQ(a->residual_unit, "DN RMS of the black frame");
  EXPECT_EQ(b->residual_unit, a->residual_unit);
  EXPECT_EQ(c->residual_unit, a->residual_unit);
}

// Two cameras with black-level offsets (8 and 4 DN) fitted jointly: camera a sees the part on all
// 64 rows, camera b on 16; each layer's samples are its own camera's fitted pixels (the rows not
// held out, every other one: 32 x 64 for a, 8 x 64 for b), not the joint fit's.
TEST(PhysicsFit, BlackLevelSamplesAreThatCamerasOwn) {
  const PatternSpec spec = GrayCodeSpec();
  const Scene twin = TwoAlbedoTwin();
  GeometryBuffer ga, gb;
  PhysicsFitOptions options;
  options.stride_px = 1;
  const PhysicsFit fit =
      FitPhysics(spec, twin,
                 {SyntheticCamera(
                      "a", spec, twin, 64, true, [](float) { return 8.0f; }, 1, &ga),
                  SyntheticCamera(
                      "b", spec, twin, 16, true, [](float) { return 4.0f; }, 2, &gb)},
                 options);
  const PhysicsLayer* a = fit.Find("black_level_a");
  const PhysicsLayer* b = fit.Find("black_level_b");
  ASSERT_TRUE(a && b) << fit.Table();
  ASSERT_TRUE(a->observable && b->observable) << fit.Table();
  EXPECT_TRUE(a->kept) << a->reason;
  EXPECT_TRUE(b->kept) << b->reason;
  EXPECT_NEAR(a->value, 8, 0.1);
  EXPECT_NEAR(b->value, 4, 0.1);
  // Uniform noise of +- 0.5 DN: every fitted pixel is within the fit's outlier gate.
  EXPECT_EQ(a->samples, 32 * 64);
  EXPECT_EQ(b->samples, 8 * 64);
}

}  // namespace
}  // namespace slshadow::twin
