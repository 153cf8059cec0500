#include "workflows/studies/sweep_reuse.h"

#include "compare/c2m_grid.h"
#include "compare/coverage.h"
#include "compare/median_spacing.h"
#include "compare/statistics.h"
#include "core/error.h"
#include "sim/renderer.h"
#include "sim/sensor_noise.h"
#include "sim/shapes.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <mutex>

namespace slshadow::studies {

std::string NoiseFreeImages::Key(const nlohmann::json& scene, const nlohmann::json& patterns) {
  nlohmann::json s = scene;
  s.erase("name");
  if (s.contains("layers") && s["layers"].is_object()) s["layers"].erase("noise");
  return nlohmann::json{{"scene", s}, {"patterns", patterns}}.dump();
}

NoiseFreeImages::NoiseFreeImages(const Simulator& simulator, const Scene& scene, const Rig& rig,
                                 const std::vector<cv::Mat>& projector_images) {
  const int batch = PatternRenderer::kMaxBatch;
  irradiance_.resize(static_cast<size_t>(simulator.num_cameras()));
  for (int c = 0; c < simulator.num_cameras(); ++c) {
    const PatternRenderer renderer(scene, rig, c, simulator.geometry(c));
    auto& out = irradiance_[static_cast<size_t>(c)];
    for (size_t first = 0; first < projector_images.size(); first += batch) {
      const std::vector<cv::Mat> chunk(
          projector_images.begin() + static_cast<std::ptrdiff_t>(first),
          projector_images.begin() +
              static_cast<std::ptrdiff_t>(std::min(first + batch, projector_images.size())));
      for (cv::Mat& m : renderer.RenderIrradianceBatch(chunk)) out.push_back(std::move(m));
    }
  }
}

void NoiseFreeImages::Render(const Scene& scene, std::vector<std::vector<cv::Mat>>* images) const {
  images->resize(irradiance_.size());
  for (size_t c = 0; c < irradiance_.size(); ++c) {
    auto& cam = (*images)[c];
    cam.resize(irradiance_[c].size());
    for (size_t p = 0; p < cam.size(); ++p) {
      // A buffer shared with a caller (e.g. a decoded view) is not overwritten: a new one is made.
      if (cam[p].u && cam[p].u->refcount > 1) cam[p].release();
      QuantizeIrradiance(irradiance_[c][p], scene, static_cast<int>(c), static_cast<int>(p),
                         &cam[p]);
    }
  }
}

// The samples of the reference surface followed by the visible points, sorted into a dense
// uniform grid (~4 points per cell, at most 8 M cells; counting sort), built once. A coverage
// query sorts the reached points into the same cells and asks, for every sample, whether one lies
// within the radius: exactly compare::Coverage's criterion, (sample - reached).squaredNorm() <
// nextafter(r)^2.
struct GroundTruthScorer::SampleGrid {
  size_t num_reference = 0, num_visible = 0;
  Eigen::Vector3d lo = Eigen::Vector3d::Zero();
  double cell = 1, inv = 1;
  int64_t nx = 0, ny = 0, nz = 0;
  std::vector<uint32_t> start;          // per cell, its first point; one more at the end
  std::vector<Eigen::Vector3d> points;  // by cell
  std::vector<uint8_t> is_reference;    // by cell order: a reference sample (else visible)
  std::vector<uint32_t> occupied;       // the cells holding points, ascending

  SampleGrid(const std::vector<Eigen::Vector3d>& reference,
             const std::vector<Eigen::Vector3d>& visible)
      : num_reference(reference.size()), num_visible(visible.size()) {
    const auto each = [&](auto&& f) {
      for (const auto& p : reference) f(p, uint8_t{1});
      for (const auto& p : visible) f(p, uint8_t{0});
    };
    Eigen::Vector3d hi = Eigen::Vector3d::Constant(-std::numeric_limits<double>::infinity());
    lo = -hi;
    each([&](const Eigen::Vector3d& p, uint8_t) {
      if (!p.allFinite()) return;  // never within a finite distance of anything
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
    });
    if (!(lo.x() <= hi.x())) return;
    const Eigen::Vector3d extent = (hi - lo).cwiseMax(1e-9);
    // About 4 points per cell of a surface (the two largest extents), at most 8 M cells.
    Eigen::Vector3d e = extent;
    std::sort(e.data(), e.data() + 3, std::greater<>());
    const double n = static_cast<double>(reference.size() + visible.size());
    cell = std::max({2 * std::sqrt(e[0] * e[1] / n), std::cbrt(extent.prod() / 8e6), e[0] / 4096});
    inv = 1 / cell;
    nx = static_cast<int64_t>(extent.x() * inv) + 1;
    ny = static_cast<int64_t>(extent.y() * inv) + 1;
    nz = static_cast<int64_t>(extent.z() * inv) + 1;
    start.assign(static_cast<size_t>(nx * ny * nz) + 1, 0);
    std::vector<uint32_t> cell_of;
    each([&](const Eigen::Vector3d& p, uint8_t) {
      if (!p.allFinite()) return;
      cell_of.push_back(static_cast<uint32_t>(Cell(p)));
      ++start[cell_of.back() + 1];
    });
    for (size_t c = 1; c < start.size(); ++c) {
      if (start[c] > 0) occupied.push_back(static_cast<uint32_t>(c - 1));
      start[c] += start[c - 1];
    }
    points.resize(cell_of.size());
    is_reference.resize(cell_of.size());
    std::vector<uint32_t> fill(start.begin(), start.end() - 1);
    size_t k = 0;
    each([&](const Eigen::Vector3d& p, uint8_t ref) {
      if (!p.allFinite()) return;
      const uint32_t slot = fill[cell_of[k++]]++;
      points[slot] = p;
      is_reference[slot] = ref;
    });
  }

