// VDI/VDE 2634 part 2 acceptance figures of an optical 3D scanner, from a cloud of a scene with
// calibrated artefacts (spheres, ball bars, a flat):
//   PF  probing error, form:  range (max - min) of the radial residuals to a least-squares sphere
//                             with free radius;
//   PS  probing error, size:  fitted diameter minus calibrated diameter;
//   SD  sphere-spacing error: distance of the two fitted centres minus the calibrated distance;
//   F   flatness error:       range of the signed residuals to a least-squares plane.
// Fits are geometric least squares (sphere: algebraic start, Gauss-Newton on the radial
// residual; plane: PCA), so noise-free points of an exact shape give 0 up to rounding.
//
// Segmentation (robust, seeded by the nominal poses of an artefact file): candidate points lie
// within search_margin_mm of the nominal surface; RANSAC (fixed seed) finds the shape among the
// candidates; the final points are those within 5 robust standard deviations (1.4826 x MAD of
// the RANSAC residuals) of it, refitted. The guideline permits excluding up to 0.3 % of the
// points as outliers; exclude_fraction (default 0) drops that share of the largest |residuals|
// before the figures are taken.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/point_cloud.h"

namespace slshadow {
class ConfigNode;
}  // namespace slshadow

namespace slshadow::compare {

struct SphereFit {
  Eigen::Vector3d center = Eigen::Vector3d::Zero();
  double radius = 0.0;
  double rms_mm = 0.0;
};
struct PlaneFit {
  Eigen::Vector3d point = Eigen::Vector3d::Zero();    // centroid
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // unit
  double rms_mm = 0.0;
};
// Least-squares fits; need >= 4 (sphere) / 3 (plane) points not all coplanar / collinear.
// Return false when the points do not determine the shape.
bool FitSphere(const std::vector<Eigen::Vector3d>& points, SphereFit* fit);
bool FitPlane(const std::vector<Eigen::Vector3d>& points, PlaneFit* fit);

// The artefact file (YAML or JSON, docs/formats.md "Artefact file"):
//   search_margin_mm: 2.0            # optional, default 2
//   spheres:      [{name: s1, center_mm: [x, y, z], diameter_mm: 25.0}, ...]
//   sphere_pairs: [{name: bar, spheres: [s1, s2], distance_mm: 100.0}, ...]
//   planes:       [{name: flat, point_mm: [x, y, z], normal: [0, 0, 1], half_size_mm: 40}, ...]
// Positions are nominal (in the cloud's frame, mm); diameters and distances are calibrated.
struct SphereArtefact {
  std::string name;
  Eigen::Vector3d nominal_center_mm = Eigen::Vector3d::Zero();
  double calibrated_diameter_mm = 0.0;
};
struct SpherePair {
  std::string name, sphere_a, sphere_b;
  double calibrated_distance_mm = 0.0;
};
struct PlaneArtefact {
  std::string name;
  Eigen::Vector3d nominal_point_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d nominal_normal = Eigen::Vector3d::UnitZ();
  double half_size_mm = 0.0;  // candidate points lie within this in-plane distance of the point
};
struct ArtefactSpec {
  double search_margin_mm = 2.0;
  std::vector<SphereArtefact> spheres;
  std::vector<SpherePair> pairs;
  std::vector<PlaneArtefact> planes;
  void Check(const std::string& what) const;  // throws slshadow::Error
};
ArtefactSpec LoadArtefactSpec(const std::filesystem::path& path);
// The same from a parsed tree, and back (the file's keys; unknown keys rejected, Check()ed).
ArtefactSpec ArtefactSpecFromConfig(const ConfigNode& node);
nlohmann::json ArtefactSpecToJson(const ArtefactSpec& spec);

struct Vdi2634Options {
  double exclude_fraction = 0.0;  // in [0, 0.003]: share of largest residuals dropped
  int ransac_iterations = 500;
  int min_points = 50;  // per artefact, else it is reported as not found
  unsigned seed = 7;
  void Check() const;
};
// Every field under its own name, and back (unknown keys rejected, Check()ed).
nlohmann::json Vdi2634OptionsToJson(const Vdi2634Options& options);
Vdi2634Options Vdi2634OptionsFromConfig(const ConfigNode& node);

struct SphereFigures {
  std::string name;
  bool found = false;
  size_t points = 0;
  SphereFit fit;
  double pf_mm = 0.0;  // probing error form
  double ps_mm = 0.0;  // probing error size
};
struct PairFigures {
  std::string name;
  bool found = false;
  double measured_distance_mm = 0.0;
  double sd_mm = 0.0;  // sphere-spacing error
};
struct PlaneFigures {
  std::string name;
  bool found = false;
  size_t points = 0;
  PlaneFit fit;
  double f_mm = 0.0;  // flatness error
};
struct Vdi2634Result {
  std::vector<SphereFigures> spheres;
  std::vector<PairFigures> pairs;
  std::vector<PlaneFigures> planes;
  std::string Summary() const;
  nlohmann::json ToJson() const;
};

Vdi2634Result EvaluateVdi2634(const PointCloud& cloud, const ArtefactSpec& spec,
                              const Vdi2634Options& options = {});

}  // namespace slshadow::compare
