#include "reconstruct/stereo_matcher.h"

#include <algorithm>
#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "core/error.h"
#include "reconstruct/dense_grid.h"
#include "tests/reconstruct/analytic_scene.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

constexpr uint8_t kOk = static_cast<uint8_t>(RejectReason::kAccepted);

Rig SmallRig() {
  Rig rig = LoadRig(testing::SourceDir() / "config/demo/rig.yaml");
  for (auto& cam : rig.cameras) cam.model = testing::Downscaled(cam.model, 4);
  return rig;
}

TEST(StereoRectificationTest, RowsAreEpipolarLinesAndDisparityGivesDepth) {
  const Rig rig = SmallRig();
  const StereoRectification rect = ComputeStereoRectification(rig.cameras[0], rig.cameras[1]);
  const Eigen::Matrix3d& r = rect.rect_from_rig_rotation;
  EXPECT_LT((r * r.transpose() - Eigen::Matrix3d::Identity()).norm(), 1e-12);
  EXPECT_NEAR(r.determinant(), 1.0, 1e-12);
  EXPECT_NEAR(rect.baseline_mm, rig.BaselineMm(rig.cameras[0], rig.cameras[1]), 1e-9);
  const Rigid3d rect0 = rect.RectCamFromRig(0), rect1 = rect.RectCamFromRig(1);
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> xy(-100, 100), z(350, 800);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector3d p(xy(rng), xy(rng), z(rng));
    const Eigen::Vector3d a = rect0 * p, b = rect1 * p;
    const double ul = rect.focal_px * a.x() / a.z() + rect.cx[0],
                 vl = rect.focal_px * a.y() / a.z() + rect.cy;
    const double ur = rect.focal_px * b.x() / b.z() + rect.cx[1],
                 vr = rect.focal_px * b.y() / b.z() + rect.cy;
    EXPECT_NEAR(vl, vr, 1e-9);
    EXPECT_NEAR(a.z(), b.z(), 1e-9);
    EXPECT_NEAR((ul - rect.cx[0]) - (ur - rect.cx[1]), rect.focal_px * rect.baseline_mm / a.z(),
                1e-9);
  }
  // Each camera's image centre lies inside its rectified image.
  for (int c = 0; c < 2; ++c) {
    const RigDevice& cam = rig.cameras[static_cast<size_t>(c)];
    const auto xy_c =
        cam.model.UndistortToNormalized(Eigen::Vector2d(cam.model.cx(), cam.model.cy()));
    const Eigen::Vector3d ray = rect.rect_from_rig_rotation *
                                cam.cam_from_rig.rotation.conjugate() *
                                Eigen::Vector3d(xy_c->x(), xy_c->y(), 1.0);
    const double u = rect.focal_px * ray.x() / ray.z() + rect.cx[c];
    const double v = rect.focal_px * ray.y() / ray.z() + rect.cy;
    EXPECT_GT(u, 0);
    EXPECT_LT(u, rect.width[c] - 1);
    EXPECT_GT(v, 0);
    EXPECT_LT(v, rect.height - 1);
  }
}

TEST(StereoRectificationTest, CoincidentCentresThrow) {
  Rig rig = SmallRig();
  rig.cameras[1].cam_from_rig =
      Rigid3d(rig.cameras[1].cam_from_rig.rotation, Eigen::Vector3d::Zero());
  EXPECT_THROW(ComputeStereoRectification(rig.cameras[0], rig.cameras[1]), Error);
}

