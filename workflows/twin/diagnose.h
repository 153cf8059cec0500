// Diagnosis of a real scan against its twin (issue 13, step 6): which differences exceed what the
// modelled noise explains, and what each points to. Every cause is tested by its own signature:
//
//   wrong_frame         a whole real frame matches another pattern better than its own. Each real
//                       frame k is correlated (zero-mean, over lit part pixels) with the predicted
//                       frame of every pattern j: B + (W - B) R(pattern_j(x)) at the twin's
//                       projector coordinate x plus the smooth calibration field below (so a
//                       calibration error does not look like a shifted frame). Evaluated first: a
//                       wrong frame corrupts the decoding, so the coordinate and cloud signatures
//                       are then not evaluated.
//   calibration         a smooth low-order field in the projector-coordinate residual (real
//                       decoded - twin ground truth): a quadratic in the camera pixel fitted
//                       robustly; detected when its RMS exceeds calibration_field_px and the
//                       error the rig's calibration uncertainty explains where the rig file
//                       says (CameraEvidence::rig_uncertainty_px, reported beside). Reported with
//                       the equivalent projector rotation; suggests `slshadow calibrate refine`.
//   projector_response  the fitted response (gamma) kept by the physics fit; the ripple of the
//                       residual at 1..4 x the fringe frequency is reported as its evidence.
//   defocus             the fitted projector blur kept by the physics fit (fringe contrast below
//                       the focused twin's).
//   multipath           local blobs where the real fringe modulation is below the twin's (the
//                       ratio over its smooth quadratic background below multipath_ratio x its
//                       median over >= min_blob_blocks 8 x 8 blocks
//                       of well-lit pixels: real white - black >= 30 % of its median).
//   pose                the twin is not where the real part is: after the calibration field is
//                       taken out, real decoded projector coordinates differ from the twin's
//                       ground truth by more than pose_residual_px on more than pose_max_share
//                       of the pixels both decode (in some camera), though the cloud fitted the
//                       part (a pose on a near-symmetric part or a large plain surface, or a
//                       part file that is not this part). Not blamed when a calibration error or
//                       a wrong frame is found; then (and when found) the part is not evaluated:
//                       clouds compared at a wrong pose say nothing about the part. The pose
//                       stage's own figures (PoseEvidence) are reported beside.
//   part                a deviation on the part's surface: the real cloud's C2M to the part minus
//                       the twin cloud's (at the nearest twin point, each smoothed over k
//                       neighbours) beyond max(4 robust sigma, part_min_mm) on a cluster of
//                       points in one mode, and every other mode deviating the same way there
//                       (mean at least half as large, same sign), and no calibration or
//                       wrong-frame cause found. A point counts only where its deviation also
//                       exceeds part_pose_sigmas x the pose's uncertainty propagated to it
//                       (ModeEvidence::pose_sigma_mm): what the registration cannot tell apart
//                       from a moved part is not blamed on the part; the bound is reported.
//
// A scan with no cause found is "consistent with the model".
#pragma once

#include <functional>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "patterns/pattern_spec.h"
#include "workflows/twin/physics_fit.h"

namespace slshadow::twin {

struct DiagnoseOptions {
  double calibration_field_px = 0.25;  // field RMS above this: calibration error
  double wrong_frame_margin = 0.2;     // corr(own) must trail corr(best other) by this
  double wrong_frame_min_corr = 0.8;   // and the best other must reach this
  double multipath_ratio = 0.65;
  int min_blob_blocks = 6;
  // pose: a pixel counts against the pose when its decoded coordinate is this far from the
  // twin's (projector px, after the calibration field; the decode's own noise is ~0.02-0.2 px,
  // a 50 um bump moves it ~0.1 px); the pose is not credible above this share of the pixels.
  double pose_residual_px = 1.0;
  double pose_max_share = 0.02;
  double part_min_mm = 0.015;
  double part_pose_sigmas = 3;  // a part deviation must also exceed this x the pose's sigma there
  double part_min_fraction = 0.001;  // of the compared points, in a cluster
  int smoothing_neighbors = 64;
  void Check() const;
};

// Per camera: what the images say.
struct CameraEvidence {
  std::string camera;
  int width = 0, height = 0;
  cv::Mat mask;              // CV_8UC1: 255 where the twin sees the part lit
  cv::Mat real_x, real_y;    // real decoded projector coordinates, NaN where invalid
  cv::Mat gt_x, gt_y;        // twin's true projector coordinates, NaN where not lit
  cv::Mat modulation_ratio;  // real / twin normalised fringe modulation, NaN where none
  const std::vector<cv::Mat>* real = nullptr;  // real images, spec order
  cv::Mat white, black;  // real white / black levels (WhiteBlackImages), CV_32FC1
  double projector_fx = 1, projector_fy = 1;
  double projector_cx = 0,
         projector_cy = 0;  // the principal point, for the field's focal-length equivalent
  // The projector-coordinate error (px, p95) the rig's own calibration uncertainty explains for
  // this camera, from the rig file's calibration evidence; NaN when the rig does not say.
  double rig_uncertainty_px = std::numeric_limits<double>::quiet_NaN();
};

// Per reconstruction mode: the clouds against the part.
struct ModeEvidence {
  std::string mode;
  std::vector<Eigen::Vector3d> real_points, virtual_points;  // rig frame
  std::vector<double> real_c2m, virtual_c2m;                 // signed distance to the part, mm
  // 1-sigma of a real point's distance to the part that the pose's own uncertainty explains
  // (PoseUncertainty::PointSigmaMm at the point), or empty when the pose's uncertainty is unknown.
  std::function<double(const Eigen::Vector3d& point_in_rig)> pose_sigma_mm;
};

// The pose stage's own figures (twin.cc), reported with the pose signature.
struct PoseEvidence {
  bool known = false;
  std::string source;                      // "given", "given+icp", "global+icp"
  double fitness = 0, inlier_rmse_mm = 0;  // the cloud against the part at the pose (1 mm gate)
  // Global registration's ambiguity (compare::RegistrationResult): the chosen hypothesis's
  // refined fitness and the best other's (-1: none), how far that one is turned and moved.
  double candidate_fitness = -1, alternative_fitness = -1;
  double alternative_rotation_deg = 0, alternative_translation_mm = 0;
};

struct Finding {
  std::string cause;
  bool evaluated = true;
  bool detected = false;
  std::string message;
  nlohmann::json evidence = nlohmann::json::object();
};

struct Diagnosis {
  std::vector<Finding> findings;
  std::vector<std::string> causes;  // detected causes, in the order above
  std::string verdict;              // "consistent with the model" or the causes named
  nlohmann::json ToJson() const;
  std::string Summary() const;  // a few lines
};

// `projector_images` are the spec's projector images (CV_8UC1); `response` the projector value ->
// intensity table (256 entries) of the fitted twin.
Diagnosis Diagnose(const PatternSpec& spec, const std::vector<cv::Mat>& projector_images,
                   const std::vector<float>& response, const PhysicsFit& physics,
                   const std::vector<CameraEvidence>& cameras,
                   const std::vector<ModeEvidence>& modes, const DiagnoseOptions& options = {},
                   const PoseEvidence& pose = {});

// The robust quadratic field of a coordinate residual (exposed for maps and tests): per pixel of
// `residual` (NaN where unknown, restricted to `mask`), the fitted field value (CV_32FC1), or an
// empty Mat when fewer than 50 samples.
cv::Mat SmoothField(const cv::Mat& residual, const cv::Mat& mask, double* rms_px = nullptr,
                    double* mean_px = nullptr);

}  // namespace slshadow::twin
