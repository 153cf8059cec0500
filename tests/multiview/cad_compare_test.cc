#include "workflows/multiview/cad_compare.h"

#include <gtest/gtest.h>

#include <random>

#include "compare/compare.h"
#include "core/error.h"
#include "core/mesh.h"
#include "sim/shapes.h"
#include "tests/multiview/multiview_test_util.h"
#include "tests/testing/error_of.h"
#include "tests/testing/temp_dir.h"
#include "workflows/multiview/turntable_scene.h"

namespace slshadow::multiview {
namespace {

// The occlusion part on the demo's turntable, in the part frame (the rig frame at angle 0).
struct OcclusionSetup {
  Rig rig;
  TriangleMesh cad;
};

OcclusionSetup MakeOcclusionSetup() {
  Scene scene = pipeline::LoadSceneOrDemo("");
  scene.objects[0].mesh = std::make_shared<const TriangleMesh>(MakeOcclusionPart(2.0));
  const TurntableSetup setup = MakeTurntableSetup(pipeline::LoadRigOrDemo(""), scene);
  return {setup.rig, PartSurface(setup.scene)};
}

// Dense random points exactly on the mesh (area-uniform), moved `offset_mm` along the normals.
PointCloud SurfaceCloud(const TriangleMesh& mesh, size_t n, double offset_mm) {
  const compare::Reference r = compare::ReferenceFromMesh(mesh, "cad", n);
  PointCloud cloud;
  for (size_t i = 0; i < r.cloud.size(); ++i)
    cloud.points.push_back(r.cloud.points[i] + offset_mm * r.cloud.normals[i].cast<double>());
  return cloud;
}

std::vector<CadView> TableViews(const Rig& rig, int count, const PointCloud* cloud_in_part) {
  std::vector<CadView> views;
  for (int i = 0; i < count; ++i) {
    const Rigid3d part_from_rig = rig.turntable->RigFromTableTurn(360.0 * i / count).Inverse();
    std::string name = "v";  // (not "v" + ...: GCC 12's false -Wrestrict once inlined)
    name += std::to_string(i);
    views.push_back(CadView{name, part_from_rig, nullptr});
  }
  (void)cloud_in_part;
  return views;
}

// Share of the samples in `region` (a predicate on the sample point, part's object frame) that
// have `reason`.
template <typename Region>
double ShareWithReason(const CadComparison& c, const Rigid3d& object_from_part, Region region,
                       CoverageReason reason, size_t* count = nullptr) {
  size_t in = 0, with = 0;
  for (size_t i = 0; i < c.sample_points.size(); ++i) {
    if (!region(object_from_part * c.sample_points[i])) continue;
    ++in;
    with += c.sample_reason[i] == static_cast<uint8_t>(reason);
  }
  if (count) *count = in;
  return in ? static_cast<double>(with) / static_cast<double>(in) : 0.0;
}

TEST(CadCompareTest, ExactCloudCoversEverythingWithZeroDeviationAndSignIsOutward) {
  const OcclusionSetup s = MakeOcclusionSetup();
  CadCompareOptions options;
  options.samples = 20000;
  options.coverage_radius_mm = 1.5;  // the random cloud leaves no hole that large
  for (const double offset : {0.0, 0.1, -0.1}) {
    const PointCloud cloud = SurfaceCloud(s.cad, 400000, offset);
    const std::vector<CadView> views = TableViews(s.rig, 4, nullptr);
    const CadComparison c = CompareWithCad(s.cad, s.rig, ReconstructMode::kStereo, views, cloud,
                                           s.rig.turntable, options);
    // Exact but for points offset near an edge, which lie closer to the neighbouring face.
    EXPECT_NEAR(c.merged_c2m.signed_mean_mm, offset, 0.003) << offset;
    EXPECT_NEAR(c.merged_c2m.rms_mm, std::abs(offset), 0.003) << offset;
    EXPECT_LE(c.merged_c2m.max_mm, std::abs(offset) + 1e-9) << offset;
    // Every sample is covered but those on the table.
    EXPECT_EQ(c.reason_samples[static_cast<size_t>(CoverageReason::kCovered)] +
                  c.reason_samples[static_cast<size_t>(CoverageReason::kOnTable)],
              c.samples);
    EXPECT_DOUBLE_EQ(c.coverage_reachable, 1.0);
    EXPECT_DOUBLE_EQ(c.coverage_total, 1.0);
    // The base (120 x 80 mm) is the table face.
    EXPECT_NEAR(c.reason_area_mm2[static_cast<size_t>(CoverageReason::kOnTable)], 120.0 * 80.0,
                0.05 * 120 * 80);
    // Painted vertices carry the offset.
    size_t painted = 0, near_offset = 0;
    for (const float d : c.vertex_deviation_mm) {
      if (!std::isfinite(d)) continue;
      ++painted;
      near_offset += std::abs(d - offset) < 0.02;
    }
    EXPECT_EQ(painted, c.vertex_deviation_mm.size()) << "every vertex has points around it";
    EXPECT_GT(near_offset, painted * 8 / 10) << offset;
  }
}

TEST(CadCompareTest, UncoveredSurfaceIsNamedByItsReason) {
  const OcclusionSetup s = MakeOcclusionSetup();
  // A cloud covering nothing of the part (far away): every off-table sample is uncovered, and
  // its reason comes from the geometry alone.
  PointCloud far;
  far.points = {Eigen::Vector3d(0, 0, 5000), Eigen::Vector3d(1, 0, 5000)};
  CadCompareOptions options;
  options.samples = 40000;
  const Rigid3d part_from_object = pipeline::LoadSceneOrDemo("").objects[0].rig_from_object;
  const Rigid3d object_from_part = part_from_object.Inverse();
  const auto hole_bottom = [](const Eigen::Vector3d& p) {
    return std::abs(p.z() - 10) < 0.01 && p.x() > -39 && p.x() < -31 && std::abs(p.y()) < 4;
  };
  const auto overhang_underside = [](const Eigen::Vector3d& p) {
    return std::abs(p.z() - 50) < 0.01 && p.x() > -9 && p.x() < 29 && std::abs(p.y()) < 39;
  };
  const auto tower_top = [](const Eigen::Vector3d& p) {
    return std::abs(p.z() - 60) < 0.01 && p.x() > -59 && p.x() < 29 && std::abs(p.y()) > 6;
  };
  for (const int n : {1, 12}) {
    const CadComparison c =
        CompareWithCad(s.cad, s.rig, ReconstructMode::kStereo, TableViews(s.rig, n, nullptr), far,
                       s.rig.turntable, options);
    EXPECT_EQ(c.reason_samples[static_cast<size_t>(CoverageReason::kCovered)], 0u);
    size_t count = 0;
    // The hole's bottom, 50 mm down a 10 mm hole: hidden from some device in every view.
    EXPECT_EQ(ShareWithReason(c, object_from_part, hole_bottom, CoverageReason::kOccluded, &count),
              1.0)
        << n << " views";
    EXPECT_GT(count, 3u);
    // The overhang's underside faces the table: no view sees it.
    EXPECT_EQ(
        ShareWithReason(c, object_from_part, overhang_underside, CoverageReason::kOccluded, &count),
        1.0)
        << n << " views";
    EXPECT_GT(count, 100u);
    // The top faces are reachable: not reconstructed (the cloud is elsewhere).
    EXPECT_GT(
        ShareWithReason(c, object_from_part, tower_top, CoverageReason::kNotReconstructed, &count),
        0.99)
        << n << " views";
    EXPECT_DOUBLE_EQ(c.coverage_reachable, 0.0);
  }
  // More views reach more of the part.
  const CadComparison one =
      CompareWithCad(s.cad, s.rig, ReconstructMode::kStereo, TableViews(s.rig, 1, nullptr), far,
                     s.rig.turntable, options);
  const CadComparison twelve =
      CompareWithCad(s.cad, s.rig, ReconstructMode::kStereo, TableViews(s.rig, 12, nullptr), far,
                     s.rig.turntable, options);
  EXPECT_GT(twelve.reachable_share, one.reachable_share + 0.05);
  // Outside the field: cameras too narrow to see the whole part.
  Rig narrow = s.rig;
  for (RigDevice& c : narrow.cameras) {
    c.model.width = 400;
    c.model.params[CameraModel::kCx] = 200;
  }
  const CadComparison cut =
      CompareWithCad(s.cad, narrow, ReconstructMode::kStereo, TableViews(narrow, 1, nullptr), far,
                     narrow.turntable, options);
  EXPECT_GT(cut.reason_samples[static_cast<size_t>(CoverageReason::kOutsideField)],
            cut.samples / 10);
}

// too_dark is measured, not guessed: a reachable, uncovered sample is too dark when every view
// that sees it recorded the decoder's dark pixels and a camera's pixel under it is dark there.
TEST(CadCompareTest, TooDarkWhereEveryViewThatSeesItHasADarkPixelThere) {
  const OcclusionSetup s = MakeOcclusionSetup();
  PointCloud far;
  far.points = {Eigen::Vector3d(0, 0, 5000), Eigen::Vector3d(1, 0, 5000)};
  CadCompareOptions options;
  options.samples = 20000;
  const auto at = [](const CadComparison& c, CoverageReason r) {
    return c.reason_samples[static_cast<size_t>(r)];
  };
  // Every camera pixel dark (all_dark) or none (all_lit), for the stereo mode's two cameras.
  const auto masks = [&](uint8_t value) {
    std::vector<DarkPixels> m;
    for (size_t k = 0; k < 2; ++k) {
      const RigDevice& cam = s.rig.cameras[k];
      m.push_back(DarkPixels{cam.name, cam.model.width, cam.model.height,
                             std::vector<uint8_t>(static_cast<size_t>(cam.model.width) *
                                                      static_cast<size_t>(cam.model.height),
                                                  value)});
    }
    return m;
  };
  const std::vector<DarkPixels> all_dark = masks(1), all_lit = masks(0);
  std::vector<CadView> views = TableViews(s.rig, 4, nullptr);
  const CadComparison plain =
      CompareWithCad(s.cad, s.rig, ReconstructMode::kStereo, views, far, s.rig.turntable, options);
  const size_t reachable = at(plain, CoverageReason::kNotReconstructed);
  ASSERT_GT(reachable, 1000u);
  EXPECT_EQ(at(plain, CoverageReason::kTooDark), 0u);  // no record: nothing is called too dark

  for (CadView& v : views) v.dark = &all_lit;
  const CadComparison lit =
      CompareWithCad(s.cad, s.rig, ReconstructMode::kStereo, views, far, s.rig.turntable, options);
  EXPECT_EQ(at(lit, CoverageReason::kTooDark), 0u);
  EXPECT_EQ(at(lit, CoverageReason::kNotReconstructed), reachable);

  for (CadView& v : views) v.dark = &all_dark;
  const CadComparison dark =
      CompareWithCad(s.cad, s.rig, ReconstructMode::kStereo, views, far, s.rig.turntable, options);
  EXPECT_EQ(at(dark, CoverageReason::kTooDark), reachable);
  EXPECT_EQ(at(dark, CoverageReason::kNotReconstructed), 0u);
  EXPECT_DOUBLE_EQ(dark.reachable_share, plain.reachable_share);  // still reachable
  for (const CoverageReason r : {CoverageReason::kGrazing, CoverageReason::kOccluded,
                                 CoverageReason::kOutsideField, CoverageReason::kOnTable})
    EXPECT_EQ(at(dark, r), at(plain, r)) << ToString(r);

  // View 0 lit where the others are dark: what view 0 sees is not too dark, the rest is. The
  // oracle for "what view 0 sees": the comparison of view 0 alone.
  views[0].dark = &all_lit;
  const CadComparison mixed =
      CompareWithCad(s.cad, s.rig, ReconstructMode::kStereo, views, far, s.rig.turntable, options);
  const CadComparison only0 = CompareWithCad(s.cad, s.rig, ReconstructMode::kStereo, {views[0]},
                                             far, s.rig.turntable, options);
  const size_t seen_by_0 = at(only0, CoverageReason::kNotReconstructed);
  EXPECT_GT(seen_by_0, 100u);
  EXPECT_LT(seen_by_0, reachable);
  EXPECT_EQ(at(mixed, CoverageReason::kNotReconstructed), seen_by_0);
  EXPECT_EQ(at(mixed, CoverageReason::kTooDark), reachable - seen_by_0);
  for (size_t i = 0; i < mixed.samples; ++i) {
    if (only0.sample_reason[i] == static_cast<uint8_t>(CoverageReason::kNotReconstructed)) {
      ASSERT_EQ(mixed.sample_reason[i], static_cast<uint8_t>(CoverageReason::kNotReconstructed));
    }
  }
  // A view without a record can tell nothing: the same as lit.
  views[0].dark = nullptr;
  const CadComparison unknown =
      CompareWithCad(s.cad, s.rig, ReconstructMode::kStereo, views, far, s.rig.turntable, options);
  EXPECT_EQ(unknown.sample_reason, mixed.sample_reason);
  EXPECT_NE(dark.Summary().find("too_dark"), std::string::npos);
  EXPECT_TRUE(dark.ToJson()["surface_by_reason"].contains("too_dark"));
}

TEST(CadCompareTest, DarkPixelsFromTheDecodersStatus) {
  cv::Mat status(2, 3, CV_8UC1, cv::Scalar(static_cast<int>(PixelStatus::kValid)));
  status.at<uint8_t>(0, 1) = static_cast<uint8_t>(PixelStatus::kShadow);
  status.at<uint8_t>(1, 2) = static_cast<uint8_t>(PixelStatus::kLowContrast);
  status.at<uint8_t>(1, 0) = static_cast<uint8_t>(PixelStatus::kSaturated);
  const DarkPixels d = DarkPixels::FromStatus("left", status);
  EXPECT_EQ(d.dark, (std::vector<uint8_t>{0, 1, 0, 0, 0, 1}));
  EXPECT_TRUE(d.At({1.4, 0.2}));   // nearest pixel (1, 0)
  EXPECT_FALSE(d.At({1.6, 0.2}));  // (2, 0)
  EXPECT_TRUE(d.At({2.0, 1.0}));
  EXPECT_FALSE(d.At({-0.6, 0.0}));  // outside the image
  EXPECT_FALSE(d.At({3.0, 0.0}));
  EXPECT_THROW(DarkPixels::FromStatus("left", cv::Mat(2, 2, CV_32FC1)), Error);
}

TEST(CadCompareTest, PerViewFiguresAndPaintedMesh) {
  const OcclusionSetup s = MakeOcclusionSetup();
  // Two views whose clouds (rig frame) are the exact surface seen at their poses, one offset.
  const PointCloud in_part = SurfaceCloud(s.cad, 100000, 0.0);
  std::vector<CadView> views = TableViews(s.rig, 2, nullptr);
  PointCloud a, b;
  for (const auto& p : in_part.points) {
    a.points.push_back(views[0].part_from_rig.Inverse() * p);
    b.points.push_back(views[1].part_from_rig.Inverse() * (p + Eigen::Vector3d(0, 0, 0.05)));
  }
  views[0].cloud = &a;
  views[1].cloud = &b;
  views.push_back(CadView{"left_out", views[0].part_from_rig, nullptr});
  CadCompareOptions options;
  options.samples = 20000;
  const CadComparison c = CompareWithCad(s.cad, s.rig, ReconstructMode::kProjector, views, in_part,
                                         s.rig.turntable, options);
  ASSERT_EQ(c.views.size(), 3u);
  EXPECT_NEAR(c.views[0].c2m.rms_mm, 0, 1e-6);
  EXPECT_GT(c.views[1].c2m.rms_mm, 0.001);
  EXPECT_FALSE(c.views[2].merged);
  EXPECT_NE(c.Summary().find("left_out    left out of the merge"), std::string::npos);
  const nlohmann::json j = c.ToJson();
  EXPECT_EQ(j["views"].size(), 3u);
  EXPECT_EQ(j["surface_by_reason"]["covered"]["samples"].get<size_t>(),
            c.reason_samples[static_cast<size_t>(CoverageReason::kCovered)]);

  const testing::TempDir tmp;
  WritePaintedMesh(tmp / "painted.ply", s.cad, c);
  const TriangleMesh back = ReadMesh(tmp / "painted.ply");
  EXPECT_EQ(back.NumTriangles(), s.cad.NumTriangles());
  const PointCloud vertices = ReadPly(tmp / "painted.ply");
  ASSERT_EQ(vertices.size(), s.cad.vertices.size());
  ASSERT_TRUE(vertices.HasColors());
  ASSERT_NE(vertices.Scalar("deviation_mm"), nullptr);
  ASSERT_NE(vertices.Scalar("reason"), nullptr);
  TriangleMesh other = s.cad;
  other.vertices.pop_back();
  EXPECT_THROW(WritePaintedMesh(tmp / "bad.ply", other, c), Error);
  EXPECT_FALSE(std::filesystem::exists(tmp / "bad.ply"));
}

TEST(CadCompareTest, BadInputs) {
  const OcclusionSetup s = MakeOcclusionSetup();
  PointCloud cloud;
  cloud.points = {Eigen::Vector3d(0, 0, 500)};
  CadCompareOptions options;
  options.grazing_deg = 0;
  EXPECT_NE(testing::ErrorOf([&] {
              CompareWithCad(s.cad, s.rig, ReconstructMode::kStereo, {}, cloud, std::nullopt,
                             options);
            }).find("grazing_deg must be in (0, 90] (got 0)"),
            std::string::npos);
  EXPECT_THROW(
      CompareWithCad(TriangleMesh(), s.rig, ReconstructMode::kStereo, {}, cloud, std::nullopt),
      Error);
  EXPECT_THROW(
      CompareWithCad(s.cad, s.rig, ReconstructMode::kStereo, {}, PointCloud(), std::nullopt),
      Error);
  Rig no_projector = s.rig;
  no_projector.projector.reset();
  EXPECT_NE(testing::ErrorOf([&] {
              CompareWithCad(s.cad, no_projector, ReconstructMode::kStereo, {}, cloud,
                             std::nullopt);
            }).find("has no projector"),
            std::string::npos);
}

}  // namespace
}  // namespace slshadow::multiview
