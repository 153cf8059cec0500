#include "calib/synthetic.h"

#include <cmath>
#include <random>

#include "core/error.h"

namespace slshadow {

SyntheticRig SyntheticRig::OneCamera() {
  SyntheticRig rig;
  RigDevice cam;
  cam.name = "cam0";
  cam.model = CameraModel(1280, 1024, 1400, 1405, 650, 500, -0.15, 0.1, 0.0005, -0.0003, 0.0);
  rig.devices.push_back(cam);
  return rig;
}

SyntheticRig SyntheticRig::Stereo() {
  SyntheticRig rig = OneCamera();
  RigDevice cam;
  cam.name = "cam1";
  cam.model = CameraModel(1280, 1024, 1390, 1392, 630, 515, -0.12, 0.08, -0.0002, 0.0004, 0.0);
  // Centre at (150, 0, 0) in the rig, looking 10 degrees towards -x (towards the rig axis).
  const Eigen::Quaterniond rig_from_cam_rot(
      Eigen::AngleAxisd(-10.0 * M_PI / 180.0, Eigen::Vector3d::UnitY()));
  const Rigid3d rig_from_cam(rig_from_cam_rot, Eigen::Vector3d(150, 0, 0));
  cam.cam_from_rig = rig_from_cam.Inverse();
  rig.devices.push_back(cam);
  return rig;
}

SyntheticData MakeSyntheticData(const SyntheticRig& rig, int num_poses, double noise_px,
                                uint32_t seed) {
  SLSHADOW_THROW_IF(rig.devices.empty(), "MakeSyntheticData: rig has no devices");
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::normal_distribution<double> noise(0.0, noise_px > 0 ? noise_px : 1.0);
  std::vector<Eigen::Vector3d> board;
  for (int r = 0; r < rig.board_rows; ++r) {
    for (int c = 0; c < rig.board_cols; ++c)
      board.emplace_back(c * rig.square_size_mm, r * rig.square_size_mm, 0);
  }
  const Eigen::Vector3d board_centre((rig.board_cols - 1) * rig.square_size_mm / 2,
                                     (rig.board_rows - 1) * rig.square_size_mm / 2, 0);
  // Aim at the middle of the devices' centres, at the working distance.
  Eigen::Vector3d aim = Eigen::Vector3d::Zero();
  for (const auto& d : rig.devices) aim += d.CenterInRig();
  aim /= static_cast<double>(rig.devices.size());
  aim.z() += rig.distance_mm;

  SyntheticData data;
  data.input.num_poses = num_poses;
  for (const auto& d : rig.devices) {
    CalibrationDevice cd;
    cd.name = d.name;
    cd.width = d.model.width;
    cd.height = d.model.height;
    data.input.devices.push_back(cd);
  }
  for (int p = 0; p < num_poses; ++p) {
    for (int attempt = 0;; ++attempt) {
      SLSHADOW_CHECK(attempt < 10000);
      const Eigen::Quaterniond rot =
          Eigen::AngleAxisd(0.3 * u(rng), Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(rig.max_tilt_rad * u(rng), Eigen::Vector3d::UnitX()) *
          Eigen::AngleAxisd(rig.max_tilt_rad * u(rng), Eigen::Vector3d::UnitY());
      const double shift = rig.shift_fraction * rig.distance_mm;
      const Eigen::Vector3d centre = aim + Eigen::Vector3d(shift * u(rng), 0.75 * shift * u(rng),
                                                           0.2 * rig.distance_mm * u(rng));
      const Rigid3d rig_from_board(rot, centre - rot * board_centre);
      bool all_inside = true;
      std::vector<BoardView> views;
      for (size_t d = 0; d < rig.devices.size() && all_inside; ++d) {
        BoardView v;
        v.device = static_cast<int>(d);
        v.pose = p;
        v.label = rig.devices[d].name + "/pose" + std::to_string(p);
        const double w = (rig.board_cols - 1) * rig.square_size_mm,
                     h = (rig.board_rows - 1) * rig.square_size_mm;
        for (const auto& x : board) {
          const double s = 2 * x.x() / w - 1, t = 2 * x.y() / h - 1;
          const Eigen::Vector3d warped(
              x.x(), x.y(),
              rig.board_warp_mm.x() * (1 - s * s) + rig.board_warp_mm.y() * (1 - t * t));
          const auto px =
              rig.devices[d].model.Project(rig.devices[d].cam_from_rig * (rig_from_board * warped));
          if (!px || px->x() < 10 || px->y() < 10 || px->x() > rig.devices[d].model.width - 11 ||
              px->y() > rig.devices[d].model.height - 11) {
            all_inside = false;
            break;
          }
          v.points_in_board_mm.push_back(x);
          v.pixels_px.push_back(*px);
        }
        views.push_back(std::move(v));
      }
      if (!all_inside) continue;
      for (auto& v : views) {
        if (noise_px > 0) {
          for (auto& px : v.pixels_px) px += Eigen::Vector2d(noise(rng), noise(rng));
        }
        data.input.views.push_back(std::move(v));
      }
      data.rig_from_board.push_back(rig_from_board);
      break;
    }
  }
  return data;
}

}  // namespace slshadow
