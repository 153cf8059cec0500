#include "sim/renderer.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include "core/error.h"
#include "sim/shapes.h"
#include "tests/sim/sim_test_util.h"

namespace slshadow {
namespace {

using testing::FlatProjectorImage;
using testing::MakePrimitive;
using testing::PlaneScene;
using testing::Pose;
using testing::SameFloat;
using testing::SmallDemoRig;
using testing::Trace;

void ExpectSameBuffers(const GeometryBuffer& a, const GeometryBuffer& b) {
  ASSERT_EQ(a.proj_x.size(), b.proj_x.size());
  for (size_t i = 0; i < a.proj_x.size(); ++i) {
    ASSERT_TRUE(SameFloat(a.proj_x[i], b.proj_x[i])) << i;
    ASSERT_TRUE(SameFloat(a.proj_y[i], b.proj_y[i])) << i;
    ASSERT_EQ(a.factor[i], b.factor[i]) << i;
    ASSERT_EQ(a.albedo[i], b.albedo[i]) << i;
  }
  EXPECT_EQ(cv::norm(a.visibility, b.visibility, cv::NORM_INF), 0);
  EXPECT_EQ(cv::norm(a.object_id, b.object_id, cv::NORM_INF), 0);
  for (int y = 0; y < a.height; ++y) {
    for (int x = 0; x < a.width; ++x) {
      ASSERT_TRUE(SameFloat(a.depth_mm.at<float>(y, x), b.depth_mm.at<float>(y, x)));
    }
  }
  EXPECT_EQ(a.primary_rays, b.primary_rays);
  EXPECT_EQ(a.shadow_rays, b.shadow_rays);
}

// Every camera ray is the camera model's own unprojection of its sample (CameraModel::Unproject,
// Newton from the distorted point), and NaN exactly where that finds no solution: a lens whose
// distortion folds over inside the image corners, 1 and 3x3 samples per pixel, and an image tall
// enough for several row bands of the vectorised solver.
TEST(CameraRaysTest, EqualTheModelsUnprojectionIncludingPastTheFold) {
  CameraModel cam(300, 260, 255, 257, 151.3, 127.8);
  cam.params[CameraModel::kK1] = -0.32;  // folds at r ~ 1.02 (distorted r ~ 0.68)
  cam.params[CameraModel::kP1] = 0.002;
  cam.params[CameraModel::kP2] = -0.003;
  cam.params[CameraModel::kK3] = 0.004;
  for (const int n : {1, 3}) {
    const CameraRays rays = ComputeCameraRays(cam, n);
    ASSERT_EQ(rays.samples.size(), static_cast<size_t>(cam.width) * cam.height * n * n);
    int folded = 0;
    double worst = 0, worst_px = 0;
    for (int y = 0; y < cam.height; ++y) {
      for (int x = 0; x < cam.width; ++x) {
        for (int b = 0; b < n; ++b) {
          for (int a = 0; a < n; ++a) {
            const Eigen::Vector2d pixel(x + (a + 0.5) / n - 0.5, y + (b + 0.5) / n - 0.5);
            const Eigen::Vector3f& d =
                rays.samples[(static_cast<size_t>(y) * cam.width + x) * n * n + b * n + a];
            const std::optional<Eigen::Vector3d> expected = cam.Unproject(pixel);
            if (!expected) {
              ++folded;
              ASSERT_TRUE(d.array().isNaN().all()) << pixel.transpose();
              continue;
            }
            ASSERT_TRUE(d.allFinite()) << pixel.transpose();
            worst = std::max(worst, (d.cast<double>() - *expected).norm());
            const std::optional<Eigen::Vector2d> back = cam.Project(d.cast<double>());
            ASSERT_TRUE(back.has_value());
            worst_px = std::max(worst_px, (*back - pixel).norm());
          }
        }
      }
    }
    EXPECT_GT(folded, 0) << "the test lens should fold over in the image corners";
    EXPECT_LT(folded, cam.width * cam.height * n * n / 10);
    EXPECT_LT(worst, 1e-7) << n;  // float rounding of a unit vector
    // Back through the model; near the fold the lens compresses the image, which magnifies the
    // float rounding of the direction in pixels.
    EXPECT_LT(worst_px, 1e-3) << n;
  }
  // Recycled storage (a larger, supersampled ray set) gives the same rays as fresh storage.
  CameraModel other = cam;
  other.params[CameraModel::kCx] += 3.25;
  const CameraRays fresh = ComputeCameraRays(other, 1);
  const CameraRays recycled = ComputeCameraRays(other, 1, ComputeCameraRays(cam, 3));
  ASSERT_EQ(recycled.samples.size(), fresh.samples.size());
  EXPECT_TRUE(recycled.centers.empty());
  for (size_t i = 0; i < fresh.samples.size(); ++i) {
    ASSERT_TRUE(fresh.samples[i].array().isNaN().all() ? recycled.samples[i].array().isNaN().all()
                                                       : recycled.samples[i] == fresh.samples[i])
        << i;
  }
}

// Rows of one sample per pixel are written 4 rays at a time with a scalar tail: widths 5 to 8
// (tails of 1, 2, 3 and no rays) give the camera model's unprojection everywhere.
TEST(CameraRaysTest, RowTailsEqualTheModelsUnprojection) {
  for (const int width : {5, 6, 7, 8}) {
    CameraModel cam(width, 3, 4.1, 3.9, 0.4 * width, 1.3);
    cam.params[CameraModel::kK1] = -0.05;
    cam.params[CameraModel::kP2] = 0.002;
    const CameraRays rays = ComputeCameraRays(cam, 1);
    ASSERT_EQ(rays.samples.size(), static_cast<size_t>(width) * 3);
    for (int y = 0; y < 3; ++y) {
      for (int x = 0; x < width; ++x) {
        const std::optional<Eigen::Vector3d> expected = cam.Unproject(Eigen::Vector2d(x, y));
        ASSERT_TRUE(expected.has_value());
        const Eigen::Vector3f& d = rays.samples[static_cast<size_t>(y) * width + x];
        EXPECT_LT((d.cast<double>() - *expected).norm(), 1e-7) << width << ": " << x << "," << y;
      }
    }
  }
}

// Brute force (rtcIntersect1 / rtcOccluded1 per ray) against the packet render of the demo scene,
// with supersampling so both the sample and the centre passes are covered.
TEST(TraceGeometryTest, SingleRayReferenceEqualsPacketRender) {
  Scene scene = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
  scene.layers.supersampling = 2;
  const Rig rig = SmallDemoRig(8);
  for (int camera = 0; camera < 2; ++camera) {
    const GeometryBuffer packet = Trace(scene, rig, camera, TraceMode::kPacket16);
    const GeometryBuffer single = Trace(scene, rig, camera, TraceMode::kSingleRay);
    ExpectSameBuffers(packet, single);
    const auto counts = packet.projector.CountByStatus();
    EXPECT_GT(counts[0], packet.width * packet.height / 4) << "most of the view is lit";
    EXPECT_GT(counts[1], 0) << "the demo part casts shadows";
    std::mt19937 rng(1);
    cv::Mat pattern(rig.projector->model.height, rig.projector->model.width, CV_8UC1);
    cv::randu(pattern, 0, 256);
    const cv::Mat a = PatternRenderer(scene, rig, camera, packet).Render(pattern, 0);
    const cv::Mat b = PatternRenderer(scene, rig, camera, single).Render(pattern, 0);
    EXPECT_EQ(cv::norm(a, b, cv::NORM_INF), 0);
  }
}

// Rays whose segment misses the bounds of Embree's geometry skip its traversal. That must change
// nothing: the demo part on its table (most of the view is table around the part, and shadow
// rays from the table graze the part's bounds), both trace modes.
TEST(TraceGeometryTest, BoundsCullingChangesNothing) {
  const Scene scene = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
  const Rig rig = SmallDemoRig(8);
  const RayCaster culled(scene, /*cull_by_bounds=*/true), full(scene, /*cull_by_bounds=*/false);
  for (int camera = 0; camera < 2; ++camera) {
    const CameraRays rays = ComputeCameraRays(rig.cameras[static_cast<size_t>(camera)].model, 1);
    for (const TraceMode mode : {TraceMode::kPacket16, TraceMode::kSingleRay}) {
      ExpectSameBuffers(TraceGeometry(culled, rig, camera, rays, mode),
                        TraceGeometry(full, rig, camera, rays, mode));
    }
  }
}

// The pass traces packets of 4 x 4 pixels; packets over the image's right and bottom edges have
// lanes outside it, and a pixel without a camera ray (NaN: past a lens's fold) is a lane left
// out. Such pixels get the values the same rays give inside full packets: a camera whose rays
// are the top-left 237 x 147 crop of a 240 x 150 camera's (so its edge packets are partial where
// the larger camera's are full), with and without ground truth, 1 and 2x2 samples per pixel.
TEST(TraceGeometryTest, EdgePacketsAndMissingRaysEqualFullPackets) {
  const Rig big = SmallDemoRig(8);
  ASSERT_EQ(big.cameras[0].model.width, 240);
  ASSERT_EQ(big.cameras[0].model.height, 150);
  Rig small = big;
  const int w = 237, h = 147;
  small.cameras[0].model.width = w;
  small.cameras[0].model.height = h;
  const std::vector<cv::Point> no_ray = {{5, 7}, {236, 146}, {100, 3}, {236, 0}, {0, 146}};
  for (const int n : {1, 2}) {
    CameraRays big_rays = ComputeCameraRays(big.cameras[0].model, n);
    CameraRays small_rays;
    small_rays.width = w;
    small_rays.height = h;
    small_rays.samples_per_axis = n;
    const auto crop = [&](std::vector<Eigen::Vector3f>& from, std::vector<Eigen::Vector3f>& to,
                          int per_pixel) {
      for (const cv::Point& q : no_ray) {
        for (int k = 0; k < per_pixel; ++k)
          from[(static_cast<size_t>(q.y) * 240 + q.x) * per_pixel + k].setConstant(NAN);
      }
      for (int y = 0; y < h; ++y) {
        const auto row = from.begin() + static_cast<ptrdiff_t>(y) * 240 * per_pixel;
        to.insert(to.end(), row, row + static_cast<ptrdiff_t>(w) * per_pixel);
      }
    };
    crop(big_rays.samples, small_rays.samples, n * n);
    if (n > 1) crop(big_rays.centers, small_rays.centers, 1);
    Scene scene = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
    scene.layers.supersampling = n;
    const RayCaster caster(scene);
    for (const bool ground_truth : {true, false}) {
      const GeometryBuffer a =
          TraceGeometry(caster, big, 0, big_rays, TraceMode::kPacket16, ground_truth);
      const GeometryBuffer b =
          TraceGeometry(caster, small, 0, small_rays, TraceMode::kPacket16, ground_truth);
      const size_t nn = static_cast<size_t>(n) * n;
      int lit = 0;
      for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) {
          for (size_t k = 0; k < nn; ++k) {
            const size_t i = (static_cast<size_t>(y) * 240 + x) * nn + k,
                         j = (static_cast<size_t>(y) * w + x) * nn + k;
            ASSERT_TRUE(SameFloat(a.proj_x[i], b.proj_x[j])) << x << "," << y;
            ASSERT_TRUE(SameFloat(a.proj_y[i], b.proj_y[j])) << x << "," << y;
            ASSERT_EQ(a.factor[i], b.factor[j]) << x << "," << y;
            ASSERT_EQ(a.albedo[i], b.albedo[j]) << x << "," << y;
            lit += !std::isnan(b.proj_x[j]);
          }
          if (!ground_truth) continue;
          ASSERT_TRUE(SameFloat(a.depth_mm.at<float>(y, x), b.depth_mm.at<float>(y, x)))
              << x << "," << y;
          ASSERT_EQ(a.object_id.at<int32_t>(y, x), b.object_id.at<int32_t>(y, x)) << x << "," << y;
          ASSERT_EQ(a.visibility.at<uint8_t>(y, x), b.visibility.at<uint8_t>(y, x))
              << x << "," << y;
          ASSERT_EQ(a.projector.status.at<uint8_t>(y, x), b.projector.status.at<uint8_t>(y, x))
              << x << "," << y;
          ASSERT_TRUE(
              SameFloat(a.projector.proj_x.at<float>(y, x), b.projector.proj_x.at<float>(y, x)))
              << x << "," << y;
          for (int k = 0; k < 3; ++k) {
            ASSERT_TRUE(SameFloat(a.point_in_rig.at<cv::Vec3f>(y, x)[k],
                                  b.point_in_rig.at<cv::Vec3f>(y, x)[k]));
            ASSERT_TRUE(SameFloat(a.normal_in_rig.at<cv::Vec3f>(y, x)[k],
                                  b.normal_in_rig.at<cv::Vec3f>(y, x)[k]));
          }
        }
      }
      EXPECT_GT(lit, w * h * static_cast<int>(nn) / 2) << "most of the view is lit";
      for (const cv::Point& q : no_ray) {
        for (size_t k = 0; k < nn; ++k) {
          const size_t j = (static_cast<size_t>(q.y) * w + q.x) * nn + k;
          EXPECT_TRUE(std::isnan(b.proj_x[j]) && b.factor[j] == 0 && b.albedo[j] == 0)
              << "no ray: nothing seen";
        }
        if (ground_truth) {
          EXPECT_EQ(b.visibility.at<uint8_t>(q), 0);
          EXPECT_EQ(b.object_id.at<int32_t>(q), -1);
          EXPECT_TRUE(std::isnan(b.depth_mm.at<float>(q)));
        }
      }
      const int64_t expected_primary =
          (static_cast<int64_t>(w) * h - static_cast<int64_t>(no_ray.size())) *
          (static_cast<int64_t>(nn) + (n > 1 && ground_truth ? 1 : 0));
      EXPECT_EQ(b.primary_rays, expected_primary);
    }
  }
}