  // The cell coordinate, clamped to [0, n - 1], of a point at t cells from the grid's origin
  // along an axis of n cells: Cell's, without a call to floor. False when floor(t) lies more than
  // `reach` cells outside (or t is not finite): the point reaches no sample then.
  static bool Axis(double t, int64_t n, int64_t reach, int64_t* cell) {
    if (!(t >= -static_cast<double>(reach) && t < static_cast<double>(n + reach + 1))) return false;
    *cell = t < 0 ? 0 : t >= static_cast<double>(n) ? n - 1 : static_cast<int64_t>(t);
    return true;
  }

  int64_t Cell(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d c = ((p - lo) * inv).array().floor();
    const int64_t x = std::clamp<int64_t>(static_cast<int64_t>(c.x()), 0, nx - 1);
    const int64_t y = std::clamp<int64_t>(static_cast<int64_t>(c.y()), 0, ny - 1);
    const int64_t z = std::clamp<int64_t>(static_cast<int64_t>(c.z()), 0, nz - 1);
    return (z * ny + y) * nx + x;
  }

  // The cells within `reach` cells of an occupied one (per axis, clamped to the grid): the only
  // ones whose reached points can cover a sample. Numbered in cell order, so that consecutive
  // cells of a row that are all near have consecutive numbers.
  struct NearCells {
    int64_t reach = -1;
    std::vector<uint32_t> number;  // per cell: its number among the near cells, or kNotNear
    uint32_t count = 0;
  };
  static constexpr uint32_t kNotNear = std::numeric_limits<uint32_t>::max();

  // Scratch of Cover, reused from call to call (a sweep measures two clouds a job).
  struct Scratch {
    std::vector<uint32_t> cell_of, first;
    std::vector<Eigen::Vector3d> sorted;
  };

  // `near` is built under near_mutex (no parallel work inside: a thread waiting in a parallel
  // loop may run another call's tasks, which then wait for it); `scratch` is taken with try_lock
  // only (a call finding it taken uses buffers of its own).
  mutable std::mutex near_mutex, scratch_mutex;
  mutable std::shared_ptr<const NearCells> near;
  mutable Scratch scratch;

  std::shared_ptr<const NearCells> NearFor(int64_t reach) const {
    const std::lock_guard<std::mutex> lock(near_mutex);
    if (near && near->reach == reach) return near;
    auto n = std::make_shared<NearCells>();
    n->reach = reach;
    n->number.assign(start.size() - 1, kNotNear);
    for (const uint32_t c : occupied) {
      const auto cx = static_cast<int64_t>(c) % nx;
      const auto cy = static_cast<int64_t>(c) / nx % ny;
      const auto cz = static_cast<int64_t>(c) / nx / ny;
      for (int64_t z = std::max<int64_t>(cz - reach, 0); z <= std::min(cz + reach, nz - 1); ++z) {
        for (int64_t y = std::max<int64_t>(cy - reach, 0); y <= std::min(cy + reach, ny - 1); ++y) {
          const int64_t row = (z * ny + y) * nx;
          for (int64_t x = std::max<int64_t>(cx - reach, 0); x <= std::min(cx + reach, nx - 1);
               ++x) {
            n->number[static_cast<size_t>(row + x)] = 0;
          }
        }
      }
    }
    for (uint32_t& k : n->number) {
      if (k != kNotNear) k = n->count++;
    }
    near = n;
    return n;
  }

