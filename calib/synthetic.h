// Synthetic board observations with known truth: the fixture factory for calibration tests,
// Monte Carlo checks of the predicted uncertainty, and planning how many views a rig needs.
// (Image-level validation renders boards with sim/; this makes corner lists directly.)
#pragma once

#include <cstdint>
#include <vector>

#include "calib/calibration.h"
#include "core/rig.h"

namespace slshadow {

struct SyntheticRig {
  std::vector<RigDevice> devices;  // true models and cam_from_rig; device 0 is the rig frame
  int board_cols = 11;             // inner corners
  int board_rows = 8;
  double square_size_mm = 30;
  double distance_mm = 650;   // mean distance of the board centre along device 0's axis
  double max_tilt_rad = 0.6;  // board tilt about x and y drawn uniformly in +-max_tilt_rad
  double shift_fraction =
      0.2;  // board centre shifted sideways by up to this fraction of distance_mm
  // True board warp (w_x, w_y), mm, as CalibrationOptions::estimate_board_warp models it; the
  // observations' board points stay flat (nominal), as a user would give them.
  Eigen::Vector2d board_warp_mm = Eigen::Vector2d::Zero();

  // 1280x1024, fx 1400, fy 1405, mild barrel distortion.
  static SyntheticRig OneCamera();
  // OneCamera plus a second 1280x1024 camera 150 mm to the right, toed in by 10 degrees.
  static SyntheticRig Stereo();
};

struct SyntheticData {
  CalibrationInput input;               // devices named as the rig's, no initial models
  std::vector<Rigid3d> rig_from_board;  // the true pose of each board pose
};

// `num_poses` random board poses (tilts up to ~35 degrees, shifted across the image) whose corners
// all land inside every device's image, each seen by every device; corners get isotropic Gaussian
// noise of `noise_px` per coordinate. Deterministic for a given seed.
SyntheticData MakeSyntheticData(const SyntheticRig& rig, int num_poses, double noise_px,
                                uint32_t seed);

}  // namespace slshadow