// DN = exposure * full * (ambient * albedo + albedo * cos_p * (d_ref/d_p)^2 * I), evaluated
// independently per pixel by intersecting the viewing ray with the plane in closed form.
TEST(RadiometryTest, TiltedPlaneFollowsCosOverDistanceSquared) {
  const Rig rig = SmallDemoRig(4);
  const Rigid3d pose = Pose(Eigen::Vector3d(0.15, 0.45, 0), Eigen::Vector3d(10, -5, 480));
  Scene scene = PlaneScene(pose, 0.6);
  scene.layers.ambient = 0.1;
  scene.radiometry.adc_bits = 16;
  const double full = 65535, d_ref = rig.working_distance_mm;
  const Eigen::Vector3d n = pose.rotation * Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d proj_center = rig.projector->CenterInRig();
  for (int camera = 0; camera < 2; ++camera) {
    const GeometryBuffer g = Trace(scene, rig, camera);
    const cv::Mat irradiance =
        PatternRenderer(scene, rig, camera, g).RenderIrradiance(FlatProjectorImage(rig, 255));
    const RigDevice& cam = rig.cameras[static_cast<size_t>(camera)];
    int lit = 0, checked = 0;
    for (int y = 0; y < g.height; y += 3) {
      for (int x = 0; x < g.width; x += 3) {
        const auto ray = cam.model.Unproject(Eigen::Vector2d(x, y));
        ASSERT_TRUE(ray);
        const Eigen::Vector3d origin = cam.CenterInRig();
        const Eigen::Vector3d dir = cam.cam_from_rig.rotation.conjugate() * *ray;
        const double t = (pose.translation - origin).dot(n) / dir.dot(n);
        const Eigen::Vector3d p = origin + t * dir;
        const Eigen::Vector3d to_proj = proj_center - p;
        const double cos_p = std::abs(n.dot(to_proj.normalized()));
        const auto uv = rig.projector->model.Project(rig.projector->cam_from_rig * p);
        const bool in_projector = uv && rig.projector->model.IsInImage(*uv);
        const Eigen::Vector3d local = pose.Inverse() * p;
        if (std::abs(local.x()) > 300 || std::abs(local.y()) > 200) {
          ASSERT_EQ(irradiance.at<float>(y, x), 0) << "off the plane: black";
          continue;
        }
        const double expected =
            0.8 * full * 0.6 *
            (0.1 + (in_projector ? cos_p * d_ref * d_ref / to_proj.squaredNorm() : 0.0));
        ASSERT_NEAR(irradiance.at<float>(y, x), expected, 2e-4 * expected)
            << camera << " " << x << "," << y;
        ASSERT_NEAR(g.depth_mm.at<float>(y, x), (cam.cam_from_rig * p).z(), 1e-3);
        lit += in_projector;
        ++checked;
      }
    }
    EXPECT_GT(lit, checked / 2);
  }
}

