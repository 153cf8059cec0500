#include "reconstruct/ray_cache.h"

#include <random>

#include <gtest/gtest.h>

#include "core/rig.h"
#include "tests/reconstruct/analytic_scene.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

CameraModel SmallDemoCamera() {
  const Rig rig = LoadRig(testing::SourceDir() / "config/demo/rig.yaml");
  return testing::Downscaled(rig.cameras[0].model, 8);
}

TEST(RayCacheTest, GridEqualsPerPixelUndistortion) {
  const CameraModel model = SmallDemoCamera();
  const RayGrid grid = ComputeRayGrid(model);
  ASSERT_EQ(grid.width, model.width);
  ASSERT_EQ(grid.height, model.height);
  for (int v = 0; v < model.height; ++v) {
    for (int u = 0; u < model.width; ++u) {
      const auto xy = model.UndistortToNormalized(Eigen::Vector2d(u, v));
      ASSERT_TRUE(xy);
      ASSERT_LT((grid.at(u, v) - *xy).norm(), 1e-12);  // both converged to the Newton tolerance
      // And the ray projects back onto the pixel.
      const auto back = model.Project(Eigen::Vector3d(xy->x(), xy->y(), 1.0));
      ASSERT_LT((*back - Eigen::Vector2d(u, v)).norm(), 1e-9);
    }
  }
}

TEST(RayCacheTest, UndistortWithGridAgreesWithThePlainIterationAnywhere) {
  const Rig rig = LoadRig(testing::SourceDir() / "config/demo/rig.yaml");
  const CameraModel& model = rig.projector->model;
  const RayGrid grid = ComputeRayGrid(model);
  std::mt19937 rng(6);
  std::uniform_real_distribution<double> x(-3, model.width + 2), y(-3, model.height + 2);
  for (int i = 0; i < 20000; ++i) {
    const Eigen::Vector2d pixel(x(rng), y(rng));  // includes positions outside the grid
    const auto fast = UndistortWithGrid(model, grid, pixel);
    const auto plain = model.UndistortToNormalized(pixel);
    ASSERT_EQ(fast.has_value(), plain.has_value());
    if (fast) {
      ASSERT_LT((*fast - *plain).norm(), 1e-12) << pixel.transpose();
    }
  }
  // The warm start only changes the start: a point past the fold is still refused.
  CameraModel folded(200, 200, 100, 100, 99.5, 99.5, -0.6);
  EXPECT_FALSE(UndistortFrom(folded, Eigen::Vector2d(0, 0), Eigen::Vector2d(-0.9, -0.9)));
}

TEST(RayCacheTest, PixelsPastTheFoldOfTheDistortionAreNaN) {
  // Strong barrel distortion: the model folds over before the image corners.
  CameraModel model(200, 200, 100, 100, 99.5, 99.5, -0.6);
  const RayGrid grid = ComputeRayGrid(model);
  EXPECT_TRUE(grid.Valid(100, 100));
  EXPECT_FALSE(grid.Valid(0, 0));
  int invalid = 0;
  for (int v = 0; v < 200; ++v) {
    for (int u = 0; u < 200; ++u) {
      const bool expected = model.UndistortToNormalized(Eigen::Vector2d(u, v)).has_value();
      ASSERT_EQ(grid.Valid(u, v), expected);
      invalid += expected ? 0 : 1;
    }
  }
  EXPECT_GT(invalid, 0);
}

TEST(RayCacheTest, CacheSharesGridsPerModelAndEvictsTheOldest) {
  ClearRayCache();
  const CameraModel model = SmallDemoCamera();
  const auto a = CachedRayGrid(model);
  const auto b = CachedRayGrid(model);
  EXPECT_EQ(a.get(), b.get());
  EXPECT_EQ(RayCacheSize(), 1u);
  CameraModel changed = model;
  changed.params[CameraModel::kK1] += 1e-12;  // any change of a parameter is another model
  const auto c = CachedRayGrid(changed);
  EXPECT_NE(a.get(), c.get());
  EXPECT_EQ(RayCacheSize(), 2u);
  for (int i = 0; i < kMaxCachedRayGrids + 3; ++i) {
    CameraModel m = model;
    m.params[CameraModel::kCx] += i + 1;
    CachedRayGrid(m);
  }
  EXPECT_EQ(RayCacheSize(), static_cast<size_t>(kMaxCachedRayGrids));
  // `a` was evicted from the cache but stays alive with its owner; a new request recomputes it.
  const auto d = CachedRayGrid(model);
  EXPECT_NE(a.get(), d.get());
  EXPECT_EQ(a->xy, d->xy);
  ClearRayCache();
  EXPECT_EQ(RayCacheSize(), 0u);
}

}  // namespace
}  // namespace slshadow
