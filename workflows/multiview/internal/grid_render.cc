#include "workflows/multiview/internal/grid_render.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "workflows/multiview/internal/prediction_reasons.h"

namespace slshadow::multiview::internal {

namespace {
constexpr auto kAcceptedCell = static_cast<uint8_t>(RejectReason::kAccepted);
constexpr auto kNotDecodedCell = static_cast<uint8_t>(RejectReason::kNotDecoded);
constexpr auto kJumpCell = static_cast<uint8_t>(RejectReason::kDepthDiscontinuity);
}  // namespace

GridRender RenderGrid(const SightCaster& caster, const ReferenceGrid& grid,
                      const std::vector<Eigen::Vector3d>& samples, const Rigid3d& part_from_rig) {
  GridRender render;
  const Rigid3d grid_from_part = grid.grid_from_rig * part_from_rig.Inverse();
  const Rigid3d part_from_grid = grid_from_part.Inverse();
  // The window of the grid the part covers (its samples' cells, a margin of 2).
  double u0 = std::numeric_limits<double>::infinity(), v0 = u0, u1 = -u0, v1 = -u0;
  for (const Eigen::Vector3d& p : samples) {
    if (const auto px = grid.Pixel(grid_from_part * p)) {
      u0 = std::min(u0, px->x()), u1 = std::max(u1, px->x());
      v0 = std::min(v0, px->y()), v1 = std::max(v1, px->y());
    }
  }
  if (!(u0 <= u1)) return render;
  const int cu0 = std::max(0, static_cast<int>(std::floor(u0)) - 2);
  const int cv0 = std::max(0, static_cast<int>(std::floor(v0)) - 2);
  const int cu1 = std::min(grid.width - 1, static_cast<int>(std::ceil(u1)) + 2);
  const int cv1 = std::min(grid.height - 1, static_cast<int>(std::ceil(v1)) + 2);
  if (cu0 > cu1 || cv0 > cv1) return render;
  render.u0 = cu0, render.v0 = cv0, render.width = cu1 - cu0 + 1, render.height = cv1 - cv0 + 1;
  render.origin = part_from_grid.translation;
  const size_t cells = render.Cells(), w = static_cast<size_t>(render.width);
  // Each cell's ray onto the part.
  render.dirs.assign(cells, Eigen::Vector3d::Zero());
  render.active.assign(cells, 0);
  tbb::parallel_for(size_t{0}, cells, [&](size_t c) {
    const Eigen::Vector2d px(cu0 + static_cast<int>(c % w), cv0 + static_cast<int>(c / w));
    if (const auto ray = grid.Ray(px)) {
      render.dirs[c] = part_from_grid.rotation * ray->normalized();
      render.active[c] = 1;
    }
  });
  const std::vector<Eigen::Vector3d> origins(cells, render.origin);
  render.hits = caster.LineHits(origins, render.dirs, render.active, 1, 0, /*forward_only=*/true);
  return render;
}

void FillDenseGrid(const GridRender& render, const ReferenceGrid& grid,
                   const std::vector<uint8_t>& accept_hit, const TablePlane& table,
                   const SightCaster& caster, const std::vector<const RigDevice*>& devices,
                   const Rigid3d& part_from_rig, double grazing_deg, DenseGrid* dense,
                   std::vector<uint8_t>* background) {
  const size_t cells = render.Cells();
  const Rigid3d rig_from_part = part_from_rig.Inverse();
  dense->width = render.width;
  dense->height = render.height;
  dense->viewpoint_in_rig = grid.grid_from_rig.Inverse().translation;
  dense->focal_px = grid.focal_px;
  dense->point_in_rig.assign(cells, Eigen::Vector3d::Zero());
  dense->reason.assign(cells, kNotDecodedCell);
  background->assign(cells, 0);
  std::vector<Eigen::Vector3d> table_points;
  std::vector<size_t> table_cell;
  for (size_t c = 0; c < cells; ++c) {
    if (!render.active[c]) continue;
    if (render.Hit(c).found) {
      if (!accept_hit[c]) continue;
      dense->reason[c] = kAcceptedCell;
      dense->point_in_rig[c] = rig_from_part * render.Hit(c).point;
      continue;
    }
    (*background)[c] = 1;
    const Eigen::Vector3d& d = render.dirs[c];
    const double denom = table.up.dot(d);
    const double t =
        std::abs(denom) > 1e-12 ? (table.lowest - table.up.dot(render.origin)) / denom : -1.0;
    if (table.present && t > 0) {
      table_points.push_back(render.origin + t * d);
      table_cell.push_back(c);
      continue;
    }
    dense->reason[c] = kAcceptedCell;
    dense->point_in_rig[c] = rig_from_part * (render.origin + 1e4 * d);
  }
  if (table_points.empty()) return;
  const std::vector<Eigen::Vector3f> table_normals(table_points.size(), table.up.cast<float>());
  const std::vector<uint8_t> table_sight =
      caster.View(table_points, table_normals, devices, part_from_rig, grazing_deg);
  for (size_t k = 0; k < table_points.size(); ++k) {
    if (table_sight[k] > kGrazing) continue;
    dense->reason[table_cell[k]] = kAcceptedCell;
    dense->point_in_rig[table_cell[k]] = rig_from_part * table_points[k];
  }
}

ProjectorMap RenderProjectorMap(const SightCaster& caster, const RigDevice& camera,
                                const RigDevice& projector,
                                const std::vector<Eigen::Vector3d>& samples,
                                const Rigid3d& part_from_rig, double grazing_deg, bool code_y) {
  const int w = camera.model.width, h = camera.model.height;
  ProjectorMap map;
  map.Allocate(w, h, true, code_y);
  // The window of the image the part covers (its samples' pixels, a margin of 4: the
  // rectification's 4 x 4 source pixels and the code-jump test's neighbours).
  const Rigid3d cam_from_part = camera.cam_from_rig * part_from_rig.Inverse();
  double u0 = std::numeric_limits<double>::infinity(), v0 = u0, u1 = -u0, v1 = -u0;
  for (const Eigen::Vector3d& p : samples) {
    if (const auto px = camera.model.Project(cam_from_part * p)) {
      u0 = std::min(u0, px->x()), u1 = std::max(u1, px->x());
      v0 = std::min(v0, px->y()), v1 = std::max(v1, px->y());
    }
  }
  if (!(u0 <= u1)) return map;
  const int cu0 = std::max(0, static_cast<int>(std::floor(u0)) - 4);
  const int cv0 = std::max(0, static_cast<int>(std::floor(v0)) - 4);
  const int cu1 = std::min(w - 1, static_cast<int>(std::ceil(u1)) + 4);
  const int cv1 = std::min(h - 1, static_cast<int>(std::ceil(v1)) + 4);
  if (cu0 > cu1 || cv0 > cv1) return map;
  const auto ww = static_cast<size_t>(cu1 - cu0 + 1);
  const size_t n = ww * static_cast<size_t>(cv1 - cv0 + 1);
  const Rigid3d part_from_cam = cam_from_part.Inverse();
  const std::vector<Eigen::Vector3d> origins(n, part_from_cam.translation);
  std::vector<Eigen::Vector3d> dirs(n, Eigen::Vector3d::Zero());
  std::vector<uint8_t> active(n, 0);
  tbb::parallel_for(size_t{0}, n, [&](size_t c) {
    const Eigen::Vector2d px(cu0 + static_cast<int>(c % ww), cv0 + static_cast<int>(c / ww));
    if (const auto ray = camera.model.Unproject(px)) {
      dirs[c] = part_from_cam.rotation * ray->normalized();
      active[c] = 1;
    }
  });
  const std::vector<SightCaster::LineHit> hits =
      caster.LineHits(origins, dirs, active, 1, 0, /*forward_only=*/true);
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector3f> normals;
  std::vector<size_t> cell_of;
  for (size_t c = 0; c < n; ++c) {
    if (!hits[2 * c].found) continue;
    points.push_back(hits[2 * c].point);
    normals.push_back(hits[2 * c].normal);
    cell_of.push_back(c);
  }
  const std::vector<uint8_t> lit =
      caster.View(points, normals, {&projector}, part_from_rig, grazing_deg);
  const Rigid3d proj_from_part = projector.cam_from_rig * part_from_rig.Inverse();
  for (size_t k = 0; k < points.size(); ++k) {
    if (lit[k] != kCovered) continue;
    const auto q = projector.model.Project(proj_from_part * points[k]);
    if (!q) continue;
    const int u = cu0 + static_cast<int>(cell_of[k] % ww);
    const int v = cv0 + static_cast<int>(cell_of[k] / ww);
    map.proj_x.at<float>(v, u) = static_cast<float>(q->x());
    if (code_y) map.proj_y.at<float>(v, u) = static_cast<float>(q->y());
    map.status.at<uint8_t>(v, u) = static_cast<uint8_t>(PixelStatus::kValid);
    map.quality.at<float>(v, u) = 255.0f;
  }
  return map;
}

size_t MarkRejectedByReconstruction(const SightCaster& caster, const ReferenceGrid& grid,
                                    const std::vector<Eigen::Vector3d>& samples,
                                    const std::vector<const RigDevice*>& devices,
                                    const Rigid3d& part_from_rig, double grazing_deg, bool code_y,
                                    const ReconstructOptions& options,
                                    std::vector<uint8_t>* sight) {
  if (!options.filter_depth_discontinuities) return 0;
  const bool stereo = devices.size() == 3;
  const RigDevice& projector = *devices.back();
  Rig rig;
  rig.cameras.push_back(*devices[0]);
  if (stereo) rig.cameras.push_back(*devices[1]);
  rig.projector = projector;
  // The outlier filter runs after the depth-discontinuity filter and does not change its cells.
  ReconstructOptions o = options;
  o.filter_outliers = false;
  const ProjectorMap left = RenderProjectorMap(caster, *devices[0], projector, samples,
                                               part_from_rig, grazing_deg, code_y);
  const Reconstruction rec =
      stereo ? ReconstructStereo(rig, devices[0]->name, devices[1]->name, left,
                                 RenderProjectorMap(caster, *devices[1], projector, samples,
                                                    part_from_rig, grazing_deg, code_y),
                                 o, 1)
             : ReconstructWithProjector(rig, devices[0]->name, left, o, 1);
  const DenseGrid& cells = rec.grid;
  const Rigid3d grid_from_part = grid.grid_from_rig * part_from_rig.Inverse();
  size_t marked = 0;
  for (size_t i = 0; i < samples.size(); ++i) {
    if ((*sight)[i] > kDark) continue;
    const auto px = grid.Pixel(grid_from_part * samples[i]);
    if (!px) continue;
    const long u = std::lround(px->x()), v = std::lround(px->y());
    if (u < 0 || v < 0 || u >= cells.width || v >= cells.height) continue;
    if (cells.reason[cells.Index(static_cast<int>(u), static_cast<int>(v))] == kJumpCell) {
      (*sight)[i] = kGrazing;
      ++marked;
    }
  }
  return marked;
}

}  // namespace slshadow::multiview::internal
