#include "compare/report.h"
#include "compare/median_spacing.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <Eigen/Eigenvalues>

#include "compare/statistics.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/string_printf.h"

namespace slshadow::compare {
namespace fs = std::filesystem;

namespace {

nlohmann::json StatsJson(const DistanceStats& s) {
  nlohmann::json j;
  j["count"] = s.count;
  j["invalid"] = s.num_invalid;
  j["mean_mm"] = s.mean_mm;
  j["std_mm"] = s.std_mm;
  j["rms_mm"] = s.rms_mm;
  j["median_mm"] = s.median_mm;
  j["p95_mm"] = s.p95_mm;
  j["max_mm"] = s.max_mm;
  if (s.is_signed) {
    j["signed_mean_mm"] = s.signed_mean_mm;
    j["signed_std_mm"] = s.signed_std_mm;
  }
  j["threshold_mm"] = s.threshold_mm;
  j["inliers"] = s.inliers;
  j["outliers"] = s.outliers;
  j["outlier_fraction"] =
      s.count ? static_cast<double>(s.outliers) / static_cast<double>(s.count) : 0.0;
  j["histogram"] = {{"signed", s.is_signed},
                    {"lo_mm", s.histogram.lo_mm},
                    {"hi_mm", s.histogram.hi_mm},
                    {"counts", s.histogram.counts},
                    {"underflow", s.histogram.underflow},
                    {"overflow", s.histogram.overflow}};
  return j;
}

// Float keeps a coordinate to half a unit in the last place: <= 2^-11 mm below 8192 mm.
bool FitsFloatPositions(const std::vector<Eigen::Vector3d>& points) {
  for (const auto& p : points) {
    if (!(p.cwiseAbs().maxCoeff() < 8192.0)) return false;
  }
  return true;
}

}  // namespace

ViewCamera FitView(const PointCloud& cloud, int width_px) {
  SLSHADOW_THROW_IF(cloud.empty(), "deviation map: no points to frame");
  SLSHADOW_THROW_IF(width_px < 16, "deviation map: width must be >= 16 px (got ", width_px, ")");
  const auto& pts = cloud.points;
  const size_t stride = std::max<size_t>(1, pts.size() / 100000);
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  size_t n = 0;
  for (size_t i = 0; i < pts.size(); i += stride, ++n) c += pts[i];
  c /= static_cast<double>(n);
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  double radius = 0;
  for (size_t i = 0; i < pts.size(); i += stride) {
    const Eigen::Vector3d d = pts[i] - c;
    cov += d * d.transpose();
    radius = std::max(radius, d.norm());
  }
  radius = std::max(radius, 1e-3);
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  Eigen::Vector3d axis = eig.eigenvectors().col(0);  // smallest spread: look along it
  Eigen::Vector3d toward_camera = -c;                // the origin's side (a scanner's)
  if (cloud.HasNormals()) {
    Eigen::Vector3d m = Eigen::Vector3d::Zero();
    for (size_t i = 0; i < pts.size(); i += stride) m += cloud.normals[i].cast<double>();
    if (m.norm() > 0) toward_camera = m;
  }
  if (axis.dot(toward_camera) < 0) axis = -axis;
  const Eigen::Vector3d eye = c + 2.5 * radius * axis;
  const Eigen::Vector3d z = -axis;
  Eigen::Vector3d x = eig.eigenvectors().col(2);
  x = (x - x.dot(z) * z).normalized();
  const Eigen::Vector3d y = z.cross(x);
  Eigen::Matrix3d cam_from_ref_rot;
  cam_from_ref_rot.row(0) = x.transpose();
  cam_from_ref_rot.row(1) = y.transpose();
  cam_from_ref_rot.row(2) = z.transpose();
  ViewCamera v;
  v.cam_from_reference = Rigid3d(Eigen::Quaterniond(cam_from_ref_rot), -(cam_from_ref_rot * eye));
  double mx = 1e-9, my = 1e-9;
  for (size_t i = 0; i < pts.size(); i += stride) {
    const Eigen::Vector3d p = v.cam_from_reference * pts[i];
    mx = std::max(mx, std::abs(p.x() / p.z()));
    my = std::max(my, std::abs(p.y() / p.z()));
  }
  const int height =
      std::clamp(static_cast<int>(std::lround(width_px * my / mx)), width_px / 2, width_px);
  const double f = std::min((width_px / 2.0 - 1) / (1.04 * mx), (height / 2.0 - 1) / (1.04 * my));
  v.camera = CameraModel(width_px, height, f, f, (width_px - 1) / 2.0, (height - 1) / 2.0);
  return v;
}

ValueImage RenderValues(const std::vector<Eigen::Vector3d>& points,
                        const std::vector<double>& values, const ViewCamera& view, int splat_px,
                        double spacing_mm) {
  SLSHADOW_THROW_IF(points.size() != values.size(), "deviation map: ", values.size(),
                    " values for ", points.size(), " points");
  view.camera.Check("deviation map camera");
  const int w = view.camera.width, h = view.camera.height;
  ValueImage img;
  img.width = w;
  img.height = h;
  img.values.assign(static_cast<size_t>(w) * static_cast<size_t>(h),
                    std::numeric_limits<float>::quiet_NaN());
  if (points.empty()) return img;
  // Each point in the view's frame, computed where it is needed (a copy of a 2 M-point cloud
  // would cost ~50 MB of fresh pages).
  const Eigen::Matrix3d rotation = view.cam_from_reference.rotation.toRotationMatrix();
  const Eigen::Vector3d translation = view.cam_from_reference.translation;
  const auto in_cam = [&](size_t i) -> Eigen::Vector3d {
    return rotation * points[i] + translation;
  };
  if (splat_px <= 0) {
    // Point spacing at the median depth, in pixels.
    std::vector<double> zs;
    const size_t stride = std::max<size_t>(1, points.size() / 20000);
    for (size_t i = 0; i < points.size(); i += stride) {
      const double z = in_cam(i).z();
      if (z > 0) zs.push_back(z);
    }
    double spacing_px = 1.0;
    if (!zs.empty()) {
      std::nth_element(zs.begin(), zs.begin() + static_cast<long>(zs.size() / 2), zs.end());
      if (!(spacing_mm > 0)) spacing_mm = MedianSpacing(points, 5000);  // grid: no tree
      spacing_px = view.camera.fx() * spacing_mm / zs[zs.size() / 2];
    }
    splat_px = std::clamp(static_cast<int>(std::ceil(0.5 * spacing_px)), 0, 4);
  }
  // The projections in parallel (each point's pixel and depth), then the z-buffer in point order.
  struct Landing {
    int32_t u = 0, v = 0;
    float z = std::numeric_limits<float>::infinity();  // infinite: not drawn
  };
  std::vector<Landing> landings(points.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 16384),
                    [&](const tbb::blocked_range<size_t>& r) {
                      for (size_t i = r.begin(); i != r.end(); ++i) {
                        if (!std::isfinite(values[i])) continue;
                        const Eigen::Vector3d p = in_cam(i);
                        const auto px = view.camera.Project(p);
                        if (!px || !(std::abs(px->x()) < 1e9 && std::abs(px->y()) < 1e9)) continue;
                        landings[i] = {static_cast<int32_t>(std::lround(px->x())),
                                       static_cast<int32_t>(std::lround(px->y())),
                                       static_cast<float>(p.z())};
                      }
                    });
  std::vector<float> depth(img.values.size(), std::numeric_limits<float>::infinity());
  for (size_t i = 0; i < points.size(); ++i) {
    const Landing& l = landings[i];
    if (!(l.z < std::numeric_limits<float>::infinity())) continue;
    for (int dv = -splat_px; dv <= splat_px; ++dv) {
      const int y = l.v + dv;
      if (y < 0 || y >= h) continue;
      for (int du = -splat_px; du <= splat_px; ++du) {
        const int x = l.u + du;
        if (x < 0 || x >= w) continue;
        const size_t k = static_cast<size_t>(y) * static_cast<size_t>(w) + static_cast<size_t>(x);
        if (l.z < depth[k]) {
          depth[k] = l.z;
          img.values[k] = static_cast<float>(values[i]);
        }
      }
    }
  }
  return img;
}

