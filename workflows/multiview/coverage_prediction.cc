#include "workflows/multiview/coverage_prediction.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>

#include "compare/compare.h"
#include "core/error.h"
#include "reconstruct/dense_grid.h"
#include "reconstruct/filters.h"
#include "reconstruct/stereo_matcher.h"
#include "sim/scene.h"
#include "workflows/multiview/internal/decode_odds.h"
#include "workflows/multiview/internal/device_sight.h"
#include "workflows/multiview/internal/grid_render.h"
#include "workflows/multiview/internal/prediction_reasons.h"
#include "workflows/multiview/virtual_project.h"

namespace slshadow::multiview {

using internal::GlossLobe;
using internal::kCovered;
using internal::kDark;
using internal::kGrazing;
using internal::kOccluded;
using internal::kOnTable;
using internal::kOutside;
using internal::Share;

namespace {

// The lit range (8-bit grey levels) per unit of cos_p * (d_ref / d_p)^2, and d_ref^2.
struct Light {
  double range_per_factor = 0;
  std::vector<float> sample_albedo;  // per sample when the part is printed; else in the factor
  std::vector<float> sample_gloss;   // per sample: the specular lobe's weight (empty: none)
  std::vector<float> sample_gloss_inv_alpha_sq;  // and 1 / its alpha^2
  std::vector<float> sample_offset;              // per sample: grey levels added (empty: none)
  double ref_distance_sq = 0;
  double threshold = 0;
  // The decoder at its thresholds (CoveragePredictionOptions::pixel_noise_dn): inactive unless set.
  internal::DecodeOdds odds;
  int window_neighbours = 8;    // the outlier filter's window, cells besides the centre
  double sample_area_mm2 = 0;   // surface per sample; 0: one camera pixel per sample (ViewPoints)
  double max_code_step_px = 0;  // stereo: 0 = no gate
  // Stereo: the rectified right camera (stereo_matcher.h), where the matcher walks the rows.
  bool rectified_right = false;
  Rigid3d rect_right_from_rig;
  double rect_focal_px = 1, rect_cx_right = 0, rect_cy = 0;
  SceneLayers::Defocus camera_defocus, projector_defocus;
  double fringe_period_px = 16;
  bool code_y = true;
};

using internal::ReferenceGrid;

// The cells around the grid's pixel of `in_grid` on the surface's tangent plane (normal `n_grid`,
// grid frame): the depth-discontinuity filter's largest range change to a 4-neighbour, and the
// statistical outlier filter's score (RMS distance to the `outlier_neighbors` nearest cells of
// the window), both in footprints (reconstruct/filters.h). Infinity where a neighbour's ray
// misses the plane.
struct CellFigures {
  double jump_footprints = 0;
  double outlier_score = 0;
};
CellFigures TangentCells(const ReferenceGrid& grid, const Eigen::Vector3d& in_grid,
                         const Eigen::Vector3d& n_grid, const Eigen::Vector2d& pixel) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  const double range = in_grid.norm(), footprint = range / grid.focal_px;
  const double plane = n_grid.dot(in_grid);
  CellFigures f;
  thread_local std::vector<double> d2;  // no allocation per sample
  d2.clear();
  const int r = std::max(1, grid.outlier_radius);
  for (int dv = -r; dv <= r; ++dv) {
    for (int du = -r; du <= r; ++du) {
      if (du == 0 && dv == 0) continue;
      const bool four = std::abs(du) + std::abs(dv) == 1;
      if (!four && !grid.outliers) continue;
      Eigen::Vector3d q;
      bool hit = false;
      if (const auto ray = grid.Ray(pixel + Eigen::Vector2d(du, dv))) {
        const double denom = n_grid.dot(*ray);
        const double t = std::abs(denom) > 1e-12 ? plane / denom : -1;
        if (t > 0) q = *ray * t, hit = true;
      }
      if (four)
        f.jump_footprints = std::max(f.jump_footprints, hit ? std::abs(q.norm() - range) : kInf);
      d2.push_back(hit ? (q - in_grid).squaredNorm() : kInf);
    }
  }
  if (grid.outliers) {
    const auto k = std::min(d2.size(), static_cast<size_t>(std::max(1, grid.outlier_neighbors)));
    std::partial_sort(d2.begin(), d2.begin() + static_cast<std::ptrdiff_t>(k), d2.end());
    double sum = 0;
    for (size_t i = 0; i < k; ++i) sum += d2[i];
    f.outlier_score = std::sqrt(sum / static_cast<double>(k)) / footprint;
  }
  f.jump_footprints /= footprint;
  return f;
}

// How the projector coordinates change from the camera pixel of `in_cam` to its neighbours, with
// the surface as its tangent plane (normal `n_cam`, camera frame): column 0 to the next pixel along
// the row, column 1 to the next along the column, projector px. Nullopt when a neighbour's ray
// misses the plane or the projector.
std::optional<Eigen::Matrix2d> ProjectorSteps(const RigDevice& cam, const RigDevice& projector,
                                              const Eigen::Vector3d& in_cam,
                                              const Eigen::Vector3d& n_cam,
                                              const Eigen::Vector2d& pixel) {
  const Rigid3d proj_from_cam = projector.cam_from_rig * cam.cam_from_rig.Inverse();
  const auto proj_pixel = [&](const Eigen::Vector3d& x) {
    return projector.model.Project(proj_from_cam * x);
  };
  const auto centre = proj_pixel(in_cam);
  if (!centre) return std::nullopt;
  Eigen::Matrix2d steps;
  for (int k = 0; k < 2; ++k) {
    const auto ray = cam.model.Unproject(pixel + Eigen::Vector2d(k == 0, k == 1));
    if (!ray) return std::nullopt;
    const double denom = n_cam.dot(*ray);
    if (std::abs(denom) < 1e-12) return std::nullopt;
    const auto q = proj_pixel(*ray * (n_cam.dot(in_cam) / denom));
    if (!q) return std::nullopt;
    steps.col(k) = *q - *centre;
  }
  return steps;
}

// The projector column's step from the rectified right camera's cell of `p_rig` (normal `n_rig`,
// rig frame) to the next cell along its row, the surface as its tangent plane, projector px:
// what MatchRectifiedMaps compares with the code-step gate. Infinity when the cell or its
// neighbour misses the plane or the projector.
double RectifiedRowStep(const Light& light, const RigDevice& projector,
                        const Eigen::Vector3d& p_rig, const Eigen::Vector3d& n_rig) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  const Eigen::Vector3d in_rect = light.rect_right_from_rig * p_rig;
  if (in_rect.z() <= 0) return kInf;
  const Eigen::Vector3d n_rect = light.rect_right_from_rig.rotation * n_rig;
  const double u = light.rect_focal_px * in_rect.x() / in_rect.z() + light.rect_cx_right;
  const double v = light.rect_focal_px * in_rect.y() / in_rect.z() + light.rect_cy;
  const Eigen::Vector3d ray((u + 1 - light.rect_cx_right) / light.rect_focal_px,
                            (v - light.rect_cy) / light.rect_focal_px, 1.0);
  const double denom = n_rect.dot(ray);
  if (std::abs(denom) < 1e-12) return kInf;
  const double t = n_rect.dot(in_rect) / denom;
  if (t <= 0) return kInf;
  const Rigid3d proj_from_rect = projector.cam_from_rig * light.rect_right_from_rig.Inverse();
  const auto a = projector.model.Project(proj_from_rect * in_rect);
  const auto b = projector.model.Project(proj_from_rect * (ray * t));
  if (!a || !b) return kInf;
  return std::abs(b->x() - a->x());
}

