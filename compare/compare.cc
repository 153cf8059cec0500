#include "compare/compare.h"
#include "compare/coverage.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <random>
#include <sstream>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "compare/charts.h"
#include "compare/median_spacing.h"
#include "compare/mesh_distance.h"
#include "core/config.h"
#include "core/error.h"
#include "core/kdtree.h"
#include "core/string_printf.h"

namespace slshadow::compare {
namespace fs = std::filesystem;

namespace {

std::vector<Eigen::Vector3d> NormalsAsDouble(const PointCloud& c) {
  std::vector<Eigen::Vector3d> n;
  n.reserve(c.normals.size());
  for (const auto& v : c.normals) n.push_back(v.cast<double>());
  return n;
}

}  // namespace

Reference ReferenceFromMesh(TriangleMesh mesh, const std::string& source, size_t samples) {
  mesh.Check(source, /*reject_degenerate=*/false);
  SLSHADOW_THROW_IF(samples < 1, source, ": needs at least one surface sample");
  Reference ref;
  ref.source = source;
  std::vector<double> cumulative(mesh.NumTriangles());
  double total = 0;
  for (size_t t = 0; t < mesh.NumTriangles(); ++t) {
    total += mesh.TriangleArea(t);
    cumulative[t] = total;
  }
  SLSHADOW_THROW_IF(!(total > 0), source, ": the mesh has zero surface area");
  std::mt19937_64 rng(20261122);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  ref.cloud.points.reserve(samples);
  ref.cloud.normals.reserve(samples);
  for (size_t i = 0; i < samples; ++i) {
    const double r = u(rng) * total;
    const size_t t = std::min<size_t>(
        static_cast<size_t>(std::upper_bound(cumulative.begin(), cumulative.end(), r) -
                            cumulative.begin()),
        mesh.NumTriangles() - 1);
    const Eigen::Vector3i& f = mesh.triangles[t];
    const double s = std::sqrt(u(rng)), b = u(rng);
    const Eigen::Vector3d& a = mesh.vertices[static_cast<size_t>(f[0])];
    const Eigen::Vector3d& p1 = mesh.vertices[static_cast<size_t>(f[1])];
    const Eigen::Vector3d& p2 = mesh.vertices[static_cast<size_t>(f[2])];
    ref.cloud.points.push_back((1 - s) * a + s * (1 - b) * p1 + s * b * p2);
    ref.cloud.normals.push_back(mesh.FaceNormal(t).cast<float>());
  }
  ref.mesh = std::move(mesh);
  ref.mesh_distance = std::make_shared<const MeshDistance>(ref.mesh);
  return ref;
}

Reference ReferenceFromCloud(PointCloud cloud, const std::string& source) {
  cloud.Check(source);
  SLSHADOW_THROW_IF(cloud.empty(), source, ": the reference cloud has no points");
  Reference ref;
  ref.source = source;
  ref.cloud = std::move(cloud);
  return ref;
}

Reference LoadReference(const fs::path& path, size_t mesh_samples) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  if (ext == ".stl" || ext == ".obj")
    return ReferenceFromMesh(ReadMesh(path), path.string(), mesh_samples);
  SLSHADOW_THROW_IF(ext != ".ply", path.string(), ": reference must be .ply, .stl or .obj (got '",
                    ext, "')");
  const PlyData ply = ReadPlyData(path);
  const PlyElement* faces = ply.Find("face");
  if (faces && faces->count > 0)
    return ReferenceFromMesh(ReadMesh(path), path.string(), mesh_samples);
  return ReferenceFromCloud(ReadPly(path), path.string());
}

void CompareOptions::Check() const {
  registration.Check();
  c2c.Check();
  SLSHADOW_THROW_IF(!(threshold_mm > 0) || !std::isfinite(threshold_mm),
                    "threshold_mm: must be finite and > 0 (got ", threshold_mm, ")");
  SLSHADOW_THROW_IF(!(coverage_radius_mm >= 0) || !std::isfinite(coverage_radius_mm),
                    "coverage_radius_mm: must be finite and >= 0 (got ", coverage_radius_mm, ")");
  SLSHADOW_THROW_IF(!(color_range_mm >= 0) || !std::isfinite(color_range_mm),
                    "color_range_mm: must be finite and >= 0 (0: scaled to the data; got ",
                    color_range_mm, ")");
  SLSHADOW_THROW_IF(histogram_bins < 2 || histogram_bins > 10000,
                    "histogram_bins: must be in [2, 10000] (got ", histogram_bins, ")");
  if (m3c2) m3c2_options.Check();
  if (artefacts) {
    artefacts->Check("artefacts");
    vdi2634.Check();
  }
}

