#include "calib/uncertainty.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <set>

#include <ceres/ceres.h>
#include <ceres/jet.h>
#include <ceres/rotation.h>

#include <Eigen/Eigenvalues>

#include "core/error.h"
#include "core/statistics.h"

namespace slshadow {
namespace {

void FinishStats(PixelMap* map, int width, int height) {
  std::vector<float> v;
  for (int r = 0; r < map->values.rows; ++r) {
    for (int c = 0; c < map->values.cols; ++c) {
      const float x = map->values.at<float>(r, c);
      if (std::isfinite(x)) v.push_back(x);
    }
  }
  if (v.empty()) {
    map->median = map->p95 = map->max = map->centre = std::nan("");
    return;
  }
  std::sort(v.begin(), v.end());
  map->median = v[PercentileRank(v.size(), 50)];  // core/statistics.h: nearest rank
  map->p95 = v[PercentileRank(v.size(), 95)];
  map->max = v.back();
  const int cc = std::min(map->values.cols - 1, static_cast<int>((width / 2.0) / map->cell_px));
  const int cr = std::min(map->values.rows - 1, static_cast<int>((height / 2.0) / map->cell_px));
  map->centre = map->values.at<float>(cr, cc);
}

PixelMap MakeMap(int width, int height, int cell_px) {
  SLSHADOW_THROW_IF(cell_px < 1, "pixel map: cell_px must be positive (got ", cell_px, ")");
  PixelMap m;
  m.cell_px = cell_px;
  m.values = cv::Mat((height + cell_px - 1) / cell_px, (width + cell_px - 1) / cell_px, CV_32FC1,
                     cv::Scalar(std::nanf("")));
  return m;
}

// d ImgFromCam / d (params, frame rotation) at the ray through `pixel`: 2x9 and 2x3.
bool ProjectionJacobians(const CameraModel& model, const Eigen::Vector2d& pixel,
                         Eigen::Matrix<double, 2, 9>* j_params,
                         Eigen::Matrix<double, 2, 3>* j_rot) {
  const auto xy = model.UndistortToNormalized(pixel);
  if (!xy) return false;
  using Jet = ceres::Jet<double, 12>;
  Jet params[CameraModel::kNumParams];
  for (int i = 0; i < CameraModel::kNumParams; ++i) params[i] = Jet(model.params[i], i);
  const Jet omega[3] = {Jet(0.0, 9), Jet(0.0, 10), Jet(0.0, 11)};
  const Jet ray[3] = {Jet(xy->x()), Jet(xy->y()), Jet(1.0)};
  Jet rotated[3];
  ceres::AngleAxisRotatePoint(omega, ray, rotated);
  Jet px[2];
  CameraModel::ImgFromCam(params, rotated, px);
  for (int r = 0; r < 2; ++r) {
    j_params->row(r) = px[r].v.head<9>().transpose();
    j_rot->row(r) = px[r].v.tail<3>().transpose();
  }
  return true;
}

// |Project_b(R ray_a(q)) - q| residuals for fitting the frame rotation R between two models.
struct RotationFitFunctor {
  RotationFitFunctor(const CameraModel& b, const Eigen::Vector2d& ray_xy, const Eigen::Vector2d& q)
      : model_b(b), ray(ray_xy), pixel(q) {}
  template <typename T>
  bool operator()(const T* omega, T* residual) const {
    const T r[3] = {T(ray.x()), T(ray.y()), T(1.0)};
    T rotated[3];
    ceres::AngleAxisRotatePoint(omega, r, rotated);
    T params[CameraModel::kNumParams];
    for (int i = 0; i < CameraModel::kNumParams; ++i) params[i] = T(model_b.params[i]);
    T px[2];
    CameraModel::ImgFromCam(params, rotated, px);
    residual[0] = px[0] - T(pixel.x());
    residual[1] = px[1] - T(pixel.y());
    return true;
  }
  const CameraModel& model_b;
  Eigen::Vector2d ray, pixel;
};

}  // namespace

std::optional<Eigen::Matrix2d> ProjectionCovariance(const CameraModel& model,
                                                    const Matrix9d& covariance,
                                                    const Eigen::Vector2d& pixel) {
  const auto xy = model.UndistortToNormalized(pixel);
  if (!xy) return std::nullopt;
  using Jet = ceres::Jet<double, CameraModel::kNumParams>;
  Jet params[CameraModel::kNumParams];
  for (int i = 0; i < CameraModel::kNumParams; ++i) params[i] = Jet(model.params[i], i);
  const Jet point[3] = {Jet(xy->x()), Jet(xy->y()), Jet(1.0)};
  Jet px[2];
  CameraModel::ImgFromCam(params, point, px);
  Eigen::Matrix<double, 2, CameraModel::kNumParams> j;
  j.row(0) = px[0].v.transpose();
  j.row(1) = px[1].v.transpose();
  return Eigen::Matrix2d(j * covariance * j.transpose());
}

PixelMap ProjectionUncertaintyMap(const CameraModel& model, const Matrix9d& covariance, int cell_px,
                                  bool compensate_rotation) {
  PixelMap m = MakeMap(model.width, model.height, cell_px);
  const int n = m.values.rows * m.values.cols;
  std::vector<Eigen::Matrix<double, 2, 9>> jp(static_cast<size_t>(n));
  std::vector<Eigen::Matrix<double, 2, 3>> jr(static_cast<size_t>(n));
  std::vector<bool> ok(static_cast<size_t>(n), false);
  Eigen::Matrix3d ktk = Eigen::Matrix3d::Zero();
  Eigen::Matrix<double, 3, 9> ktj = Eigen::Matrix<double, 3, 9>::Zero();
  for (int r = 0; r < m.values.rows; ++r) {
    for (int c = 0; c < m.values.cols; ++c) {
      const size_t i = static_cast<size_t>(r * m.values.cols + c);
      ok[i] = ProjectionJacobians(model, PixelMap::CellCentre(c, r, cell_px), &jp[i], &jr[i]);
      if (!ok[i]) continue;
      ktk += jr[i].transpose() * jr[i];
      ktj += jr[i].transpose() * jp[i];
    }
  }
  // Rotation that best undoes a parameter perturbation dp: omega = -(K^T K)^-1 K^T J dp.
  Eigen::Matrix<double, 3, 9> undo = Eigen::Matrix<double, 3, 9>::Zero();
  if (compensate_rotation && ktk.determinant() > 0) undo = ktk.ldlt().solve(ktj);
  for (int r = 0; r < m.values.rows; ++r) {
    for (int c = 0; c < m.values.cols; ++c) {
      const size_t i = static_cast<size_t>(r * m.values.cols + c);
      if (!ok[i]) continue;
      const Eigen::Matrix<double, 2, 9> mq = jp[i] - jr[i] * undo;
      const Eigen::Matrix2d cov = mq * covariance * mq.transpose();
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(cov);
      m.values.at<float>(r, c) = static_cast<float>(std::sqrt(std::max(0.0, es.eigenvalues()(1))));
    }
  }
  FinishStats(&m, model.width, model.height);
  return m;
}

PixelMap ProjectionDifferenceMap(const CameraModel& a, const CameraModel& b, int cell_px,
                                 bool fit_rotation) {
  SLSHADOW_THROW_IF(a.width != b.width || a.height != b.height,
                    "projection difference: image sizes differ (", a.width, "x", a.height, " vs ",
                    b.width, "x", b.height, ")");
  PixelMap m = MakeMap(a.width, a.height, cell_px);
  double omega[3] = {0, 0, 0};
  if (fit_rotation) {
    ceres::Problem problem;
    for (int r = 0; r < m.values.rows; ++r) {
      for (int c = 0; c < m.values.cols; ++c) {
        const Eigen::Vector2d q = PixelMap::CellCentre(c, r, cell_px);
        const auto xy = a.UndistortToNormalized(q);
        if (!xy) continue;
        problem.AddResidualBlock(new ceres::AutoDiffCostFunction<RotationFitFunctor, 2, 3>(
                                     new RotationFitFunctor(b, *xy, q)),
                                 nullptr, omega);
      }
    }
    if (problem.NumResidualBlocks() > 0) {
      ceres::Solver::Options so;
      so.logging_type = ceres::SILENT;
      so.max_num_iterations = 50;
      ceres::Solver::Summary summary;
      ceres::Solve(so, &problem, &summary);
    }
  }
  for (int r = 0; r < m.values.rows; ++r) {
    for (int c = 0; c < m.values.cols; ++c) {
      const Eigen::Vector2d q = PixelMap::CellCentre(c, r, cell_px);
      const auto xy = a.UndistortToNormalized(q);
      if (!xy) continue;
      const double ray[3] = {xy->x(), xy->y(), 1.0};
      Eigen::Vector3d rotated;
      ceres::AngleAxisRotatePoint(omega, ray, rotated.data());
      const auto qb = b.Project(rotated);
      if (!qb) continue;
      m.values.at<float>(r, c) = static_cast<float>((*qb - q).norm());
    }
  }
  FinishStats(&m, a.width, a.height);
  return m;
}

double NeighbourResidualCorrelation(const CalibrationInput& input, const CalibrationResult& result,
                                    int device) {
  double products = 0, energy = 0;
  int pairs = 0, points = 0;
  for (const auto& v : input.views) {
    if (v.device != device || v.pose >= static_cast<int>(result.rig_from_board.size()) ||
        !result.rig_from_board[v.pose])
      continue;
    const auto px = Reproject(result, v);
    const auto& x = v.points_in_board_mm;
    double spacing = 1e300;
    for (size_t i = 0; i < x.size(); ++i) {
      for (size_t j = i + 1; j < x.size(); ++j) spacing = std::min(spacing, (x[i] - x[j]).norm());
    }
    for (size_t i = 0; i < x.size(); ++i) {
      const Eigen::Vector2d ri = px[i] - v.pixels_px[i];
      energy += ri.squaredNorm();
      ++points;
      for (size_t j = i + 1; j < x.size(); ++j) {
        if ((x[i] - x[j]).norm() > 1.01 * spacing) continue;
        products += ri.dot(px[j] - v.pixels_px[j]);
        ++pairs;
      }
    }
  }
  return pairs > 0 && energy > 0 ? (products / pairs) / (energy / points) : std::nan("");
}

bool CanCrossValidate(const CalibrationInput& input) {
  for (size_t d = 0; d < input.devices.size(); ++d) {
    std::set<int> poses;
    for (const auto& v : input.views) {
      if (v.device == static_cast<int>(d)) poses.insert(v.pose);
    }
    int even = 0, odd = 0;
    for (int p : poses) (p % 2 ? odd : even)++;
    if (even < 2 || odd < 2) return false;
  }
  return true;
}

CrossValidation CrossValidate(const CalibrationInput& input, const CalibrationOptions& options,
                              int cell_px) {
  CalibrationInput halves[2];
  for (int h = 0; h < 2; ++h) {
    halves[h].devices = input.devices;
    halves[h].num_poses = (input.num_poses + 1 - h) / 2;
    for (const auto& v : input.views) {
      if (v.pose % 2 != h) continue;
      BoardView w = v;
      w.pose = v.pose / 2;
      halves[h].views.push_back(std::move(w));
    }
    for (size_t d = 0; d < input.devices.size(); ++d) {
      int n = 0;
      for (const auto& v : halves[h].views) n += v.device == static_cast<int>(d);
      SLSHADOW_THROW_IF(n < 2, "cross-validation: device '", input.devices[d].name, "' has ", n,
                        " view(s) among the ", h == 0 ? "even" : "odd",
                        " poses; cross-validation needs at least 4 views per device");
    }
  }
  CalibrationOptions o = options;
  o.compute_covariance = false;
  CrossValidation cv;
  const CalibrationResult a = Calibrate(halves[0], o);
  const CalibrationResult b = Calibrate(halves[1], o);
  for (size_t d = 0; d < input.devices.size(); ++d) {
    cv.half_a.push_back(a.devices[d].model);
    cv.half_b.push_back(b.devices[d].model);
    cv.difference.push_back(
        ProjectionDifferenceMap(a.devices[d].model, b.devices[d].model, cell_px));
  }
  cv.summaries = {a.summary, b.summary};
  return cv;
}

QuotedCovariance PreferredCovariance(const CalibrationResult& result, int device,
                                     double max_ratio) {
  QuotedCovariance q;
  const auto d = static_cast<size_t>(device);
  if (d >= result.intrinsics_covariance.size() || !(result.intrinsics_covariance[d](0, 0) > 0)) {
    q.reason = "no covariance for this device (not computed, or its intrinsics held)";
    return q;
  }
  q.available = true;
  q.covariance = result.intrinsics_covariance[d];
  const bool have_view = d < result.intrinsics_covariance_view_correlated.size() &&
                         d < result.summary.view_noise.size();
  if (!have_view) {
    q.reason =
        "standard covariance (independent corner errors); no view-correlated covariance was "
        "computed";
    return q;
  }
  const auto& k = result.summary.view_noise[d];
  q.fx_sigma_ratio = std::sqrt(result.intrinsics_covariance_view_correlated[d](0, 0) /
                               result.intrinsics_covariance[d](0, 0));
  char line[300];
  if (k.share > 0 && q.fx_sigma_ratio > max_ratio) {
    q.view_correlated = true;
    q.covariance = result.intrinsics_covariance_view_correlated[d];
    std::snprintf(line, sizeof(line),
                  "view-correlated covariance: corner errors correlate across each view (share "
                  "%.2f over %.1f squares), "
                  "which widens fx's sigma %.2fx over the standard covariance (> %.2f)",
                  k.share, k.length_squares, q.fx_sigma_ratio, max_ratio);
  } else {
    std::snprintf(line, sizeof(line),
                  "standard covariance: corner errors look independent enough (correlated share "
                  "%.2f, fx sigma ratio %.2f <= "
                  "%.2f or no correlation)",
                  k.share, q.fx_sigma_ratio, max_ratio);
  }
  q.reason = line;
  return q;
}

}  // namespace slshadow