// The share of the finest fringe's modulation a Gaussian blur of sigma (px of the image where the
// fringe has period period_px) keeps: the Gaussian's transfer exp(-2 pi^2 sigma^2 / period^2).
double FringeTransfer(double sigma_px, double period_px) {
  return std::exp(-2 * M_PI * M_PI * sigma_px * sigma_px / (period_px * period_px));
}

// Stereo's code-step gate at the right camera (stereo_matcher.h), on the surface's tangent plane
// at `p_rig` (normal `n_rig`): the 2 x 2 block's span per coded coordinate and the rectified
// row's step of the projector column, at most max_code_step_px. What the matcher needs of the
// right map where it searches.
bool RightCameraGatesPass(const Light& light, const RigDevice& right, const RigDevice& projector,
                          const Eigen::Vector3d& p_rig, const Eigen::Vector3d& n_rig) {
  if (light.max_code_step_px <= 0) return true;
  const Eigen::Vector3d in_cam = right.cam_from_rig * p_rig;
  const auto pixel = right.model.Project(in_cam);
  if (!pixel) return false;
  const auto steps =
      ProjectorSteps(right, projector, in_cam, right.cam_from_rig.rotation * n_rig, *pixel);
  const int coords = light.code_y ? 2 : 1;
  if (!steps ||
      steps->topRows(coords).cwiseAbs().rowwise().sum().maxCoeff() > light.max_code_step_px)
    return false;
  return RectifiedRowStep(light, projector, p_rig, n_rig) <= light.max_code_step_px;
}

