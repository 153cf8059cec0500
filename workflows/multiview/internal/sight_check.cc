#include "workflows/multiview/internal/sight_check.h"

#include <algorithm>
#include <cmath>

namespace slshadow::multiview::internal {

void BuildSightlines(const std::vector<Eigen::Vector3d>& points,
                     const std::vector<Eigen::Vector3d>* backdrop, double pixels, Sightlines* out) {
  *out = Sightlines();
  size_t own = 0;  // out->direction[0, own): the view's own points
  for (const auto* set : {&points, backdrop}) {
    if (set == nullptr) continue;
    for (const Eigen::Vector3d& p : *set) {
      if (!(p.z() > 0)) continue;
      out->direction.emplace_back(p.x() / p.z(), p.y() / p.z(), 0.0);
      out->range.push_back(static_cast<float>(p.norm()));
    }
    if (set == &points) own = out->direction.size();
  }
  if (own < 5) return;
  out->tree = std::make_unique<KdTree>(out->direction, 32);
  const size_t step = std::max<size_t>(1, own / 2000);
  std::vector<double> spacing;
  std::vector<Neighbor> nn;
  for (size_t i = 0; i < own; i += step) {
    out->tree->KNearest(out->direction[i], 5, &nn);
    if (nn.size() == 5 && nn[4].distance_sq > 0) spacing.push_back(std::sqrt(nn[4].distance_sq));
  }
  if (spacing.empty()) {
    out->tree.reset();
    return;
  }
  std::nth_element(spacing.begin(), spacing.begin() + static_cast<long>(spacing.size() / 2),
                   spacing.end());
  out->radius = pixels * spacing[spacing.size() / 2];
}

SeenThrough CountSeenThrough(const Sightlines& view, const std::vector<Eigen::Vector3d>& points,
                             const std::vector<uint32_t>& indices, const Rigid3d& view_from_points,
                             double tol_mm) {
  SeenThrough s;
  if (!view.tree || view.radius <= 0) return s;
  std::vector<Neighbor> nn;
  for (uint32_t i : indices) {
    const Eigen::Vector3d q = view_from_points * points[i];
    if (!(q.z() > 0)) continue;
    view.tree->Radius(Eigen::Vector3d(q.x() / q.z(), q.y() / q.z(), 0.0), view.radius, &nn);
    if (nn.size() < 3) continue;
    ++s.judged;
    const double beyond = q.norm() + tol_mm;
    bool all = true;
    for (const Neighbor& n : nn) {
      if (view.range[n.index] <= beyond) {
        all = false;
        break;
      }
    }
    s.through += all ? 1 : 0;
  }
  return s;
}

}  // namespace slshadow::multiview::internal
