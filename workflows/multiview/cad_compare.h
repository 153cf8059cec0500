// A multi-view scan compared with the part's CAD model: the signed cloud-to-mesh distance (C2M,
// compare/mesh_distance.h) of the merged cloud and of each view's cloud at its pose, the
// deviation painted on the CAD mesh per vertex, and the CAD surface no view covered with the
// reason when the geometry tells it.
//
// Frames and units: the part frame (workflows/multiview/views.h), mm. The CAD mesh is in the part
// frame; each view's cloud is in the rig frame and moves into the part frame by the view's
// part_from_rig.
//
// Coverage. The CAD surface is represented by area-uniform samples (compare::ReferenceFromMesh,
// fixed seed) with their face normals. A sample is reached by a cloud when one of the cloud's
// inliers (|C2M| <= threshold) lies within the coverage radius of it (as compare/compare.h
// defines coverage). Each sample not reached gets the reason, from the geometry of the views
// (the CAD mesh ray-cast with Embree, every device of the reconstruction mode: stereo needs both
// cameras and the projector, projector mode the first camera and the projector):
//   on_table           a face lying on the turntable (normal against the axis, at the part's
//                      lowest height along it): excluded from the reachable surface;
//   outside_field      in no view inside every device's image;
//   occluded           in every view where it is in the field, hidden from a device by the part
//                      (or facing away from it);
//   grazing            seen unoccluded by every device of some view, but at an incidence beyond
//                      grazing_deg to one of them;
//   too_dark           reachable, no cloud covers it, and in every view that sees it the decoder
//                      found a camera's pixel there too dark to decode (ProjectorMap status shadow
//                      or low contrast: white - black or the fringes' contrast below the decode
//                      thresholds): measured on the view's own images (CadView::dark), not
//                      predicted; views without that record leave the sample not_reconstructed;
//   not_reconstructed  reachable (some view sees it with every device, unoccluded, not grazing)
//                      but no cloud covers it, and not too dark: filtered, noisy, or a merge that
//                      left a view out.
// Coverage of the reachable surface = covered / (covered + not_reconstructed + too_dark) samples;
// the "reachable" share is what the rig could at best cover from these views.
#pragma once

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "compare/statistics.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "core/projector_map.h"
#include "core/rig.h"
#include "core/rigid3.h"
#include "reconstruct/reconstruct.h"