// Stereo's ambiguous matches (stereo_matcher.h MatchRectifiedMaps): the matcher looks for the left
// cell's projector column along the right camera's rectified row (the epipolar plane through the
// left and right centres and the sample) and rejects the cell when it crosses that column more
// than once (kAmbiguousMatch; the disparity range is the depth gates', wide open). The points
// carrying the same column on that row lie on the line where the epipolar plane meets the
// projector's plane of that column: another crossing of the part on that line (Embree, both
// ways, beyond one rectified footprint of the sample) that the right camera sees and the
// projector lights (unoccluded, facing both, inside both images, not grazing) and where the right
// map passes the code-step gate is a second solution. Such samples are marked occluded (the part
// itself is in the way of the match) in `sight`; only samples every other rule keeps are tested.
void AmbiguousMatches(const internal::SightCaster& caster,
                      const std::vector<Eigen::Vector3d>& samples,
                      const std::vector<const RigDevice*>& devices, const Rigid3d& part_from_rig,
                      double grazing_deg, const Light& light, const ReferenceGrid& grid,
                      std::vector<uint8_t>* sight) {
  constexpr int kMaxHits = 4;
  const size_t ns = samples.size();
  const RigDevice& right = *devices[1];
  const RigDevice& projector = *devices.back();
  const Rigid3d rig_from_part = part_from_rig.Inverse();
  const Rigid3d rig_from_projector = projector.cam_from_rig.Inverse();
  const Eigen::Vector3d cl = devices[0]->CenterInRig(), cr = right.CenterInRig();
  std::vector<Eigen::Vector3d> dirs(ns, Eigen::Vector3d::Zero());
  std::vector<uint8_t> test(ns, 0);
  double skip_mm = std::numeric_limits<double>::infinity();
  tbb::parallel_for(size_t{0}, ns, [&](size_t i) {
    if ((*sight)[i] > kDark) return;
    const Eigen::Vector3d p_rig = rig_from_part * samples[i];
    const auto pp = projector.model.Project(projector.cam_from_rig * p_rig);
    if (!pp) return;
    const auto r1 = projector.model.Unproject(*pp);
    const auto r2 = projector.model.Unproject(*pp + Eigen::Vector2d(0, 1));
    if (!r1 || !r2) return;
    const Eigen::Vector3d n_col =
        (rig_from_projector.rotation * *r1).cross(rig_from_projector.rotation * *r2);
    const Eigen::Vector3d n_epi = (cr - cl).cross(p_rig - cl);
    const Eigen::Vector3d d = n_col.cross(n_epi);
    if (d.norm() < 1e-12 * n_col.norm() * n_epi.norm()) return;
    dirs[i] = part_from_rig.rotation * d.normalized();
    test[i] = 1;
  });
  // One rectified footprint at the part's nearest sample: a crossing closer than that is the
  // sample's own segment of the right row.
  for (size_t i = 0; i < ns; ++i) {
    if (test[i])
      skip_mm = std::min(skip_mm, (grid.grid_from_rig * (rig_from_part * samples[i])).norm());
  }
  if (!std::isfinite(skip_mm)) return;
  skip_mm /= grid.focal_px;
  const std::vector<internal::SightCaster::LineHit> hits =
      caster.LineHits(samples, dirs, test, kMaxHits, skip_mm);
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector3f> hit_normals;
  std::vector<size_t> owner;
  for (size_t h = 0; h < hits.size(); ++h) {
    if (!hits[h].found) continue;
    points.push_back(hits[h].point);
    hit_normals.push_back(hits[h].normal);
    owner.push_back(h / (2 * kMaxHits));
  }
  const std::vector<uint8_t> seen =
      caster.View(points, hit_normals, {&right, &projector}, part_from_rig, grazing_deg);
  std::vector<uint8_t> ambiguous(ns, 0);
  for (size_t k = 0; k < points.size(); ++k) {
    if (seen[k] != kCovered || ambiguous[owner[k]]) continue;
    if (RightCameraGatesPass(light, right, projector, rig_from_part * points[k],
                             rig_from_part.rotation * hit_normals[k].cast<double>()))
      ambiguous[owner[k]] = 1;
  }
  for (size_t i = 0; i < ns; ++i) {
    if (ambiguous[i]) (*sight)[i] = std::max((*sight)[i], kOccluded);
  }
}