namespace {

template <typename Parse>
auto ParseName(const ConfigNode& node, Parse parse) {
  try {
    return parse(node.AsString());
  } catch (const Error& e) {
    node.Fail(e.what());
  }
}

unsigned GetSeed(const ConfigNode& node, const std::string& key, unsigned fallback) {
  const int64_t seed = node.GetInt(key, fallback);
  if (seed < 0 || seed > 0xffffffffLL) node[key].Fail("must be in [0, 2^32 - 1]");
  return static_cast<unsigned>(seed);
}

}  // namespace

nlohmann::json CompareOptionsToJson(const CompareOptions& o) {
  const RegistrationOptions& r = o.registration;
  nlohmann::json j;
  j["registration"] = {{"method", ToString(r.method)},
                       {"voxel_mm", r.voxel_mm},
                       {"feature_radius_mm", r.feature_radius_mm},
                       {"ransac_iterations", r.ransac_iterations},
                       {"ransac_inlier_fraction", r.ransac_inlier_fraction},
                       {"seed", r.seed},
                       {"icp_max_correspondence_mm", r.icp_max_correspondence_mm},
                       {"icp_max_iterations", r.icp_max_iterations},
                       {"icp_max_points", r.icp_max_points},
                       {"icp_tolerance", r.icp_tolerance}};
  j["c2c"] = {{"max_distance_mm", o.c2c.max_distance_mm},
              {"local_model", ToString(o.c2c.local_model)},
              {"local_model_neighbors", o.c2c.local_model_neighbors}};
  j["threshold_mm"] = o.threshold_mm;
  j["coverage_radius_mm"] = o.coverage_radius_mm;
  j["histogram_bins"] = o.histogram_bins;
  j["color_range_mm"] = o.color_range_mm;
  j["m3c2"] = o.m3c2;
  j["m3c2_options"] = {{"projection_radius_mm", o.m3c2_options.projection_radius_mm},
                       {"max_depth_mm", o.m3c2_options.max_depth_mm},
                       {"registration_error_mm", o.m3c2_options.registration_error_mm},
                       {"min_points", o.m3c2_options.min_points}};
  j["artefacts"] = o.artefacts ? ArtefactSpecToJson(*o.artefacts) : nlohmann::json(nullptr);
  j["vdi2634"] = Vdi2634OptionsToJson(o.vdi2634);
  return j;
}

