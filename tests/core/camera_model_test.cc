#include "core/camera_model.h"

#include <random>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>

#include "core/error.h"

namespace slshadow {
namespace {

CameraModel NoDistortion() { return CameraModel(1920, 1200, 2730, 2725, 963.4, 597.8); }
CameraModel MildDistortion() {
  return CameraModel(1920, 1200, 2730, 2730, 963.4, 597.8, -0.0821, 0.1234, 0.00021, -0.00013, 0.0);
}
// Strong barrel distortion of a short lens (as from cv::calibrateCamera on a 4 mm lens).
CameraModel StrongDistortion() {
  return CameraModel(640, 480, 535.9, 535.9, 342.3, 235.6, -0.26637, -0.03859, 0.0017832,
                     -0.00028122, 0.23839);
}

void ExpectRoundTripOverImage(const CameraModel& model, double tolerance_px) {
  int checked = 0;
  for (double y = -0.5; y <= model.height - 0.5; y += model.height / 37.0) {
    for (double x = -0.5; x <= model.width - 0.5; x += model.width / 53.0) {
      const Eigen::Vector2d pixel(x, y);
      const auto ray = model.Unproject(pixel);
      ASSERT_TRUE(ray.has_value()) << "pixel " << x << ", " << y;
      EXPECT_NEAR(ray->norm(), 1.0, 1e-12);
      const auto back = model.Project(*ray * 731.0);
      ASSERT_TRUE(back.has_value());
      EXPECT_NEAR((*back - pixel).norm(), 0.0, tolerance_px) << "pixel " << x << ", " << y;
      ++checked;
    }
  }
  // The four extreme corners too.
  for (const Eigen::Vector2d& corner :
       {Eigen::Vector2d(-0.5, -0.5), Eigen::Vector2d(model.width - 0.5, -0.5),
        Eigen::Vector2d(-0.5, model.height - 0.5),
        Eigen::Vector2d(model.width - 0.5, model.height - 0.5)}) {
    const auto ray = model.Unproject(corner);
    ASSERT_TRUE(ray.has_value());
    EXPECT_NEAR((*model.Project(*ray) - corner).norm(), 0.0, tolerance_px);
    ++checked;
  }
  EXPECT_GT(checked, 1900);
}

TEST(CameraModel, RoundTripWithoutDistortion) { ExpectRoundTripOverImage(NoDistortion(), 1e-9); }
TEST(CameraModel, RoundTripWithMildDistortion) { ExpectRoundTripOverImage(MildDistortion(), 1e-9); }
TEST(CameraModel, RoundTripWithStrongDistortion) {
  ExpectRoundTripOverImage(StrongDistortion(), 1e-9);
}

TEST(CameraModel, ProjectAgreesWithOpenCv) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> xy(-0.6, 0.6), z(100, 2000);
  for (const CameraModel& model : {NoDistortion(), MildDistortion(), StrongDistortion()}) {
    std::vector<cv::Point3d> points;
    for (int i = 0; i < 500; ++i) {
      const double d = z(rng);
      points.emplace_back(xy(rng) * d, xy(rng) * d, d);
    }
    const cv::Matx33d k(model.fx(), 0, model.cx(), 0, model.fy(), model.cy(), 0, 0, 1);
    const std::vector<double> dist(model.params.begin() + 4, model.params.end());
    std::vector<cv::Point2d> expected;
    cv::projectPoints(points, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), k, dist, expected);
    for (size_t i = 0; i < points.size(); ++i) {
      const auto pixel = model.Project({points[i].x, points[i].y, points[i].z});
      ASSERT_TRUE(pixel.has_value());
      EXPECT_NEAR(pixel->x(), expected[i].x, 1e-9);
      EXPECT_NEAR(pixel->y(), expected[i].y, 1e-9);
    }
  }
}

TEST(CameraModel, PointsBehindTheCameraDoNotProject) {
  EXPECT_FALSE(MildDistortion().Project({0.1, 0.2, -5}).has_value());
  EXPECT_FALSE(MildDistortion().Project({0.1, 0.2, 0}).has_value());
}

TEST(CameraModel, NonConvergenceIsReportedNotHidden) {
  // k1 > 0 with a strong k2 < 0: the distortion folds over a short way off-axis, so pixels far
  // out are images of no point in front of the lens.
  const CameraModel folding(1000, 1000, 500, 500, 500, 500, 0.0, -0.5, 0, 0, 0);
  EXPECT_TRUE(folding.Unproject({500, 500}).has_value());
  EXPECT_FALSE(folding.Unproject({-3000, -3000}).has_value());
  EXPECT_FALSE(folding.UndistortToNormalized({1e6, 0}).has_value());
  // Too few iterations for a strongly distorted corner: reported as failure.
  EXPECT_FALSE(StrongDistortion().UndistortToNormalized({-0.5, -0.5}, 1).has_value());
}

TEST(CameraModel, TemplatedProjectionMatchesDoubleVersion) {
  const CameraModel model = StrongDistortion();
  const double point[3] = {12.0, -7.0, 40.0};
  double pixel[2];
  CameraModel::ImgFromCam(model.params.data(), point, pixel);
  const auto expected = model.Project({12.0, -7.0, 40.0});
  EXPECT_EQ(pixel[0], expected->x());
  EXPECT_EQ(pixel[1], expected->y());
}

TEST(CameraModel, CheckRejectsBadParameters) {
  CameraModel m = MildDistortion();
  EXPECT_NO_THROW(m.Check("test"));
  m.params[CameraModel::kFx] = -3;
  EXPECT_THROW(m.Check("test"), Error);
  m = MildDistortion();
  m.params[CameraModel::kK2] = std::nan("");
  try {
    m.Check("rig.yaml: cameras[0]");
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("rig.yaml: cameras[0]: k2"), std::string::npos)
        << e.what();
  }
  m = MildDistortion();
  m.width = 0;
  EXPECT_THROW(m.Check("test"), Error);
}

TEST(CameraModel, FieldOfViewOfPinhole) {
  const CameraModel m(1000, 500, 500, 500, 499.5, 249.5);
  EXPECT_NEAR(m.HorizontalFovRad(), 2 * std::atan(1.0), 1e-12);
  EXPECT_NEAR(m.VerticalFovRad(), 2 * std::atan(0.5), 1e-12);
}

}  // namespace
}  // namespace slshadow
