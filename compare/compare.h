// Compare a cloud against a reference (a mesh or a cloud): optional registration, per-point
// deviations, statistics and coverage. This is the library call behind `slshadow compare`;
// compare/report.h writes the result as a report folder.
//
// Deviations: with a mesh reference, the signed distance to the nearest triangle (C2M, positive
// outside); with a cloud reference, the nearest-neighbour distance (C2C, unsigned, with the
// optional local model). The "c2c" statistics are always over |deviation|, i.e. the unsigned
// distance to the reference surface; "c2m" adds the signed statistics for a mesh reference.
//
// Coverage (in [0, 1]): the share of the reference surface the compared cloud reaches within
// the threshold. The reference surface is represented by samples (a mesh: area-uniform random
// samples, fixed seed, `reference_samples` of them; a cloud: its own points); a sample counts as
// reached when an inlier of the compared cloud (|deviation| <= threshold) lies within
// coverage_radius_mm of it. The automatic radius is max(threshold, 3 x the compared cloud's
// median nearest-neighbour spacing): a correct cloud sampled more coarsely than the threshold
// still covers the surface it sees, also when its points are random rather than on a grid
// (random points at density rho leave a disc of radius 3 x 0.5 / sqrt(rho) empty with
// probability exp(-9 pi / 4) = 0.1 %). Parts the scanner cannot see count as not covered.
#pragma once

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "compare/distances.h"
#include "compare/registration.h"
#include "compare/statistics.h"
#include "compare/vdi2634.h"
#include "core/mesh.h"
#include "core/point_cloud.h"

namespace slshadow::compare {

class MeshDistance;

struct Reference {
  std::string source;  // file name or a description, for the report
  TriangleMesh mesh;   // non-empty for a mesh reference
  // The distance hierarchy over `mesh`, built once by ReferenceFromMesh and shared by every
  // Compare() against this reference (and by copies of it); Compare builds one when it is null.
  // Rebuild it (or reset it) after changing `mesh`.
  std::shared_ptr<const MeshDistance> mesh_distance;
  // Points (with unit normals) representing the reference: a cloud reference's own points, or
  // area-uniform samples of the mesh with their face normals. Registration and coverage use it.
  PointCloud cloud;
  bool IsMesh() const { return !mesh.empty(); }
};

// Mesh reference: `samples` area-uniform samples (random, fixed seed) with face normals.
Reference ReferenceFromMesh(TriangleMesh mesh, const std::string& source, size_t samples = 200000);
Reference ReferenceFromCloud(PointCloud cloud, const std::string& source);
// .stl / .obj: a mesh; .ply: a mesh when it has faces, else a cloud. Throws slshadow::Error.
Reference LoadReference(const std::filesystem::path& path, size_t mesh_samples = 200000);

struct CompareOptions {
  RegistrationOptions registration = [] {
    RegistrationOptions r;
    r.method = RegistrationMethod::kNone;  // clouds from slshadow share the reference's frame
    return r;
  }();
  C2COptions c2c;                   // cloud references only
  double threshold_mm = 0.25;       // inlier / outlier threshold
  double coverage_radius_mm = 0.0;  // 0: automatic (see above)
  int histogram_bins = 60;
  // Colour (and histogram) range of the deviation map, histogram and PLY colours, mm: 0 scales
  // to the data (symmetric at the 99th percentile of |deviation|), > 0 fixes it at +-range.
  double color_range_mm = 0.0;
  bool m3c2 = false;  // also compute M3C2 distances at every compared point
  M3C2Options m3c2_options;
  // VDI/VDE 2634-2 figures of the artefacts in the (registered) compared cloud, when given.
  std::optional<ArtefactSpec> artefacts;
  Vdi2634Options vdi2634;
  void Check() const;  // throws slshadow::Error naming the bad field
};

// CompareOptions as a file (YAML or JSON, docs/formats.md "Compare options"): every field under its
// own name (registration, c2c, m3c2_options and vdi2634 as nested mappings, artefacts as an
// artefact file's mapping or null); missing fields keep their defaults, unknown keys are rejected
// at every level, the result is Check()ed. Throws slshadow::Error naming the file, field, value.
nlohmann::json CompareOptionsToJson(const CompareOptions& options);
CompareOptions CompareOptionsFromConfig(const ConfigNode& node);

struct M3C2Summary {
  M3C2Options options;
  size_t num_valid = 0, num_significant = 0;
  DistanceStats stats;  // of the valid signed M3C2 distances
  double mean_lod95_mm = 0.0;
};

struct CompareResult {
  std::string cloud_source, reference_source;
  bool reference_is_mesh = false;
  size_t reference_size = 0;  // triangles (mesh) or points (cloud)
  CompareOptions options;
  RegistrationResult registration;
  std::string distance_method;       // "nearest_triangle" (C2M) or "nearest_point" (C2C)
  DistanceStats c2c;                 // unsigned statistics (see the header comment)
  std::optional<DistanceStats> c2m;  // signed statistics, mesh references only
  size_t num_not_found = 0;          // C2C points beyond c2c.max_distance_mm
  double coverage = 0.0;
  double coverage_radius_mm = 0.0;
  size_t coverage_samples = 0;
  // MedianSpacing of the compared points when the automatic coverage radius needed it, else 0.
  double median_spacing_mm = 0.0;
  std::optional<M3C2Summary> m3c2;
  std::optional<Vdi2634Result> vdi2634;
  // The compared cloud moved into the reference frame, with scalar fields "deviation" (signed
  // for a mesh, else unsigned), "m3c2_distance" / "m3c2_lod95" / "m3c2_significant" when
  // computed, and colours from the deviation (compare/charts.h colour map over the histogram
  // range).
  PointCloud compared;
  std::vector<double> deviations_mm;  // one per compared point (same as the "deviation" field)
  // Coverage of each extra sample set given to Compare (e.g. the surface a camera sees), with
  // the criterion and radius of `coverage`: Coverage(samples, inliers, coverage_radius_mm).
  std::vector<double> extra_coverage;
  double time_s = 0.0;

  // One screen of text: inputs, registration, statistics, coverage.
  std::string Summary() const;
};

CompareResult Compare(const PointCloud& cloud, const Reference& reference,
                      const CompareOptions& options, const std::string& cloud_source = "cloud");
// The same, moving the cloud into CompareResult::compared instead of copying it.
CompareResult Compare(PointCloud&& cloud, const Reference& reference, const CompareOptions& options,
                      const std::string& cloud_source = "cloud");
// The same, also measuring the coverage of each of `extra_coverage_samples` (in
// CompareResult::extra_coverage, in that order) from the same index of the inliers.
CompareResult Compare(
    PointCloud&& cloud, const Reference& reference, const CompareOptions& options,
    const std::string& cloud_source,
    const std::vector<const std::vector<Eigen::Vector3d>*>& extra_coverage_samples);

}  // namespace slshadow::compare