CompareOptions CompareOptionsFromConfig(const ConfigNode& node) {
  if (!node.IsObject()) node.Fail("expected a mapping of compare options");
  node.RejectUnknownKeys({"registration", "c2c", "threshold_mm", "coverage_radius_mm",
                          "histogram_bins", "m3c2", "m3c2_options", "artefacts", "vdi2634",
                          "color_range_mm"});
  CompareOptions o;
  if (node.Has("registration")) {
    const ConfigNode n = node["registration"];
    n.RejectUnknownKeys({"method", "voxel_mm", "feature_radius_mm", "ransac_iterations",
                         "ransac_inlier_fraction", "seed", "icp_max_correspondence_mm",
                         "icp_max_iterations", "icp_max_points", "icp_tolerance"});
    RegistrationOptions& r = o.registration;
    if (n.Has("method"))
      r.method = ParseName(n["method"],
                           [](const std::string& s) { return RegistrationMethodFromString(s); });
    r.voxel_mm = n.GetDouble("voxel_mm", r.voxel_mm);
    r.feature_radius_mm = n.GetDouble("feature_radius_mm", r.feature_radius_mm);
    r.ransac_iterations = static_cast<int>(n.GetInt("ransac_iterations", r.ransac_iterations));
    r.ransac_inlier_fraction = n.GetDouble("ransac_inlier_fraction", r.ransac_inlier_fraction);
    r.seed = GetSeed(n, "seed", r.seed);
    r.icp_max_correspondence_mm =
        n.GetDouble("icp_max_correspondence_mm", r.icp_max_correspondence_mm);
    r.icp_max_iterations = static_cast<int>(n.GetInt("icp_max_iterations", r.icp_max_iterations));
    r.icp_max_points = static_cast<int>(n.GetInt("icp_max_points", r.icp_max_points));
    r.icp_tolerance = n.GetDouble("icp_tolerance", r.icp_tolerance);
  }
  if (node.Has("c2c")) {
    const ConfigNode n = node["c2c"];
    n.RejectUnknownKeys({"max_distance_mm", "local_model", "local_model_neighbors"});
    o.c2c.max_distance_mm = n.GetDouble("max_distance_mm", o.c2c.max_distance_mm);
    if (n.Has("local_model")) {
      o.c2c.local_model =
          ParseName(n["local_model"], [](const std::string& s) { return LocalModelFromString(s); });
    }
    o.c2c.local_model_neighbors =
        static_cast<int>(n.GetInt("local_model_neighbors", o.c2c.local_model_neighbors));
  }
  o.threshold_mm = node.GetDouble("threshold_mm", o.threshold_mm);
  o.coverage_radius_mm = node.GetDouble("coverage_radius_mm", o.coverage_radius_mm);
  o.histogram_bins = static_cast<int>(node.GetInt("histogram_bins", o.histogram_bins));
  o.color_range_mm = node.GetDouble("color_range_mm", o.color_range_mm);
  o.m3c2 = node.GetBool("m3c2", o.m3c2);
  if (node.Has("m3c2_options")) {
    const ConfigNode n = node["m3c2_options"];
    n.RejectUnknownKeys(
        {"projection_radius_mm", "max_depth_mm", "registration_error_mm", "min_points"});
    M3C2Options& m = o.m3c2_options;
    m.projection_radius_mm = n.GetDouble("projection_radius_mm", m.projection_radius_mm);
    m.max_depth_mm = n.GetDouble("max_depth_mm", m.max_depth_mm);
    m.registration_error_mm = n.GetDouble("registration_error_mm", m.registration_error_mm);
    m.min_points = static_cast<int>(n.GetInt("min_points", m.min_points));
  }
  if (node.Has("artefacts") && !node["artefacts"].json().is_null())
    o.artefacts = ArtefactSpecFromConfig(node["artefacts"]);
  if (node.Has("vdi2634")) o.vdi2634 = Vdi2634OptionsFromConfig(node["vdi2634"]);
  try {
    o.Check();
    o.m3c2_options.Check();  // checked whatever `m3c2` says: a file keeps no invalid values
  } catch (const Error& e) {
    SLSHADOW_THROW(node.file(), node.path().empty() ? "" : ": ", node.path(), ": ", e.what());
  }
  return o;
}

CompareResult Compare(const PointCloud& cloud, const Reference& reference,
                      const CompareOptions& options, const std::string& cloud_source) {
  return Compare(PointCloud(cloud), reference, options, cloud_source);
}

CompareResult Compare(PointCloud&& cloud, const Reference& reference, const CompareOptions& options,
                      const std::string& cloud_source) {
  return Compare(std::move(cloud), reference, options, cloud_source, {});
}