// A box between the projector and a plane: shadowed pixels get exactly the ambient term, and
// the shadow is where the segment from the surface to the projector's centre crosses the box.
TEST(RadiometryTest, ShadowedPixelsGetAmbientOnly) {
  const Rig rig = SmallDemoRig(4);
  Scene scene = PlaneScene(Pose(Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 560)), 0.5);
  SceneObject box = MakePrimitive(
      ObjectType::kBox, Pose(Eigen::Vector3d(0.2, 0.3, 0), Eigen::Vector3d(-30, 10, 470)), 0.9);
  box.size_mm = Eigen::Vector3d(40, 30, 20);
  scene.objects.push_back(box);
  scene.layers.ambient = 0.05;
  const Eigen::Vector3d proj_center = rig.projector->CenterInRig();
  const Rigid3d box_from_rig = box.rig_from_object.Inverse();
  const GeometryBuffer g = Trace(scene, rig, 0);
  const cv::Mat irradiance =
      PatternRenderer(scene, rig, 0, g).RenderIrradiance(FlatProjectorImage(rig, 255));
  int shadowed = 0, lit = 0;
  for (int y = 0; y < g.height; ++y) {
    for (int x = 0; x < g.width; ++x) {
      if (g.object_id.at<int32_t>(y, x) != 0) continue;  // plane pixels only
      const cv::Vec3f pf = g.point_in_rig.at<cv::Vec3f>(y, x);
      const Eigen::Vector3d p(pf[0], pf[1], pf[2]);
      const auto uv = rig.projector->model.Project(rig.projector->cam_from_rig * p);
      if (!uv || !rig.projector->model.IsInImage(*uv)) continue;
      const Eigen::Vector3d o = box_from_rig * p;
      const Eigen::Vector3d d = box_from_rig.rotation * (proj_center - p);
      PrimitiveHit hit;
      SceneObject shrunk = box, grown = box;
      shrunk.size_mm -= Eigen::Vector3d::Constant(0.02);
      grown.size_mm += Eigen::Vector3d::Constant(0.02);
      const bool surely_shadow = IntersectPrimitive(shrunk, o, d, 0, 1, &hit);
      const bool surely_lit = !IntersectPrimitive(grown, o, d, 0, 1, &hit);
      const int vis = g.visibility.at<uint8_t>(y, x);
      if (surely_shadow) {
        ASSERT_EQ(vis, 1) << x << "," << y;
        EXPECT_FLOAT_EQ(irradiance.at<float>(y, x), static_cast<float>(0.8 * 255 * 0.05 * 0.5));
        ++shadowed;
      }
      if (surely_lit) {
        ASSERT_EQ(vis, 2) << x << "," << y;
        ++lit;
      }
    }
  }
  EXPECT_GT(shadowed, 200);
  EXPECT_GT(lit, 1000);
}