// The relative code-jump test (max_step_ratio): a jump of the projector column below the gate
// (3 times the plane's step between neighbouring pixels, < 4 px) is neither interpolated across
// with the test (no rectified cell takes a value in the jump's gap) nor kept from being so without
// it; on the smooth, tilted plane itself the test rejects no cell.
TEST(RectifyProjectorMapTest, CodeJumpBelowTheGateIsNotInterpolatedAcross) {
  // Cameras and projector 4x coarser: about 0.7 projector px between neighbouring pixels.
  Rig rig = SmallRig();
  rig.projector->model = testing::Downscaled(rig.projector->model, 4);
  const Eigen::Vector3d n = Eigen::Vector3d(0.3, 0.05, -1).normalized();
  const double d = n.dot(Eigen::Vector3d(0, 0, 500));
  const auto view = testing::RenderAnalytic(rig, rig.cameras[1], testing::Plane(n, d));
  const StereoRectification rect = ComputeStereoRectification(rig.cameras[0], rig.cameras[1]);
  const ProjectorMap& smooth = view.map;
  const int w = smooth.width(), h = smooth.height(), x_jump = w / 2;
  // The plane's column step between horizontal neighbours at the jump, its largest on any row.
  double step = 0;
  for (int y = 0; y < h; ++y) {
    const double a = smooth.proj_x.at<double>(y, x_jump - 1),
                 b = smooth.proj_x.at<double>(y, x_jump);
    if (std::isfinite(a) && std::isfinite(b)) step = std::max(step, std::abs(b - a));
  }
  ASSERT_GT(step, 0.5);
  const double jump = 3 * step;
  ASSERT_LT(step + jump, 4.0);
  ProjectorMap jumped = smooth;
  jumped.proj_x = smooth.proj_x.clone();
  for (int y = 0; y < h; ++y)
    for (int x = x_jump; x < w; ++x) jumped.proj_x.at<double>(y, x) += jump;
  const auto count_accepted = [](const RectifiedMap& m) {
    return std::count(m.reason.begin(), m.reason.end(), kOk);
  };
  // Cells whose column lies in the gap: between the last column left of the jump and the first
  // right of it, on the source row.
  const auto in_gap = [&](const RectifiedMap& m) {
    int64_t n_gap = 0;
    for (size_t i = 0; i < m.reason.size(); ++i) {
      if (m.reason[i] != kOk) continue;
      const int y = static_cast<int>(std::lround(m.source_v[i]));
      if (m.source_u[i] < x_jump - 1 || m.source_u[i] > x_jump || y < 0 || y >= h) continue;
      const double lo = jumped.proj_x.at<double>(y, x_jump - 1) + 0.1,
                   hi = jumped.proj_x.at<double>(y, x_jump) - 0.1;
      n_gap += m.proj_x[i] > std::min(lo, hi) && m.proj_x[i] < std::max(lo, hi) ? 1 : 0;
    }
    return n_gap;
  };
  const RectifiedMap off =
      RectifyProjectorMap(rect, 1, rig.cameras[1], jumped, 4.0, 0.0f, false, 0);
  const RectifiedMap on =
      RectifyProjectorMap(rect, 1, rig.cameras[1], jumped, 4.0, 0.0f, false, 2.5);
  EXPECT_GT(in_gap(off), 50);
  EXPECT_EQ(in_gap(on), 0);
  EXPECT_LT(count_accepted(on), count_accepted(off));
  // The smooth plane: the same cells with and without the test.
  const RectifiedMap plain_off =
      RectifyProjectorMap(rect, 1, rig.cameras[1], smooth, 4.0, 0.0f, false, 0);
  const RectifiedMap plain_on =
      RectifyProjectorMap(rect, 1, rig.cameras[1], smooth, 4.0, 0.0f, false, 2.5);
  EXPECT_EQ(plain_on.reason, plain_off.reason);
  EXPECT_GT(count_accepted(plain_on), 50000);
}

TEST(RectifyProjectorMapTest, ResampledCodesMatchTheAnalyticCodes) {
  const Rig rig = SmallRig();
  const Eigen::Vector3d n = Eigen::Vector3d(0.1, 0.05, -1).normalized();
  const double d = n.dot(Eigen::Vector3d(0, 0, 500));
  const auto view = testing::RenderAnalytic(rig, rig.cameras[1], testing::Plane(n, d));
  const StereoRectification rect = ComputeStereoRectification(rig.cameras[0], rig.cameras[1]);
  const RectifiedMap map = RectifyProjectorMap(rect, 1, rig.cameras[1], view.map, 4.0, 0.0f);
  ASSERT_EQ(map.width, rect.width[1]);
  ASSERT_EQ(map.height, rect.height);
  const Rigid3d rig_from_rect = rect.RectCamFromRig(1).Inverse();
  const RigDevice& proj = *rig.projector;
  int checked = 0;
  double worst = 0;
  std::vector<double> errors;
  for (int v = 0; v < map.height; ++v) {
    for (int u = 0; u < map.width; ++u) {
      const size_t i = map.Index(u, v);
      if (map.reason[i] != kOk) continue;
      const Eigen::Vector2d xy = rect.Normalized(1, u, v);
      const Eigen::Vector3d dir = rig_from_rect.rotation * Eigen::Vector3d(xy.x(), xy.y(), 1.0);
      const Eigen::Vector3d o = rig_from_rect.translation;
      const Eigen::Vector3d p = o + dir * ((d - n.dot(o)) / n.dot(dir));
      const Eigen::Vector2d code = *proj.model.Project(proj.cam_from_rig * p);
      const double e =
          std::max(std::abs(map.proj_x[i] - code.x()), std::abs(map.proj_y[i] - code.y()));
      worst = std::max(worst, e);
      errors.push_back(e);
      ++checked;
    }
  }
  EXPECT_GT(checked, 50000);
  // Bicubic interpolation of a smooth map between pixel centres (4x downscaled camera), bilinear
  // where the 4x4 block leaves the decoded region (its border: the worst cells).
  std::sort(errors.begin(), errors.end());
  const double p99 = errors[errors.size() * 99 / 100];
  EXPECT_LT(p99, 2e-4);    // measured 5.9e-5 px
  EXPECT_LT(worst, 2e-3);  // measured 2.8e-4 px
  RecordProperty("code_error_px_p99_max", std::to_string(p99) + " " + std::to_string(worst));
}

