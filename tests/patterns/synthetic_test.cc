#include "patterns/synthetic.h"

#include <gtest/gtest.h>

#include <cmath>

#include "core/error.h"

namespace slshadow {
namespace {

cv::Mat Ramp() {
  cv::Mat proj(20, 30, CV_8UC1);
  for (int r = 0; r < 20; ++r) {
    for (int c = 0; c < 30; ++c) proj.at<uint8_t>(r, c) = static_cast<uint8_t>(3 * c + 5 * r);
  }
  return proj;
}

TEST(SimulateCameraImages, BilinearSamplingGainOffsetAndOutside) {
  const cv::Mat proj = Ramp();
  // Identity, then a half-pixel shift, then a point outside the projector.
  cv::Mat mx(1, 4, CV_64FC1), my(1, 4, CV_64FC1);
  mx.at<double>(0, 0) = 4;
  my.at<double>(0, 0) = 7;
  mx.at<double>(0, 1) = 4.5;
  my.at<double>(0, 1) = 7.25;
  mx.at<double>(0, 2) = 30.2;  // right of the projector's last column edge (29.5)
  my.at<double>(0, 2) = 3;
  mx.at<double>(0, 3) = std::nan("");
  my.at<double>(0, 3) = 3;
  CameraSimOptions sim;
  sim.gain = 0.5;
  sim.offset = 10;
  const auto out = SimulateCameraImages({proj}, mx, my, sim);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].at<uint8_t>(0, 0), static_cast<int>(std::floor(10 + 0.5 * (12 + 35) + 0.5)));
  EXPECT_EQ(out[0].at<uint8_t>(0, 1),
            static_cast<int>(std::floor(10 + 0.5 * (3 * 4.5 + 5 * 7.25) + 0.5)));
  EXPECT_EQ(out[0].at<uint8_t>(0, 2), 10);
  EXPECT_EQ(out[0].at<uint8_t>(0, 3), 10);
  sim.bit_depth = 16;
  const auto out16 = SimulateCameraImages({proj}, mx, my, sim);
  EXPECT_EQ(out16[0].type(), CV_16UC1);
  EXPECT_EQ(out16[0].at<uint16_t>(0, 0), static_cast<int>(std::floor(257 * (10 + 0.5 * 47) + 0.5)));
}

TEST(SimulateCameraImages, NoiseHasTheRequestedSigmaAndIsSeeded) {
  const cv::Mat proj(10, 10, CV_8UC1, cv::Scalar(100));
  cv::Mat mx(200, 300, CV_64FC1, cv::Scalar(5)), my(200, 300, CV_64FC1, cv::Scalar(5));
  CameraSimOptions sim;
  sim.noise_sigma = 3;
  sim.bit_depth = 16;
  sim.seed = 3;
  const auto a = SimulateCameraImages({proj}, mx, my, sim);
  const auto b = SimulateCameraImages({proj}, mx, my, sim);
  EXPECT_EQ(cv::norm(a[0], b[0], cv::NORM_INF), 0);
  cv::Scalar mean, stddev;
  cv::meanStdDev(a[0], mean, stddev);
  EXPECT_NEAR(mean[0] / 257, 8 + 0.8 * 100, 0.05);
  EXPECT_NEAR(stddev[0] / 257, 3.0, 0.05);
  sim.seed = 4;
  EXPECT_GT(cv::norm(a[0], SimulateCameraImages({proj}, mx, my, sim)[0], cv::NORM_INF), 0);
}

TEST(SimulateCameraImages, GammaAndBadOptions) {
  const cv::Mat proj(4, 4, CV_8UC1, cv::Scalar(128));
  cv::Mat mx(1, 1, CV_64FC1, cv::Scalar(1)), my(1, 1, CV_64FC1, cv::Scalar(1));
  CameraSimOptions sim;
  sim.gamma = 2.0;
  sim.gain = 1;
  sim.offset = 0;
  EXPECT_EQ(SimulateCameraImages({proj}, mx, my, sim)[0].at<uint8_t>(0, 0),
            static_cast<int>(std::floor(255 * std::pow(128 / 255.0, 2) + 0.5)));
  sim.gamma = 0;
  EXPECT_THROW(SimulateCameraImages({proj}, mx, my, sim), Error);
  sim = {};
  sim.bit_depth = 12;
  EXPECT_THROW(SimulateCameraImages({proj}, mx, my, sim), Error);
  EXPECT_THROW(SimulateCameraImages({proj}, mx, cv::Mat(2, 1, CV_64FC1), {}), Error);
}

TEST(HomographyMaps, MapsPixelCentres) {
  const cv::Matx33d h(2, 0, 3, 0, 1, -1, 0, 0, 1);
  cv::Mat mx, my;
  HomographyMaps(h, 5, 4, &mx, &my);
  EXPECT_DOUBLE_EQ(mx.at<double>(2, 4), 11);
  EXPECT_DOUBLE_EQ(my.at<double>(2, 4), 1);
}

}  // namespace
}  // namespace slshadow
