#include "workflows/multiview/cad_compare.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <limits>

#include "compare/charts.h"
#include "compare/compare.h"
#include "compare/distances.h"
#include "compare/median_spacing.h"
#include "compare/mesh_distance.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/kdtree.h"
#include "core/string_printf.h"
#include "workflows/multiview/internal/device_sight.h"

namespace slshadow::multiview {

namespace {

std::vector<Eigen::Vector3d> Moved(const PointCloud& cloud, const Rigid3d& motion) {
  std::vector<Eigen::Vector3d> points(cloud.size());
  tbb::parallel_for(size_t{0}, cloud.size(),
                    [&](size_t i) { points[i] = motion * cloud.points[i]; });
  return points;
}

double AutoRadius(const std::vector<Eigen::Vector3d>& points, const CadCompareOptions& options) {
  if (options.coverage_radius_mm > 0) return options.coverage_radius_mm;
  return std::max(options.threshold_mm, 3 * compare::MedianSpacing(points));
}

// reached[i]: an inlier of `points` (deviation within the threshold) lies within `radius` of
// samples[i].
std::vector<uint8_t> Reached(const std::vector<Eigen::Vector3d>& points,
                             const std::vector<double>& deviations_mm, double threshold_mm,
                             double radius_mm, const std::vector<Eigen::Vector3d>& samples) {
  std::vector<Eigen::Vector3d> inliers;
  inliers.reserve(points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    if (std::abs(deviations_mm[i]) <= threshold_mm) inliers.push_back(points[i]);
  }
  std::vector<uint8_t> reached(samples.size(), 0);
  if (inliers.empty()) return reached;
  const KdTree tree(inliers);
  tbb::parallel_for(size_t{0}, samples.size(), [&](size_t i) {
    Neighbor n;
    reached[i] = tree.Nearest(samples[i], &n, radius_mm) ? 1 : 0;
  });
  return reached;
}

// The best sight over `views` of each sample by every device in `devices` (CoverageReason: kCovered
// when some view sees it with all of them), by ray casting the CAD mesh (internal/device_sight.h).
std::vector<uint8_t> BestSight(const TriangleMesh& cad, const std::vector<Eigen::Vector3d>& samples,
                               const std::vector<Eigen::Vector3f>& normals,
                               const std::vector<const RigDevice*>& devices,
                               const std::vector<Rigid3d>& part_from_rig, double grazing_deg) {
  const internal::SightCaster caster(cad);
  std::vector<uint8_t> best(samples.size(), static_cast<uint8_t>(CoverageReason::kOutsideField));
  std::vector<uint8_t> active(samples.size(), 1);
  for (const Rigid3d& pose : part_from_rig) {
    const std::vector<uint8_t> sight =
        caster.View(samples, normals, devices, pose, grazing_deg, &active);
    for (size_t i = 0; i < samples.size(); ++i) {
      best[i] = std::min(best[i], sight[i]);
      active[i] = best[i] != static_cast<uint8_t>(CoverageReason::kCovered);
    }
  }
  return best;
}

// Splits kNotReconstructed samples of `reason` into kTooDark where every view that sees the sample
// (every device, unoccluded, not grazing) recorded its dark pixels and a camera's pixel under the
// sample is dark in it. Views without a record keep their samples not_reconstructed.
void MarkTooDark(const TriangleMesh& cad, const std::vector<Eigen::Vector3d>& samples,
                 const std::vector<Eigen::Vector3f>& normals,
                 const std::vector<const RigDevice*>& devices, const Rig& rig,
                 const std::vector<CadView>& views, double grazing_deg,
                 std::vector<uint8_t>* reason) {
  constexpr auto kNot = static_cast<uint8_t>(CoverageReason::kNotReconstructed);
  std::vector<uint8_t> active(samples.size());
  for (size_t i = 0; i < samples.size(); ++i) active[i] = (*reason)[i] == kNot;
  if (std::none_of(active.begin(), active.end(), [](uint8_t a) { return a != 0; })) return;
  // Per sample: 0 no view seen it yet, 1 every view that saw it was dark there, 2 some was not.
  std::vector<uint8_t> state(samples.size(), 0);
  const internal::SightCaster caster(cad);
  for (const CadView& v : views) {
    const std::vector<uint8_t> sight =
        caster.View(samples, normals, devices, v.part_from_rig, grazing_deg, &active);
    const Rigid3d rig_from_part = v.part_from_rig.Inverse();
    std::vector<std::pair<const RigDevice*, const DarkPixels*>> cameras;
    if (v.dark) {
      for (const DarkPixels& d : *v.dark) cameras.push_back({&rig.Camera(d.camera), &d});
    }
    tbb::parallel_for(size_t{0}, samples.size(), [&](size_t i) {
      if (!active[i] || sight[i] != static_cast<uint8_t>(CoverageReason::kCovered)) return;
      bool dark = false;
      const Eigen::Vector3d x_rig = rig_from_part * samples[i];
      for (const auto& [device, pixels] : cameras) {
        const auto pixel = device->model.Project(device->cam_from_rig * x_rig);
        if (pixel && pixels->At(*pixel)) dark = true;
      }
      state[i] = dark && state[i] != 2 ? 1 : 2;
    });
  }
  for (size_t i = 0; i < samples.size(); ++i) {
    if (active[i] && state[i] == 1) (*reason)[i] = static_cast<uint8_t>(CoverageReason::kTooDark);
  }
}

nlohmann::json StatsJson(const compare::DistanceStats& s) {
  return {{"count", s.count},
          {"rms_mm", s.rms_mm},
          {"mean_abs_mm", s.mean_mm},
          {"signed_mean_mm", s.signed_mean_mm},
          {"signed_std_mm", s.signed_std_mm},
          {"median_abs_mm", s.median_mm},
          {"p95_abs_mm", s.p95_mm},
          {"max_abs_mm", s.max_mm},
          {"inliers", s.inliers},
          {"outliers", s.outliers}};
}

}  // namespace

std::string ToString(CoverageReason reason) {
  switch (reason) {
    case CoverageReason::kCovered:
      return "covered";
    case CoverageReason::kNotReconstructed:
      return "not_reconstructed";
    case CoverageReason::kGrazing:
      return "grazing";
    case CoverageReason::kOccluded:
      return "occluded";
    case CoverageReason::kOutsideField:
      return "outside_field";
    case CoverageReason::kOnTable:
      return "on_table";
    case CoverageReason::kTooDark:
      return "too_dark";
  }
  return "unknown";
}

std::array<uint8_t, 3> ReasonColor(CoverageReason reason) {
  static const std::array<uint8_t, 3> kColors[kNumCoverageReasons] = {
      {40, 170, 60},   {220, 30, 30}, {240, 150, 20}, {40, 80, 220},
      {150, 150, 150}, {0, 0, 0},     {120, 20, 20}};
  return kColors[static_cast<size_t>(reason)];
}

DarkPixels DarkPixels::FromStatus(const std::string& camera, const cv::Mat& status) {
  SLSHADOW_THROW_IF(status.type() != CV_8UC1, "dark pixels of camera '", camera,
                    "': the status map must be CV_8UC1");
  DarkPixels d;
  d.camera = camera;
  d.width = status.cols;
  d.height = status.rows;
  d.dark.resize(static_cast<size_t>(d.width) * static_cast<size_t>(d.height));
  for (int y = 0; y < d.height; ++y) {
    const uint8_t* row = status.ptr<uint8_t>(y);
    for (int x = 0; x < d.width; ++x) {
      const auto s = static_cast<PixelStatus>(row[x]);
      d.dark[static_cast<size_t>(y) * static_cast<size_t>(d.width) + static_cast<size_t>(x)] =
          s == PixelStatus::kShadow || s == PixelStatus::kLowContrast;
    }
  }
  return d;
}

bool DarkPixels::At(const Eigen::Vector2d& pixel) const {
  // Integer coordinates are pixel centres (core/projector_map.h).
  const double x = std::round(pixel.x()), y = std::round(pixel.y());
  if (!(x >= 0 && y >= 0 && x < width && y < height)) return false;
  return dark[static_cast<size_t>(y) * static_cast<size_t>(width) + static_cast<size_t>(x)] != 0;
}

void CadCompareOptions::Check() const {
  SLSHADOW_THROW_IF(!(threshold_mm > 0), "CAD comparison: threshold_mm must be positive (got ",
                    threshold_mm, ")");
  SLSHADOW_THROW_IF(!(coverage_radius_mm >= 0),
                    "CAD comparison: coverage_radius_mm must be >= 0 (got ", coverage_radius_mm,
                    ")");
  SLSHADOW_THROW_IF(samples < 100, "CAD comparison: samples must be at least 100 (got ", samples,
                    ")");
  SLSHADOW_THROW_IF(!(grazing_deg > 0 && grazing_deg <= 90),
                    "CAD comparison: grazing_deg must be in (0, 90] (got ", grazing_deg, ")");
  SLSHADOW_THROW_IF(!(table_tolerance_mm >= 0),
                    "CAD comparison: table_tolerance_mm must be >= 0 (got ", table_tolerance_mm,
                    ")");
  SLSHADOW_THROW_IF(histogram_bins < 1, "CAD comparison: histogram_bins must be positive (got ",
                    histogram_bins, ")");
  SLSHADOW_THROW_IF(!(color_range_mm >= 0), "CAD comparison: color_range_mm must be >= 0 (got ",
                    color_range_mm, ")");
}

CadComparison CompareWithCad(const TriangleMesh& cad_in_part, const Rig& rig, ReconstructMode mode,
                             const std::vector<CadView>& views, const PointCloud& merged_in_part,
                             const std::optional<TurntableAxis>& table_axis,
                             const CadCompareOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  options.Check();
  SLSHADOW_THROW_IF(cad_in_part.empty(), "CAD comparison: the CAD mesh is empty");
  SLSHADOW_THROW_IF(merged_in_part.empty(), "CAD comparison: the merged cloud is empty");
  const std::vector<const RigDevice*> devices = internal::ModeDevices(rig, mode, "CAD comparison");
  CadComparison result;

  const compare::Reference reference =
      compare::ReferenceFromMesh(cad_in_part, "CAD model", options.samples);
  const compare::MeshDistance& mesh = *reference.mesh_distance;
  const std::vector<Eigen::Vector3d>& samples = reference.cloud.points;
  result.samples = samples.size();
  result.cad_area_mm2 = cad_in_part.SurfaceArea();

  // The merged cloud.
  result.merged_points = merged_in_part.size();
  result.merged_deviations_mm =
      compare::CloudToMesh(merged_in_part.points, mesh).signed_distances_mm;
  result.merged_c2m = compare::ComputeStats(result.merged_deviations_mm, true, options.threshold_mm,
                                            options.histogram_bins, options.color_range_mm);
  // The automatic radius of the merged cloud is that of its sparsest view: where views overlap
  // the merged cloud is denser than where one view alone sees the surface.
  result.coverage_radius_mm = AutoRadius(merged_in_part.points, options);
  if (options.coverage_radius_mm <= 0) {
    for (const CadView& v : views) {
      if (v.cloud && !v.cloud->empty())
        result.coverage_radius_mm =
            std::max(result.coverage_radius_mm, AutoRadius(v.cloud->points, options));
    }
  }
  const std::vector<uint8_t> covered =
      Reached(merged_in_part.points, result.merged_deviations_mm, options.threshold_mm,
              result.coverage_radius_mm, samples);

  // What the views could see, and the face on the table.
  std::vector<Rigid3d> poses;
  for (const CadView& v : views) poses.push_back(v.part_from_rig);
  const std::vector<uint8_t> sight =
      BestSight(cad_in_part, samples, reference.cloud.normals, devices, poses, options.grazing_deg);
  const std::vector<uint8_t> on_table = internal::OnTableMask(
      cad_in_part, samples, reference.cloud.normals, table_axis, options.table_tolerance_mm);
  result.sample_reason.resize(samples.size());
  for (size_t i = 0; i < samples.size(); ++i) {
    CoverageReason r;
    if (on_table[i]) {
      r = CoverageReason::kOnTable;
    } else if (covered[i]) {
      r = CoverageReason::kCovered;
    } else {
      r = sight[i] == static_cast<uint8_t>(CoverageReason::kCovered)
              ? CoverageReason::kNotReconstructed
              : static_cast<CoverageReason>(sight[i]);
    }
    result.sample_reason[i] = static_cast<uint8_t>(r);
  }
  MarkTooDark(cad_in_part, samples, reference.cloud.normals, devices, rig, views,
              options.grazing_deg, &result.sample_reason);
  for (const uint8_t r : result.sample_reason) ++result.reason_samples[r];
  const double n_samples = static_cast<double>(samples.size());
  for (int r = 0; r < kNumCoverageReasons; ++r) {
    result.reason_area_mm2[static_cast<size_t>(r)] =
        result.cad_area_mm2 * static_cast<double>(result.reason_samples[static_cast<size_t>(r)]) /
        n_samples;
  }
  const auto count = [&](CoverageReason r) {
    return static_cast<double>(result.reason_samples[static_cast<size_t>(r)]);
  };
  const double reachable = count(CoverageReason::kCovered) +
                           count(CoverageReason::kNotReconstructed) +
                           count(CoverageReason::kTooDark);
  const double off_table = n_samples - count(CoverageReason::kOnTable);
  result.coverage_reachable = reachable > 0 ? count(CoverageReason::kCovered) / reachable : 0;
  result.coverage_total = off_table > 0 ? count(CoverageReason::kCovered) / off_table : 0;
  result.reachable_share = off_table > 0 ? reachable / off_table : 0;

  // Each view alone, at its pose.
  for (const CadView& v : views) {
    CadViewFigures f;
    f.name = v.name;
    f.merged = v.cloud != nullptr && !v.cloud->empty();
    if (f.merged) {
      const std::vector<Eigen::Vector3d> points = Moved(*v.cloud, v.part_from_rig);
      const std::vector<double> d = compare::CloudToMesh(points, mesh).signed_distances_mm;
      f.points = points.size();
      f.c2m = compare::ComputeStats(d, true, options.threshold_mm, options.histogram_bins,
                                    options.color_range_mm);
      f.coverage_radius_mm = AutoRadius(points, options);
      const std::vector<uint8_t> reached =
          Reached(points, d, options.threshold_mm, f.coverage_radius_mm, samples);
      size_t hit = 0;
      for (size_t i = 0; i < samples.size(); ++i) {
        if (reached[i] && Reachable(static_cast<CoverageReason>(result.sample_reason[i]))) ++hit;
      }
      f.coverage = reachable > 0 ? static_cast<double>(hit) / reachable : 0;
    }
    result.views.push_back(std::move(f));
  }

  // The painting: per CAD vertex the mean deviation of the merged points around it.
  result.color_range_mm = options.color_range_mm > 0
                              ? options.color_range_mm
                              : std::max(result.merged_c2m.histogram.hi_mm, 1e-6);
  {
    const KdTree merged_tree(merged_in_part.points);
    const KdTree sample_tree(samples);
    const size_t nv = cad_in_part.vertices.size();
    result.vertex_deviation_mm.assign(nv, std::numeric_limits<float>::quiet_NaN());
    result.vertex_reason.assign(nv, 0);
    tbb::parallel_for(size_t{0}, nv, [&](size_t i) {
      const Eigen::Vector3d& x = cad_in_part.vertices[i];
      std::vector<Neighbor> near;
      merged_tree.Radius(x, result.coverage_radius_mm, &near);
      if (!near.empty()) {
        double sum = 0;
        for (const auto& n : near) sum += result.merged_deviations_mm[n.index];
        result.vertex_deviation_mm[i] = static_cast<float>(sum / static_cast<double>(near.size()));
      }
      Neighbor s;
      if (sample_tree.Nearest(x, &s)) result.vertex_reason[i] = result.sample_reason[s.index];
    });
  }
  result.sample_points = samples;
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

nlohmann::json CadComparison::ToJson() const {
  nlohmann::json j;
  j["merged"] = StatsJson(merged_c2m);
  j["merged"]["points"] = merged_points;
  j["merged"]["coverage_radius_mm"] = coverage_radius_mm;
  j["coverage"] = {{"reachable", coverage_reachable},
                   {"total_off_table", coverage_total},
                   {"reachable_share", reachable_share},
                   {"cad_area_mm2", cad_area_mm2},
                   {"samples", samples}};
  nlohmann::json areas = nlohmann::json::object();
  for (int r = 0; r < kNumCoverageReasons; ++r) {
    areas[ToString(static_cast<CoverageReason>(r))] = {
        {"samples", reason_samples[static_cast<size_t>(r)]},
        {"area_mm2", reason_area_mm2[static_cast<size_t>(r)]},
        {"share", samples ? static_cast<double>(reason_samples[static_cast<size_t>(r)]) /
                                static_cast<double>(samples)
                          : 0.0}};
  }
  j["surface_by_reason"] = areas;
  j["views"] = nlohmann::json::array();
  for (const CadViewFigures& v : views) {
    nlohmann::json view = {{"name", v.name}, {"merged", v.merged}};
    if (v.merged) {
      view["c2m"] = StatsJson(v.c2m);
      view["points"] = v.points;
      view["coverage_reachable"] = v.coverage;
      view["coverage_radius_mm"] = v.coverage_radius_mm;
    }
    j["views"].push_back(std::move(view));
  }
  j["color_range_mm"] = color_range_mm;
  j["seconds"] = seconds;
  return j;
}

std::string CadComparison::Summary() const {
  std::string out = StringPrintf(
      "CAD comparison: merged cloud %zu points, signed C2M RMS %.4f mm, mean %+.4f mm, p95 |d| "
      "%.4f mm, max |d| %.3f mm, outliers %zu (> %.3f mm)\n"
      "coverage: %.2f %% of the reachable CAD surface, %.2f %% of the surface off the table "
      "(reachable: %.2f %%; radius %.3f mm)\n",
      merged_points, merged_c2m.rms_mm, merged_c2m.signed_mean_mm, merged_c2m.p95_mm,
      merged_c2m.max_mm, merged_c2m.outliers, merged_c2m.threshold_mm, 100 * coverage_reachable,
      100 * coverage_total, 100 * reachable_share, coverage_radius_mm);
  out += "CAD surface by reason:";
  for (int r = 0; r < kNumCoverageReasons; ++r) {
    out +=
        StringPrintf(" %s %.0f mm2 (%.2f %%)%s", ToString(static_cast<CoverageReason>(r)).c_str(),
                     reason_area_mm2[static_cast<size_t>(r)],
                     samples ? 100.0 * static_cast<double>(reason_samples[static_cast<size_t>(r)]) /
                                   static_cast<double>(samples)
                             : 0.0,
                     r + 1 < kNumCoverageReasons ? "," : "\n");
  }
  out += "view        points    RMS (mm)  mean (mm)  p95 (mm)  coverage of reachable\n";
  for (const CadViewFigures& v : views) {
    if (!v.merged) {
      out += StringPrintf("%-10s  left out of the merge\n", v.name.c_str());
      continue;
    }
    out += StringPrintf("%-10s %8zu   %8.4f   %+8.4f  %8.4f  %6.2f %%\n", v.name.c_str(), v.points,
                        v.c2m.rms_mm, v.c2m.signed_mean_mm, v.c2m.p95_mm, 100 * v.coverage);
  }
  return out;
}

void WritePaintedMesh(const std::filesystem::path& path, const TriangleMesh& cad,
                      const CadComparison& comparison) {
  SLSHADOW_THROW_IF(comparison.vertex_deviation_mm.size() != cad.vertices.size(), path.string(),
                    ": the comparison was made with another mesh (",
                    comparison.vertex_deviation_mm.size(), " painted vertices, the mesh has ",
                    cad.vertices.size(), ")");
  WriteFileAtomically(path, [&](const std::filesystem::path& tmp) {
    std::ofstream out(tmp, std::ios::binary);
    SLSHADOW_THROW_IF(!out, tmp.string(), ": cannot open for writing");
    out << "ply\nformat binary_little_endian 1.0\ncomment slshadow: CAD mesh painted by the signed "
           "C2M of the merged cloud (mm); grey = not covered\n"
        << "comment color range +-" << comparison.color_range_mm << " mm\n"
        << "element vertex " << cad.vertices.size()
        << "\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty "
           "uchar green\nproperty uchar blue\nproperty float deviation_mm\nproperty uchar reason\n"
        << "element face " << cad.triangles.size()
        << "\nproperty list uchar int vertex_indices\nend_header\n";
    const double range = comparison.color_range_mm;
    for (size_t i = 0; i < cad.vertices.size(); ++i) {
      const float xyz[3] = {static_cast<float>(cad.vertices[i].x()),
                            static_cast<float>(cad.vertices[i].y()),
                            static_cast<float>(cad.vertices[i].z())};
      out.write(reinterpret_cast<const char*>(xyz), sizeof(xyz));
      const float d = comparison.vertex_deviation_mm[i];
      std::array<uint8_t, 3> rgb = {160, 160, 160};
      if (std::isfinite(d)) rgb = compare::DeviationColor((d + range) / (2 * range));
      out.write(reinterpret_cast<const char*>(rgb.data()), 3);
      out.write(reinterpret_cast<const char*>(&d), sizeof(d));
      out.put(static_cast<char>(comparison.vertex_reason[i]));
    }
    for (const Eigen::Vector3i& t : cad.triangles) {
      out.put(3);
      const int32_t idx[3] = {t.x(), t.y(), t.z()};
      out.write(reinterpret_cast<const char*>(idx), sizeof(idx));
    }
    SLSHADOW_THROW_IF(!out.good(), tmp.string(), ": write failed");
  });
}

}  // namespace slshadow::multiview
