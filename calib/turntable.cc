#include "calib/turntable.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <memory>
#include <sstream>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <Eigen/QR>

#include "calib/calibration_input.h"
#include "calib/internal/calibration_problem.h"
#include "calib/internal/initialization.h"
#include "core/error.h"
#include "core/threads.h"

namespace slshadow {
namespace {

namespace fs = std::filesystem;
using calib::internal::FromPose6;
using calib::internal::Intr9;
using calib::internal::Pose6;
using calib::internal::PoseByPnP;
using calib::internal::ToPose6;

constexpr double kDeg = M_PI / 180.0;
constexpr int kNumUnknowns = 11;

// The reference of the direction and point parameters: n = |n0 + a u + b v|, c = c0 + s u + t v.
struct AxisFrame {
  Eigen::Vector3d n0, u, v, c0;
  static AxisFrame At(const Eigen::Vector3d& n, const Eigen::Vector3d& c) {
    AxisFrame f;
    f.n0 = n.normalized();
    const Eigen::Vector3d other =
        std::abs(f.n0.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
    f.u = f.n0.cross(other).normalized();
    f.v = f.n0.cross(f.u);  // u x v = n0
    f.c0 = c;
    return f;
  }
};

struct Unknowns {
  Pose6 board_at_zero{};  // rig_from_board at commanded 0: angle-axis (rad), translation (mm)
  std::array<double, 2> direction{};
  std::array<double, 2> point{};
  std::array<double, 1> scale{1.0};
};

// r = ImgFromCam(intrinsics, cam_from_rig * T(a) * rig_from_board_at_zero * X) - u.
struct TurnFunctor {
  TurnFunctor(const RigDevice& camera, const AxisFrame& frame, double commanded_deg,
              const Eigen::Vector3d& point_in_board, const Eigen::Vector2d& pixel)
      : intrinsics(camera.model.params),
        cam_rotation(camera.cam_from_rig.rotation.toRotationMatrix()),
        cam_translation(camera.cam_from_rig.translation),
        f(frame),
        commanded_rad(commanded_deg * kDeg),
        x(point_in_board),
        u(pixel) {}

  template <typename T>
  bool operator()(const T* board_at_zero, const T* direction, const T* point, const T* scale,
                  T* residual) const {
    const T xb[3] = {T(x.x()), T(x.y()), T(x.z())};
    T x0[3];
    ceres::AngleAxisRotatePoint(board_at_zero, xb, x0);
    T n[3], c[3], d[3];
    for (int i = 0; i < 3; ++i) {
      x0[i] += board_at_zero[3 + i];
      n[i] = T(f.n0[i]) + direction[0] * T(f.u[i]) + direction[1] * T(f.v[i]);
      c[i] = T(f.c0[i]) + point[0] * T(f.u[i]) + point[1] * T(f.v[i]);
    }
    using std::sqrt;
    const T norm = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    const T theta = scale[0] * T(commanded_rad);
    T turn[3];
    for (int i = 0; i < 3; ++i) {
      turn[i] = theta * n[i] / norm;
      d[i] = x0[i] - c[i];
    }
    T turned[3];
    ceres::AngleAxisRotatePoint(turn, d, turned);
    T in_cam[3];
    for (int r = 0; r < 3; ++r) {
      in_cam[r] = T(cam_translation[r]);
      for (int k = 0; k < 3; ++k) in_cam[r] += T(cam_rotation(r, k)) * (turned[k] + c[k]);
    }
    T params[CameraModel::kNumParams];
    for (int i = 0; i < CameraModel::kNumParams; ++i) params[i] = T(intrinsics[i]);
    T pixel[2];
    CameraModel::ImgFromCam(params, in_cam, pixel);
    residual[0] = pixel[0] - T(u.x());
    residual[1] = pixel[1] - T(u.y());
    return true;
  }

