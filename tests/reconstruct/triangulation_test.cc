#include "reconstruct/triangulation.h"

#include <random>

#include <gtest/gtest.h>

#include "core/error.h"
#include "core/rig.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

const TriangulationMethod kMethods[] = {TriangulationMethod::kMidpoint, TriangulationMethod::kDlt,
                                        TriangulationMethod::kOptimal};

class TriangulationTest : public ::testing::Test {
 protected:
  void SetUp() override { rig_ = LoadRig(testing::SourceDir() / "config/demo/rig.yaml"); }
  TriangulationView View(const RigDevice& d) const {
    return TriangulationView(d.cam_from_rig, 0.5 * (d.model.fx() + d.model.fy()));
  }
  // Random points in the demo rig's working volume (rig frame).
  std::vector<Eigen::Vector3d> Points(int n, unsigned seed) const {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> xy(-120, 120), z(350, 800);
    std::vector<Eigen::Vector3d> out;
    for (int i = 0; i < n; ++i) out.emplace_back(xy(rng), xy(rng), z(rng));
    return out;
  }
  static Eigen::Vector2d Normalized(const TriangulationView& v, const Eigen::Vector3d& p) {
    const Eigen::Vector3d c = v.ToCam(p);
    return c.head<2>() / c.z();
  }
  Rig rig_;
};

TEST_F(TriangulationTest, MethodNamesRoundTrip) {
  for (auto m : kMethods) EXPECT_EQ(TriangulationMethodFromString(ToString(m)), m);
  EXPECT_THROW(TriangulationMethodFromString("hartley"), Error);
}

TEST_F(TriangulationTest, ExactObservationsGiveTheTruePointForEveryMethodAndPair) {
  const RigDevice* pairs[][2] = {{&rig_.cameras[0], &*rig_.projector},
                                 {&rig_.cameras[1], &*rig_.projector},
                                 {&rig_.cameras[0], &rig_.cameras[1]}};
  for (auto& pair : pairs) {
    const TwoViewTriangulator tri(View(*pair[0]), View(*pair[1]));
    for (const Eigen::Vector3d& p : Points(500, 7)) {
      const Eigen::Vector2d x0 = Normalized(tri.view0(), p), x1 = Normalized(tri.view1(), p);
      for (auto m : kMethods) {
        const auto q = tri.Triangulate(x0, x1, m);
        ASSERT_TRUE(q) << ToString(m);
        EXPECT_LT((*q - p).norm(), 1e-6)
            << ToString(m) << " " << pair[0]->name << "-" << pair[1]->name;
      }
      EXPECT_LT(tri.EpipolarDistancePx(x0, x1), 1e-6);
    }
  }
}

TEST_F(TriangulationTest, ExactPixelsThroughTheDistortedModelsGiveTheTruePoint) {
  const RigDevice& cam = rig_.cameras[0];
  const RigDevice& proj = *rig_.projector;
  const TwoViewTriangulator tri(View(cam), View(proj));
  for (const Eigen::Vector3d& p : Points(300, 8)) {
    const auto pc = cam.model.Project(cam.cam_from_rig * p);
    const auto pp = proj.model.Project(proj.cam_from_rig * p);
    ASSERT_TRUE(pc && pp);
    const auto x0 = cam.model.UndistortToNormalized(*pc);
    const auto x1 = proj.model.UndistortToNormalized(*pp);
    ASSERT_TRUE(x0 && x1);
    for (auto m : kMethods) {
      const auto q = tri.Triangulate(*x0, *x1, m);
      ASSERT_TRUE(q);
      EXPECT_LT((*q - p).norm(), 1e-6) << ToString(m);
    }
  }
}