// The exact sphere against UV spheres: the tessellated surface lies inside (hits are farther)
// by at most the tessellation gap r (1 - sqrt(1 - 2 sin^2(pi / segments))) along the normal.
TEST(TessellationTest, AnalyticSphereVsMeshDifferOnlyByTessellationError) {
  const Rig rig = SmallDemoRig(4);
  const double r = 40;
  const Rigid3d pose = Pose(Eigen::Vector3d(0.3, 0.1, 0.2), Eigen::Vector3d(5, 0, 480));
  Scene analytic;
  SceneObject sphere = MakePrimitive(ObjectType::kSphere, pose);
  sphere.radius_mm = r;
  analytic.objects.push_back(sphere);
  const GeometryBuffer ga = Trace(analytic, rig, 0);
  for (int segments : {32, 128}) {
    Scene tess;
    SceneObject mesh = MakePrimitive(ObjectType::kMesh, pose);
    mesh.mesh = std::make_shared<const TriangleMesh>(MakeSphereMesh(r, segments));
    tess.objects.push_back(mesh);
    const GeometryBuffer gm = Trace(tess, rig, 0);
    // The mesh's largest gap to the sphere, measured on the mesh: r - min |p| over each face
    // (barycentric grid).
    double gap = 0;
    for (size_t f = 0; f < mesh.mesh->NumTriangles(); ++f) {
      const auto& t = mesh.mesh->triangles[f];
      const Eigen::Vector3d a = mesh.mesh->vertices[static_cast<size_t>(t[0])],
                            b = mesh.mesh->vertices[static_cast<size_t>(t[1])],
                            c = mesh.mesh->vertices[static_cast<size_t>(t[2])];
      for (int i = 0; i <= 20; ++i) {
        for (int j = 0; i + j <= 20; ++j) {
          gap = std::max(gap, r - (a + (b - a) * (i / 20.0) + (c - a) * (j / 20.0)).norm());
        }
      }
    }
    double max_excess = 0;
    int compared = 0;
    for (int y = 0; y < ga.height; ++y) {
      for (int x = 0; x < ga.width; ++x) {
        const float da = ga.depth_mm.at<float>(y, x), dm = gm.depth_mm.at<float>(y, x);
        if (std::isnan(da) || std::isnan(dm)) continue;
        const cv::Vec3f nf = ga.normal_in_rig.at<cv::Vec3f>(y, x);
        const cv::Vec3f pf = ga.point_in_rig.at<cv::Vec3f>(y, x);
        const Eigen::Vector3d view = Eigen::Vector3d(pf[0], pf[1], pf[2]).normalized();
        const double cos_inc = std::abs(view.dot(Eigen::Vector3d(nf[0], nf[1], nf[2])));
        if (cos_inc < 0.3) continue;
        // Depth difference = distance along the ray * view.z.
        const double along_ray = (dm - da) / view.z();
        ASSERT_GE(along_ray, -1e-3) << "mesh vertices lie on the sphere, faces inside it";
        ASSERT_LE(along_ray, 1.05 * gap / cos_inc + 1e-3)
            << segments << " segments at " << x << "," << y;
        max_excess = std::max(max_excess, along_ray * cos_inc);
        ++compared;
      }
    }
    EXPECT_GT(compared, 2000);
    EXPECT_GT(max_excess, gap / 3) << "the tessellation error is visible at this resolution";
  }
}

