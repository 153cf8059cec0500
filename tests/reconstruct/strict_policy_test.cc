// Strict mode's policy (strict_policy.h) on summaries with known checks and counts: each of the
// three violations is found and named, a stereo projector-error check covers its camera's
// one-axis projector mode, and a clean set passes.
#include "reconstruct/strict_policy.h"

#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/error.h"

namespace slshadow {
namespace {

ReconstructSummary Summary(ReconstructMode mode, const std::string& camera,
                           const std::string& other, int64_t valid, int64_t points) {
  ReconstructSummary s;
  s.mode = mode;
  s.camera = camera;
  s.other_device = other;
  s.decode_status[static_cast<size_t>(PixelStatus::kValid)] = valid;
  s.points = points;
  s.calibration_check.available = true;
  s.calibration_check.pair = camera + "-" + other;
  return s;
}

std::string Joined(const std::vector<std::string>& v) {
  std::string m;
  for (const auto& s : v) m += s + "\n";
  return m;
}

TEST(StrictPolicyTest, FindsEachViolation) {
  StrictOptions strict;
  strict.enabled = true;
  const ReconstructSummary good =
      Summary(ReconstructMode::kProjector, "left", "projector", 1000, 900);
  EXPECT_TRUE(StrictViolations({good}, strict).empty());
  EXPECT_NO_THROW(EnforceStrict({good}, strict, "reconstruct"));

  ReconstructSummary warned = good;
  warned.calibration_check.warn = true;
  ReconstructSummary unchecked =
      Summary(ReconstructMode::kProjector, "right", "projector", 1000, 900);
  unchecked.calibration_check =
      UnavailableCalibrationCheck("right-projector", "only projector columns are coded");
  const ReconstructSummary sparse =
      Summary(ReconstructMode::kStereo, "left", "right", 2000, 400);  // 40 % of 1000 per camera
  const auto v = StrictViolations({warned, unchecked, sparse}, strict);
  ASSERT_EQ(v.size(), 3u) << Joined(v);
  EXPECT_NE(v[0].find("left-projector: the calibration check warns"), std::string::npos) << v[0];
  EXPECT_NE(v[1].find("right-projector: no calibration check, because only projector columns"),
            std::string::npos)
      << v[1];
  EXPECT_NE(v[2].find("left-right: 400 points are 40.0 % of the 1000 valid pixels (under the "
                      "50.0 % minimum)"),
            std::string::npos)
      << v[2];
  try {
    EnforceStrict({warned, unchecked, sparse}, strict, "reconstruct");
    ADD_FAILURE() << "no throw";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_EQ(m.rfind("reconstruct: --strict: left-projector", 0), 0u) << m;
    EXPECT_NE(m.find("; nothing written"), std::string::npos) << m;
  }
  // Not enabled: nothing enforced; the share is an option.
  strict.enabled = false;
  EXPECT_NO_THROW(EnforceStrict({warned, unchecked, sparse}, strict, "reconstruct"));
  strict.min_point_share = 0.3;
  EXPECT_EQ(StrictViolations({sparse}, strict).size(), 0u);
  strict.min_point_share = 1.5;
  EXPECT_THROW(StrictViolations({sparse}, strict), Error);
}

TEST(StrictPolicyTest, StereoProjectorCheckCoversOneAxisProjectorMode) {
  StrictOptions strict;
  ReconstructSummary procam = Summary(ReconstructMode::kProjector, "left", "projector", 1000, 900);
  procam.calibration_check = UnavailableCalibrationCheck("left-projector", "one axis");
  ReconstructSummary stereo = Summary(ReconstructMode::kStereo, "left", "right", 2000, 900);
  stereo.calibration_check.residual = CalibrationResidual::kProjectorError;
  EXPECT_TRUE(StrictViolations({procam, stereo}, strict).empty());
  // Not when the stereo check warns (then it is a violation of its own), nor by the fitted
  // projector (which does not involve the rig's projector), nor for another camera.
  ReconstructSummary warned = stereo;
  warned.calibration_check.warn = true;
  EXPECT_EQ(StrictViolations({procam, warned}, strict).size(), 2u);
  ReconstructSummary fitted = stereo;
  fitted.calibration_check.residual = CalibrationResidual::kFittedProjectorError;
  EXPECT_EQ(StrictViolations({procam, fitted}, strict).size(), 1u);
  ReconstructSummary right = procam;
  right.camera = "right";
  EXPECT_EQ(StrictViolations({right, stereo}, strict).size(), 1u);
}

}  // namespace
}  // namespace slshadow