TEST_F(TriangulationTest, ParallelRaysGiveNoPoint) {
  const TwoViewTriangulator tri(View(rig_.cameras[0]), View(rig_.cameras[1]));
  // The same rig-frame direction seen from both centres: rays parallel, point at infinity.
  const Eigen::Vector3d dir(0.1, -0.05, 1.0);
  const Eigen::Vector3d d0 = tri.view0().cam_from_rig_rotation * dir;
  const Eigen::Vector3d d1 = tri.view1().cam_from_rig_rotation * dir;
  const Eigen::Vector2d x0 = d0.head<2>() / d0.z(), x1 = d1.head<2>() / d1.z();
  EXPECT_LT(tri.SinAngle(x0, x1), 1e-12);
  for (auto m : kMethods) EXPECT_FALSE(tri.Triangulate(x0, x1, m)) << ToString(m);
}

TEST_F(TriangulationTest, Niter2CorrectionSatisfiesTheEpipolarConstraintAndIsSmallest) {
  const TwoViewTriangulator tri(View(rig_.cameras[0]), View(*rig_.projector));
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.5);  // pixels
  double sum_opt = 0, sum_mid = 0, sum_dlt = 0;
  for (const Eigen::Vector3d& p : Points(400, 9)) {
    Eigen::Vector2d x0 = Normalized(tri.view0(), p), x1 = Normalized(tri.view1(), p);
    x0 += Eigen::Vector2d(noise(rng), noise(rng)) / tri.view0().focal_px;
    x1 += Eigen::Vector2d(noise(rng), noise(rng)) / tri.view1().focal_px;
    Eigen::Vector2d c0, c1;
    ASSERT_TRUE(tri.CorrectNiter2(x0, x1, &c0, &c1));
    EXPECT_LT(tri.EpipolarDistancePx(c0, c1), 1e-6);
    // Squared image residual (px^2) of a 3D point against the noisy observations.
    auto residual = [&](const Eigen::Vector3d& q) {
      return ((Normalized(tri.view0(), q) - x0) * tri.view0().focal_px).squaredNorm() +
             ((Normalized(tri.view1(), q) - x1) * tri.view1().focal_px).squaredNorm();
    };
    const double r_opt = residual(*tri.Optimal(x0, x1));
    const double r_mid = residual(*tri.Midpoint(x0, x1));
    const double r_dlt = residual(*tri.Dlt(x0, x1));
    // The optimal point has the smallest image residual (to second order: allow 1e-9 px^2).
    EXPECT_LE(r_opt, r_mid + 1e-9);
    EXPECT_LE(r_opt, r_dlt + 1e-9);
    sum_opt += r_opt;
    sum_mid += r_mid;
    sum_dlt += r_dlt;
  }
  EXPECT_LT(sum_opt, sum_mid);
  EXPECT_LT(sum_opt, sum_dlt);
}

TEST_F(TriangulationTest, WithNoisyObservationsOptimalIsNoWorseThanMidpointIn3D) {
  // Unequal focal lengths (camera 2730 px, projector 1850 px) are where midpoint, which weighs
  // angles, departs from the image-space optimum.
  const TwoViewTriangulator tri(View(rig_.cameras[0]), View(*rig_.projector));
  std::mt19937 rng(11);
  std::normal_distribution<double> noise(0.0, 0.3);
  double err_opt = 0, err_mid = 0, err_dlt = 0;
  const auto points = Points(4000, 12);
  for (const Eigen::Vector3d& p : points) {
    Eigen::Vector2d x0 = Normalized(tri.view0(), p), x1 = Normalized(tri.view1(), p);
    x0 += Eigen::Vector2d(noise(rng), noise(rng)) / tri.view0().focal_px;
    x1 += Eigen::Vector2d(noise(rng), noise(rng)) / tri.view1().focal_px;
    err_opt += (*tri.Optimal(x0, x1) - p).squaredNorm();
    err_mid += (*tri.Midpoint(x0, x1) - p).squaredNorm();
    err_dlt += (*tri.Dlt(x0, x1) - p).squaredNorm();
  }
  const double n = static_cast<double>(points.size());
  RecordProperty("rms_optimal_mm", std::to_string(std::sqrt(err_opt / n)));
  RecordProperty("rms_midpoint_mm", std::to_string(std::sqrt(err_mid / n)));
  EXPECT_LE(std::sqrt(err_opt / n), std::sqrt(err_mid / n) * 1.001);
  EXPECT_LE(std::sqrt(err_opt / n), std::sqrt(err_dlt / n) * 1.001);
}