// Fibonacci samples of a sphere with exact normals, rendered as discs with radius from spacing,
// against a finely tessellated mesh of the same sphere: same depth within 0.02 mm and the same
// image within 4 DN (8-bit, mean <= 1 DN) wherever the surface is not grazing (cos of incidence
// >= 0.3). Discs are flat: their normal is the point's, off the true normal at the hit by up to
// disc radius / sphere radius (~0.01 rad here), which moves cos_p by a few percent at grazing
// projector incidence: that, not geometry, is the residual.
TEST(PointCloudTest, DiscsMatchMeshOfTheSameSurface) {
  const Rig rig = SmallDemoRig(4);
  const double r = 30;
  const Rigid3d pose = Pose(Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 5, 470));
  auto cloud = std::make_shared<PointCloud>();
  const int n = 200000;
  const double golden = M_PI * (3 - std::sqrt(5.0));
  for (int i = 0; i < n; ++i) {
    const double z = 1 - 2 * (i + 0.5) / n, rho = std::sqrt(1 - z * z), a = golden * i;
    const Eigen::Vector3d u(rho * std::cos(a), rho * std::sin(a), z);
    cloud->points.push_back(r * u);
    cloud->normals.push_back(u.cast<float>());
  }
  Scene discs;
  SceneObject pc = MakePrimitive(ObjectType::kPointCloud, pose);
  pc.disc_radii_mm = DiscRadiiFromSpacing(cloud->points);
  pc.points = cloud;
  discs.objects.push_back(pc);
  Scene meshed;
  SceneObject mesh = MakePrimitive(ObjectType::kMesh, pose);
  mesh.mesh = std::make_shared<const TriangleMesh>(MakeSphereMesh(r, 512));
  meshed.objects.push_back(mesh);
  const GeometryBuffer gd = Trace(discs, rig, 0), gm = Trace(meshed, rig, 0);
  const cv::Mat white = FlatProjectorImage(rig, 255);
  const cv::Mat id = PatternRenderer(discs, rig, 0, gd).Render(white, 0);
  const cv::Mat im = PatternRenderer(meshed, rig, 0, gm).Render(white, 0);
  int compared = 0, max_dn = 0;
  double sum_dn = 0;
  for (int y = 0; y < gd.height; ++y) {
    for (int x = 0; x < gd.width; ++x) {
      const float dd = gd.depth_mm.at<float>(y, x), dm = gm.depth_mm.at<float>(y, x);
      if (std::isnan(dd) || std::isnan(dm) ||
          gd.visibility.at<uint8_t>(y, x) != gm.visibility.at<uint8_t>(y, x))
        continue;
      const cv::Vec3f nf = gm.normal_in_rig.at<cv::Vec3f>(y, x);
      const cv::Vec3f pf = gm.point_in_rig.at<cv::Vec3f>(y, x);
      const double cos_inc = std::abs(Eigen::Vector3d(pf[0], pf[1], pf[2])
                                          .normalized()
                                          .dot(Eigen::Vector3d(nf[0], nf[1], nf[2])));
      if (cos_inc < 0.3) continue;
      ASSERT_NEAR(dd, dm, 0.02) << x << "," << y;
      const int diff = std::abs(id.at<uint8_t>(y, x) - im.at<uint8_t>(y, x));
      max_dn = std::max(max_dn, diff);
      sum_dn += diff;
      ++compared;
    }
  }
  EXPECT_GT(compared, 3000);
  std::printf("discs vs mesh: %d pixels, max |dDN| %d, mean %.3f\n", compared, max_dn,
              sum_dn / compared);
  EXPECT_LE(max_dn, 4);
  EXPECT_LE(sum_dn / compared, 1.0);
}

}  // namespace
}  // namespace slshadow