// Per sample, this view's reason (kCovered .. kOutside) with every device of `devices`: the
// geometry of the CAD comparison (internal/device_sight.h), then, where every device sees the
// sample, the rules of the light, the matcher and the filters. The reasons grow from covered to
// outside, so a view's reason is the largest of its rules'.
std::vector<uint8_t> ViewSight(const internal::SightCaster& caster,
                               const std::vector<Eigen::Vector3d>& samples,
                               const std::vector<Eigen::Vector3f>& normals,
                               const std::vector<const RigDevice*>& devices,
                               const Rigid3d& part_from_rig, double grazing_deg, const Light& light,
                               const ReferenceGrid& grid, std::vector<double>* levels = nullptr) {
  std::vector<uint8_t> sight = caster.View(samples, normals, devices, part_from_rig, grazing_deg);
  if (levels) levels->assign(samples.size(), std::numeric_limits<double>::quiet_NaN());
  const Rigid3d rig_from_part = part_from_rig.Inverse();
  const Rigid3d grid_from_part = grid.grid_from_rig * rig_from_part;
  const RigDevice& projector = *devices.back();
  const Eigen::Vector3d projector_centre = part_from_rig * projector.CenterInRig();
  // The draws of the decoder's odds: per sample and view (independent between views).
  const uint64_t view_seed = internal::PoseSeed(part_from_rig);
  // The outlier filter's score of each sample's cell and the cells per sample (its weight in the
  // filter's mean and spread over the grid's cells: cos / footprint^2 per unit of area).
  std::vector<double> score(samples.size(), 0), weight(samples.size(), 0);
  tbb::parallel_for(size_t{0}, samples.size(), [&](size_t i) {
    if (sight[i] > kGrazing) return;  // hidden from or outside a device
    const Eigen::Vector3d& p = samples[i];
    const Eigen::Vector3d nrm = normals[i].cast<double>();
    const Eigen::Vector3d p_rig = rig_from_part * p;
    const Eigen::Vector3d n_rig = rig_from_part.rotation * nrm;
    uint8_t r = sight[i];
    // The projector's light (sim/scene.h radiometry): the lit range, then the fringe's
    // modulation through the projector's and each camera's defocus (the finest fringe, period
    // fringe_period_px in the projector; in a camera, divided by how many projector px one camera
    // px spans along the coded axes).
    const Eigen::Vector3d to = projector_centre - p;
    const double cos_p = nrm.dot(to) / to.norm();
    double range = light.range_per_factor * cos_p * light.ref_distance_sq / to.squaredNorm();
    double albedo = light.sample_albedo.empty() ? 1.0 : light.sample_albedo[i];
    if (!light.sample_gloss.empty() && light.sample_gloss[i] > 0) {
      // The lobe about the mirror direction of the projector into the reference camera.
      const Eigen::Vector3d to_c = part_from_rig * devices[0]->CenterInRig() - p;
      const Eigen::Vector3d half = (to.normalized() + to_c.normalized()).normalized();
      const double cos_h = std::max(1e-6, std::abs(nrm.dot(half)));
      const double tan2 = (1 - cos_h * cos_h) / (cos_h * cos_h);
      albedo += light.sample_gloss[i] * GlossLobe(tan2, light.sample_gloss_inv_alpha_sq[i]);
    }
    range *= albedo;
    if (!light.sample_offset.empty()) range = std::max(0.0, range + light.sample_offset[i]);
    if (light.projector_defocus.enabled) {
      const double depth = (projector.cam_from_rig * p_rig).z();
      range *= FringeTransfer(light.projector_defocus.SigmaPx(projector.model.fx(), depth),
                              light.fringe_period_px);
    }
    double camera_transfer = 1;  // the worst camera's: every camera must decode
    for (size_t d = 0; d + 1 < devices.size(); ++d) {
      if (!light.camera_defocus.enabled && light.max_code_step_px <= 0) break;
      const RigDevice& camera = *devices[d];
      const Eigen::Vector3d in_cam = camera.cam_from_rig * p_rig;
      const auto pixel = camera.model.Project(in_cam);
      if (!pixel) continue;
      const auto steps =
          ProjectorSteps(camera, projector, in_cam, camera.cam_from_rig.rotation * n_rig, *pixel);
      // Stereo's code-step gate (stereo_matcher.h), in the reconstruction's two places:
      // RectifyProjectorMap keeps a rectified cell only when the 2 x 2 camera pixels around its
      // source position span at most max_code_step_px in each coded projector coordinate (on the
      // tangent plane a coordinate's span over the block is |step along x| + |step along y|), and
      // MatchRectifiedMaps does not search the right camera's rectified row across a step of the
      // projector column larger than it.
      if (light.max_code_step_px > 0) {
        const int coords = light.code_y ? 2 : 1;
        if (!steps ||
            (steps->topRows(coords).cwiseAbs().rowwise().sum().maxCoeff() > light.max_code_step_px))
          r = std::max(r, kGrazing);
        if (d == 1 && light.rectified_right &&
            RectifiedRowStep(light, projector, p_rig, n_rig) > light.max_code_step_px)
          r = std::max(r, kGrazing);
      }
      if (light.camera_defocus.enabled && steps) {
        // Projector px per camera px along each coded axis's gradient.
        double gradient = steps->row(0).norm();
        if (light.code_y) gradient = std::max(gradient, steps->row(1).norm());
        const double sigma = light.camera_defocus.SigmaPx(camera.model.fx(), in_cam.z());
        camera_transfer =
            std::min(camera_transfer, FringeTransfer(sigma * gradient, light.fringe_period_px));
      }
    }
    if (levels) (*levels)[i] = range * camera_transfer;
    if (!light.odds.Active()) {
      if (range * camera_transfer < light.threshold) r = std::max(r, kDark);
    } else {
      // A pixel decodes with the odds at the mean level; the outlier filter keeps it with a decoded
      // neighbour; the sample is reconstructed when one of the reference camera's pixels on its
      // share of the surface is kept (CoveragePredictionOptions::pixel_noise_dn).
      const double decode = light.odds.Decode(range * camera_transfer);
      double reconstructed = decode;
      if (light.sample_area_mm2 > 0) {
        const double kept = decode * (1 - std::pow(1 - decode, light.window_neighbours));
        const Eigen::Vector3d to_c = part_from_rig * devices[0]->CenterInRig() - p;
        const double footprint = to_c.norm() / devices[0]->model.fx();
        const double cos_c = std::max(0.05, std::abs(nrm.dot(to_c)) / to_c.norm());
        const double pixels = light.sample_area_mm2 * cos_c / (footprint * footprint);
        reconstructed = 1 - std::pow(1 - kept, pixels);
      }
      if (!(internal::FixedUniform(view_seed + i) < reconstructed)) r = std::max(r, kDark);
    }
    // The filters on the reference grid.
    if (grid.max_depth_jump_footprints > 0 || grid.outliers) {
      const Eigen::Vector3d in_grid = grid_from_part * p;
      const Eigen::Vector3d n_grid = grid_from_part.rotation * nrm;
      if (const auto cell = grid.Pixel(in_grid)) {
        const CellFigures f = TangentCells(grid, in_grid, n_grid, *cell);
        if (grid.max_depth_jump_footprints > 0 &&
            f.jump_footprints > grid.max_depth_jump_footprints)
          r = std::max(r, kGrazing);
        score[i] = f.outlier_score;
        weight[i] = std::abs(n_grid.dot(in_grid)) * grid.focal_px * grid.focal_px /
                    std::pow(in_grid.squaredNorm(), 1.5);
      }
    }
    sight[i] = r;
  });
  if (light.rectified_right)
    AmbiguousMatches(caster, samples, devices, part_from_rig, grazing_deg, light, grid, &sight);
  if (grid.outliers) {
    // The filter's limit over the cells that reach it (the samples every other rule keeps):
    // max(mean + std_ratio * spread, floor); a cell above it is rejected (a surface too steep for
    // its neighbours to stay close, or with a neighbour's ray off the plane); grazing before too
    // dark, as the other rules rank them.
    double w = 0, ws = 0, ws2 = 0;
    for (size_t i = 0; i < samples.size(); ++i) {
      if (sight[i] != kCovered || !std::isfinite(score[i])) continue;
      w += weight[i];
      ws += weight[i] * score[i];
      ws2 += weight[i] * score[i] * score[i];
    }
    const double mean = w > 0 ? ws / w : 0;
    const double spread = w > 0 ? std::sqrt(std::max(0.0, ws2 / w - mean * mean)) : 0;
    const double limit = std::max(mean + grid.outlier_std_ratio * spread, grid.outlier_floor);
    for (size_t i = 0; i < samples.size(); ++i) {
      if (sight[i] <= kDark && score[i] > limit) sight[i] = kGrazing;
    }
  }
  return sight;
}

}  // namespace