TEST_F(TriangulationTest, EpipolarDistanceMeasuresTheOffsetAcrossTheLine) {
  const TwoViewTriangulator tri(View(rig_.cameras[0]), View(*rig_.projector));
  const Eigen::Vector3d p(10, -20, 500), q(10, -20, 650);  // same camera ray? no: build one below
  const Eigen::Vector2d x0 = Normalized(tri.view0(), p);
  // A second point on the camera ray through p: its projector image lies on the epipolar line.
  const Eigen::Vector3d ray = tri.view0().RayInRig(x0);
  const Eigen::Vector3d p2 = tri.view0().center_in_rig + ray * (650.0 / ray.z());
  const Eigen::Vector2d a = Normalized(tri.view1(), p) * tri.view1().focal_px;
  const Eigen::Vector2d b = Normalized(tri.view1(), p2) * tri.view1().focal_px;
  EXPECT_LT(tri.EpipolarDistancePx(x0, b / tri.view1().focal_px), 1e-6);
  const Eigen::Vector2d along = (b - a).normalized();
  const Eigen::Vector2d across(-along.y(), along.x());
  const Eigen::Vector2d moved = (a + 0.75 * across) / tri.view1().focal_px;
  EXPECT_NEAR(tri.EpipolarDistancePx(x0, moved), 0.75, 1e-6);
  (void)q;
}

TEST_F(TriangulationTest, RayAxisSolveIsExactAgainstTheDistortedProjector) {
  const RigDevice& cam = rig_.cameras[0];
  const RigDevice& proj = *rig_.projector;
  ASSERT_TRUE(proj.model.HasDistortion());
  const TriangulationView pv = View(proj);
  for (const Eigen::Vector3d& p : Points(300, 13)) {
    const auto pp = proj.model.Project(proj.cam_from_rig * p);
    ASSERT_TRUE(pp);
    const Eigen::Vector3d c = cam.CenterInRig();
    const Eigen::Vector3d ray = (p - c).normalized();
    for (int axis = 0; axis < 2; ++axis) {
      double sin_angle = -1;
      const auto q = TriangulateRayAxis(c, ray, proj.model, pv, axis, (*pp)[axis], &sin_angle);
      ASSERT_TRUE(q);
      EXPECT_LT((*q - p).norm(), 1e-6) << "axis " << axis;
      // sin_angle against a numerical gradient of the projector coordinate.
      Eigen::Vector3d grad;
      for (int k = 0; k < 3; ++k) {
        Eigen::Vector3d d = Eigen::Vector3d::Zero();
        d[k] = 1e-4;
        grad[k] = ((*proj.model.Project(proj.cam_from_rig * (p + d)))[axis] -
                   (*proj.model.Project(proj.cam_from_rig * (p - d)))[axis]) /
                  2e-4;
      }
      EXPECT_NEAR(sin_angle, std::abs(grad.normalized().dot(ray)), 1e-6);
    }
  }
}

TEST_F(TriangulationTest, RayAxisSolveRejectsRaysThatNeverReachTheCode) {
  const RigDevice& proj = *rig_.projector;
  const TriangulationView pv = View(proj);
  // A ray pointing away from everything the projector lights: behind the projector.
  const Eigen::Vector3d c = rig_.cameras[0].CenterInRig();
  EXPECT_FALSE(TriangulateRayAxis(c, Eigen::Vector3d(0, 0, -1), proj.model, pv, 0, 640.0));
}

}  // namespace
}  // namespace slshadow