// Hand-made rectified maps of one row.
RectifiedMap Row(const std::vector<double>& values) {
  RectifiedMap m;
  m.width = static_cast<int>(values.size());
  m.height = 1;
  m.proj_x = values;
  m.proj_y.assign(values.size(), std::nan(""));
  m.quality.assign(values.size(), 1.0f);
  m.source_u.assign(values.size(), 0.0f);
  m.source_v.assign(values.size(), 0.0f);
  m.reason.assign(values.size(), kOk);
  for (size_t i = 0; i < values.size(); ++i) {
    if (!std::isfinite(values[i])) m.reason[i] = static_cast<uint8_t>(RejectReason::kNotDecoded);
  }
  return m;
}

StereoRectification RowRect(int width) {
  StereoRectification rect;
  rect.focal_px = 100;
  rect.height = 1;
  rect.width[0] = rect.width[1] = width;
  rect.cx[0] = rect.cx[1] = 0;
  return rect;
}

TEST(MatchRectifiedMapsTest, FindsTheSubPixelCrossingWithinTheDisparityRange) {
  const double nan = std::nan("");
  // Right row: code 10 + 0.5 k (monotone); left codes at various places.
  std::vector<double> right(20);
  for (int k = 0; k < 20; ++k) right[static_cast<size_t>(k)] = 10 + 0.5 * k;
  const RectifiedMap r = Row(right);
  const RectifiedMap l = Row({nan,  nan, nan, nan, nan, 12.25, 13.0, 30.0, nan, nan,
                              10.0, nan, nan, nan, nan, nan,   nan,  nan,  nan, nan});
  const StereoMatches m = MatchRectifiedMaps(RowRect(20), l, r, 0.0, 5.0, 4.0);
  EXPECT_NEAR(m.right_u[5], 4.5, 1e-12);  // 12.25 between samples 4 (12.0) and 5 (12.5)
  EXPECT_NEAR(m.right_u[6], 6.0, 1e-12);  // exactly on a sample shared by two segments: one match
  EXPECT_EQ(m.reason[6], kOk);
  EXPECT_EQ(m.reason[7], static_cast<uint8_t>(RejectReason::kNoMatch));  // code not on the row
  EXPECT_TRUE(std::isnan(m.right_u[7]));
  // Code 10 is at right sample 0: disparity 10 - 0 = 10 > 5, outside the range.
  EXPECT_EQ(m.reason[10], static_cast<uint8_t>(RejectReason::kNoMatch));
  const StereoMatches wider = MatchRectifiedMaps(RowRect(20), l, r, 0.0, 10.0, 4.0);
  EXPECT_NEAR(wider.right_u[10], 0.0, 1e-12);
}

TEST(MatchRectifiedMapsTest, DisparityRangeAmbiguityAndCodeJumps) {
  const double nan = std::nan("");
  // Non-monotone right row: code 12.5 appears twice (k = 2.5 and k = 7.5).
  const RectifiedMap r = Row({10, 11, 12, 13, 14, 15, 14, 13, 12, 11, 40, 41});
  const RectifiedMap l = Row({nan, nan, nan, nan, nan, nan, nan, nan, 12.5, nan, nan, 40.5});
  const auto rect = RowRect(12);
  const StereoMatches wide = MatchRectifiedMaps(rect, l, r, 0.0, 100.0, 4.0);
  EXPECT_EQ(wide.reason[8], static_cast<uint8_t>(RejectReason::kAmbiguousMatch));
  EXPECT_NEAR(wide.right_u[11], 10.5, 1e-12);
  // A disparity window that keeps only one of the two.
  const StereoMatches window = MatchRectifiedMaps(rect, l, r, 0.0, 1.0, 4.0);
  EXPECT_EQ(window.reason[8], kOk);
  EXPECT_NEAR(window.right_u[8], 7.5, 1e-12);
  // Code 25 lies in the jump 11 -> 40 between samples 9 and 10: never bridged.
  const RectifiedMap l2 = Row({nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, 25.0, nan});
  const StereoMatches jump = MatchRectifiedMaps(rect, l2, r, -100.0, 100.0, 4.0);
  EXPECT_EQ(jump.reason[10], static_cast<uint8_t>(RejectReason::kNoMatch));
  const StereoMatches bridged = MatchRectifiedMaps(rect, l2, r, -100.0, 100.0, 100.0);
  EXPECT_EQ(bridged.reason[10], kOk);
}

