#include "reconstruct/dense_grid.h"

#include <algorithm>
#include <set>
#include <string>

#include <gtest/gtest.h>

namespace slshadow {
namespace {

TEST(DenseGridTest, ReasonNamesAreDistinct) {
  std::set<std::string> names;
  for (int r = 0; r < kNumRejectReasons; ++r) names.insert(ToString(static_cast<RejectReason>(r)));
  EXPECT_EQ(names.size(), static_cast<size_t>(kNumRejectReasons));
  EXPECT_EQ(names.count("unknown"), 0u);
}

TEST(DenseGridTest, CloudHoldsExactlyTheAcceptedCellsWithTheirFields) {
  DenseGrid grid;
  grid.Allocate(4, 3);
  EXPECT_EQ(grid.CountByReason()[static_cast<size_t>(RejectReason::kNotDecoded)], 12);
  std::vector<Eigen::Vector3f> normals(12, Eigen::Vector3f::Zero());
  for (int v = 0; v < 3; ++v) {
    for (int u = 0; u < 4; ++u) {
      const size_t i = grid.Index(u, v);
      grid.source_u[i] = static_cast<float>(u);
      grid.source_v[i] = static_cast<float>(v);
      if ((u + v) % 2 == 0) {
        grid.reason[i] = static_cast<uint8_t>(RejectReason::kAccepted);
        grid.point_in_rig[i] = Eigen::Vector3d(u, v, 100 + u);
        grid.quality[i] = static_cast<float>(10 * u + v);
        grid.reprojection_error_px[i] = 0.1f * static_cast<float>(u);
        normals[i] = Eigen::Vector3f(0, 0, -1);
      } else {
        grid.reason[i] = static_cast<uint8_t>(RejectReason::kOutlier);
      }
    }
  }
  const auto counts = grid.CountByReason();
  EXPECT_EQ(counts[0], 6);
  EXPECT_EQ(counts[static_cast<size_t>(RejectReason::kOutlier)], 6);
  const PointCloud cloud = grid.ToPointCloud(&normals);
  ASSERT_EQ(cloud.size(), 6u);
  EXPECT_NO_THROW(cloud.Check("grid"));
  ASSERT_TRUE(cloud.HasNormals());
  const auto* u = cloud.Scalar("u");
  const auto* v = cloud.Scalar("v");
  const auto* q = cloud.Scalar("quality");
  ASSERT_TRUE(u && v && q && cloud.Scalar("reprojection_error_px"));
  for (size_t k = 0; k < cloud.size(); ++k) {
    EXPECT_EQ((static_cast<int>((*u)[k]) + static_cast<int>((*v)[k])) % 2, 0);
    EXPECT_EQ(cloud.points[k], Eigen::Vector3d((*u)[k], (*v)[k], 100 + (*u)[k]));
    EXPECT_EQ((*q)[k], 10 * (*u)[k] + (*v)[k]);
  }
  EXPECT_FALSE(grid.ToPointCloud().HasNormals());
}

// ToPointCloud(normals, max_points) is the whole cloud's every s-th point (s = ceil(accepted /
// max_points)): the same points, normals and scalar fields as PointCloud::Select would keep.
TEST(DenseGridTest, CappedCloudIsEverySthPointOfTheWholeCloud) {
  DenseGrid grid;
  const int w = 37, h = 23;
  grid.Allocate(w, h);
  std::vector<Eigen::Vector3f> normals(static_cast<size_t>(w * h), Eigen::Vector3f::Zero());
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      const size_t i = grid.Index(u, v);
      if ((u * 7 + v * 3) % 5 == 0) continue;  // rejected cells scattered over the rows
      grid.reason[i] = static_cast<uint8_t>(RejectReason::kAccepted);
      grid.point_in_rig[i] = Eigen::Vector3d(u, v, 0.5 * u * v);
      grid.quality[i] = static_cast<float>(u + 100 * v);
      grid.source_u[i] = static_cast<float>(u);
      grid.source_v[i] = static_cast<float>(v);
      grid.reprojection_error_px[i] = 0.01f * static_cast<float>(u * v);
      normals[i] = Eigen::Vector3f(static_cast<float>(u), static_cast<float>(v), 1).normalized();
    }
  }
  const PointCloud whole = grid.ToPointCloud(&normals);
  for (size_t max_points : {size_t{1}, size_t{7}, size_t{100}, size_t{339}, whole.size() - 1,
                            whole.size(), whole.size() + 5}) {
    const size_t stride = std::max<size_t>(1, (whole.size() + max_points - 1) / max_points);
    std::vector<bool> keep(whole.size(), false);
    for (size_t i = 0; i < whole.size(); i += stride) keep[i] = true;
    const PointCloud expected = whole.Select(keep);
    const PointCloud capped = grid.ToPointCloud(&normals, max_points);
    ASSERT_EQ(capped.size(), expected.size()) << max_points;
    EXPECT_LE(capped.size(), max_points);
    EXPECT_EQ(capped.points, expected.points) << max_points;
    EXPECT_EQ(capped.normals, expected.normals) << max_points;
    for (const char* field : {"quality", "u", "v", "reprojection_error_px"})
      EXPECT_EQ(*capped.Scalar(field), *expected.Scalar(field)) << field << " " << max_points;
  }
}

}  // namespace
}  // namespace slshadow
