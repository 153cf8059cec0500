// Rigid registration of a compared cloud onto a reference: reference_from_cloud.
//
//  none        identity (the clouds already share a frame);
//  icp         point-to-plane ICP from the identity (Chen & Medioni 1991; linearised rotation,
//              6x6 normal equations per iteration) against the reference's normals;
//  global+icp  coarse alignment without an initial guess: both clouds voxel-downsampled, FPFH
//              features (Rusu et al. 2009) and PCL's SampleConsensusPrerejective (Buch et al.
//              2013), then the ICP above starting from it. RANSAC keeps its most supported
//              distinct hypotheses (global_candidates); each is refined by a short ICP on a
//              subset of the full cloud and the one that puts the largest share of the cloud
//              on the reference at the finest gate wins (RANSAC's support breaks ties within
//              0.01): a large plain surface or a near symmetry gives wrong poses nearly the
//              support of the true one, not its fit.
//
// The ICP's correspondence gate starts at icp_max_correspondence_mm and shrinks each iteration
// to max(3 x current RMS, 3 x the reference's median point spacing), so partial overlap (a scan
// of one side of a part) does not bias it. Fitness and inlier RMSE are measured at the final
// gate, as Open3D reports them: fitness = fraction of the cloud's ICP points with a reference
// point within the gate; inlier_rmse = RMS of those nearest-point distances.
// PCL stays inside registration.cc.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/rigid3.h"

namespace slshadow::compare {

enum class RegistrationMethod { kNone, kIcp, kGlobalIcp };
std::string ToString(RegistrationMethod m);  // "none", "icp", "global+icp"
RegistrationMethod RegistrationMethodFromString(
    const std::string& name);  // throws slshadow::Error on others

struct RegistrationOptions {
  RegistrationMethod method = RegistrationMethod::kGlobalIcp;
  // Global stage. 0 means automatic: voxel = reference bounding-box diagonal / 60,
  // normals from 12 neighbours, feature radius = 5 voxels.
  double voxel_mm = 0.0;
  double feature_radius_mm = 0.0;
  int ransac_iterations = 20000;         // SampleConsensusPrerejective iterations
  double ransac_inlier_fraction = 0.2;   // of the downsampled cloud, to accept a pose
  unsigned seed = 1;                     // for the random draws (results are reproducible)
  int global_candidates = 8;             // distinct RANSAC hypotheses refined and compared
  int global_candidate_points = 20000;   // cloud points of each hypothesis's ICP
  int global_candidate_iterations = 30;  // ICP iterations per hypothesis
  // ICP. 0 means automatic: 2 voxels after the global stage, 5 % of the diagonal without it.
  double icp_max_correspondence_mm = 0.0;
  int icp_max_iterations = 60;
  int icp_max_points = 100000;  // cloud points used by ICP (evenly strided subset)
  double icp_tolerance = 1e-7;  // stop when an update moves points by less than this x diagonal
  void Check() const;
};

struct RegistrationResult {
  RegistrationMethod method = RegistrationMethod::kNone;
  Rigid3d reference_from_cloud;
  double fitness = 1.0;  // see above, in [0, 1]
  double inlier_rmse_mm = 0.0;
  double max_correspondence_mm = 0.0;  // the final gate fitness and RMSE refer to
  int icp_iterations = 0;
  bool converged = true;        // ICP stopped by tolerance (not by the iteration limit)
  bool global_found = true;     // global stage found a pose (false: ICP from identity)
  double global_fitness = 0.0;  // inlier fraction of the global pose on the voxel clouds
  int global_candidates = 0;    // distinct hypotheses the global stage compared
  // With more than one: the chosen one's refined fitness at the reference's finest gate (3 x its
  // median spacing), and the best other (at least 5 deg or 2 voxels from the chosen one):
  // its fitness at that gate (-1: none), how far it is turned and how far it moves the cloud's
  // centroid. An alternative nearly as good as the chosen one means the pose is ambiguous.
  double candidate_fitness = -1.0;
  double alternative_fitness = -1.0;
  double alternative_rotation_deg = 0.0;
  double alternative_translation_mm = 0.0;
  double time_s = 0.0;
  std::string BriefReport() const;  // one line
};

// reference_normals: one unit normal per reference point, or empty to estimate them (PCA of 12
// neighbours). Throws slshadow::Error on empty inputs or bad options; a failed global stage is
// reported in the result (global_found = false), not thrown.
RegistrationResult Register(const std::vector<Eigen::Vector3d>& cloud,
                            const std::vector<Eigen::Vector3d>& reference,
                            const std::vector<Eigen::Vector3d>& reference_normals,
                            const RegistrationOptions& options = {});

// Angle of the rotation between two transforms (degrees) and distance of their translations (mm):
// handy for reporting and tests.
double RotationDifferenceDeg(const Rigid3d& a, const Rigid3d& b);

}  // namespace slshadow::compare