  std::array<double, CameraModel::kNumParams> intrinsics;
  Eigen::Matrix3d cam_rotation;
  Eigen::Vector3d cam_translation;
  AxisFrame f;
  double commanded_rad;
  Eigen::Vector3d x;
  Eigen::Vector2d u;
};

void AddResiduals(const TurntableInput& input, const std::vector<BoardView>& views,
                  const AxisFrame& frame, const TurntableOptions& options, Unknowns* s,
                  ceres::Problem* problem) {
  for (const auto& v : views) {
    const RigDevice& cam = input.cameras[static_cast<size_t>(v.device)];
    const double a = input.commanded_deg[static_cast<size_t>(v.pose)];
    for (size_t i = 0; i < v.pixels_px.size(); ++i) {
      auto* cost = new ceres::AutoDiffCostFunction<TurnFunctor, 2, 6, 2, 2, 1>(
          new TurnFunctor(cam, frame, a, v.points_in_board_mm[i], v.pixels_px[i]));
      ceres::LossFunction* loss = nullptr;
      if (options.loss == LossType::kHuber) loss = new ceres::HuberLoss(options.loss_scale_px);
      if (options.loss == LossType::kCauchy) loss = new ceres::CauchyLoss(options.loss_scale_px);
      problem->AddResidualBlock(cost, loss, s->board_at_zero.data(), s->direction.data(),
                                s->point.data(), s->scale.data());
    }
  }
}

Eigen::Vector2d Residual(const TurntableInput& input, const BoardView& v, size_t i,
                         const AxisFrame& frame, const Unknowns& s) {
  const TurnFunctor f(input.cameras[static_cast<size_t>(v.device)], frame,
                      input.commanded_deg[static_cast<size_t>(v.pose)], v.points_in_board_mm[i],
                      v.pixels_px[i]);
  Eigen::Vector2d r;
  f(s.board_at_zero.data(), s.direction.data(), s.point.data(), s.scale.data(), r.data());
  return r;
}

double Rms(const TurntableInput& input, const std::vector<BoardView>& views, const AxisFrame& frame,
           const Unknowns& s) {
  double sq = 0;
  size_t n = 0;
  for (const auto& v : views) {
    for (size_t i = 0; i < v.pixels_px.size(); ++i, ++n)
      sq += Residual(input, v, i, frame, s).squaredNorm();
  }
  return n ? std::sqrt(sq / static_cast<double>(n)) : 0;
}

// Signed turn angle (rad, in [-pi, pi]) of `r` about the unit axis n.
double SignedAngle(const Eigen::Quaterniond& r, const Eigen::Vector3d& n) {
  const Eigen::AngleAxisd aa(r);
  return aa.axis().dot(n) >= 0 ? aa.angle() : -aa.angle();
}

double WrapDeg(double a) { return a - 360.0 * std::round(a / 360.0); }  // to [-180, 180]

struct AxisEstimate {
  Eigen::Vector3d n = Eigen::Vector3d::UnitY();
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  double scale = 1;
  double max_turn_deg = 0;  // largest measured turn between two poses
};

// The closed-form axis of the header from the board poses (rig_from_board) of the poses with
// `known` set.
AxisEstimate AxisFromPoses(const std::vector<Rigid3d>& rig_from_board,
                           const std::vector<bool>& known, const std::vector<double>& angles_deg,
                           const Eigen::Vector3d& mean_centre) {
  struct Pair {
    Rigid3d motion;  // board at p -> board at q, rig frame
    double step_deg;
  };
  std::vector<Pair> pairs;
  for (size_t p = 0; p < rig_from_board.size(); ++p) {
    for (size_t q = p + 1; q < rig_from_board.size(); ++q) {
      if (!known[p] || !known[q]) continue;
      pairs.push_back(
          {rig_from_board[q] * rig_from_board[p].Inverse(), angles_deg[q] - angles_deg[p]});
    }
  }
  AxisEstimate e;
  Eigen::Matrix3d s = Eigen::Matrix3d::Zero();
  for (const auto& pr : pairs) {
    const Eigen::Matrix3d m = pr.motion.rotation.toRotationMatrix() - Eigen::Matrix3d::Identity();
    s += m.transpose() * m;
    e.max_turn_deg = std::max(e.max_turn_deg, Eigen::AngleAxisd(pr.motion.rotation).angle() / kDeg);
  }
  if (pairs.empty()) return e;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(s);
  e.n = es.eigenvectors().col(0).normalized();
  // Sign: positive commanded steps (of less than a half turn) turn positively about n.
  double score = 0;
  for (const auto& pr : pairs) {
    if (std::abs(pr.step_deg) < 170) score += SignedAngle(pr.motion.rotation, e.n) * pr.step_deg;
  }
  if (score < 0) e.n = -e.n;
  // Scale: the measured turns, unwrapped next to the commanded steps, on the steps.
  double num = 0, den = 0;
  for (const auto& pr : pairs) {
    double turn_deg = SignedAngle(pr.motion.rotation, e.n) / kDeg;
    turn_deg += 360.0 * std::round((pr.step_deg - turn_deg) / 360.0);
    num += turn_deg * pr.step_deg;
    den += pr.step_deg * pr.step_deg;
  }
  if (den > 0) e.scale = num / den;
  // Point: (I - R) c = t for every pair, and n . c = n . mean_centre.
  Eigen::MatrixXd a(3 * static_cast<Eigen::Index>(pairs.size()) + 1, 3);
  Eigen::VectorXd b(a.rows());
  for (size_t k = 0; k < pairs.size(); ++k) {
    const auto i = 3 * static_cast<Eigen::Index>(k);
    a.block<3, 3>(i, 0) = Eigen::Matrix3d::Identity() - pairs[k].motion.rotation.toRotationMatrix();
    b.segment<3>(i) = pairs[k].motion.translation;
  }
  a.row(a.rows() - 1) = e.n.transpose();
  b(b.rows() - 1) = e.n.dot(mean_centre);
  e.c = a.colPivHouseholderQr().solve(b);
  return e;
}

// The half turn about the board normal that maps the board's extent onto itself:
// F(X) = (xmin + xmax - x, ymin + ymax - y, z).
Rigid3d HalfTurn(const Eigen::Vector4d& extent) {
  return Rigid3d(Eigen::Quaterniond(0, 0, 0, 1),
                 Eigen::Vector3d(extent[0] + extent[1], extent[2] + extent[3], 0));
}

// Whether F maps the view's points onto themselves (within 1e-6 mm): its labelling is then
// ambiguous.
bool HalfTurnSymmetric(const BoardView& v, const Rigid3d& half_turn) {
  for (const auto& x : v.points_in_board_mm) {
    const Eigen::Vector3d fx = half_turn * x;
    bool found = false;
    for (const auto& y : v.points_in_board_mm) {
      if ((y - fx).norm() < 1e-6) {
        found = true;
        break;
      }
    }
    if (!found) return false;
  }
  return true;
}

std::string PoseName(const TurntableInput& input, int pose) {
  std::ostringstream out;
  out << "pose " << pose << " (" << input.commanded_deg[static_cast<size_t>(pose)] << " deg";
  if (static_cast<size_t>(pose) < input.pose_labels.size() &&
      !input.pose_labels[static_cast<size_t>(pose)].empty())
    out << ", " << input.pose_labels[static_cast<size_t>(pose)];
  out << ")";
  return out.str();
}

double MaxEigenvalue(const Eigen::Matrix2d& m) {
  return Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(m).eigenvalues().maxCoeff();
}

}  // namespace

void TurntableInput::Check() const {
  SLSHADOW_THROW_IF(cameras.empty(), "turntable input: no cameras");
  for (const auto& c : cameras) {
    c.model.Check("turntable input: camera '" + c.name + "'");
    SLSHADOW_THROW_IF(
        !c.cam_from_rig.translation.allFinite() || !c.cam_from_rig.rotation.coeffs().allFinite(),
        "turntable input: camera '", c.name, "': non-finite cam_from_rig");
  }
  std::vector<double> distinct;
  for (size_t p = 0; p < commanded_deg.size(); ++p) {
    SLSHADOW_THROW_IF(!std::isfinite(commanded_deg[p]), "turntable input: pose ", p,
                      ": commanded angle must be finite (got ", commanded_deg[p], ")");
    bool seen = false;
    for (double d : distinct) seen = seen || std::abs(d - commanded_deg[p]) <= 1e-6;
    if (!seen) distinct.push_back(commanded_deg[p]);
  }
  SLSHADOW_THROW_IF(distinct.size() < 3, "turntable input: ", commanded_deg.size(), " pose(s) at ",
                    distinct.size(),
                    " distinct commanded angle(s); the axis needs the board at 3 or more "
                    "different table angles");
  SLSHADOW_THROW_IF(!pose_labels.empty() && pose_labels.size() != commanded_deg.size(),
                    "turntable input: ", pose_labels.size(), " pose labels for ",
                    commanded_deg.size(), " poses");
  std::vector<int> views_of_pose(commanded_deg.size(), 0);
  for (size_t k = 0; k < views.size(); ++k) {
    const BoardView& v = views[k];
    const std::string what = "turntable input: view " + std::to_string(k) +
                             (v.label.empty() ? "" : " (" + v.label + ")");
    SLSHADOW_THROW_IF(v.device < 0 || static_cast<size_t>(v.device) >= cameras.size(), what,
                      ": camera index ", v.device, " out of range (", cameras.size(), " cameras)");
    SLSHADOW_THROW_IF(v.pose < 0 || static_cast<size_t>(v.pose) >= commanded_deg.size(), what,
                      ": pose index ", v.pose, " out of range (", commanded_deg.size(), " poses)");
    SLSHADOW_THROW_IF(v.IsCarried(), what, ": carried views are not accepted");
    SLSHADOW_THROW_IF(v.points_in_board_mm.size() != v.pixels_px.size(), what, ": ",
                      v.points_in_board_mm.size(), " board points but ", v.pixels_px.size(),
                      " pixels");
    SLSHADOW_THROW_IF(v.pixels_px.size() < 4, what, ": ", v.pixels_px.size(),
                      " points (at least 4 needed)");
    for (size_t i = 0; i < v.pixels_px.size(); ++i) {
      SLSHADOW_THROW_IF(!v.points_in_board_mm[i].allFinite() || !v.pixels_px[i].allFinite(), what,
                        ": point ", i, " is not finite");
    }
    ++views_of_pose[static_cast<size_t>(v.pose)];
  }
  for (size_t p = 0; p < commanded_deg.size(); ++p) {
    SLSHADOW_THROW_IF(views_of_pose[p] == 0,
                      "turntable input: ", PoseName(*this, static_cast<int>(p)),
                      ": no camera saw the board");
  }
}

void TurntableOptions::Check() const {
  SLSHADOW_THROW_IF(max_iterations < 1, "turntable options: max_iterations must be >= 1 (got ",
                    max_iterations, ")");
  SLSHADOW_THROW_IF(!(loss_scale_px > 0) || !std::isfinite(loss_scale_px),
                    "turntable options: loss_scale_px must be > 0 (got ", loss_scale_px, ")");
  SLSHADOW_THROW_IF(!(min_angle_span_deg > 0) || !std::isfinite(min_angle_span_deg),
                    "turntable options: min_angle_span_deg must be > 0 (got ", min_angle_span_deg,
                    ")");
  SLSHADOW_THROW_IF(!(max_turn_mismatch_deg > 0) || !std::isfinite(max_turn_mismatch_deg),
                    "turntable options: max_turn_mismatch_deg must be > 0 (got ",
                    max_turn_mismatch_deg, ")");
  SLSHADOW_THROW_IF(!(min_measured_turn_deg > 0) || !(min_measured_turn_deg < 180),
                    "turntable options: min_measured_turn_deg must be in (0, 180) (got ",
                    min_measured_turn_deg, ")");
}

TurntableResult CalibrateTurntable(const TurntableInput& input, const TurntableOptions& options) {
  options.Check();
  input.Check();
  const auto [min_a, max_a] =
      std::minmax_element(input.commanded_deg.begin(), input.commanded_deg.end());
  SLSHADOW_THROW_IF(*max_a - *min_a < options.min_angle_span_deg,
                    "turntable input: the commanded angles span ", *max_a - *min_a, " deg (from ",
                    *min_a, " to ", *max_a, "); at least ", options.min_angle_span_deg,
                    " deg are needed to locate the axis");
  const size_t num_poses = input.commanded_deg.size();
  std::vector<BoardView> views = input.views;

  // Each view posed alone; the board's extent for the half-turn labelling check.
  Eigen::Vector4d extent(1e300, -1e300, 1e300, -1e300);
  for (const auto& v : views) {
    for (const auto& x : v.points_in_board_mm) {
      extent[0] = std::min(extent[0], x.x());
      extent[1] = std::max(extent[1], x.x());
      extent[2] = std::min(extent[2], x.y());
      extent[3] = std::max(extent[3], x.y());
    }
  }
  const Rigid3d half_turn = HalfTurn(extent);
  std::vector<std::optional<Rigid3d>> posed(views.size());
  std::vector<bool> ambiguous(views.size(), false);
  for (size_t k = 0; k < views.size(); ++k) {
    const RigDevice& cam = input.cameras[static_cast<size_t>(views[k].device)];
    Intr9 params;
    std::copy(cam.model.params.begin(), cam.model.params.end(), params.begin());
    if (const auto p = PoseByPnP(params, views[k])) {
      posed[k] = cam.cam_from_rig.Inverse() * FromPose6(*p);
    }
    ambiguous[k] = HalfTurnSymmetric(views[k], half_turn);
  }
  // Reference: the posed view with the most points of the first pose that has one.
  int ref = -1;
  for (size_t k = 0; k < views.size(); ++k) {
    if (!posed[k]) continue;
    if (ref < 0 || views[k].pose < views[static_cast<size_t>(ref)].pose ||
        (views[k].pose == views[static_cast<size_t>(ref)].pose &&
         views[k].pixels_px.size() > views[static_cast<size_t>(ref)].pixels_px.size()))
      ref = static_cast<int>(k);
  }
  SLSHADOW_THROW_IF(ref < 0, "turntable: no view could be posed (solvePnP failed on all views)");
  const Rigid3d ref_pose = *posed[static_cast<size_t>(ref)];
  const double ref_deg =
      input.commanded_deg[static_cast<size_t>(views[static_cast<size_t>(ref)].pose)];
  // The per-pose board pose from the chosen views, and the mean board centre.
  const Eigen::Vector3d board_centre((extent[0] + extent[1]) / 2, (extent[2] + extent[3]) / 2, 0);
  auto pose_estimates = [&](const std::vector<int>& choice, std::vector<Rigid3d>* poses,
                            std::vector<bool>* known, Eigen::Vector3d* mean_centre) {
    poses->assign(num_poses, Rigid3d());
    known->assign(num_poses, false);
    std::vector<size_t> best(num_poses, 0);
    for (size_t k = 0; k < views.size(); ++k) {
      if (!posed[k] || choice[k] < 0) continue;
      const auto p = static_cast<size_t>(views[k].pose);
      if ((*known)[p] && views[k].pixels_px.size() <= best[p]) continue;
      (*poses)[p] = choice[k] == 1 ? *posed[k] * half_turn : *posed[k];
      (*known)[p] = true;
      best[p] = views[k].pixels_px.size();
    }
    *mean_centre = Eigen::Vector3d::Zero();
    int n = 0;
    for (size_t p = 0; p < num_poses; ++p) {
      if (!(*known)[p]) continue;
      *mean_centre += (*poses)[p] * board_centre;
      ++n;
    }
    if (n) *mean_centre /= n;
  };
  // Labelling (0 as detected, 1 turned by a half turn, -1 undecided): pass 1 by the turn angle the
  // commanded angles predict, pass 2 for the undecided by the predicted rotation.
  std::vector<int> choice(views.size(), 0);
  for (size_t k = 0; k < views.size(); ++k) {
    if (!posed[k] || !ambiguous[k] || static_cast<int>(k) == ref) continue;
    const double expected =
        std::abs(WrapDeg(input.commanded_deg[static_cast<size_t>(views[k].pose)] - ref_deg));
    auto miss = [&](const Rigid3d& pose) {
      return std::abs(Eigen::AngleAxisd(pose.rotation * ref_pose.rotation.conjugate()).angle() /
                          kDeg -
                      expected);
    };
    const double keep = miss(*posed[k]), turned = miss(*posed[k] * half_turn);
    choice[k] = std::abs(keep - turned) > 20 ? (turned < keep ? 1 : 0) : -1;
  }
  if (std::count(choice.begin(), choice.end(), -1) > 0) {
    std::vector<Rigid3d> poses;
    std::vector<bool> known;
    Eigen::Vector3d centre;
    pose_estimates(choice, &poses, &known, &centre);
    const AxisEstimate e = AxisFromPoses(poses, known, input.commanded_deg, centre);
    for (size_t k = 0; k < views.size(); ++k) {
      if (choice[k] != -1) continue;
      const double step = input.commanded_deg[static_cast<size_t>(views[k].pose)] - ref_deg;
      const Eigen::Quaterniond predicted =
          Eigen::Quaterniond(Eigen::AngleAxisd(e.scale * step * kDeg, e.n)) * ref_pose.rotation;
      const double keep = posed[k]->rotation.angularDistance(predicted);
      const double turned = (*posed[k] * half_turn).rotation.angularDistance(predicted);
      choice[k] = turned < keep ? 1 : 0;
    }
  }
  {
    // Before relabelling (which could make a half turn out of a board that did not move).
    std::vector<int> as_detected(views.size(), 0);
    std::vector<Rigid3d> poses;
    std::vector<bool> known;
    Eigen::Vector3d centre;
    pose_estimates(as_detected, &poses, &known, &centre);
    const double turn = AxisFromPoses(poses, known, input.commanded_deg, centre).max_turn_deg;
    SLSHADOW_THROW_IF(turn < options.min_measured_turn_deg,
                      "turntable: the board turns by at most ", turn,
                      " deg between the poses (commanded angles from ", *min_a, " to ", *max_a,
                      " deg); at least ", options.min_measured_turn_deg,
                      " deg are needed: did the board turn with the table?");
  }
  TurntableResult result;
  for (size_t k = 0; k < views.size(); ++k) {
    if (choice[k] != 1) continue;
    for (auto& x : views[k].points_in_board_mm) x = half_turn * x;
    *posed[k] = *posed[k] * half_turn;
    choice[k] = 0;
    ++result.num_relabelled;
  }
  std::vector<Rigid3d> poses;
  std::vector<bool> known;
  Eigen::Vector3d mean_centre;
  pose_estimates(choice, &poses, &known, &mean_centre);
  for (size_t p = 0; p < num_poses; ++p) {
    SLSHADOW_THROW_IF(!known[p], "turntable: ", PoseName(input, static_cast<int>(p)),
                      ": no camera could pose the board (solvePnP failed)");
  }
  const AxisEstimate init = AxisFromPoses(poses, known, input.commanded_deg, mean_centre);
  // Every pose where the closed-form axis puts it.
  const int ref_pose_index = views[static_cast<size_t>(ref)].pose;
  for (size_t p = 0; p < num_poses; ++p) {
    const double predicted = init.scale * (input.commanded_deg[p] - ref_deg);
    const Eigen::Quaterniond expected =
        Eigen::Quaterniond(Eigen::AngleAxisd(predicted * kDeg, init.n)) *
        poses[static_cast<size_t>(ref_pose_index)].rotation;
    const double miss = poses[p].rotation.angularDistance(expected) / kDeg;
    const double measured =
        SignedAngle(
            poses[p].rotation * poses[static_cast<size_t>(ref_pose_index)].rotation.conjugate(),
            init.n) /
        kDeg;
    SLSHADOW_THROW_IF(
        miss > options.max_turn_mismatch_deg, "turntable: ", PoseName(input, static_cast<int>(p)),
        ": the board turned by ", measured, " deg from ", PoseName(input, ref_pose_index),
        " but the commanded angles predict ", WrapDeg(predicted), " deg (", miss,
        " deg apart, at most ", options.max_turn_mismatch_deg,
        " allowed): are the angles in degrees and in the order of the images, and did the "
        "board stay put on the table?");
  }
  SLSHADOW_THROW_IF(!(init.scale > 0.5 && init.scale < 2.0), "turntable: the board turns by ",
                    init.scale,
                    " times the commanded angles (expected about 1): are the angles in degrees "
                    "and in the order of the images?");

  // Refinement.
  TurntableAxis axis;
  axis.direction_in_rig = init.n;
  axis.point_in_rig_mm = init.c;
  axis.angle_scale = init.scale;
  const size_t first_pose = 0;
  Unknowns s;
  s.board_at_zero =
      ToPose6(axis.RigFromTableTurn(input.commanded_deg[first_pose]).Inverse() * poses[first_pose]);
  s.scale[0] = init.scale;
  AxisFrame frame = AxisFrame::At(init.n, init.c);
  result.initial_rms_px = Rms(input, views, frame, s);
  {
    ceres::Problem problem;
    AddResiduals(input, views, frame, options, &s, &problem);
    ceres::Solver::Options so;
    so.linear_solver_type = ceres::DENSE_QR;
    so.max_num_iterations = options.max_iterations;
    so.function_tolerance = 1e-12;
    so.gradient_tolerance = 1e-14;
    so.parameter_tolerance = 1e-12;
    so.num_threads = ThreadBudget();
    so.logging_type = ceres::SILENT;
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    result.iterations = static_cast<int>(summary.iterations.size());
    result.converged = summary.termination_type == ceres::CONVERGENCE;
    result.termination = summary.message;
  }
  // The solution, re-expressed about its own axis: direction and point parameters 0, the point
  // nearest to the mean board centre.
  {
    Eigen::Vector3d n = frame.n0 + s.direction[0] * frame.u + s.direction[1] * frame.v;
    n.normalize();
    Eigen::Vector3d c = frame.c0 + s.point[0] * frame.u + s.point[1] * frame.v;
    axis.direction_in_rig = n;
    axis.angle_scale = s.scale[0];
    axis.point_in_rig_mm = c;  // temporarily, to place the new centre
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    const Rigid3d board_zero = FromPose6(s.board_at_zero);
    for (size_t p = 0; p < num_poses; ++p)
      centre += axis.RigFromTableTurn(input.commanded_deg[p]) * (board_zero * board_centre);
    centre /= static_cast<double>(num_poses);
    c += n * n.dot(centre - c);
    axis.point_in_rig_mm = c;
    frame = AxisFrame::At(n, c);
    s.direction = {0, 0};
    s.point = {0, 0};
  }
  result.rig_from_board_at_zero = FromPose6(s.board_at_zero);
  result.board_extent_mm = extent;
  result.tangent_u = frame.u;
  result.tangent_v = frame.v;

  // Residual statistics.
  double sq = 0;
  for (const auto& v : views) {
    TurntableViewStats st;
    st.camera = v.device;
    st.pose = v.pose;
    st.label = v.label;
    st.num_points = static_cast<int>(v.pixels_px.size());
    double view_sq = 0;
    for (size_t i = 0; i < v.pixels_px.size(); ++i) {
      const Eigen::Vector2d r = Residual(input, v, i, frame, s);
      view_sq += r.squaredNorm();
      st.max_px = std::max(st.max_px, r.norm());
    }
    st.rms_px = std::sqrt(view_sq / st.num_points);
    sq += view_sq;
    result.num_points += st.num_points;
    result.max_px = std::max(result.max_px, st.max_px);
    result.views.push_back(st);
  }
  for (size_t k = 0; k < views.size(); ++k)
    result.views[k].relabelled = views[k].points_in_board_mm != input.views[k].points_in_board_mm;
  result.num_poses = static_cast<int>(num_poses);
  result.rms_px = std::sqrt(sq / std::max(1, result.num_points));
  const int dof = 2 * result.num_points - kNumUnknowns;
  result.residual_sigma_px = dof > 0 ? std::sqrt(sq / dof) : 0;

  // Covariance at the solution.
  if (options.compute_covariance && dof > 0) {
    ceres::Problem problem;
    AddResiduals(input, views, frame, options, &s, &problem);
    ceres::Problem::EvaluateOptions eo;
    eo.parameter_blocks = {s.board_at_zero.data(), s.direction.data(), s.point.data(),
                           s.scale.data()};
    eo.num_threads = ThreadBudget();
    ceres::CRSMatrix crs;
    double cost = 0;
    if (problem.Evaluate(eo, &cost, nullptr, nullptr, &crs)) {
      Eigen::Matrix<double, kNumUnknowns, kNumUnknowns> jtj;
      jtj.setZero();
      for (int r = 0; r < crs.num_rows; ++r) {
        for (int a = crs.rows[r]; a < crs.rows[r + 1]; ++a) {
          for (int b = crs.rows[r]; b < crs.rows[r + 1]; ++b)
            jtj(crs.cols[a], crs.cols[b]) += crs.values[a] * crs.values[b];
        }
      }
      const Eigen::Matrix<double, kNumUnknowns, 1> scale =
          jtj.diagonal().cwiseMax(1e-300).cwiseSqrt().cwiseInverse();
      const Eigen::Matrix<double, kNumUnknowns, kNumUnknowns> scaled =
          scale.asDiagonal() * jtj * scale.asDiagonal();
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, kNumUnknowns, kNumUnknowns>> es(
          scaled);
      const double max_ev = es.eigenvalues().maxCoeff();
      if (es.info() == Eigen::Success && es.eigenvalues().minCoeff() > 1e-12 * max_ev) {
        const Eigen::Matrix<double, kNumUnknowns, kNumUnknowns> cov =
            result.residual_sigma_px * result.residual_sigma_px * scale.asDiagonal() *
            (es.eigenvectors() * es.eigenvalues().cwiseInverse().asDiagonal() *
             es.eigenvectors().transpose()) *
            scale.asDiagonal();
        result.covariance = cov.bottomRightCorner<5, 5>();
        result.covariance_available = true;
        axis.sigma_direction_deg =
            std::sqrt(MaxEigenvalue(result.covariance.topLeftCorner<2, 2>())) / kDeg;
        axis.sigma_point_mm = std::sqrt(MaxEigenvalue(result.covariance.block<2, 2>(2, 2)));
        axis.sigma_angle_scale = std::sqrt(result.covariance(4, 4));
      }
    }
  }
  axis.angle_offset_deg = 0;  // the angle origin: the table at commanded 0 (see the header)
  axis.sigma_angle_offset_deg = 0;
  result.axis = axis;
  for (size_t p = 0; p < num_poses; ++p) {
    result.true_angle_deg.push_back(axis.TrueAngleDeg(input.commanded_deg[p]));
    result.sigma_true_angle_deg.push_back(std::abs(input.commanded_deg[p]) *
                                          axis.sigma_angle_scale);
  }
  return result;
}

std::vector<Eigen::Vector2d> ReprojectTurntable(const TurntableInput& input,
                                                const TurntableResult& result, size_t view) {
  SLSHADOW_THROW_IF(view >= input.views.size() || view >= result.views.size(),
                    "ReprojectTurntable: view ", view, " out of range (", input.views.size(),
                    " views)");
  const BoardView& v = input.views[view];
  const RigDevice& cam = input.cameras[static_cast<size_t>(v.device)];
  Rigid3d cam_from_board =
      cam.cam_from_rig *
      result.axis.RigFromTableTurn(input.commanded_deg[static_cast<size_t>(v.pose)]) *
      result.rig_from_board_at_zero;
  if (result.views[view].relabelled)
    cam_from_board = cam_from_board * HalfTurn(result.board_extent_mm);
  std::vector<Eigen::Vector2d> out;
  for (const auto& x : v.points_in_board_mm) {
    const auto px = cam.model.Project(cam_from_board * x);
    out.push_back(px ? *px : Eigen::Vector2d::Constant(std::nan("")));
  }
  return out;
}

std::string TurntableResult::BriefReport() const {
  char line[640];
  const auto& n = axis.direction_in_rig;
  const auto& c = axis.point_in_rig_mm;
  std::snprintf(line, sizeof(line),
                "turntable axis: direction (%.6f, %.6f, %.6f) +- %.4f deg, point (%.3f, %.3f, "
                "%.3f) mm +- %.4f mm, scale %.6f +- %.2g; %d poses, %zu views, %d points: RMS "
                "%.4f px (worst %.4f px), %s after %d iterations",
                n.x(), n.y(), n.z(), axis.sigma_direction_deg, c.x(), c.y(), c.z(),
                axis.sigma_point_mm, axis.angle_scale, axis.sigma_angle_scale, num_poses,
                views.size(), num_points, rms_px, max_px, converged ? "converged" : "NOT converged",
                iterations);
  return line;
}

std::string TurntableResult::FullReport() const {
  std::ostringstream out;
  out << BriefReport() << "\n";
  char line[640];
  std::snprintf(line, sizeof(line),
                "termination: %s\ninitial RMS %.4f px, residual sigma %.4f px per coordinate\n"
                "angle offset: 0 by definition (angle origin: the table at commanded 0; the offset "
                "is not observable from a board placed anywhere on the table)\n",
                termination.c_str(), initial_rms_px, residual_sigma_px);
  out << line;
  if (!covariance_available) out << "covariance: not computed or not estimable\n";
  if (num_relabelled > 0)
    out << num_relabelled << " view(s) relabelled by a half turn of the board\n";
  for (size_t p = 0; p < true_angle_deg.size(); ++p) {
    std::snprintf(line, sizeof(line), "pose %zu: true angle %.5f deg +- %.5f\n", p,
                  true_angle_deg[p], sigma_true_angle_deg[p]);
    out << line;
  }
  for (const auto& v : views) {
    std::snprintf(line, sizeof(line),
                  "  view pose %d camera %d %s: %d points, RMS %.4f px, max %.4f px%s\n", v.pose,
                  v.camera, v.label.c_str(), v.num_points, v.rms_px, v.max_px,
                  v.relabelled ? " (relabelled)" : "");
    out << line;
  }
  return out.str();
}

double CommandedAngleFromFolderName(const fs::path& folder) {
  std::string name = (folder.has_filename() ? folder : folder.parent_path()).filename().string();
  std::string number = name;
  if (number.size() > 3 && number.compare(number.size() - 3, 3, "deg") == 0)
    number.resize(number.size() - 3);
  char* end = nullptr;
  const double a = number.empty() ? 0 : std::strtod(number.c_str(), &end);
  SLSHADOW_THROW_IF(number.empty() || end != number.c_str() + number.size() || !std::isfinite(a),
                    folder.string(), ": folder name '", name,
                    "' is not a commanded angle (a number of degrees such as 030, -15.5 or 30deg; "
                    "or give the angles explicitly)");
  return a;
}

TurntableInput TurntableInputFromFolders(const Rig& rig, const TargetSpec& spec,
                                         const std::vector<fs::path>& folders,
                                         const std::vector<double>& commanded_deg,
                                         std::vector<ImageCheck>* checks) {
  SLSHADOW_THROW_IF(folders.size() != commanded_deg.size(), "turntable: ", folders.size(),
                    " image folders but ", commanded_deg.size(), " commanded angles");
  spec.Check("target");
  TurntableInput input;
  input.cameras = rig.cameras;
  input.commanded_deg = commanded_deg;
  const auto board = BoardPoints(spec);
  std::string names;
  for (const auto& c : rig.cameras) names += (names.empty() ? "" : ", ") + c.name;
  for (size_t p = 0; p < folders.size(); ++p) {
    const fs::path& dir = folders[p];
    SLSHADOW_THROW_IF(!fs::is_directory(dir), dir.string(), ": no such folder");
    input.pose_labels.push_back(dir.string());
    std::map<int, fs::path> image_of;
    for (const auto& file : ImageFiles({dir.string()}, "turntable images")) {
      const int c = rig.CameraIndex(file.stem().string());
      if (c < 0) continue;
      SLSHADOW_THROW_IF(image_of.count(c), dir.string(), ": two images of camera '",
                        rig.cameras[static_cast<size_t>(c)].name, "' (",
                        image_of[c].filename().string(), ", ", file.filename().string(), ")");
      image_of[c] = file;
    }
    SLSHADOW_THROW_IF(image_of.empty(), dir.string(),
                      ": no image named after a rig camera (expected <camera>.png or another "
                      "image extension, cameras: ",
                      names, ")");
    std::string reasons;
    bool any = false;
    for (const auto& [c, file] : image_of) {
      const RigDevice& cam = rig.cameras[static_cast<size_t>(c)];
      const TargetDetection det = DetectTargetInFile(spec, file);
      SLSHADOW_THROW_IF(det.width != cam.model.width || det.height != cam.model.height,
                        file.string(), ": image is ", det.width, "x", det.height, " but camera '",
                        cam.name, "' is ", cam.model.width, "x", cam.model.height);
      checks->push_back({file.string(), c, det.found, det.reason, det.saturated_fraction});
      if (!det.found) {
        reasons += (reasons.empty() ? "" : "; ") + file.filename().string() + ": " + det.reason;
        continue;
      }
      any = true;
      BoardView v;
      v.device = c;
      v.pose = static_cast<int>(p);
      v.label = file.string();
      for (size_t i = 0; i < det.pixels_px.size(); ++i) {
        v.points_in_board_mm.push_back(board[static_cast<size_t>(det.point_ids[i])]);
        v.pixels_px.push_back(det.pixels_px[i]);
      }
      input.views.push_back(std::move(v));
    }
    SLSHADOW_THROW_IF(!any, dir.string(), ": the board was not found in any image (", reasons, ")");
  }
  return input;
}

}  // namespace slshadow
