// Reconstruction options as files and their automatic code-step gate, and the residual
// statistics of a reconstruction's summary: the parts of reconstruct/reconstruct.h that need no
// scan (tests/reconstruct/reconstruct_test.cc reconstructs).
#include "reconstruct/reconstruct.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "core/config.h"
#include "core/error.h"
#include "reconstruct/reconstruct_image_set.h"

namespace slshadow {
namespace {

TEST(ResidualStatsTest, QuantilesMatchASortedCopy) {
  std::mt19937 rng(9);
  std::exponential_distribution<float> dist(3.0f);
  std::vector<float> values(10001);
  for (float& v : values) v = dist(rng);
  values[17] = std::nanf("");
  std::vector<float> sorted;
  for (float v : values) {
    if (std::isfinite(v)) sorted.push_back(v);
  }
  std::sort(sorted.begin(), sorted.end());
  const ResidualStats s = ComputeResidualStats(values);
  EXPECT_EQ(s.count, 10000);
  // The nearest rank (core/statistics.h): rank ceil(q n), 1-based, at least 1.
  const auto at = [&](double q) {
    return sorted[static_cast<size_t>(
                      std::max(1.0, std::ceil(q * static_cast<double>(sorted.size())))) -
                  1];
  };
  EXPECT_EQ(s.median, at(0.5));
  EXPECT_EQ(s.p95, at(0.95));
  EXPECT_EQ(s.max, sorted.back());
  double sum2 = 0;
  for (float v : sorted) sum2 += static_cast<double>(v) * v;
  EXPECT_NEAR(s.rms, std::sqrt(sum2 / sorted.size()), 1e-9);
  std::vector<float> empty;
  EXPECT_EQ(ComputeResidualStats(empty).count, 0);
}

TEST(ResidualStatsTest, QuantilesAreExactWithTiesSignsAndTinySets) {
  // Values quantised to few levels (long runs of ties), both signs and zeros of both signs, and
  // sets of 1..5 values: the ranks must equal those of a sorted copy.
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> level(-20, 200);
  for (size_t n : {1, 2, 3, 5, 1000, 200001}) {
    std::vector<float> values(n);
    for (float& v : values) v = static_cast<float>(level(rng)) * 0.125f;
    if (n > 3) {
      values[1] = -0.0f;
      values[2] = 0.0f;
    }
    std::vector<float> sorted = values;
    std::sort(sorted.begin(), sorted.end());
    const ResidualStats s = ComputeResidualStats(values);
    // The nearest rank (core/statistics.h): rank ceil(q n), 1-based, at least 1.
    const auto at = [&](double q) {
      return sorted[static_cast<size_t>(
                        std::max(1.0, std::ceil(q * static_cast<double>(sorted.size())))) -
                    1];
    };
    EXPECT_EQ(s.count, static_cast<int64_t>(n));
    EXPECT_EQ(s.median, at(0.5)) << n;
    EXPECT_EQ(s.p95, at(0.95)) << n;
  }
}

// Options as files: every field written is read back (JSON and YAML, infinite gates as "inf"),
// unknown keys and bad values are refused naming the file and the field.
TEST(ReconstructOptionsFile, RoundTripsEveryFieldAndRejectsUnknownKeys) {
  ReconstructOptions o;
  o.method = TriangulationMethod::kOptimal;
  o.reference_noise_ratio = 0.02;
  o.min_depth_mm = 100;
  o.max_depth_mm = 900;
  o.min_triangulation_angle_deg = 3.5;
  o.max_reprojection_error_px = std::numeric_limits<double>::infinity();
  o.max_epipolar_error_px = 0.75;
  o.min_quality = 1.5f;
  o.max_code_step_px = 3;
  o.max_code_step_ratio = 3.5;
  o.stereo_interpolation = StereoInterpolation::kCubic;
  o.filter_depth_discontinuities = false;
  o.max_depth_jump_footprints = 6;
  o.discontinuity_dilation_px = 2;
  o.filter_outliers = false;
  o.outlier_window_radius_px = 2;
  o.outlier_neighbors = 6;
  o.outlier_std_ratio = 3;
  o.outlier_min_distance_footprints = 5;
  o.estimate_normals = false;
  o.report_residuals = false;
  o.calibration_warning_px = std::numeric_limits<double>::infinity();
  const nlohmann::json j = o.ToJson();
  EXPECT_EQ(j["max_reprojection_error_px"], "inf");
  for (const ConfigNode& node :
       {ConfigNode::FromJson(j, "r.json"), ConfigNode::ParseYaml(JsonToYaml(j), "r.yaml")}) {
    const ReconstructOptions r = ReconstructOptionsFromConfig(node);
    EXPECT_EQ(r.method, o.method);
    EXPECT_EQ(r.max_reprojection_error_px, o.max_reprojection_error_px);
    EXPECT_EQ(r.min_quality, o.min_quality);
    EXPECT_EQ(r.stereo_interpolation, o.stereo_interpolation);
    EXPECT_EQ(r.outlier_neighbors, o.outlier_neighbors);
    EXPECT_EQ(r.calibration_warning_px, o.calibration_warning_px);
    EXPECT_EQ(r.ToJson(), j);  // every other field
  }
  EXPECT_EQ(ReconstructOptionsFromConfig(ConfigNode::FromJson(nlohmann::json::object(), "r.json"))
                .ToJson(),
            ReconstructOptions{}.ToJson());
  nlohmann::json typo = j;
  typo["min_depth"] = 1;
  EXPECT_THROW(ReconstructOptionsFromConfig(ConfigNode::FromJson(typo, "r.json")), Error);
  nlohmann::json bad_method = j;
  bad_method["method"] = "guess";
  try {
    ReconstructOptionsFromConfig(ConfigNode::FromJson(bad_method, "r.json"));
    FAIL() << "unknown method accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("r.json: method"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("guess"), std::string::npos) << e.what();
  }
  nlohmann::json bad_value = j;
  bad_value["min_depth_mm"] = 1000;  // above max_depth_mm
  EXPECT_THROW(ReconstructOptionsFromConfig(ConfigNode::FromJson(bad_value, "r.json")), Error);
  // The code-step gate: "auto" (0) round-trips; another word names the field.
  ReconstructOptions automatic;
  automatic.max_code_step_px = 0;
  EXPECT_EQ(automatic.ToJson()["max_code_step_px"], "auto");
  nlohmann::json gate = j;
  gate["max_code_step_px"] = "auto";
  EXPECT_EQ(ReconstructOptionsFromConfig(ConfigNode::FromJson(gate, "r.json")).max_code_step_px, 0);
  gate["max_code_step_px"] = "wide";
  try {
    ReconstructOptionsFromConfig(ConfigNode::FromJson(gate, "r.json"));
    FAIL() << "a word other than auto accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("max_code_step_px"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("auto"), std::string::npos) << e.what();
  }
  // The relative code-jump test: 0 (off) or a ratio above 1; a ratio of 1 or less names the field.
  nlohmann::json ratio = j;
  ratio["max_code_step_ratio"] = 0;
  EXPECT_EQ(ReconstructOptionsFromConfig(ConfigNode::FromJson(ratio, "r.json")).max_code_step_ratio,
            0);
  ratio["max_code_step_ratio"] = 0.8;
  try {
    ReconstructOptionsFromConfig(ConfigNode::FromJson(ratio, "r.json"));
    FAIL() << "max_code_step_ratio 0.8 accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("max_code_step_ratio"), std::string::npos) << e.what();
  }

  ImageSetReconstructOptions s;
  s.mode = ReconstructMode::kStereo;
  s.cameras = {"right", "left"};
  s.reconstruct = o;
  s.decode.shadow_threshold = 20;
  const nlohmann::json sj = s.ToJson();
  const ImageSetReconstructOptions sr =
      ImageSetReconstructOptionsFromConfig(ConfigNode::ParseYaml(JsonToYaml(sj), "s.yaml"));
  EXPECT_EQ(sr.mode, s.mode);
  EXPECT_EQ(sr.cameras, s.cameras);
  EXPECT_EQ(sr.decode.shadow_threshold, 20);
  EXPECT_EQ(sr.ToJson(), sj);
  nlohmann::json nested_typo = sj;
  nested_typo["decode"]["parallell"] = true;
  try {
    ImageSetReconstructOptionsFromConfig(ConfigNode::FromJson(nested_typo, "s.json"));
    FAIL() << "unknown nested key accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("parallell"), std::string::npos) << e.what();
  }
}

// The automatic code-step gate: 3 x the largest median of neighbour steps per map and direction
// (brute force over every 2nd row and column), at least 4; undecoded pixels and uncoded axes left
// out.
TEST(AutoCodeStepGate, IsThreeMediansOfTheSteeperMapAndAtLeastFour) {
  const auto ramp = [](int w, int h, double dx, double dy, bool both, int depth) {
    ProjectorMap m;
    m.Allocate(w, h, true, both);
    m.proj_x.convertTo(m.proj_x, depth);
    m.proj_y.convertTo(m.proj_y, depth);
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const double u = dx * x + 0.3 * std::sin(0.7 * x + 1.3 * y), v = dy * y;
        if (depth == CV_64F) {
          m.proj_x.at<double>(y, x) = u;
          if (both) m.proj_y.at<double>(y, x) = v;
        } else {
          m.proj_x.at<float>(y, x) = static_cast<float>(u);
          if (both) m.proj_y.at<float>(y, x) = static_cast<float>(v);
        }
      }
    }
    return m;
  };
  const auto brute = [](const ProjectorMap& m) {
    const auto at = [&](const cv::Mat& a, int y, int x) {
      return a.depth() == CV_64F ? a.at<double>(y, x) : a.at<float>(y, x);
    };
    double median = 0;
    for (const auto& [dy, dx] : {std::pair{0, 1}, std::pair{1, 0}}) {
      std::vector<double> steps;
      for (int y = 0; y + 1 < m.height(); y += 2) {
        for (int x = 0; x + 1 < m.width(); x += 2) {
          double step = std::abs(at(m.proj_x, y + dy, x + dx) - at(m.proj_x, y, x));
          if (m.has_y) {
            step = std::max(step, std::abs(at(m.proj_y, y + dy, x + dx) - at(m.proj_y, y, x)));
          }
          if (std::isfinite(step)) steps.push_back(step);
        }
      }
      std::sort(steps.begin(), steps.end());
      median = std::max(median, steps[steps.size() / 2]);
    }
    return median;
  };
  const ProjectorMap flat = ramp(64, 48, 0.5, 0.5, true, CV_32F);
  EXPECT_EQ(AutoCodeStepGate(flat, flat), 4.0);  // the floor
  ProjectorMap steep = ramp(64, 48, 2.5, 0.5, false, CV_64F);
  for (int x = 0; x < 64; x += 5) steep.proj_x.at<double>(10, x) = std::nan("");
  const double expected = 3 * std::max(brute(flat), brute(steep));
  EXPECT_GT(expected, 4);
  EXPECT_DOUBLE_EQ(AutoCodeStepGate(flat, steep), expected);
  EXPECT_DOUBLE_EQ(AutoCodeStepGate(steep, flat), expected);
  const ProjectorMap steep_y = ramp(64, 48, 0.5, 3.0, true, CV_32F);
  EXPECT_DOUBLE_EQ(AutoCodeStepGate(steep_y, flat), 3 * brute(steep_y));
  ProjectorMap none = ramp(8, 8, 1, 1, true, CV_32F);
  none.proj_x.setTo(std::nan(""));
  EXPECT_EQ(AutoCodeStepGate(none, none), 4.0);
}

}  // namespace
}  // namespace slshadow
