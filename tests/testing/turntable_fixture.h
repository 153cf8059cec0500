// A known turntable in the demo rig (config/demo/rig.yaml), the fixture of the turntable axis
// tests (tests/calib/turntable_test.cc, tests/apps/cmd_calibrate_turntable_test.cc): the table's
// axis stands where the two cameras' optical axes meet, tipped towards the cameras, which look
// down at the table by 45 degrees; the table has a scale error of +0.12 % and an offset of 0.7
// degrees (which the calibration cannot see and absorbs into the board's pose at zero). The
// board, a 13 x 9 chessboard with 15 mm squares, either lies flat on the table 10 mm off the
// axis, turned a full turn in 24 steps of 15 degrees (the recommended capture, docs/formats.md
// "Turntable calibration images"), or stands on it 20 mm in front of the axis, facing the cameras
// at commanded 0, turned from -40 to 40 degrees in steps of 10.
#pragma once

#include <vector>

#include <Eigen/Geometry>

#include "calib/target.h"
#include "core/rig.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::testing {

struct SimTurntable {
  Rig rig;
  TurntableAxis axis;     // the truth
  Rigid3d board_at_zero;  // rig_from_board at commanded angle 0 under `axis`
  TargetSpec board;
  std::vector<double> angles_deg;

  Rigid3d RigFromBoard(double commanded_deg) const {
    return axis.RigFromTableTurn(commanded_deg) * board_at_zero;
  }
};

enum class TableBoard { kFlat, kStanding };

inline SimTurntable MakeSimTurntable(TableBoard placement = TableBoard::kFlat) {
  SimTurntable t;
  t.rig = LoadRig(SourceDir() / "config/demo/rig.yaml");
  t.board.type = TargetType::kChessboard;
  t.board.cols = 13;
  t.board.rows = 9;
  t.board.square_size_mm = 15;
  // Where the optical axes of the first two cameras pass closest to each other.
  const RigDevice& a = t.rig.cameras[0];
  const RigDevice& b = t.rig.cameras[1];
  const Eigen::Vector3d pa = a.CenterInRig(), da = a.AxisInRig(), pb = b.CenterInRig(),
                        db = b.AxisInRig();
  const Eigen::Vector3d w = pa - pb;
  const double aa = da.dot(da), ab = da.dot(db), bb = db.dot(db), d = da.dot(w), e = db.dot(w);
  const double sa = (ab * e - bb * d) / (aa * bb - ab * ab);
  const double sb = (aa * e - ab * d) / (aa * bb - ab * ab);
  const Eigen::Vector3d aim = (pa + sa * da + pb + sb * db) / 2;
  const Eigen::Vector3d up = Eigen::Vector3d(0.03, -1, -1).normalized();
  t.axis.direction_in_rig = up;
  t.axis.angle_offset_deg = 0.7;
  t.axis.angle_scale = 1.0012;
  // Horizontal directions on the table: across (about the rig's x) and towards the cameras.
  const Eigen::Vector3d across = (Eigen::Vector3d::UnitX() - up * up.x()).normalized();
  const Eigen::Vector3d towards = across.cross(up);
  // Board frame: z away from the cameras (into the table, or behind the standing board).
  Eigen::Matrix3d r;
  Eigen::Vector3d centre_in_rig;
  if (placement == TableBoard::kFlat) {
    t.axis.point_in_rig_mm = aim;
    r << across, (-up).cross(across), -up;
    centre_in_rig = aim + 10 * across;
    for (double angle = 0; angle < 360; angle += 15) t.angles_deg.push_back(angle);
  } else {
    t.axis.point_in_rig_mm = aim - 70 * up;
    r << up.cross(towards), -up, -towards;
    centre_in_rig = t.axis.point_in_rig_mm + 70 * up + 20 * towards;
    for (double angle = -40; angle <= 40; angle += 10) t.angles_deg.push_back(angle);
  }
  const Eigen::Vector3d centre_in_board((t.board.cols - 1) * t.board.square_size_mm / 2,
                                        (t.board.rows - 1) * t.board.square_size_mm / 2, 0);
  // The placement is defined at the true angle 0; at commanded 0 the table stands at the offset.
  const Rigid3d board_at_true_zero(Eigen::Quaterniond(r), centre_in_rig - r * centre_in_board);
  TurntableAxis no_offset = t.axis;
  no_offset.angle_offset_deg = 0;
  no_offset.angle_scale = 1;
  t.board_at_zero = no_offset.RigFromTableTurn(-t.axis.angle_offset_deg) * board_at_true_zero;
  return t;
}

}  // namespace slshadow::testing