std::string ToString(PredictedReason reason) {
  switch (reason) {
    case PredictedReason::kReconstructed:
      return "reconstructed";
    case PredictedReason::kTooDark:
      return "too_dark";
    case PredictedReason::kGrazing:
      return "grazing";
    case PredictedReason::kOccluded:
      return "occluded";
    case PredictedReason::kOutsideField:
      return "outside_field";
    case PredictedReason::kOnTable:
      return "on_table";
  }
  return "unknown";
}

CoveragePredictionOptions WithSceneRadiometry(CoveragePredictionOptions options,
                                              const Scene& scene) {
  options.exposure_fraction = scene.radiometry.exposure_fraction;
  options.reference_distance_mm = scene.radiometry.reference_distance_mm;
  double albedo = std::numeric_limits<double>::infinity();
  for (const SceneObject& o : scene.objects) {
    if (o.type == ObjectType::kMesh && !o.albedo.IsTextured())
      albedo = std::min(albedo, o.albedo.value);
  }
  if (std::isfinite(albedo)) options.albedo = albedo;
  options.camera_defocus = scene.layers.camera_defocus;
  options.projector_defocus = scene.layers.projector_defocus;
  return options;
}

CoveragePredictionOptions WithPatterns(CoveragePredictionOptions options, const PatternSpec& spec) {
  const std::vector<double> periods = spec.PeriodsPx();
  options.fringe_period_px =
      periods.empty() ? 4.0 : *std::min_element(periods.begin(), periods.end());
  options.code_y = spec.code_y;
  return options;
}

void CoveragePredictionOptions::Check() const {
  SLSHADOW_THROW_IF(!(albedo > 0 && albedo <= 1),
                    "coverage prediction: albedo must be in (0, 1] (got ", albedo, ")");
  SLSHADOW_THROW_IF(!(exposure_fraction > 0),
                    "coverage prediction: exposure_fraction must be positive (got ",
                    exposure_fraction, ")");
  SLSHADOW_THROW_IF(!(reference_distance_mm >= 0),
                    "coverage prediction: reference_distance_mm must be >= 0 (got ",
                    reference_distance_mm, ")");
  SLSHADOW_THROW_IF(!(fringe_period_px > 0),
                    "coverage prediction: fringe_period_px must be positive (got ",
                    fringe_period_px, ")");
  reconstruct.Check();
  SLSHADOW_THROW_IF(!(shadow_threshold >= 0),
                    "coverage prediction: shadow_threshold must be >= 0 (got ", shadow_threshold,
                    ")");
  SLSHADOW_THROW_IF(
      !(gloss >= 0 && gloss_dark >= 0 && gloss_alpha > 0 && gloss_alpha_dark > 0),
      "coverage prediction: gloss and gloss_dark must be >= 0, gloss_alpha and gloss_alpha_dark "
      "positive (got ",
      gloss, ", ", gloss_dark, ", ", gloss_alpha, ", ", gloss_alpha_dark, ")");
  SLSHADOW_THROW_IF(!(pixel_noise_dn >= 0 && contrast_threshold >= 0),
                    "coverage prediction: pixel_noise_dn and contrast_threshold must be >= 0 (got ",
                    pixel_noise_dn, ", ", contrast_threshold, ")");
  for (const auto& axis : bit_global_dn) {
    for (double g : axis) {
      SLSHADOW_THROW_IF(!(g >= 0 && std::isfinite(g)),
                        "coverage prediction: bit_global_dn must be finite and >= 0 (got ", g, ")");
    }
  }
  for (const PixelBitContrast& b : bit_contrasts) {
    for (const auto& axis : b.ratio) {
      for (float q : axis) {
        SLSHADOW_THROW_IF(!(q >= 0 && std::isfinite(q)),
                          "coverage prediction: bit_contrasts must be finite and >= 0 (got ", q,
                          ")");
      }
    }
  }
  SLSHADOW_THROW_IF(samples < 100, "coverage prediction: samples must be at least 100 (got ",
                    samples, ")");
  SLSHADOW_THROW_IF(!(grazing_deg > 0 && grazing_deg <= 90),
                    "coverage prediction: grazing_deg must be in (0, 90] (got ", grazing_deg, ")");
  SLSHADOW_THROW_IF(!(table_tolerance_mm >= 0),
                    "coverage prediction: table_tolerance_mm must be >= 0 (got ",
                    table_tolerance_mm, ")");
}

