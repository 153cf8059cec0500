// Calibration check and self-calibration from a scan's dense camera-projector correspondences.
//
// A decoded scan gives, for camera pixels q_c, the projector pixel q_p they see. With the rig's
// models, x_c = Unproject_cam(q_c) and x_p = Unproject_proj(q_p) are rays, and a correct
// calibration makes every pair coplanar with the baseline: x_p^T [t]x R x_c = 0 with
// (R, t) = proj_from_cam. The residual used is the Sampson distance of that epipolar constraint,
// scaled by the projector's focal length into projector pixels. A bumped rig, swapped devices or
// a wrong file shows as residuals far above the decoding noise (a fraction of a pixel).
//
// Refinement re-estimates proj_from_cam (rotation, and the translation's direction) by
// minimising the Cauchy-robustified residuals with Ceres; the translation's length (the
// baseline) is kept from the original calibration (epipolar geometry has no scale), so the scale
// is not verified unless a known length is given (RefineOptions: a baseline in mm, or a measured
// distance between two scene points). A solution is rejected (RefineResult::rejected) when it
// fails cheirality (the twisted pair or the reversed baseline of the same epipolar geometry: the
// triangulated points lie behind a device) or fits only a minority of the correspondences.
// Intrinsics are kept unless RefineOptions::refine_focal: then the focal length of the second
// device of the pair (the projector, or camera_b in stereo) is re-estimated too, as one scale on fx
// and fy (aspect, principal point and distortion kept).
//
// Stereo: two cameras' decoded ProjectorMaps of one scan give camera-camera correspondences
// (pixels that see the same projector coordinate); the same residual and refinement then apply
// to camera_b's pose relative to camera_a, in camera_b pixels.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json_fwd.hpp>

#include "core/projector_map.h"
#include "core/rig.h"

namespace slshadow {

struct Correspondence {
  Eigen::Vector2d camera_px;
  Eigen::Vector2d projector_px;
};

// Up to `max_samples` valid pixels of `map` (both axes decoded), spread evenly over the image.
std::vector<Correspondence> SampleCorrespondences(const ProjectorMap& map, int max_samples = 20000);

struct EpipolarStats {
  int count = 0;         // correspondences that could be unprojected
  double median_px = 0;  // |residual|, projector px
  double p95_px = 0;
  double rms_px = 0;
};

// Residuals of `correspondences` under the rig's camera `camera` and its projector.
EpipolarStats EpipolarResiduals(const Rig& rig, int camera,
                                const std::vector<Correspondence>& correspondences,
                                std::vector<double>* residuals_px = nullptr);

// A distance measured in the scene between two points, each given by a correspondence of the
// pair (camera_px in the first device, projector_px the second device's pixel).
struct KnownDistance {
  Correspondence first, second;
  double distance_mm = 0;
};

struct RefineOptions {
  double loss_scale_px = 1.0;  // Cauchy loss scale, projector px
  int max_iterations = 100;
  // A check warns when the median residual exceeds this (px of the second device).
  double warn_median_px = 0.5;
  // Also re-estimate the second device's focal length (one scale on fx, fy). Needs a pair whose
  // optical axes are not coplanar with the baseline (else focal length and pose trade off).
  bool refine_focal = false;
  // A known length fixes the scale (at most one): the baseline between the pair's centres (mm),
  // or the distance between two scene points. 0 / empty: the rig file's baseline is kept.
  double known_baseline_mm = 0;
  std::vector<KnownDistance> known_distances;  // at most one
  // Rejection: fewer than this share of the correspondences fit the refined pose within
  // inlier_px (px of the second device), or of those inliers triangulate in front of both devices.
  double min_front_share = 0.8;
  double min_inlier_share = 0.5;
  double inlier_px = 3.0;

  void Check() const;  // throws slshadow::Error naming the field
};

struct RefineResult {
  Rig rig;  // the input rig with the projector's cam_from_rig refined
  EpipolarStats before, after;
  double rotation_change_rad = 0;   // angle between the old and the new proj_from_cam rotation
  double direction_change_rad = 0;  // angle between the old and the new baseline direction
  double focal_scale = 1;  // new / old focal length of the second device (1 unless refine_focal)
  bool converged = false;
  double front_share = 0;  // share of the inliers triangulated in front of both devices
  double inlier_share =
      0;  // share of correspondences within RefineOptions::inlier_px after refinement
  double baseline_mm = 0;  // the refined pair's baseline length
  bool scale_verified =
      false;  // a known length set the scale (else the rig file's baseline is kept)
  // A solution to refuse: the reason (cheirality or lost correspondences) is in `rejection` and
  // `message`; `rig` must not be used.
  bool rejected = false;
  std::string rejection;
  // The report for the user: accepted, one paragraph (figures, warnings, notes); rejected,
  // `rejection` ("rejected: why") on the first line, then the refused solution's figures and
  // notes, one a line.
  std::string message;
};

// Refines the projector's pose relative to camera `camera` (throws slshadow::Error when the rig
// has no projector, the camera index is out of range, or fewer than 20 correspondences unproject;
// a solution that fails cheirality or loses most correspondences comes back `rejected`).
RefineResult RefineProjectorPose(const Rig& rig, int camera,
                                 const std::vector<Correspondence>& correspondences,
                                 const RefineOptions& options = {});

// Camera-camera correspondences from two cameras' ProjectorMaps of the same scan (both axes
// decoded): for up to `max_samples` valid pixels of `a`, spread evenly, the sub-pixel position in
// `b` with the same projector coordinate (an affine fit of b's pixel position against projector
// coordinates over b's 5x5 neighbourhood of the closest match). camera_px is the pixel in `a`,
// projector_px the matching pixel in `b`. Pixels without a consistent match are skipped.
std::vector<Correspondence> StereoCorrespondences(const ProjectorMap& a, const ProjectorMap& b,
                                                  int max_samples = 20000);

// The correspondence of camera pixel `pixel` (rounded) of `a`: with its projector coordinate, or,
// with `b`, the matching pixel of camera b (as StereoCorrespondences); nullopt where it has none.
// For KnownDistance points.
std::optional<Correspondence> CorrespondenceAt(const ProjectorMap& a, const ProjectorMap* b,
                                               const Eigen::Vector2d& pixel);

// What a refinement did, as kept in the refined rig's `calibration.refine` (`slshadow calibrate
// refine`): {imageset, camera, stereo (empty: the projector was refined), focal_scale,
// before_median_px, before_p95_px, after_median_px, after_p95_px, rotation_change_rad,
// direction_change_rad, converged, front_share, inlier_share, baseline_mm, scale_verified}.
nlohmann::json RefineRecordToJson(const RefineResult& result, const std::string& imageset,
                                  const std::string& camera, const std::string& stereo);

// Residuals (camera_b px) of stereo correspondences (camera_px in camera_a, projector_px in
// camera_b) under the rig's two cameras.
EpipolarStats StereoEpipolarResiduals(const Rig& rig, int camera_a, int camera_b,
                                      const std::vector<Correspondence>& correspondences,
                                      std::vector<double>* residuals_px = nullptr);

// Refines camera_b's pose relative to camera_a (camera_a stays where it is) from stereo
// correspondences, keeping the baseline length; with options.refine_focal also camera_b's focal
// length. Throws like RefineProjectorPose (indices out of range or equal, < 20 correspondences).
RefineResult RefineStereoPose(const Rig& rig, int camera_a, int camera_b,
                              const std::vector<Correspondence>& correspondences,
                              const RefineOptions& options = {});

}  // namespace slshadow
