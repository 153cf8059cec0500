// The coverage prediction's reference grid (coverage_prediction.h): the reconstruction's grid of
// cells where its filters run (reconstruct.h: the rectified left camera in stereo, the first
// camera in projector mode), rendered over the part by ray casting (Embree, one ray per cell), so
// that the reconstruction's own filter functions (reconstruct/filters.h) run on the depth a view
// of the CAD gives (CoveragePredictor::ViewPoints); and the cameras' projector maps ray-cast, so
// that the whole reconstruction runs on them (MarkRejectedByReconstruction: the cells its gates,
// matcher and filters reject along the part's occlusion edges). Internal to workflows/multiview/.
//
// Frames and units: the part frame (views.h), mm; cells are the grid's integer pixel centres.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "core/projector_map.h"
#include "core/rig.h"
#include "core/rigid3.h"
#include "reconstruct/dense_grid.h"
#include "reconstruct/reconstruct.h"
#include "workflows/multiview/internal/device_sight.h"

namespace slshadow::multiview::internal {

// The reconstruction's reference grid: the rectified left camera in stereo (stereo_matcher.h:
// pinhole, focal_px, cx, cy, centred on the left camera), the first camera's own image in
// projector mode. Footprints are range / focal_px (DenseGrid).
struct ReferenceGrid {
  Rigid3d grid_from_rig;
  int width = 0, height = 0;  // cells
  bool rectified = false;
  double focal_px = 1, cx = 0, cy = 0;
  const RigDevice* camera = nullptr;  // projector mode
  // The reconstruction's filters (0: off).
  double max_depth_jump_footprints = 0;
  bool outliers = false;
  int outlier_radius = 1, outlier_neighbors = 4;
  double outlier_std_ratio = 4, outlier_floor = 4;

  std::optional<Eigen::Vector2d> Pixel(const Eigen::Vector3d& in_grid) const {
    if (in_grid.z() <= 0) return std::nullopt;
    if (!rectified) return camera->model.Project(in_grid);
    return Eigen::Vector2d(focal_px * in_grid.x() / in_grid.z() + cx,
                           focal_px * in_grid.y() / in_grid.z() + cy);
  }
  std::optional<Eigen::Vector3d> Ray(const Eigen::Vector2d& pixel) const {
    if (!rectified) return camera->model.Unproject(pixel);
    return Eigen::Vector3d((pixel.x() - cx) / focal_px, (pixel.y() - cy) / focal_px, 1.0);
  }
};

// The turntable's plane for the rays that miss the part: the part's lowest plane across the axis
// (`up`, part frame: the axis direction; `lowest`: min over the part of up . x). Absent: none.
struct TablePlane {
  bool present = false;
  Eigen::Vector3d up = Eigen::Vector3d::Zero();
  double lowest = 0;
};

// One view's reference grid over the part: the window of cells the part's samples fall in (a
// margin of 2 cells), each cell's ray (part frame) and its first crossing of the part.
struct GridRender {
  int u0 = 0, v0 = 0, width = 0, height = 0;  // the window: cells (u0 .. u0 + width - 1, ...)
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();  // the grid's centre, part frame
  std::vector<Eigen::Vector3d> dirs;                 // per cell (row-major in the window), unit
  std::vector<uint8_t> active;                       // the cell has a ray
  std::vector<SightCaster::LineHit> hits;            // hits[2 c]: cell c's first crossing
  size_t Cells() const { return static_cast<size_t>(width) * static_cast<size_t>(height); }
  const SightCaster::LineHit& Hit(size_t c) const { return hits[2 * c]; }
};
// Empty (width 0) when no sample is in front of the grid.
GridRender RenderGrid(const SightCaster& caster, const ReferenceGrid& grid,
                      const std::vector<Eigen::Vector3d>& samples, const Rigid3d& part_from_rig);

// The DenseGrid of the window (rig frame, viewpoint the grid's centre): a cell whose ray hits the
// part is accepted with the hit where accept_hit[c], else kNotDecoded. A cell whose ray misses
// the part: the table plane's point where the ray meets it and every device sees it (unoccluded,
// not grazing) past the part, else a far background (10 m along the ray), accepted for the
// filters; `background` (per cell) marks both.
void FillDenseGrid(const GridRender& render, const ReferenceGrid& grid,
                   const std::vector<uint8_t>& accept_hit, const TablePlane& table,
                   const SightCaster& caster, const std::vector<const RigDevice*>& devices,
                   const Rigid3d& part_from_rig, double grazing_deg, DenseGrid* dense,
                   std::vector<uint8_t>* background);

// A camera's ProjectorMap of one view of the part, ray-cast (Embree) instead of decoded: each
// pixel of the camera within `window` (its samples' pixels and a margin; the rest not decoded)
// carries the projector coordinates of its ray's first crossing of the part where the projector
// lights that point (unoccluded, facing, not grazing), as a noise-free decode would; elsewhere
// not decoded (shadow). CV_32F like a decoded map (so the reconstruction interpolates as on a
// scan). code_y: the projector's rows are coded too.
ProjectorMap RenderProjectorMap(const SightCaster& caster, const RigDevice& camera,
                                const RigDevice& projector,
                                const std::vector<Eigen::Vector3d>& samples,
                                const Rigid3d& part_from_rig, double grazing_deg, bool code_y);

// The reconstruction's depth-discontinuity filter where the reconstruction itself puts it: the
// reconstruction (ReconstructStereo with devices[0] and devices[1], or ReconstructWithProjector
// with devices[0]; reconstruct.h, `options`, its outlier filter off) run on the view's rendered
// projector maps, so that the cells reaching the filter are those its gates (the code-step gate,
// the relative code-jump test) and its matcher leave, and FilterDepthDiscontinuities marks them
// with its own code. The samples of `sight` the other rules keep (<= kDark) whose nearest cell of
// the reference grid it marks kDepthDiscontinuity become kGrazing; returns how many. (Only that
// reason: on the exact maps the gates and the matcher reject more cells along edges than on
// decoded ones, docs/benchmarks/log/2026-12-08-prediction-edges.md.)
size_t MarkRejectedByReconstruction(const SightCaster& caster, const ReferenceGrid& grid,
                                    const std::vector<Eigen::Vector3d>& samples,
                                    const std::vector<const RigDevice*>& devices,
                                    const Rigid3d& part_from_rig, double grazing_deg, bool code_y,
                                    const ReconstructOptions& options, std::vector<uint8_t>* sight);

}  // namespace slshadow::multiview::internal