size_t CoveragePrediction::OffTable() const {
  return sample_points.size() - reason_samples[static_cast<size_t>(CoverageReason::kOnTable)];
}

std::vector<PredictedViewPose> PosesOfViews(const ViewsFile& views, const Rig& rig) {
  std::vector<PredictedViewPose> poses;
  for (const ViewSpec& v : views.views) poses.push_back({v.name, VirtualViewPose(v, rig)});
  return poses;
}

struct CoveragePredictor::Impl {
  CoveragePredictionOptions options;
  std::vector<Eigen::Vector3d> samples;
  std::vector<Eigen::Vector3f> normals;
  std::vector<uint8_t> on_table;
  double cad_area_mm2 = 0;
  std::vector<RigDevice> devices;  // copies: the rig may go away
  std::unique_ptr<internal::SightCaster> caster;
  Light light;
  ReferenceGrid grid;
  internal::TablePlane table;  // the axis's lowest plane of the part (for the grid's misses)
};

CoveragePredictor::CoveragePredictor(const TriangleMesh& cad_in_part, const Rig& rig,
                                     const std::optional<TurntableAxis>& table_axis,
                                     const CoveragePredictionOptions& options)
    : impl_(std::make_unique<Impl>()) {
  options.Check();
  SLSHADOW_THROW_IF(cad_in_part.empty(), "coverage prediction: the CAD mesh is empty");
  Impl& m = *impl_;
  m.options = options;
  for (const RigDevice* d : internal::ModeDevices(rig, options.mode, "coverage prediction"))
    m.devices.push_back(*d);

  // The samples of CompareWithCad (same seed, same count).
  compare::Reference reference =
      compare::ReferenceFromMesh(cad_in_part, "CAD model", options.samples);
  m.samples = std::move(reference.cloud.points);
  m.normals = std::move(reference.cloud.normals);
  m.cad_area_mm2 = cad_in_part.SurfaceArea();
  m.on_table = internal::OnTableMask(cad_in_part, m.samples, m.normals, table_axis,
                                     options.table_tolerance_mm);
  m.caster = std::make_unique<internal::SightCaster>(cad_in_part);
  if (table_axis) {
    m.table.present = true;
    m.table.up = table_axis->direction_in_rig.normalized();
    m.table.lowest = std::numeric_limits<double>::infinity();
    for (const Eigen::Vector3d& v : cad_in_part.vertices)
      m.table.lowest = std::min(m.table.lowest, m.table.up.dot(v));
  }
  m.light.range_per_factor = options.exposure_fraction * 255.0 *
                             (options.albedo_texture.IsTextured() ? 1.0 : options.albedo);
  if (options.albedo_texture.IsTextured()) {
    m.light.sample_albedo.resize(m.samples.size());
    for (size_t i = 0; i < m.samples.size(); ++i) {
      m.light.sample_albedo[i] =
          static_cast<float>(options.albedo_texture.Evaluate(m.samples[i].x(), m.samples[i].y()));
    }
  }
  if (!options.square_offset_dn.empty() &&
      options.albedo_texture.kind == Albedo::Kind::kCheckerboard) {
    const Albedo& t = options.albedo_texture;
    m.light.sample_offset.assign(m.samples.size(), 0.0f);
    for (size_t i = 0; i < m.samples.size(); ++i) {
      const int a = static_cast<int>(std::floor(m.samples[i].x() / t.square_mm)) + 1;
      const int b = static_cast<int>(std::floor(m.samples[i].y() / t.square_mm)) + 1;
      const auto q = static_cast<size_t>(a + t.squares_x * b);
      if (a >= 0 && b >= 0 && a < t.squares_x && b < t.squares_y &&
          q < options.square_offset_dn.size())
        m.light.sample_offset[i] = options.square_offset_dn[q];
    }
  }
  if (options.gloss > 0 || options.gloss_dark > 0) {
    const Albedo& t = options.albedo_texture;
    const bool board = t.kind == Albedo::Kind::kCheckerboard;
    m.light.sample_gloss.assign(m.samples.size(), static_cast<float>(options.gloss));
    m.light.sample_gloss_inv_alpha_sq.assign(
        m.samples.size(), static_cast<float>(1 / (options.gloss_alpha * options.gloss_alpha)));
    for (size_t i = 0; board && i < m.samples.size(); ++i) {
      if (t.Evaluate(m.samples[i].x(), m.samples[i].y()) == t.dark && t.dark != t.light) {
        m.light.sample_gloss[i] = static_cast<float>(options.gloss_dark);
        m.light.sample_gloss_inv_alpha_sq[i] =
            static_cast<float>(1 / (options.gloss_alpha_dark * options.gloss_alpha_dark));
      }
    }
  }
  const double d_ref =
      options.reference_distance_mm > 0 ? options.reference_distance_mm : rig.working_distance_mm;
  m.light.ref_distance_sq = d_ref * d_ref;
  m.light.threshold = options.shadow_threshold;
  m.light.odds =
      internal::DecodeOdds(options.shadow_threshold, options.pixel_noise_dn, options.bit_global_dn,
                           options.contrast_threshold, options.bit_contrasts);
  const int window = 2 * std::max(1, options.reconstruct.outlier_window_radius_px) + 1;
  m.light.window_neighbours = options.reconstruct.filter_outliers ? window * window - 1 : 0;
  m.light.sample_area_mm2 = m.cad_area_mm2 / static_cast<double>(m.samples.size());
  m.light.camera_defocus = options.camera_defocus;
  m.light.projector_defocus = options.projector_defocus;
  m.light.fringe_period_px = options.fringe_period_px;
  m.light.code_y = options.code_y;
  const ReconstructOptions& r = options.reconstruct;
  // The automatic gate (0) is at least 4 px (AutoCodeStepGate): its floor.
  if (options.mode == ReconstructMode::kStereo)
    m.light.max_code_step_px = r.max_code_step_px > 0 ? r.max_code_step_px : 4.0;
  ReferenceGrid& grid = m.grid;
  const RigDevice& left = m.devices[0];
  grid.camera = &left;
  grid.focal_px = 0.5 * (left.model.fx() + left.model.fy());
  grid.grid_from_rig = left.cam_from_rig;
  grid.width = left.model.width;
  grid.height = left.model.height;
  if (options.mode == ReconstructMode::kStereo) {
    const StereoRectification rect = ComputeStereoRectification(left, m.devices[1]);
    grid.rectified = true;
    grid.grid_from_rig = rect.RectCamFromRig(0);
    grid.focal_px = rect.focal_px;
    grid.cx = rect.cx[0];
    grid.cy = rect.cy;
    grid.width = rect.width[0];
    grid.height = rect.height;
    m.light.rectified_right = true;
    m.light.rect_right_from_rig = rect.RectCamFromRig(1);
    m.light.rect_focal_px = rect.focal_px;
    m.light.rect_cx_right = rect.cx[1];
    m.light.rect_cy = rect.cy;
  }
  grid.max_depth_jump_footprints = r.filter_depth_discontinuities ? r.max_depth_jump_footprints : 0;
  grid.outliers = r.filter_outliers;
  grid.outlier_radius = r.outlier_window_radius_px;
  grid.outlier_neighbors = r.outlier_neighbors;
  grid.outlier_std_ratio = r.outlier_std_ratio;
  grid.outlier_floor = r.outlier_min_distance_footprints;
}