CompareResult Compare(
    PointCloud&& cloud, const Reference& reference, const CompareOptions& options,
    const std::string& cloud_source,
    const std::vector<const std::vector<Eigen::Vector3d>*>& extra_coverage_samples) {
  options.Check();
  cloud.Check(cloud_source);
  SLSHADOW_THROW_IF(cloud.empty(), cloud_source, ": the compared cloud has no points");
  SLSHADOW_THROW_IF(reference.cloud.empty(), reference.source, ": the reference is empty");
  const auto t0 = std::chrono::steady_clock::now();
  CompareResult r;
  r.cloud_source = cloud_source;
  r.reference_source = reference.source;
  r.reference_is_mesh = reference.IsMesh();
  r.reference_size = reference.IsMesh() ? reference.mesh.NumTriangles() : reference.cloud.size();
  r.options = options;

  const auto ref_normals = NormalsAsDouble(reference.cloud);
  r.registration =
      Register(cloud.points, reference.cloud.points, ref_normals, options.registration);
  r.compared = std::move(cloud);
  const Rigid3d& t = r.registration.reference_from_cloud;
  for (auto& p : r.compared.points) p = t * p;
  const Eigen::Matrix3f rot = t.rotation.toRotationMatrix().cast<float>();
  for (auto& n : r.compared.normals) n = rot * n;
  const auto& pts = r.compared.points;

  // Trees only where a query needs them: C2M and the coverage use none.
  std::unique_ptr<KdTree> ref_tree;
  if (!reference.IsMesh() || options.m3c2)
    ref_tree = std::make_unique<KdTree>(reference.cloud.points);
  bool is_signed = false;
  if (reference.IsMesh()) {
    r.distance_method = "nearest_triangle";
    r.deviations_mm = (reference.mesh_distance ? CloudToMesh(pts, *reference.mesh_distance)
                                               : CloudToMesh(pts, MeshDistance(reference.mesh)))
                          .signed_distances_mm;
    is_signed = true;
  } else {
    r.distance_method = "nearest_point";
    C2CResult c2c = CloudToCloud(pts, *ref_tree, options.c2c);
    r.deviations_mm = std::move(c2c.distances_mm);
    r.num_not_found = c2c.num_not_found;
  }
  if (is_signed) {
    UnsignedAndSigned both = ComputeUnsignedAndSignedStats(
        r.deviations_mm, options.threshold_mm, options.histogram_bins, options.color_range_mm);
    r.c2c = std::move(both.unsigned_stats);
    r.c2m = std::move(both.signed_stats);
  } else {
    r.c2c = ComputeStats(r.deviations_mm, false, options.threshold_mm, options.histogram_bins,
                         options.color_range_mm);
  }

  // Coverage: the grid of the reached points (those within the threshold) taken from the cloud.
  if (!(options.coverage_radius_mm > 0)) r.median_spacing_mm = MedianSpacing(pts);
  r.coverage_radius_mm = options.coverage_radius_mm > 0
                             ? options.coverage_radius_mm
                             : std::max(options.threshold_mm, 3.0 * r.median_spacing_mm);
  {
    std::vector<uint8_t> reached(pts.size());
    for (size_t i = 0; i < pts.size(); ++i)
      reached[i] = std::abs(r.deviations_mm[i]) <= options.threshold_mm ? 1 : 0;
    std::vector<const std::vector<Eigen::Vector3d>*> sets = {&reference.cloud.points};
    sets.insert(sets.end(), extra_coverage_samples.begin(), extra_coverage_samples.end());
    std::vector<double> coverages = Coverages(sets, pts, reached, r.coverage_radius_mm);
    r.coverage = coverages.front();
    r.extra_coverage.assign(coverages.begin() + 1, coverages.end());
  }
  r.coverage_samples = reference.cloud.size();

  // Scalar fields and colours.
  std::vector<float> dev(pts.size());
  const Histogram& h = is_signed ? r.c2m->histogram : r.c2c.histogram;
  r.compared.colors.resize(pts.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, pts.size(), 65536),
                    [&](const tbb::blocked_range<size_t>& range) {
                      for (size_t i = range.begin(); i != range.end(); ++i) {
                        dev[i] = static_cast<float>(r.deviations_mm[i]);
                        r.compared.colors[i] =
                            DeviationColor((r.deviations_mm[i] - h.lo_mm) / (h.hi_mm - h.lo_mm));
                      }
                    });
  r.compared.SetScalar("deviation", std::move(dev));

  if (options.m3c2) {
    std::vector<Eigen::Vector3d> hints(pts.size(), Eigen::Vector3d::UnitZ());
    if (!ref_normals.empty()) {
      Neighbor nb;
      for (size_t i = 0; i < pts.size(); ++i) {
        if (ref_tree->Nearest(pts[i], &nb)) hints[i] = ref_normals[nb.index];
      }
    }
    const auto normals = EstimateNormals(pts, *ref_tree, 12, hints);
    const KdTree cmp_tree(pts);
    const M3C2Result m = M3C2(pts, normals, *ref_tree, cmp_tree, options.m3c2_options);
    M3C2Summary s;
    s.options = options.m3c2_options;
    s.num_valid = m.num_valid;
    s.num_significant = m.num_significant;
    s.stats = ComputeStats(m.distance_mm, true, options.threshold_mm, options.histogram_bins,
                           options.color_range_mm);
    double lod = 0;
    std::vector<float> d(pts.size()), l(pts.size()), sig(pts.size());
    for (size_t i = 0; i < pts.size(); ++i) {
      d[i] = static_cast<float>(m.distance_mm[i]);
      l[i] = static_cast<float>(m.lod95_mm[i]);
      sig[i] =
          std::isfinite(m.distance_mm[i]) && std::abs(m.distance_mm[i]) > m.lod95_mm[i] ? 1.f : 0.f;
      if (std::isfinite(m.lod95_mm[i])) lod += m.lod95_mm[i];
    }
    s.mean_lod95_mm = m.num_valid ? lod / static_cast<double>(m.num_valid) : 0.0;
    r.compared.SetScalar("m3c2_distance", std::move(d));
    r.compared.SetScalar("m3c2_lod95", std::move(l));
    r.compared.SetScalar("m3c2_significant", std::move(sig));
    r.m3c2 = s;
  }
  if (options.artefacts)
    r.vdi2634 = EvaluateVdi2634(r.compared, *options.artefacts, options.vdi2634);
  r.time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

