#include "calib/projector.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Dense>

#include "core/error.h"

namespace slshadow {
namespace {

// Normalised DLT homography dst ~ H src by least squares over all pairs (Hartley normalisation).
bool FitHomography(const std::vector<Eigen::Vector2d>& src, const std::vector<Eigen::Vector2d>& dst,
                   Eigen::Matrix3d* h) {
  const size_t n = src.size();
  if (n < 4) return false;
  auto normaliser = [](const std::vector<Eigen::Vector2d>& p) {
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    for (const auto& x : p) mean += x;
    mean /= static_cast<double>(p.size());
    double spread = 0;
    for (const auto& x : p) spread += (x - mean).norm();
    spread /= static_cast<double>(p.size());
    const double s = spread > 0 ? std::sqrt(2.0) / spread : 1.0;
    Eigen::Matrix3d t;
    t << s, 0, -s * mean.x(), 0, s, -s * mean.y(), 0, 0, 1;
    return t;
  };
  const Eigen::Matrix3d ts = normaliser(src), td = normaliser(dst);
  Eigen::MatrixXd a(2 * n, 9);
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d s = ts * src[i].homogeneous();
    const Eigen::Vector3d d = td * dst[i].homogeneous();
    const auto r = static_cast<Eigen::Index>(2 * i);
    a.row(r) << s.x(), s.y(), 1, 0, 0, 0, -d.x() * s.x(), -d.x() * s.y(), -d.x();
    a.row(r + 1) << 0, 0, 0, s.x(), s.y(), 1, -d.y() * s.x(), -d.y() * s.y(), -d.y();
  }
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(a, Eigen::ComputeFullV);
  const Eigen::VectorXd v = svd.matrixV().col(8);
  Eigen::Matrix3d hn;
  hn << v(0), v(1), v(2), v(3), v(4), v(5), v(6), v(7), v(8);
  *h = td.inverse() * hn * ts;
  if (std::abs((*h)(2, 2)) < 1e-300) return false;
  *h /= (*h)(2, 2);
  return h->allFinite();
}

Eigen::Vector2d Apply(const Eigen::Matrix3d& h, const Eigen::Vector2d& x) {
  return (h * x.homogeneous()).hnormalized();
}

// Jacobian d(H c)/dc and the fit's covariance of H c (white-noise propagation), from the fitted
// H and its inlier pairs. H is re-expressed around the corner, G(u) = H(c + u) - H c with
// G's (2,2) entry 1; there G(0) = 0, dG/du(0) is G's upper-left 2x2, and G(0) moves only with
// G's entries (0,2) and (1,2), whose covariance is sigma^2 (A^T A)^-1, A the Jacobian of the pairs'
// residuals in G's 8 free entries, sigma^2 the residual variance per coordinate.
void LocalFitAtCorner(const Eigen::Matrix3d& h, const Eigen::Vector2d& c,
                      const std::vector<Eigen::Vector2d>& cam,
                      const std::vector<Eigen::Vector2d>& proj, Eigen::Matrix2d* jacobian,
                      Eigen::Matrix2d* covariance) {
  const Eigen::Vector2d hc = Apply(h, c);
  Eigen::Matrix3d to_corner, from_image;
  to_corner << 1, 0, c.x(), 0, 1, c.y(), 0, 0, 1;
  from_image << 1, 0, -hc.x(), 0, 1, -hc.y(), 0, 0, 1;
  Eigen::Matrix3d g = from_image * h * to_corner;
  g /= g(2, 2);
  *jacobian = g.topLeftCorner<2, 2>();
  Eigen::Matrix<double, 8, 8> ata = Eigen::Matrix<double, 8, 8>::Zero();
  double sq = 0;
  for (size_t i = 0; i < cam.size(); ++i) {
    const Eigen::Vector2d u = cam[i] - c;
    const double w = g(2, 0) * u.x() + g(2, 1) * u.y() + 1;
    const Eigen::Vector2d f = (g * u.homogeneous()).hnormalized();
    sq += (f - (proj[i] - hc)).squaredNorm();
    Eigen::Matrix<double, 2, 8> a;
    a << u.x(), u.y(), 1, 0, 0, 0, -f.x() * u.x(), -f.x() * u.y(),  //
        0, 0, 0, u.x(), u.y(), 1, -f.y() * u.x(), -f.y() * u.y();
    a /= w;
    ata += a.transpose() * a;
  }
  const double sigma2 = cam.size() > 4 ? sq / static_cast<double>(2 * cam.size() - 8) : 0;
  const Eigen::Matrix<double, 8, 8> inv = ata.ldlt().solve(Eigen::Matrix<double, 8, 8>::Identity());
  *covariance << inv(2, 2), inv(2, 5), inv(5, 2), inv(5, 5);
  *covariance *= sigma2;
  *covariance += 1e-12 * Eigen::Matrix2d::Identity();  // positive definite even for an exact fit
}

}  // namespace