CoveragePredictor::~CoveragePredictor() = default;

const std::vector<Eigen::Vector3d>& CoveragePredictor::Samples() const { return impl_->samples; }
const std::vector<Eigen::Vector3f>& CoveragePredictor::Normals() const { return impl_->normals; }
const std::vector<uint8_t>& CoveragePredictor::OnTable() const { return impl_->on_table; }
double CoveragePredictor::CadAreaMm2() const { return impl_->cad_area_mm2; }

std::vector<uint8_t> CoveragePredictor::View(const Rigid3d& part_from_rig) const {
  const Impl& m = *impl_;
  std::vector<const RigDevice*> devices;
  for (const RigDevice& d : m.devices) devices.push_back(&d);
  std::vector<uint8_t> sight = ViewSight(*m.caster, m.samples, m.normals, devices, part_from_rig,
                                         m.options.grazing_deg, m.light, m.grid);
  if (m.options.rendered_reconstruction)
    internal::MarkRejectedByReconstruction(*m.caster, m.grid, m.samples, devices, part_from_rig,
                                           m.options.grazing_deg, m.options.code_y,
                                           m.options.reconstruct, &sight);
  for (size_t i = 0; i < sight.size(); ++i) {
    if (m.on_table[i]) sight[i] = kOnTable;
  }
  return sight;
}

std::vector<double> CoveragePredictor::ViewLevels(const Rigid3d& part_from_rig) const {
  const Impl& m = *impl_;
  std::vector<const RigDevice*> devices;
  for (const RigDevice& d : m.devices) devices.push_back(&d);
  std::vector<double> levels;
  ViewSight(*m.caster, m.samples, m.normals, devices, part_from_rig, m.options.grazing_deg, m.light,
            m.grid, &levels);
  return levels;
}