std::string CompareResult::Summary() const {
  std::ostringstream o;
  const auto pct = [](size_t a, size_t b) {
    return b ? 100.0 * static_cast<double>(a) / static_cast<double>(b) : 0.0;
  };
  o << "compare: " << cloud_source << " (" << compared.size() << " points)\n"
    << "     vs " << reference_source << " (" << (reference_is_mesh ? "mesh, " : "cloud, ")
    << reference_size << (reference_is_mesh ? " triangles)\n" : " points)\n");
  o << registration.BriefReport() << "\n";
  o << "distance: "
    << (reference_is_mesh ? "signed point-to-triangle (C2M)" : "nearest neighbour (C2C)");
  if (!reference_is_mesh && options.c2c.local_model != LocalModel::kNone) {
    o << ", local model " << ToString(options.c2c.local_model);
  }
  o << "\n";
  const DistanceStats& s = c2c;
  o << "  points      " << s.count
    << (s.num_invalid ? " (" + std::to_string(s.num_invalid) + " invalid)" : "") << "\n"
    << "  mean        " << StringPrintf("%.4f mm", s.mean_mm) << "    std "
    << StringPrintf("%.4f mm", s.std_mm) << "\n"
    << "  rms         " << StringPrintf("%.4f mm", s.rms_mm) << "    median "
    << StringPrintf("%.4f mm", s.median_mm) << "\n"
    << "  p95         " << StringPrintf("%.4f mm", s.p95_mm) << "    max "
    << StringPrintf("%.4f mm", s.max_mm) << "\n";
  if (c2m) {
    o << "  signed mean " << StringPrintf("%+.4f mm", c2m->signed_mean_mm) << "    signed std "
      << StringPrintf("%.4f mm", c2m->signed_std_mm) << "\n";
  }
  o << "  threshold   " << StringPrintf("%.3f mm", s.threshold_mm) << ": " << s.inliers
    << " inliers, " << s.outliers << " outliers ("
    << StringPrintf("%.3f %%", pct(s.outliers, s.count)) << ")\n";
  if (num_not_found) o << "  beyond max search distance: " << num_not_found << "\n";
  o << "coverage: " << StringPrintf("%.2f %%", 100.0 * coverage) << " of the reference surface ("
    << coverage_samples << " samples, radius " << StringPrintf("%.3f mm", coverage_radius_mm)
    << ")\n";
  if (m3c2) {
    o << "M3C2: " << m3c2->num_valid << " valid, " << m3c2->num_significant << " significant ("
      << StringPrintf("%.2f %%", pct(m3c2->num_significant, m3c2->num_valid)) << "), mean "
      << StringPrintf("%+.4f mm", m3c2->stats.signed_mean_mm) << ", mean LoD95 "
      << StringPrintf("%.4f mm", m3c2->mean_lod95_mm) << "\n";
  }
  if (vdi2634) o << vdi2634->Summary();
  o << "time: " << StringPrintf("%.2f s", time_s) << "\n";
  return o.str();
}

}  // namespace slshadow::compare