  // (reference coverage, visible coverage), as compare::Coverage gives each, of the points
  // pts[i] with |deviations[i]| <= threshold (the reached ones) within `radius_mm`. False when the
  // radius is not a positive finite bound (compare::Coverage then takes another path).
  //
  // The reached points near a sample's cell are sorted into the near cells (counting sort; a
  // point outside the grid into the nearest boundary cell, which moves it towards every sample,
  // so a sample still finds it within `reach` cells; points more than `reach` cells outside, or
  // in no near cell, reach no sample), then each sample looks for one reached point within the
  // radius, its own cell first, and stops at the first: most samples are settled by the first few
  // points they look at.
  bool Cover(const std::vector<Eigen::Vector3d>& pts, const std::vector<double>& deviations,
             double threshold_mm, double radius_mm, double* reference_cov,
             double* visible_cov) const {
    const double r = std::nextafter(radius_mm, 1e300);
    const double bound = r * r;
    if (!(bound > 0) || !std::isfinite(bound)) return false;
    *reference_cov = *visible_cov = 0;
    if (pts.empty() || points.empty()) return true;
    const auto reach = static_cast<int64_t>(std::ceil(r * 1.001 * inv));  // margin: rounding
    const std::shared_ptr<const NearCells> near_cells = NearFor(reach);
    const std::vector<uint32_t>& number = near_cells->number;
    // This call's buffers: the shared scratch, or (another call holding it) its own.
    const std::unique_lock<std::mutex> lock(scratch_mutex, std::try_to_lock);
    Scratch own;
    Scratch& buf = lock.owns_lock() ? scratch : own;
    std::vector<uint32_t>& cell_of = buf.cell_of;
    cell_of.resize(pts.size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, pts.size(), 16384),
                      [&](const tbb::blocked_range<size_t>& range) {
                        for (size_t i = range.begin(); i < range.end(); ++i) {
                          cell_of[i] = kNotNear;
                          if (!(std::abs(deviations[i]) <= threshold_mm)) continue;
                          const Eigen::Vector3d t = (pts[i] - lo) * inv;
                          int64_t x = 0, y = 0, z = 0;
                          if (Axis(t.x(), nx, reach, &x) && Axis(t.y(), ny, reach, &y) &&
                              Axis(t.z(), nz, reach, &z)) {
                            cell_of[i] = number[static_cast<size_t>((z * ny + y) * nx + x)];
                          }
                        }
                      });
    // Counting sort: counts, inclusive prefix sums (near cell c's end), then filled from the back,
    // which leaves first[c] at near cell c's start (the order within a cell does not matter).
    std::vector<uint32_t>& first = buf.first;
    first.assign(static_cast<size_t>(near_cells->count) + 1, 0);
    for (const uint32_t c : cell_of) {
      if (c != kNotNear) ++first[c];
    }
    for (size_t c = 1; c < first.size(); ++c) first[c] += first[c - 1];
    std::vector<Eigen::Vector3d>& sorted = buf.sorted;
    sorted.resize(first.back());
    for (size_t i = pts.size(); i-- > 0;) {
      if (cell_of[i] != kNotNear) sorted[--first[cell_of[i]]] = pts[i];
    }
    // Whether a reached point lies within the radius of sample p in cells [x0, x1] of row `row`
    // (all near: they lie within `reach` of the sample's occupied cell).
    const auto any_in = [&](const Eigen::Vector3d& p, int64_t row, int64_t x0, int64_t x1) {
      const uint32_t end = first[number[static_cast<size_t>(row + x1)] + 1];
      for (uint32_t k = first[number[static_cast<size_t>(row + x0)]]; k < end; ++k) {
        if ((p - sorted[k]).squaredNorm() < bound) return true;
      }
      return false;
    };
    using Counts = std::pair<size_t, size_t>;  // covered (reference samples, visible points)
    const Counts covered = tbb::parallel_reduce(
        tbb::blocked_range<size_t>(0, occupied.size(), 256), Counts{0, 0},
        [&](const tbb::blocked_range<size_t>& range, Counts acc) {
          for (size_t j = range.begin(); j < range.end(); ++j) {
            const size_t c = occupied[j];
            const auto cx = static_cast<int64_t>(c) % nx;
            const auto cy = static_cast<int64_t>(c) / nx % ny;
            const auto cz = static_cast<int64_t>(c) / nx / ny;
            const int64_t x0 = std::max<int64_t>(cx - reach, 0), x1 = std::min(cx + reach, nx - 1);
            for (uint32_t k = start[c]; k < start[c + 1]; ++k) {
              const Eigen::Vector3d& p = points[k];
              bool hit = any_in(p, static_cast<int64_t>(c) - cx, cx, cx);
              for (int64_t z = std::max<int64_t>(cz - reach, 0);
                   !hit && z <= std::min(cz + reach, nz - 1); ++z) {
                for (int64_t y = std::max<int64_t>(cy - reach, 0);
                     !hit && y <= std::min(cy + reach, ny - 1); ++y) {
                  hit = any_in(p, (z * ny + y) * nx, x0, x1);
                }
              }
              if (hit) (is_reference[k] ? acc.first : acc.second) += 1;
            }
          }
          return acc;
        },
        [](Counts a, Counts b) {
          return Counts{a.first + b.first, a.second + b.second};
        });
    if (num_reference) {
      *reference_cov = static_cast<double>(covered.first) / static_cast<double>(num_reference);
    }
    if (num_visible) {
      *visible_cov = static_cast<double>(covered.second) / static_cast<double>(num_visible);
    }
    return true;
  }
};