namespace slshadow::multiview {

enum class CoverageReason {
  kCovered,
  kNotReconstructed,
  kGrazing,
  kOccluded,
  kOutsideField,
  kOnTable,
  kTooDark,  // last, so that the numbers of the others (PLY `reason` scalars) stay as they were
};
// "covered", "not_reconstructed", "grazing", "occluded", "outside_field", "on_table", "too_dark"
std::string ToString(CoverageReason reason);
constexpr int kNumCoverageReasons = 7;
// The colour of a reason in cad_coverage.ply (docs/formats.md): covered green, not reconstructed
// red, grazing orange, occluded blue, outside the field grey, on the table black, too dark dark
// red.
std::array<uint8_t, 3> ReasonColor(CoverageReason reason);
// Reachable: some view sees the sample with every device, unoccluded, not grazing.
inline bool Reachable(CoverageReason r) {
  return r == CoverageReason::kCovered || r == CoverageReason::kNotReconstructed ||
         r == CoverageReason::kTooDark;
}

struct CadCompareOptions {
  double threshold_mm = 0.25;  // inlier threshold of coverage
  // 0: per cloud, max(threshold, 3 x its median spacing); for the merged cloud the largest of
  // that and its views' radii (one view alone covers some of the surface).
  double coverage_radius_mm = 0.0;
  size_t samples = 200000;          // CAD surface samples
  double grazing_deg = 80;          // incidence to a device beyond which the surface is grazing
  double table_tolerance_mm = 0.5;  // height above the part's lowest point still "on the table"
  int histogram_bins = 60;
  double color_range_mm = 0.0;  // painting: 0 scales at the 99th percentile of |C2M|
  void Check() const;           // throws slshadow::Error naming the bad field
};

// Where the decoder found one camera of a view too dark to decode: per camera pixel, 1 where the
// ProjectorMap status is shadow or low contrast (core/projector_map.h).
struct DarkPixels {
  std::string camera;  // the rig camera's name
  int width = 0;
  int height = 0;
  std::vector<uint8_t> dark;  // row-major, width x height
  // 1 where `status` (CV_8UC1 of PixelStatus) is kShadow or kLowContrast.
  static DarkPixels FromStatus(const std::string& camera, const cv::Mat& status);
  bool At(const Eigen::Vector2d& pixel) const;  // the nearest pixel; false outside the image
};

// One view as the comparison sees it.
struct CadView {
  std::string name;
  Rigid3d part_from_rig;              // the view's pose (merged, or the truth in a test)
  const PointCloud* cloud = nullptr;  // rig frame; null: the view is left out of the merge
  // The decoder's dark pixels of the mode's cameras in this view; null: not recorded (the view
  // cannot tell too_dark from not_reconstructed).
  const std::vector<DarkPixels>* dark = nullptr;
};

struct CadViewFigures {
  std::string name;
  bool merged = true;  // false: left out (no cloud); only its geometry counted
  size_t points = 0;
  compare::DistanceStats c2m;  // signed
  double coverage = 0;         // of the reachable surface, this view's cloud alone
  double coverage_radius_mm = 0;
};

struct CadComparison {
  compare::DistanceStats merged_c2m;  // signed C2M of the merged cloud
  size_t merged_points = 0;
  double coverage_radius_mm = 0;  // of the merged cloud
  std::vector<CadViewFigures> views;
  double cad_area_mm2 = 0;
  size_t samples = 0;
  // Samples and area (area = cad_area_mm2 x share of samples) by reason, CoverageReason order.
  std::array<size_t, kNumCoverageReasons> reason_samples{};
  std::array<double, kNumCoverageReasons> reason_area_mm2{};
  double coverage_reachable = 0;  // covered / reachable (covered, not_reconstructed, too_dark)
  double coverage_total = 0;      // covered / samples not on the table
  double reachable_share = 0;     // reachable / samples not on the table
  // Per CAD vertex: the mean C2M of the merged points within the coverage radius (NaN: none), and
  // the reason of the nearest surface sample.
  std::vector<float> vertex_deviation_mm;
  std::vector<uint8_t> vertex_reason;
  std::vector<double> merged_deviations_mm;  // one per merged point
  std::vector<uint8_t> sample_reason;        // one per surface sample (CoverageReason)
  std::vector<Eigen::Vector3d> sample_points;
  double color_range_mm = 0;  // of the painting
  double seconds = 0;

  nlohmann::json ToJson() const;  // figures only (no per-point arrays)
  std::string Summary() const;    // one screen: merged, per view, uncovered area by reason
};

// Compares `merged_in_part` and the views' clouds with `cad_in_part` (see the header comment).
// `table_axis`: the turntable's axis in the part frame (a turntable project: the rig's axis),
// whose table face is excluded; nullopt: nothing excluded. Throws slshadow::Error on an empty CAD
// mesh, an empty merged cloud, a rig without the mode's devices or invalid options.
CadComparison CompareWithCad(const TriangleMesh& cad_in_part, const Rig& rig, ReconstructMode mode,
                             const std::vector<CadView>& views, const PointCloud& merged_in_part,
                             const std::optional<TurntableAxis>& table_axis,
                             const CadCompareOptions& options = {});

// The CAD mesh painted by vertex_deviation_mm as a binary PLY (atomically) that MeshLab and
// CloudCompare open: vertex x, y, z (float), red, green, blue (uchar; compare/charts.h colour map
// over [-color_range, +color_range], grey where no merged point covers the vertex),
// deviation_mm (float, NaN where uncovered), reason (uchar, CoverageReason); face vertex_indices.
void WritePaintedMesh(const std::filesystem::path& path, const TriangleMesh& cad,
                      const CadComparison& comparison);

}  // namespace slshadow::multiview