// A cubic code along the row: 4-point interpolation reproduces it exactly; near the ends, next to
// invalid samples and across code jumps it falls back to linear between the 2 around u.
double CubicCode(double k) { return 10 + 0.5 * k + 0.02 * k * k - 0.001 * k * k * k; }

TEST(InterpolateRowTest, CubicInsideLinearAtEndsAndJumps) {
  std::vector<double> row(12);
  for (int k = 0; k < 12; ++k) row[static_cast<size_t>(k)] = CubicCode(k);
  for (double u : {1.0, 1.25, 4.5, 7.9, 9.999})
    EXPECT_NEAR(InterpolateRow(row.data(), 12, u, 4.0), CubicCode(u), 1e-12) << u;
  // First and last segments: linear.
  EXPECT_NEAR(InterpolateRow(row.data(), 12, 0.5, 4.0), 0.5 * (row[0] + row[1]), 1e-12);
  EXPECT_NEAR(InterpolateRow(row.data(), 12, 10.5, 4.0), 0.5 * (row[10] + row[11]), 1e-12);
  EXPECT_TRUE(std::isnan(InterpolateRow(row.data(), 12, -0.1, 4.0)));
  EXPECT_TRUE(std::isnan(InterpolateRow(row.data(), 12, 11.1, 4.0)));
  // An invalid or a jumping outer sample: linear between the inner two.
  std::vector<double> holes = row;
  holes[3] = std::nan("");
  EXPECT_NEAR(InterpolateRow(holes.data(), 12, 4.5, 4.0), 0.5 * (row[4] + row[5]), 1e-12);
  std::vector<double> jump = row;
  jump[6] += 50;
  EXPECT_NEAR(InterpolateRow(jump.data(), 12, 4.5, 4.0), 0.5 * (row[4] + row[5]), 1e-12);
  EXPECT_TRUE(std::isnan(InterpolateRow(holes.data(), 12, 2.5, 4.0)));  // sample 3 itself missing
}

TEST(MatchRectifiedMapsTest, CubicCodesAreMatchedExactly) {
  const double nan = std::nan("");
  std::vector<double> right(30);
  for (int k = 0; k < 30; ++k)
    right[static_cast<size_t>(k)] = CubicCode(k);  // increasing up to k ~ 24
  const RectifiedMap r = Row(right);
  std::vector<double> left_codes(30, nan);
  std::vector<double> truth(30, nan);
  for (int u = 3; u < 20; u += 2) {
    truth[static_cast<size_t>(u)] = u - 1.0 + 0.37 * (u % 3);  // disparity in [1, 1.74]
    left_codes[static_cast<size_t>(u)] = CubicCode(truth[static_cast<size_t>(u)]);
  }
  const StereoMatches m = MatchRectifiedMaps(RowRect(30), Row(left_codes), r, 0.0, 5.0, 4.0);
  double worst_linear = 0;
  for (int u = 3; u < 20; u += 2) {
    const size_t i = static_cast<size_t>(u);
    ASSERT_EQ(m.reason[i], kOk) << u;
    EXPECT_NEAR(m.right_u[i], truth[i], 1e-12) << u;
    // What linear interpolation between the 2 samples gives (the matcher before the cubic step).
    const int k = static_cast<int>(truth[i]);
    const double linear =
        k + (left_codes[i] - right[static_cast<size_t>(k)]) /
                (right[static_cast<size_t>(k) + 1] - right[static_cast<size_t>(k)]);
    worst_linear = std::max(worst_linear, std::abs(linear - truth[i]));
  }
  EXPECT_GT(worst_linear, 1e-3);  // the test would catch a linear matcher
}

}  // namespace
}  // namespace slshadow
