// The OpenCV-compatible Gray code (PatternSpec::opencv_order) against its peer,
// cv::structured_light::GrayCodePattern (opencv_contrib): same projector images, and on real
// captures the same decoded projector pixels and the same rejected pixels.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>

#include <opencv2/structured_light.hpp>

#include "core/image_set.h"
#include "patterns/codec.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

PatternSpec OpenCvSpec(int width, int height) {
  PatternSpec s;
  s.kind = PatternKind::kGrayCode;
  s.projector_width = width;
  s.projector_height = height;
  s.opencv_order = true;
  return s;
}

TEST(OpenCvCompat, GeneratedImagesEqualGrayCodePatternGenerate) {
  for (const cv::Size size : {cv::Size(1024, 768), cv::Size(1000, 700), cv::Size(37, 5)}) {
    cv::structured_light::GrayCodePattern::Params params;
    params.width = size.width;
    params.height = size.height;
    const auto graycode = cv::structured_light::GrayCodePattern::create(params);
    std::vector<cv::Mat> theirs;
    graycode->generate(theirs);
    cv::Mat black, white;
    graycode->getImagesForShadowMasks(black, white);
    theirs.push_back(white);
    theirs.push_back(black);
    const std::vector<cv::Mat> ours = GeneratePatterns(OpenCvSpec(size.width, size.height));
    ASSERT_EQ(ours.size(), theirs.size()) << size;
    for (size_t i = 0; i < ours.size(); ++i) {
      ASSERT_EQ(cv::norm(ours[i], theirs[i], cv::NORM_INF), 0) << size << " frame " << i;
    }
  }
}

std::filesystem::path KaminoDir() { return testing::SharedDataDir() / "kamino-procam-graycode"; }

TEST(OpenCvCompat, GeneratedImagesEqualTheProjectedKaminoPatterns) {
  ASSERT_TRUE(std::filesystem::exists(KaminoDir())) << "real data not present: " << KaminoDir();
  const std::vector<cv::Mat> ours = GeneratePatterns(OpenCvSpec(1024, 768));
  ASSERT_EQ(ours.size(), 42u);
  for (size_t i = 0; i < ours.size(); ++i) {
    char name[64];
    std::snprintf(name, sizeof(name), "graycode_pattern/pattern_%02zu.png", i);
    const cv::Mat theirs = ReadGrayImage(KaminoDir() / name);
    ASSERT_EQ(cv::norm(ours[i], theirs, cv::NORM_INF), 0) << name;
  }
}

// Our decoder with OpenCV's rules (no edge midpoint, white threshold = contrast threshold, black
// threshold = shadow threshold) must agree with getProjPixel on every pixel of a real capture.
TEST(OpenCvCompat, DecodeAgreesWithGetProjPixelOnRealCaptures) {
  ASSERT_TRUE(std::filesystem::exists(KaminoDir())) << "real data not present: " << KaminoDir();
  const PatternSpec spec = OpenCvSpec(1024, 768);
  for (int pose : {0, 3}) {
    std::vector<cv::Mat> images;
    for (int i = 0; i < spec.NumImages(); ++i) {
      char name[64];
      std::snprintf(name, sizeof(name), "capture_%d/graycode_%02d.png", pose, i);
      images.push_back(ReadGrayImage(KaminoDir() / name));
    }
    DecodeOptions options;
    options.gray_edge_midpoint = false;
    options.contrast_threshold = 5;
    options.shadow_threshold = 40;
    options.saturation_level = 65535;  // OpenCV does not test saturation
    const ProjectorMap map = DecodePatterns(spec, images, options);

    cv::structured_light::GrayCodePattern::Params params;
    params.width = 1024;
    params.height = 768;
    const auto graycode = cv::structured_light::GrayCodePattern::create(params);
    graycode->setWhiteThreshold(5);
    const std::vector<cv::Mat> codes(images.begin(), images.begin() + 40);
    const cv::Mat& white = images[40];
    const cv::Mat& black = images[41];
    int64_t both_valid = 0, disagree = 0;
    for (int y = 0; y < white.rows; ++y) {
      for (int x = 0; x < white.cols; ++x) {
        // OpenCV's shadow mask: white - black > black threshold (ours: >= threshold).
        const bool lit = white.at<uint8_t>(y, x) - black.at<uint8_t>(y, x) > 40;
        cv::Point proj;
        const bool theirs_valid = lit && !graycode->getProjPixel(codes, x, y, proj);
        const int diff = white.at<uint8_t>(y, x) - black.at<uint8_t>(y, x);
        if (diff == 40) continue;  // the one level where "> 40" and ">= 40" differ
        const bool ours_valid = map.status.at<uint8_t>(y, x) == 0;
        if (ours_valid != theirs_valid) {
          ++disagree;
          continue;
        }
        if (!ours_valid) continue;
        ++both_valid;
        disagree += map.proj_x.at<float>(y, x) != static_cast<float>(proj.x) ||
                    map.proj_y.at<float>(y, x) != static_cast<float>(proj.y);
      }
    }
    EXPECT_EQ(disagree, 0) << "pose " << pose;
    EXPECT_GT(both_valid, 200000) << "pose " << pose;
  }
}

}  // namespace
}  // namespace slshadow
