#include "compare/registration.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "core/error.h"
#include "tests/compare/test_shapes.h"

namespace slshadow::compare {
namespace {

using testing::SamplePart;

constexpr double kSize = 100.0;  // mm

// Largest displacement the error transform causes over the part's bounding box.
double MaxDisplacementMm(const Rigid3d& error) {
  double worst = 0;
  for (int i = 0; i < 8; ++i) {
    const Eigen::Vector3d c((i & 1) ? kSize / 2 : -kSize / 2, (i & 2) ? kSize / 2 : -kSize / 2,
                            (i & 4) ? 0.2 * kSize : -0.1 * kSize);
    worst = std::max(worst, (error * c - c).norm());
  }
  return worst;
}

// The compared cloud: an independent sample of the part, noise of 0.1 % of its size, moved by
// cloud_from_reference.
std::vector<Eigen::Vector3d> MovedNoisySample(const Rigid3d& cloud_from_reference, size_t n) {
  auto pts = SamplePart(n, kSize, 32);
  std::mt19937 rng(33);
  std::normal_distribution<double> noise(0.0, 0.001 * kSize);
  for (auto& p : pts)
    p = cloud_from_reference * (p + Eigen::Vector3d(noise(rng), noise(rng), noise(rng)));
  return pts;
}

TEST(Register, GlobalPlusIcpRecoversALargeMotionAt200kPoints) {
  const auto reference = SamplePart(200000, kSize, 31);
  const Rigid3d cloud_from_reference(
      Eigen::Quaterniond(
          Eigen::AngleAxisd(20.0 * M_PI / 180.0, Eigen::Vector3d(1, 2, 3).normalized())),
      Eigen::Vector3d(0.1 * kSize * 0.6, -0.1 * kSize * 0.64, 0.1 * kSize * 0.48));  // |t| = 10 mm
  const auto cloud = MovedNoisySample(cloud_from_reference, 200000);
  RegistrationOptions o;
  o.method = RegistrationMethod::kGlobalIcp;
  const RegistrationResult r = Register(cloud, reference, {}, o);
  SCOPED_TRACE(r.BriefReport());
  EXPECT_TRUE(r.global_found);
  EXPECT_TRUE(r.converged);
  const Rigid3d error = r.reference_from_cloud * cloud_from_reference;  // identity when exact
  EXPECT_LT(RotationDifferenceDeg(error, Rigid3d()), 0.05);
  EXPECT_LT(MaxDisplacementMm(error), 0.05);
  EXPECT_GT(r.fitness, 0.95);
  // Nearest-point RMS of two independent samples with 0.1 mm noise per axis: above the noise.
  EXPECT_GT(r.inlier_rmse_mm, 0.1);
  EXPECT_LT(r.inlier_rmse_mm, 0.6);
}

TEST(Register, IcpRefinesASmallMisalignment) {
  const auto reference = SamplePart(50000, kSize, 34);
  const Rigid3d cloud_from_reference(
      Eigen::Quaterniond(
          Eigen::AngleAxisd(3.0 * M_PI / 180.0, Eigen::Vector3d(0.3, -1, 0.2).normalized())),
      Eigen::Vector3d(1.5, 1.0, -0.5));
  const auto cloud = MovedNoisySample(cloud_from_reference, 50000);
  RegistrationOptions o;
  o.method = RegistrationMethod::kIcp;
  const RegistrationResult r = Register(cloud, reference, {}, o);
  SCOPED_TRACE(r.BriefReport());
  const Rigid3d error = r.reference_from_cloud * cloud_from_reference;
  EXPECT_LT(RotationDifferenceDeg(error, Rigid3d()), 0.05);
  EXPECT_LT(MaxDisplacementMm(error), 0.1);
  // The same input gives the same pose to the bit, however the threads split the sums (a report
  // of the same scan must not change in its last digits from run to run).
  for (int run = 0; run < 6; ++run) {
    const RegistrationResult again = Register(cloud, reference, {}, o);
    EXPECT_TRUE(again.reference_from_cloud.rotation.coeffs() ==
                r.reference_from_cloud.rotation.coeffs())
        << "run " << run;
    EXPECT_TRUE(again.reference_from_cloud.translation == r.reference_from_cloud.translation)
        << "run " << run;
    EXPECT_EQ(again.inlier_rmse_mm, r.inlier_rmse_mm) << "run " << run;
  }
}

TEST(Register, NoneIsTheIdentityAndBadOptionsThrow) {
  const auto reference = SamplePart(100, kSize, 35);
  RegistrationOptions o;
  o.method = RegistrationMethod::kNone;
  const RegistrationResult r = Register(reference, reference, {}, o);
  EXPECT_EQ(r.reference_from_cloud.ToMatrix(), Eigen::Matrix4d::Identity());
  o.icp_max_iterations = 0;
  EXPECT_THROW(Register(reference, reference, {}, o), Error);
  EXPECT_THROW(RegistrationMethodFromString("ransac"), Error);
  EXPECT_EQ(RegistrationMethodFromString("global+icp"), RegistrationMethod::kGlobalIcp);
}

}  // namespace
}  // namespace slshadow::compare