nlohmann::json ReportJson(const CompareResult& r) {
  nlohmann::json j;
  j["format"] = "slshadow.compare_report";
  j["version"] = 1;
  j["created_utc"] = UtcTimestamp();
  j["inputs"] = {
      {"cloud", r.cloud_source},
      {"cloud_points", r.compared.size()},
      {"reference", r.reference_source},
      {"reference_kind", r.reference_is_mesh ? "mesh" : "cloud"},
      {r.reference_is_mesh ? "reference_triangles" : "reference_points", r.reference_size}};
  const CompareOptions& o = r.options;
  j["options"] = {{"threshold_mm", o.threshold_mm},
                  {"local_model", ToString(o.c2c.local_model)},
                  {"local_model_neighbors", o.c2c.local_model_neighbors},
                  {"max_distance_mm", o.c2c.max_distance_mm},
                  {"coverage_radius_mm", o.coverage_radius_mm},
                  {"histogram_bins", o.histogram_bins},
                  {"m3c2", o.m3c2}};
  const RegistrationResult& g = r.registration;
  const Eigen::Matrix4d m = g.reference_from_cloud.ToMatrix();
  nlohmann::json rows = nlohmann::json::array();
  for (int i = 0; i < 4; ++i) rows.push_back({m(i, 0), m(i, 1), m(i, 2), m(i, 3)});
  j["registration"] = {{"method", ToString(g.method)},
                       {"transform", rows},
                       {"transform_is", "reference_from_cloud, row-major 4x4, mm"},
                       {"rmse_mm", g.inlier_rmse_mm},
                       {"fitness", g.fitness},
                       {"max_correspondence_mm", g.max_correspondence_mm},
                       {"iterations", g.icp_iterations},
                       {"converged", g.converged},
                       {"global_found", g.global_found},
                       {"global_fitness", g.global_fitness},
                       {"time_s", g.time_s}};
  nlohmann::json c2c = StatsJson(r.c2c);
  c2c["method"] = r.distance_method;
  c2c["not_found"] = r.num_not_found;
  c2c["coverage"] = r.coverage;
  c2c["coverage_radius_mm"] = r.coverage_radius_mm;
  c2c["coverage_samples"] = r.coverage_samples;
  j["c2c"] = c2c;
  if (r.c2m) j["c2m"] = StatsJson(*r.c2m);
  if (r.m3c2) {
    nlohmann::json m3 = StatsJson(r.m3c2->stats);
    m3["valid"] = r.m3c2->num_valid;
    m3["significant"] = r.m3c2->num_significant;
    m3["mean_lod95_mm"] = r.m3c2->mean_lod95_mm;
    m3["projection_radius_mm"] = r.m3c2->options.projection_radius_mm;
    m3["max_depth_mm"] = r.m3c2->options.max_depth_mm;
    m3["registration_error_mm"] = r.m3c2->options.registration_error_mm;
    j["m3c2"] = m3;
  }
  if (r.vdi2634) j["vdi2634"] = r.vdi2634->ToJson();
  j["files"] = {{"cloud", "compared.ply"},
                {"histogram", "histogram.png"},
                {"deviation_map", "deviation_map.png"},
                {"summary", "summary.txt"}};
  j["time_s"] = r.time_s;
  return j;
}

