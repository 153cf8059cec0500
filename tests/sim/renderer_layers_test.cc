// The renderer's optional layers (sim/renderer.h, sim/scene.h SceneLayers), each checked against
// what it claims to model, and batches against single images with every layer on. The geometry
// and radiometry of the pattern pass are tests/sim/renderer_test.cc's.
#include "sim/renderer.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include "core/error.h"
#include "sim/shapes.h"
#include "tests/sim/sim_test_util.h"

namespace slshadow {
namespace {

using testing::FlatProjectorImage;
using testing::PlaneScene;
using testing::Pose;
using testing::SmallDemoRig;
using testing::Trace;

// A plane facing the rig head-on, filling the view.
Scene FacingPlane() {
  return PlaneScene(Pose(Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 500)), 0.7);
}

cv::Mat Stripes(const Rig& rig, int period) {
  cv::Mat m(rig.projector->model.height, rig.projector->model.width, CV_8UC1);
  for (int y = 0; y < m.rows; ++y) {
    for (int x = 0; x < m.cols; ++x) m.at<uint8_t>(y, x) = (x / period) % 2 ? 230 : 20;
  }
  return m;
}

// A batch sweep gives the same images as one image at a time, with every layer on.
TEST(LayersTest, BatchEqualsSingleImagesWithAllLayers) {
  const Rig rig = SmallDemoRig(8);
  Scene scene = LoadScene(testing::SourceDir() / "config/scenes/layers_all.yaml");
  for (int variant = 0; variant < 3; ++variant) {
    if (variant == 1) scene.layers = SceneLayers();              // core only, direct 8-bit lookups
    if (variant == 2) scene.radiometry.bilinear_lookup = false;  // nearest
    const GeometryBuffer g = Trace(scene, rig, 0);
    const PatternRenderer r(scene, rig, 0, g);
    std::vector<cv::Mat> patterns;
    // 22 images: the fused path (three vectors of lanes when vectorised); 8 and 5 as well, below.
    for (int period :
         {3, 5, 8, 13, 21, 34, 55, 89, 144, 4, 7, 11, 233, 2, 6, 9, 10, 12, 14, 15, 17, 19}) {
      patterns.push_back(Stripes(rig, period));
    }
    const auto batch = r.RenderBatch(patterns, 10);
    const std::vector<cv::Mat> five(patterns.begin(), patterns.begin() + 5);  // the general path
    const auto batch5 = r.RenderBatch(five, 10);
    const std::vector<cv::Mat> eight(patterns.begin(), patterns.begin() + 8);
    const auto batch8 = r.RenderBatch(eight, 10);
    ASSERT_EQ(batch.size(), patterns.size());
    for (size_t k = 0; k < patterns.size(); ++k) {
      EXPECT_EQ(cv::norm(batch[k], r.Render(patterns[k], 10 + static_cast<int>(k)), cv::NORM_INF),
                0)
          << variant << " " << k;
      if (k < 5) {
        EXPECT_EQ(cv::norm(batch[k], batch5[k], cv::NORM_INF), 0) << variant << " " << k;
      }
      if (k < 8) {
        EXPECT_EQ(cv::norm(batch[k], batch8[k], cv::NORM_INF), 0) << variant << " " << k;
      }
      if (variant == 1) {
        ASSERT_EQ(batch[k].type(), CV_16UC1);
        // The fused sweep against the general path (float irradiance, then the ADC).
        const cv::Mat irradiance = r.RenderIrradiance(patterns[k]);
        for (int y = 0; y < irradiance.rows; ++y) {
          for (int x = 0; x < irradiance.cols; ++x) {
            const float v = irradiance.at<float>(y, x);
            const float full = 4095;  // layers_all.yaml: 12-bit ADC, 16-bit images
            const int q =
                v <= 0 ? 0 : (v >= full ? static_cast<int>(full) : static_cast<int>(v + 0.5f));
            ASSERT_EQ(batch[k].at<uint16_t>(y, x), q) << k << " " << x << "," << y;
          }
        }
      }
    }
  }
}

// Batches of up to 32 images with 8-bit output (written 16 pixels x 16 images at a time, two
// tiles above 16 images) equal the images rendered one by one and the general path's float
// irradiance through the ADC; the camera width (274) is not a multiple of 16, so the row tails
// are covered too.
TEST(LayersTest, BatchesOf8BitImagesEqualSingleImagesAndIrradiance) {
  const Rig rig = SmallDemoRig(7);
  ASSERT_NE(rig.cameras[0].model.width % 16, 0);
  Scene scene = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
  scene.layers = SceneLayers();
  scene.radiometry.adc_bits = 8;
  const GeometryBuffer g = Trace(scene, rig, 0);
  const PatternRenderer r(scene, rig, 0, g);
  std::vector<cv::Mat> patterns, single, expected;
  for (int period : {3,  5,  8,  13, 21, 34, 55, 89, 144, 4,  7,  11, 233, 2,  6,  9,
                     10, 12, 14, 15, 17, 19, 20, 23, 25,  27, 29, 31, 37,  41, 43, 47}) {
    patterns.push_back(Stripes(rig, period));
  }
  ASSERT_EQ(patterns.size(), static_cast<size_t>(PatternRenderer::kMaxBatch));
  for (size_t k = 0; k < patterns.size(); ++k) {
    single.push_back(r.Render(patterns[k], static_cast<int>(k)));
    // The oracle: the general path's float irradiance through the ADC.
    const cv::Mat irradiance = r.RenderIrradiance(patterns[k]);
    cv::Mat q(irradiance.size(), CV_8UC1);
    int lit = 0;
    for (int y = 0; y < irradiance.rows; ++y) {
      for (int x = 0; x < irradiance.cols; ++x) {
        const float v = irradiance.at<float>(y, x);
        q.at<uint8_t>(y, x) =
            static_cast<uint8_t>(v <= 0 ? 0 : (v >= 255 ? 255 : static_cast<int>(v + 0.5f)));
        lit += q.at<uint8_t>(y, x) > 0;
      }
    }
    EXPECT_GT(lit, irradiance.total() / 10) << k;
    expected.push_back(q);
  }
  // Full and partial batches: one and two tiles of 16 images, vectors of 8 lanes full and partial
  // (a 22-pattern sequence renders as one batch of 22).
  for (const size_t n : {32u, 22u, 17u, 16u, 9u, 6u, 1u}) {
    const std::vector<cv::Mat> some(patterns.begin(),
                                    patterns.begin() + static_cast<std::ptrdiff_t>(n));
    const auto batch = r.RenderBatch(some, 0);
    ASSERT_EQ(batch.size(), n);
    for (size_t k = 0; k < n; ++k) {
      ASSERT_EQ(batch[k].type(), CV_8UC1);
      EXPECT_EQ(cv::norm(batch[k], single[k], cv::NORM_INF), 0) << n << " " << k;
      for (int y = 0; y < batch[k].rows; ++y) {
        for (int x = 0; x < batch[k].cols; ++x) {
          ASSERT_EQ(batch[k].at<uint8_t>(y, x), expected[k].at<uint8_t>(y, x))
              << n << " " << k << " " << x << "," << y;
        }
      }
    }
  }
}

// One PatternBatch (interleaved once) rendered for both cameras gives each camera the images of
// a fresh batch, and bad batches are refused.
TEST(LayersTest, PatternBatchIsSharedAcrossCamerasAndChecked) {
  const Rig rig = SmallDemoRig(8);
  Scene scene = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
  scene.layers = SceneLayers();
  scene.radiometry.adc_bits = 8;
  std::vector<cv::Mat> patterns;
  for (int period : {3, 5, 8, 13, 21, 34, 55, 89, 144, 4, 7, 11, 233, 2, 6, 9, 10, 12, 14, 15}) {
    patterns.push_back(Stripes(rig, period));
  }
  const PatternBatch shared(patterns);
  ASSERT_EQ(shared.size(), 20);
  // The interleaved bytes: image k of projector pixel i at i * size() + k, then zero padding.
  const uint8_t* inter = shared.Interleaved();
  const size_t n = patterns[0].total();
  for (size_t i = 0; i < n; i += 97) {
    for (int k = 0; k < shared.size(); ++k)
      ASSERT_EQ(inter[i * 20 + static_cast<size_t>(k)], patterns[static_cast<size_t>(k)].data[i])
          << i;
  }
  for (int k = 0; k < PatternBatch::kPadding; ++k)
    EXPECT_EQ(inter[n * 20 + static_cast<size_t>(k)], 0);
  for (int camera = 0; camera < 2; ++camera) {
    const GeometryBuffer g = Trace(scene, rig, camera);
    const PatternRenderer r(scene, rig, camera, g);
    const auto a = r.RenderBatch(shared, 0);
    const auto b = r.RenderBatch(patterns, 0);
    ASSERT_EQ(a.size(), patterns.size());
    for (size_t k = 0; k < a.size(); ++k)
      EXPECT_EQ(cv::norm(a[k], b[k], cv::NORM_INF), 0) << camera << " " << k;
    // More images than a batch holds.
    std::vector<cv::Mat> too_many(static_cast<size_t>(PatternRenderer::kMaxBatch) + 1, patterns[0]);
    EXPECT_THROW(r.RenderBatch(too_many, 0), Error);
  }
  EXPECT_THROW(PatternBatch(std::vector<cv::Mat>{}), Error);
  EXPECT_THROW(PatternBatch({patterns[0], cv::Mat(patterns[0].rows, patterns[0].cols + 1, CV_8UC1,
                                                  cv::Scalar(0))}),
               Error);
  EXPECT_THROW(PatternBatch({patterns[0], cv::Mat(patterns[0].size(), CV_16UC1, cv::Scalar(0))}),
               Error);
}

TEST(LayersTest, LayersAreOffByDefault) {
  const SceneLayers l;
  EXPECT_EQ(l.supersampling, 1);
  EXPECT_FALSE(l.camera_defocus.enabled || l.projector_defocus.enabled || l.response_enabled ||
               l.vignetting_enabled || l.noise_enabled);
  EXPECT_EQ(l.ambient, 0);
  EXPECT_EQ(l.fill_factor, 1);
}

// EMVA 1288: residual (noisy - noise-free) has variance K^2 (mu_e + read^2) + 1/12 (quantisation),
// K = full_scale / full_well; the normalised residual is standard normal. Seeded: reproducible.
TEST(LayersTest, NoiseFollowsEmvaModelAndIsSeeded) {
  const Rig rig = SmallDemoRig(4);
  Scene scene = FacingPlane();
  scene.radiometry.adc_bits = 12;
  scene.layers.noise_enabled = true;
  scene.layers.full_well_e = 8000;
  scene.layers.read_noise_e = 12;
  scene.layers.seed = 5;
  const GeometryBuffer g = Trace(scene, rig, 0);
  const PatternRenderer r(scene, rig, 0, g);
  const cv::Mat pattern = Stripes(rig, 7);
  const cv::Mat clean = r.RenderIrradiance(pattern);
  const cv::Mat noisy = r.Render(pattern, 3);
  ASSERT_EQ(noisy.type(), CV_16UC1);
  const double k = 4095.0 / 8000;
  double sum = 0, sum_sq = 0;
  int n = 0;
  for (int y = 0; y < g.height; ++y) {
    for (int x = 0; x < g.width; ++x) {
      const double mu = clean.at<float>(y, x);
      if (mu < 50 || mu > 3500) continue;  // away from clipping at 0 and saturation
      const double var = k * k * (mu / k + 12.0 * 12.0) + 1.0 / 12;
      const double z = (noisy.at<uint16_t>(y, x) - mu) / std::sqrt(var);
      sum += z;
      sum_sq += z * z;
      ++n;
    }
  }
  ASSERT_GT(n, 50000);
  const double mean = sum / n, sd = std::sqrt(sum_sq / n - mean * mean);
  EXPECT_NEAR(mean, 0, 0.02);
  EXPECT_NEAR(sd, 1, 0.02);
  EXPECT_EQ(cv::norm(noisy, r.Render(pattern, 3), cv::NORM_INF), 0)
      << "same seed, camera, pattern: same image";
  EXPECT_GT(cv::norm(noisy, r.Render(pattern, 4), cv::NORM_L1), 0)
      << "another pattern index: other noise";
  Scene other = scene;
  other.layers.seed = 6;
  EXPECT_GT(cv::norm(noisy, PatternRenderer(other, rig, 0, g).Render(pattern, 3), cv::NORM_L1), 0);
}

TEST(LayersTest, SaturationClipsAtFullScale) {
  const Rig rig = SmallDemoRig(4);
  Scene scene = FacingPlane();
  scene.radiometry.exposure_fraction = 5;  // far over full scale
  const GeometryBuffer g = Trace(scene, rig, 0);
  const cv::Mat img = PatternRenderer(scene, rig, 0, g).Render(FlatProjectorImage(rig, 255), 0);
  double max_value;
  cv::minMaxLoc(img, nullptr, &max_value);
  EXPECT_EQ(max_value, 255);
  EXPECT_GT(cv::countNonZero(img == 255), g.width * g.height / 2);
}

TEST(LayersTest, ProjectorGammaAndLut) {
  const Rig rig = SmallDemoRig(4);
  Scene linear = FacingPlane();
  Scene gamma = linear;
  gamma.layers.response_enabled = true;
  gamma.layers.gamma = 2.2;
  Scene lut = linear;
  lut.layers.response_enabled = true;
  lut.layers.response_lut.assign(256, 0.25);
  const GeometryBuffer g = Trace(linear, rig, 0);
  const cv::Mat white =
      PatternRenderer(linear, rig, 0, g).RenderIrradiance(FlatProjectorImage(rig, 255));
  const cv::Mat mid_linear =
      PatternRenderer(linear, rig, 0, g).RenderIrradiance(FlatProjectorImage(rig, 128));
  const cv::Mat mid_gamma =
      PatternRenderer(gamma, rig, 0, g).RenderIrradiance(FlatProjectorImage(rig, 128));
  const cv::Mat quarter =
      PatternRenderer(lut, rig, 0, g).RenderIrradiance(FlatProjectorImage(rig, 77));
  int n = 0;
  for (int y = 0; y < g.height; y += 5) {
    for (int x = 0; x < g.width; x += 5) {
      const float w = white.at<float>(y, x);
      if (w <= 0) continue;
      EXPECT_NEAR(mid_linear.at<float>(y, x) / w, 128.0 / 255, 1e-5);
      EXPECT_NEAR(mid_gamma.at<float>(y, x) / w, std::pow(128.0 / 255, 2.2), 1e-5);
      EXPECT_NEAR(quarter.at<float>(y, x) / w, 0.25, 1e-5);
      ++n;
    }
  }
  EXPECT_GT(n, 1000);
}

TEST(LayersTest, VignettingIsCos4OfTheViewingAngle) {
  const Rig rig = SmallDemoRig(4);
  Scene plain = FacingPlane();
  Scene vig = plain;
  vig.layers.vignetting_enabled = true;
  const GeometryBuffer g = Trace(plain, rig, 0);
  const cv::Mat a =
      PatternRenderer(plain, rig, 0, g).RenderIrradiance(FlatProjectorImage(rig, 255));
  const cv::Mat b = PatternRenderer(vig, rig, 0, g).RenderIrradiance(FlatProjectorImage(rig, 255));
  const CameraModel& cam = rig.cameras[0].model;
  double min_ratio = 1;
  for (int y = 0; y < g.height; y += 7) {
    for (int x = 0; x < g.width; x += 7) {
      if (a.at<float>(y, x) <= 0) continue;
      const auto ray = cam.Unproject(Eigen::Vector2d(x, y));
      const double cos_theta = ray->z();
      const double ratio = b.at<float>(y, x) / a.at<float>(y, x);
      EXPECT_NEAR(ratio, std::pow(cos_theta, 4), 2e-3) << x << "," << y;
      min_ratio = std::min(min_ratio, ratio);
    }
  }
  EXPECT_LT(min_ratio, 0.97) << "the corners are darker";
}

TEST(LayersTest, AmbientAddsAlbedoTimesLevelEverywhereOnTheSurface) {
  const Rig rig = SmallDemoRig(4);
  Scene a = FacingPlane();
  Scene b = a;
  b.layers.ambient = 0.1;
  const GeometryBuffer g = Trace(a, rig, 0);
  const cv::Mat black_a =
      PatternRenderer(a, rig, 0, g).RenderIrradiance(FlatProjectorImage(rig, 0));
  const cv::Mat black_b =
      PatternRenderer(b, rig, 0, g).RenderIrradiance(FlatProjectorImage(rig, 0));
  EXPECT_EQ(cv::countNonZero(black_a), 0);
  for (int y = 0; y < g.height; y += 5) {
    for (int x = 0; x < g.width; x += 5) {
      const float expected =
          g.visibility.at<uint8_t>(y, x) ? static_cast<float>(0.8 * 255 * 0.1 * 0.7) : 0.0f;
      EXPECT_FLOAT_EQ(black_b.at<float>(y, x), expected);
    }
  }
}

// Supersampling box-filters the pixel: a checkerboard edge gets intermediate values, and the
// board's mean brightness stays the same.
TEST(LayersTest, SupersamplingAntialiasesAndPreservesMean) {
  const Rig rig = SmallDemoRig(4);
  const Rigid3d pose = Pose(Eigen::Vector3d(0.1, 0.2, 0.3), Eigen::Vector3d(-60, -40, 480));
  BoardScene board = MakeCheckerboardScene(7, 5, 15, pose);
  Scene ss = board.scene;
  ss.layers.supersampling = 4;
  const cv::Mat white = FlatProjectorImage(rig, 255);
  const GeometryBuffer g1 = Trace(board.scene, rig, 0), g4 = Trace(ss, rig, 0);
  const cv::Mat i1 = PatternRenderer(board.scene, rig, 0, g1).RenderIrradiance(white);
  const cv::Mat i4 = PatternRenderer(ss, rig, 0, g4).RenderIrradiance(white);
  // Intermediate values exist only with supersampling (relative to the local light/dark levels).
  auto count_mid = [&](const cv::Mat& img, const GeometryBuffer& g) {
    int mid = 0;
    for (int y = 0; y < img.rows; ++y) {
      for (int x = 0; x < img.cols; ++x) {
        if (g.visibility.at<uint8_t>(y, x) != 2) continue;
        const double v = img.at<float>(y, x);
        if (v > 0.8 * 255 * 0.2 && v < 0.8 * 255 * 0.6) ++mid;
      }
    }
    return mid;
  };
  EXPECT_GT(count_mid(i4, g4), 5 * count_mid(i1, g1) + 100);
  EXPECT_NEAR(cv::mean(i4)[0], cv::mean(i1)[0], 0.01 * cv::mean(i1)[0]);
}

// Fill factor: averaged over many samples, the light falls to fill_factor of full.
TEST(LayersTest, FillFactorScalesAverageLight) {
  const Rig rig = SmallDemoRig(8);
  Scene full = FacingPlane();
  full.layers.supersampling = 8;
  Scene gaps = full;
  gaps.layers.fill_factor = 0.6;
  const GeometryBuffer g = Trace(full, rig, 0);
  const cv::Mat white = FlatProjectorImage(rig, 255);
  const double a = cv::mean(PatternRenderer(full, rig, 0, g).RenderIrradiance(white))[0];
  const double b = cv::mean(PatternRenderer(gaps, rig, 0, g).RenderIrradiance(white))[0];
  EXPECT_NEAR(b / a, 0.6, 0.02);
}

// Defocus (thin lens): in focus it changes nothing; out of focus it lowers fringe contrast and
// keeps the mean (a normalised PSF).
TEST(LayersTest, DefocusBlursOnlyOutOfFocus) {
  const Rig rig = SmallDemoRig(4);
  Scene sharp = FacingPlane();
  const GeometryBuffer g = Trace(sharp, rig, 0);
  const cv::Mat stripes = Stripes(rig, 4);
  const cv::Mat base = PatternRenderer(sharp, rig, 0, g).RenderIrradiance(stripes);
  cv::Scalar base_mean, base_sd;
  cv::meanStdDev(base, base_mean, base_sd);
  for (int which = 0; which < 2; ++which) {
    Scene focused = sharp, blurred = sharp;
    auto& f = which == 0 ? focused.layers.camera_defocus : focused.layers.projector_defocus;
    auto& b = which == 0 ? blurred.layers.camera_defocus : blurred.layers.projector_defocus;
    f.enabled = b.enabled = true;
    f.f_number = b.f_number = 1.4;
    // The rig is scaled down 4x in pixels: 4x the pitch keeps the demo lenses' focal lengths.
    f.pixel_pitch_um = b.pixel_pitch_um = (which == 0 ? 5.86 : 7.6) * 4;
    f.focus_distance_mm = which == 0 ? 500 : rig.projector->cam_from_rig.translation.z() + 500;
    b.focus_distance_mm = 300;
    const GeometryBuffer gf = Trace(focused, rig, 0), gb = Trace(blurred, rig, 0);
    const cv::Mat in_focus = PatternRenderer(focused, rig, 0, gf).RenderIrradiance(stripes);
    const cv::Mat out_of_focus = PatternRenderer(blurred, rig, 0, gb).RenderIrradiance(stripes);
    cv::Scalar mean, sd;
    cv::meanStdDev(out_of_focus, mean, sd);
    EXPECT_LT(sd[0], 0.8 * base_sd[0]) << (which == 0 ? "camera" : "projector");
    EXPECT_NEAR(mean[0], base_mean[0], 0.02 * base_mean[0]);
    cv::Scalar mean_f, sd_f;
    cv::meanStdDev(in_focus, mean_f, sd_f);
    EXPECT_GT(sd_f[0], 0.9 * base_sd[0]) << "at the focus distance the blur is small";
  }
}

// A sinusoidal projector image cos(2 pi u / P) on the facing plane, 8-bit.
cv::Mat SineFringe(const Rig& rig, double period_px) {
  cv::Mat m(rig.projector->model.height, rig.projector->model.width, CV_8UC1);
  for (int y = 0; y < m.rows; ++y) {
    for (int x = 0; x < m.cols; ++x) {
      m.at<uint8_t>(y, x) =
          cv::saturate_cast<uint8_t>(127.5 + 100 * std::cos(2 * M_PI * x / period_px));
    }
  }
  return m;
}

// Fringe amplitude of `image` / `white` (the radiometric factor divided out) over the pixels of a
// central window lit in `g`: least squares of A + B cos(2 pi u / P) + C sin(2 pi u / P) against
// the true projector column u; returns sqrt(B^2 + C^2).
double FringeAmplitude(const cv::Mat& image, const cv::Mat& white, const GeometryBuffer& g,
                       double period_px) {
  Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
  Eigen::Vector3d atb = Eigen::Vector3d::Zero();
  for (int y = g.height / 4; y < 3 * g.height / 4; ++y) {
    for (int x = g.width / 4; x < 3 * g.width / 4; ++x) {
      const float u = g.projector.proj_x.at<float>(y, x);
      const float w = white.at<float>(y, x);
      if (!std::isfinite(u) || !(w > 0)) continue;
      const Eigen::Vector3d a(1, std::cos(2 * M_PI * u / period_px),
                              std::sin(2 * M_PI * u / period_px));
      ata += a * a.transpose();
      atb += a * (image.at<float>(y, x) / w);
    }
  }
  const Eigen::Vector3d c = ata.ldlt().solve(atb);
  return std::hypot(c(1), c(2));
}

// Defocus against the analytic transfer of a Gaussian PSF: a sinusoidal fringe of period P
// (px of the blurred image) keeps exp(-2 pi^2 sigma^2 / P^2) of its contrast. Camera defocus
// blurs the camera image (P in camera px from the true projector-coordinate gradient); projector
// defocus blurs the pattern (P in projector px).
TEST(LayersTest, DefocusContrastFollowsTheGaussianTransferFunction) {
  const Rig rig = SmallDemoRig(4);
  const double period_px = 10;
  const cv::Mat fringe = SineFringe(rig, period_px), white = FlatProjectorImage(rig, 255);
  const Scene sharp = FacingPlane();
  const GeometryBuffer g = Trace(sharp, rig, 0);
  const double sharp_amplitude =
      FringeAmplitude(PatternRenderer(sharp, rig, 0, g).RenderIrradiance(fringe),
                      PatternRenderer(sharp, rig, 0, g).RenderIrradiance(white), g, period_px);
  // The 8-bit fringe of amplitude 100 read back through the factor: 100 / 255 of the white, less
  // the few per cent that bilinear lookups of a 10-px sampled sinusoid lose (the same in both).
  EXPECT_NEAR(sharp_amplitude, 100.0 / 255, 0.02);
  // Camera period: P / |grad u| at the image centre (the plane's projector map is nearly affine).
  const int cx = g.width / 2, cy = g.height / 2;
  const double dudx =
      (g.projector.proj_x.at<float>(cy, cx + 4) - g.projector.proj_x.at<float>(cy, cx - 4)) / 8;
  const double dudy =
      (g.projector.proj_x.at<float>(cy + 4, cx) - g.projector.proj_x.at<float>(cy - 4, cx)) / 8;
  const double camera_period_px = period_px / std::hypot(dudx, dudy);
  for (int which = 0; which < 2; ++which) {
    Scene blurred = sharp;
    auto& d = which == 0 ? blurred.layers.camera_defocus : blurred.layers.projector_defocus;
    d.enabled = true;
    d.f_number = 1.4;
    d.pixel_pitch_um = (which == 0 ? 5.86 : 7.6) * 4;  // the rig is scaled down 4x in pixels
    d.focus_distance_mm = 300;
    const GeometryBuffer gb = Trace(blurred, rig, 0);
    const PatternRenderer r(blurred, rig, 0, gb);
    const double amplitude =
        FringeAmplitude(r.RenderIrradiance(fringe), r.RenderIrradiance(white), gb, period_px);
    double sigma_px = 0, period = 0;
    if (which == 0) {
      sigma_px =
          d.SigmaPx(rig.cameras[0].model.fx(), 500);  // the facing plane: depth 500 everywhere
      period = camera_period_px;
    } else {
      std::vector<float> sigmas;
      for (size_t i = 0; i < gb.proj_sigma_px.size(); ++i) {
        if (std::isfinite(gb.proj_x[i])) sigmas.push_back(gb.proj_sigma_px[i]);
      }
      ASSERT_FALSE(sigmas.empty());
      std::nth_element(sigmas.begin(), sigmas.begin() + sigmas.size() / 2, sigmas.end());
      sigma_px = sigmas[sigmas.size() / 2];
      period = period_px;
    }
    const double expected = std::exp(-2 * M_PI * M_PI * sigma_px * sigma_px / (period * period));
    std::printf("%s defocus: sigma %.3f px, period %.2f px, contrast kept %.4f (analytic %.4f)\n",
                which == 0 ? "camera" : "projector", sigma_px, period, amplitude / sharp_amplitude,
                expected);
    ASSERT_GT(expected, 0.2) << "the set-up should blur the fringe measurably, not erase it";
    ASSERT_LT(expected, 0.9);
    EXPECT_NEAR(amplitude / sharp_amplitude, expected, 0.03)
        << (which == 0 ? "camera" : "projector");
  }
}

// Projector defocus blurs a pixelated projector too (fill factor < 1: pixel-exact lookups with dark
// gaps): a strong blur takes the same share of a sinusoidal fringe's contrast as without the fill
// factor, and the light stays the fill factor's share. (It once had no effect at all there.)
TEST(LayersTest, ProjectorDefocusBlursAPixelatedProjector) {
  const Rig rig = SmallDemoRig(4);
  const double period_px = 10;
  const cv::Mat fringe = SineFringe(rig, period_px), white = FlatProjectorImage(rig, 255);
  Scene sharp = FacingPlane();
  sharp.layers.supersampling = 4;
  Scene gaps = sharp;
  gaps.layers.fill_factor = 0.6;
  const auto blur = [&](Scene s) {
    auto& d = s.layers.projector_defocus;
    d.enabled = true;
    d.f_number = 1.4;
    d.pixel_pitch_um = 7.6 * 4;  // the rig is scaled down 4x in pixels
    d.focus_distance_mm = 300;
    return s;
  };
  const auto amplitude_and_light = [&](const Scene& s) {
    const GeometryBuffer g = Trace(s, rig, 0);
    const PatternRenderer r(s, rig, 0, g);
    const cv::Mat w = r.RenderIrradiance(white);
    return std::make_pair(FringeAmplitude(r.RenderIrradiance(fringe), w, g, period_px),
                          cv::mean(w)[0]);
  };
  const auto [a_sharp, w_sharp] = amplitude_and_light(sharp);
  const auto [a_blurred, w_blurred] = amplitude_and_light(blur(sharp));
  const auto [a_gaps, w_gaps] = amplitude_and_light(gaps);
  const auto [a_both, w_both] = amplitude_and_light(blur(gaps));
  ASSERT_LT(a_blurred, 0.7 * a_sharp);  // the blur is strong
  EXPECT_NEAR(a_both / a_gaps, a_blurred / a_sharp, 0.05);
  EXPECT_NEAR(w_both / w_blurred, 0.6, 0.03);
  EXPECT_NEAR(w_gaps / w_sharp, 0.6, 0.03);
}

}  // namespace
}  // namespace slshadow