GroundTruthScorer::GroundTruthScorer(TriangleMesh surface, std::vector<Eigen::Vector3d> visible,
                                     const std::string& what)
    : reference_(compare::ReferenceFromMesh(std::move(surface), what)),
      distance_(reference_.mesh),
      visible_(std::move(visible)),
      samples_(std::make_unique<SampleGrid>(reference_.cloud.points, visible_)) {}

GroundTruthScorer::~GroundTruthScorer() = default;

void GroundTruthScorer::Prepare(const std::vector<const PointCloud*>& clouds, int jobs_left) {
  // A few jobs' clouds do not repay the cells (a geometry group of one job never builds them).
  if (++prepared_ < 2) return;
  if (grid_) {
    // The cells the previous clouds fell in unbuilt: this job's clouds fall in nearly the same.
    if (grid_->enabled()) grid_->BuildMissed();
    return;
  }
  if (jobs_left < kGridJobs) return;
  double spacing = 0;  // the clouds' point spacing (the coarsest)
  for (const PointCloud* cloud : clouds) {
    if (cloud->size() >= 2) spacing = std::max(spacing, compare::MedianSpacing(cloud->points));
  }
  grid_ = std::make_unique<compare::C2mGrid>(reference_.mesh, distance_, spacing);
  if (!grid_->enabled()) return;
  for (const PointCloud* cloud : clouds) grid_->Prepare(cloud->points);
}

pipeline::ModeAccuracy GroundTruthScorer::Measure(const PointCloud& cloud,
                                                  const compare::CompareOptions& options,
                                                  const std::string& mode) const {
  if (options.registration.method != compare::RegistrationMethod::kNone || options.m3c2 ||
      options.artefacts) {
    const compare::CompareResult result = compare::Compare(cloud, reference_, options, mode);
    pipeline::ModeAccuracy m = pipeline::MeasureAccuracy(mode, result, visible_);
    pipeline::MeasureFigureUncertainty(result.deviations_mm, &m);
    return m;
  }
  options.Check();
  cloud.Check(mode);
  SLSHADOW_THROW_IF(cloud.empty(), mode, ": the compared cloud has no points");
  const std::vector<Eigen::Vector3d>& pts = cloud.points;
  // Signed distances: the result does not depend on the warm-start hint (compare/mesh_distance.h);
  // clouds come in grid order, so the previous point's triangle is a good one.
  std::vector<double> deviations(pts.size());
  if (grid_ && grid_->enabled()) {
    grid_->SignedDistances(pts, &deviations);
  } else {
    tbb::parallel_for(tbb::blocked_range<size_t>(0, pts.size(), 4096),
                      [&](const tbb::blocked_range<size_t>& r) {
                        uint32_t hint = std::numeric_limits<uint32_t>::max();
                        for (size_t i = r.begin(); i < r.end(); ++i) {
                          const compare::MeshHit hit = distance_.Closest(pts[i], hint);
                          deviations[i] = hit.signed_distance_mm;
                          hint = hit.triangle;
                        }
                      });
  }
  const compare::DistanceStats stats =
      compare::ComputeStats(deviations, false, options.threshold_mm);
  const double radius = options.coverage_radius_mm > 0
                            ? options.coverage_radius_mm
                            : std::max(options.threshold_mm, 3.0 * compare::MedianSpacing(pts));
  pipeline::ModeAccuracy m;
  m.mode = mode;
  m.points = pts.size();
  if (!samples_->Cover(pts, deviations, options.threshold_mm, radius, &m.coverage,
                       &m.visible_coverage)) {
    std::vector<Eigen::Vector3d> reached;
    for (size_t i = 0; i < pts.size(); ++i) {
      if (std::abs(deviations[i]) <= options.threshold_mm) reached.push_back(pts[i]);
    }
    m.coverage = compare::Coverage(reference_.cloud.points, reached, radius);
    m.visible_coverage = compare::Coverage(visible_, reached, radius);
  }
  m.mean_mm = stats.mean_mm;
  m.rms_mm = stats.rms_mm;
  m.p95_mm = stats.p95_mm;
  m.max_mm = stats.max_mm;
  m.outliers = stats.outliers;
  m.outlier_fraction =
      stats.count ? static_cast<double>(stats.outliers) / static_cast<double>(stats.count) : 0;
  pipeline::MeasureFigureUncertainty(deviations, &m);
  return m;
}

}  // namespace slshadow::studies