std::vector<Eigen::Vector3d> CoveragePredictor::ViewPoints(const Rigid3d& part_from_rig) const {
  const Impl& m = *impl_;
  const ReferenceGrid& grid = m.grid;
  const internal::GridRender render =
      internal::RenderGrid(*m.caster, grid, m.samples, part_from_rig);
  const size_t cells = render.Cells();
  if (cells == 0) return {};
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector3f> normals;
  std::vector<size_t> cell_of;
  for (size_t c = 0; c < cells; ++c) {
    if (!render.Hit(c).found) continue;
    points.push_back(render.Hit(c).point);
    normals.push_back(render.Hit(c).normal);
    cell_of.push_back(c);
  }
  // The rules per point; the filters below on the grid itself, not on tangent planes.
  std::vector<const RigDevice*> devices;
  for (const RigDevice& d : m.devices) devices.push_back(&d);
  ReferenceGrid unfiltered = grid;
  unfiltered.max_depth_jump_footprints = 0;
  unfiltered.outliers = false;
  Light per_cell = m.light;  // a cell is one pixel: its odds; the grid's own filter keeps it
  per_cell.sample_area_mm2 = 0;
  const std::vector<uint8_t> sight = ViewSight(*m.caster, points, normals, devices, part_from_rig,
                                               m.options.grazing_deg, per_cell, unfiltered);
  std::vector<uint8_t> accept(cells, 0), background;
  for (size_t k = 0; k < points.size(); ++k) accept[cell_of[k]] = sight[k] == kCovered;
  DenseGrid dense;
  internal::FillDenseGrid(render, grid, accept, m.table, *m.caster, devices, part_from_rig,
                          m.options.grazing_deg, &dense, &background);
  constexpr auto kAcceptedCell = static_cast<uint8_t>(RejectReason::kAccepted);
  constexpr auto kNotDecodedCell = static_cast<uint8_t>(RejectReason::kNotDecoded);
  const ReconstructOptions& r = m.options.reconstruct;
  if (r.filter_depth_discontinuities)
    FilterDepthDiscontinuities(dense, r.max_depth_jump_footprints, r.discontinuity_dilation_px);
  for (size_t c = 0; c < cells; ++c) {
    if (background[c] && dense.point_in_rig[c].norm() > 5e3) dense.reason[c] = kNotDecodedCell;
  }
  if (r.filter_outliers)
    FilterStatisticalOutliers(dense, r.outlier_window_radius_px, r.outlier_neighbors,
                              r.outlier_std_ratio, r.outlier_min_distance_footprints);
  std::vector<Eigen::Vector3d> kept;
  for (size_t c = 0; c < cells; ++c) {
    if (dense.reason[c] != kAcceptedCell || background[c]) continue;
    const Eigen::Vector3d p = part_from_rig * dense.point_in_rig[c];
    if (m.table.present && m.table.up.dot(p) - m.table.lowest < m.options.table_tolerance_mm)
      continue;
    kept.push_back(p);
  }
  return kept;
}

CoveragePrediction PredictCoverage(const TriangleMesh& cad_in_part, const Rig& rig,
                                   const std::vector<PredictedViewPose>& views,
                                   const std::optional<TurntableAxis>& table_axis,
                                   const CoveragePredictionOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  SLSHADOW_THROW_IF(views.empty(), "coverage prediction: no views");
  const CoveragePredictor predictor(cad_in_part, rig, table_axis, options);
  CoveragePrediction result;
  result.sample_points = predictor.Samples();
  result.sample_normals = predictor.Normals();
  result.cad_area_mm2 = predictor.CadAreaMm2();
  const std::vector<uint8_t>& on_table = predictor.OnTable();
  const size_t ns = result.sample_points.size();
  result.sample_reason.assign(ns, kOutside);
  result.sample_views.assign(ns, 0);
  for (const PredictedViewPose& v : views) {
    std::vector<uint8_t> sight = predictor.View(v.part_from_rig);
    PredictedView view;
    view.name = v.name;
    view.part_from_rig = v.part_from_rig;
    for (size_t i = 0; i < ns; ++i) {
      ++view.reason_samples[sight[i]];
      if (sight[i] == kOnTable) continue;
      result.sample_reason[i] = std::min(result.sample_reason[i], sight[i]);
      if (sight[i] == kCovered && result.sample_views[i] < 255) ++result.sample_views[i];
    }
    result.view_reason.push_back(std::move(sight));
    result.views.push_back(view);
    if (options.predict_points) {
      const std::vector<Eigen::Vector3d> points = predictor.ViewPoints(v.part_from_rig);
      result.predicted_points.insert(result.predicted_points.end(), points.begin(), points.end());
    }
  }
  for (size_t i = 0; i < ns; ++i) {
    if (on_table[i]) result.sample_reason[i] = kOnTable;
    ++result.reason_samples[result.sample_reason[i]];
  }
  const size_t off = result.OffTable();
  for (PredictedView& v : result.views) v.coverage = Share(v.reason_samples[kCovered], off);
  result.coverage_off_table = Share(result.reason_samples[kCovered], off);
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

}  // namespace slshadow::multiview