void LocalHomographyOptions::SetHalfWindow(int n) {
  half_window_px = n;
  min_valid_pixels = std::min(100, n * n);
}

void LocalHomographyOptions::Check() const {
  SLSHADOW_THROW_IF(half_window_px < 2 || half_window_px > 200,
                    "local homography: half_window_px: must be in 2..200 (got ", half_window_px,
                    ")");
  SLSHADOW_THROW_IF(min_valid_pixels < 8,
                    "local homography: min_valid_pixels: must be at least 8 (got ",
                    min_valid_pixels, ")");
  SLSHADOW_THROW_IF(!(inlier_threshold_px > 0),
                    "local homography: inlier_threshold_px: must be positive (got ",
                    inlier_threshold_px, ")");
  SLSHADOW_THROW_IF(!(max_fit_rms_px > 0),
                    "local homography: max_fit_rms_px: must be positive (got ", max_fit_rms_px,
                    ")");
}

ProjectorCorners ProjectorCornersByLocalHomography(const ProjectorMap& map,
                                                   const TargetDetection& detection,
                                                   const LocalHomographyOptions& options) {
  options.Check();
  SLSHADOW_THROW_IF(!map.has_x || !map.has_y,
                    "local homography: the decoded patterns must code both projector axes");
  SLSHADOW_THROW_IF(map.width() != detection.width || map.height() != detection.height,
                    "local homography: decoded map is ", map.width(), "x", map.height(),
                    " but the board image is ", detection.width, "x", detection.height);
  ProjectorCorners out;
  const int w = options.half_window_px;
  for (size_t k = 0; k < detection.pixels_px.size(); ++k) {
    const Eigen::Vector2d c = detection.pixels_px[k];
    const int cx = static_cast<int>(std::lround(c.x())), cy = static_cast<int>(std::lround(c.y()));
    std::vector<Eigen::Vector2d> cam, proj;
    for (int y = std::max(0, cy - w); y <= std::min(map.height() - 1, cy + w); ++y) {
      const uint8_t* status = map.status.ptr<uint8_t>(y);
      const float* px = map.proj_x.ptr<float>(y);
      const float* py = map.proj_y.ptr<float>(y);
      for (int x = std::max(0, cx - w); x <= std::min(map.width() - 1, cx + w); ++x) {
        if (status[x] != static_cast<uint8_t>(PixelStatus::kValid) || !std::isfinite(px[x]) ||
            !std::isfinite(py[x]))
          continue;
        cam.emplace_back(x, y);
        proj.emplace_back(px[x], py[x]);
      }
    }
    const std::string id = "corner " + std::to_string(detection.point_ids[k]);
    if (static_cast<int>(cam.size()) < options.min_valid_pixels) {
      out.skipped.push_back(id + ": " + std::to_string(cam.size()) +
                            " decoded pixels in the window (need " +
                            std::to_string(options.min_valid_pixels) + ")");
      continue;
    }
    Eigen::Matrix3d h;
    bool ok = FitHomography(cam, proj, &h);
    double rms = 0;
    for (int iter = 0; ok && iter < 10; ++iter) {
      std::vector<Eigen::Vector2d> cam_in, proj_in;
      double sq = 0;
      for (size_t i = 0; i < cam.size(); ++i) {
        const double e = (Apply(h, cam[i]) - proj[i]).norm();
        if (e <= options.inlier_threshold_px) {
          cam_in.push_back(cam[i]);
          proj_in.push_back(proj[i]);
          sq += e * e;
        }
      }
      rms = cam_in.empty() ? 1e9 : std::sqrt(sq / static_cast<double>(cam_in.size()));
      if (cam_in.size() == cam.size()) break;
      if (static_cast<int>(cam_in.size()) < options.min_valid_pixels) {
        ok = false;
        break;
      }
      cam.swap(cam_in);
      proj.swap(proj_in);
      ok = FitHomography(cam, proj, &h);
    }
    if (!ok) {
      out.skipped.push_back(id +
                            ": no consistent homography (too few consistently decoded pixels)");
      continue;
    }
    if (rms > options.max_fit_rms_px) {
      out.skipped.push_back(id + ": local homography fits to " + std::to_string(rms) +
                            " projector px (limit " + std::to_string(options.max_fit_rms_px) + ")");
      continue;
    }
    ProjectorCorner pc;
    pc.point_id = detection.point_ids[k];
    pc.camera_px = c;
    pc.projector_px = Apply(h, c);
    pc.num_pixels = static_cast<int>(cam.size());
    pc.fit_rms_px = rms;
    LocalFitAtCorner(h, c, cam, proj, &pc.jacobian, &pc.fit_covariance_px2);
    out.corners.push_back(pc);
  }
  return out;
}