void WriteReport(const fs::path& dir, const CompareResult& r, const ReportOptions& options) {
  SLSHADOW_THROW_IF(dir.empty(), "report: no output folder given");
  std::error_code ec;
  SLSHADOW_THROW_IF(fs::exists(dir, ec) && !fs::is_directory(dir, ec), dir.string(),
                    ": exists and is not a folder");
  SLSHADOW_THROW_IF(fs::exists(dir, ec) && !options.overwrite, dir.string(),
                    ": already exists and is kept (overwriting was disabled)");
  // Replacing is for an earlier report only: a folder of anything else (a typo'd --out naming a
  // folder of the user's) is kept. An empty folder holds nothing to lose.
  SLSHADOW_THROW_IF(
      fs::exists(dir, ec) && !fs::exists(dir / "report.json", ec) && !fs::is_empty(dir, ec),
      dir.string(),
      ": exists and is not a compare report (no report.json); it is kept, choose another --out");
  const fs::path target = fs::absolute(dir);
  if (target.has_parent_path()) fs::create_directories(target.parent_path(), ec);
  const fs::path staged = TemporarySibling(target);
  fs::create_directories(staged, ec);
  SLSHADOW_THROW_IF(ec, staged.string(), ": cannot create folder: ", ec.message());
  try {
    WriteTextFileAtomically(staged / "report.json", ReportJson(r).dump(2) + "\n");
    PlyWriteOptions ply;
    ply.binary = options.binary_ply;
    ply.double_positions = !(options.float_positions && FitsFloatPositions(r.compared.points));
    WritePly(staged / "compared.ply", r.compared, ply);
    // Histogram of the signed deviations for a mesh, else of the distances.
    const DistanceStats& s = r.c2m ? *r.c2m : r.c2c;
    HistogramChart hc;
    hc.title = r.c2m ? "signed deviation to the reference mesh" : "distance to the reference cloud";
    hc.x_label = r.c2m ? "signed deviation (mm, + outside)" : "distance (mm)";
    hc.is_signed = s.is_signed;
    hc.threshold_mm = s.threshold_mm;
    const double out_pct =
        r.c2c.count ? 100.0 * static_cast<double>(r.c2c.outliers) / static_cast<double>(r.c2c.count)
                    : 0.0;
    hc.notes = {std::to_string(r.c2c.count) + " points",
                "RMS " + StringPrintf("%.4f mm", r.c2c.rms_mm) + ", p95 " +
                    StringPrintf("%.4f mm", r.c2c.p95_mm),
                "beyond " + StringPrintf("%.3f mm", s.threshold_mm) + ": " +
                    StringPrintf("%.3f %%", out_pct),
                "coverage " + StringPrintf("%.1f %%", 100.0 * r.coverage)};
    if (r.c2m)
      hc.notes.insert(hc.notes.begin() + 1,
                      "signed mean " + StringPrintf("%+.4f mm", r.c2m->signed_mean_mm));
    const size_t beyond = s.histogram.underflow + s.histogram.overflow;
    if (beyond > 0 && s.count > 0) {
      hc.notes.push_back(
          StringPrintf("%.2f %% beyond the axis",
                       100.0 * static_cast<double>(beyond) / static_cast<double>(s.count)));
    }
    WriteHistogramPng(staged / "histogram.png", s.histogram, hc);
    const ViewCamera view = options.view ? *options.view : FitView(r.compared);
    const ValueImage img =
        RenderValues(r.compared.points, r.deviations_mm, view, 0, r.median_spacing_mm);
    MapChart mc;
    mc.title = r.c2m ? "signed deviation (mm)" : "distance to reference (mm)";
    mc.colorbar_label = r.c2m ? "signed deviation (mm)" : "distance (mm)";
    mc.lo = s.histogram.lo_mm;
    mc.hi = s.histogram.hi_mm;
    mc.marks = {s.threshold_mm};
    if (s.is_signed) mc.marks.push_back(-s.threshold_mm);
    mc.notes = {StringPrintf(r.options.color_range_mm > 0
                                 ? "colour range +-%.4g mm (fixed)"
                                 : "colour range +-%.4g mm (99 %% of points)",
                             s.histogram.hi_mm)};
    if (s.threshold_mm >= s.histogram.hi_mm)
      mc.notes.push_back(StringPrintf("threshold %.4g mm: beyond the range", s.threshold_mm));
    else
      mc.notes.push_back(StringPrintf("threshold %.4g mm: black lines", s.threshold_mm));
    WriteDeviationMapPng(staged / "deviation_map.png", img, mc);
    WriteTextFileAtomically(staged / "summary.txt", r.Summary());
    if (options.before_commit) options.before_commit(staged);
    CommitDirectory(staged, target, options.overwrite);
  } catch (...) {
    fs::remove_all(staged, ec);
    throw;
  }
}

CompareResult CompareAndReport(const PointCloud& cloud, const Reference& reference,
                               const CompareOptions& options, const fs::path& out_dir,
                               const ReportOptions& report_options,
                               const std::string& cloud_source) {
  CompareResult r = Compare(cloud, reference, options, cloud_source);
  WriteReport(out_dir, r, report_options);
  return r;
}

}  // namespace slshadow::compare