ProcamPose MakeProcamPose(const PatternSpec& patterns, const std::vector<cv::Mat>& images,
                          const TargetSpec& target, int pose, int camera_device,
                          int projector_device, const std::string& label,
                          const DecodeOptions& decode, const LocalHomographyOptions& local) {
  const int white = patterns.WhiteFrameIndex();
  SLSHADOW_THROW_IF(
      white < 0,
      "projector calibration: the pattern sequence has no all-white frame to find the board in");
  SLSHADOW_THROW_IF(
      !patterns.code_x || !patterns.code_y,
      "projector calibration: the patterns must code both projector axes (code_x and code_y)");
  SLSHADOW_THROW_IF(static_cast<int>(images.size()) != patterns.NumImages(),
                    "projector calibration: ", label, ": ", images.size(),
                    " images but the pattern sequence has ", patterns.NumImages());
  ProcamPose out;
  out.detection = DetectTarget(target, images[static_cast<size_t>(white)]);
  out.camera_view.device = camera_device;
  out.projector_view.device = projector_device;
  out.camera_view.pose = out.projector_view.pose = pose;
  out.camera_view.label = label;
  out.projector_view.label = label + " (projector)";
  if (!out.detection.found) return out;
  const ProjectorMap map = DecodePatterns(patterns, images, decode);
  out.decode_counts = map.CountByStatus();
  out.projector = ProjectorCornersByLocalHomography(map, out.detection, local);
  const auto board = BoardPoints(target);
  for (size_t i = 0; i < out.detection.pixels_px.size(); ++i) {
    out.camera_view.points_in_board_mm.push_back(
        board[static_cast<size_t>(out.detection.point_ids[i])]);
    out.camera_view.pixels_px.push_back(out.detection.pixels_px[i]);
  }
  out.projector_view.source_device = camera_device;
  for (const auto& c : out.projector.corners) {
    out.projector_view.points_in_board_mm.push_back(board[static_cast<size_t>(c.point_id)]);
    out.projector_view.pixels_px.push_back(c.projector_px);
    const auto at =
        std::find(out.detection.point_ids.begin(), out.detection.point_ids.end(), c.point_id);
    out.projector_view.source_points.push_back(
        static_cast<int>(at - out.detection.point_ids.begin()));
    out.projector_view.source_jacobians.push_back(c.jacobian);
    out.projector_view.carry_covariances_px2.push_back(c.fit_covariance_px2);
  }
  return out;
}

}  // namespace slshadow
