#include "workflows/multiview/internal/device_sight.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/error.h"
#include "sim/raycaster.h"
#include "sim/scene.h"
#include "workflows/multiview/cad_compare.h"

namespace slshadow::multiview::internal {

namespace {

constexpr auto kCovered = static_cast<uint8_t>(CoverageReason::kCovered);
constexpr auto kGrazing = static_cast<uint8_t>(CoverageReason::kGrazing);
constexpr auto kOccluded = static_cast<uint8_t>(CoverageReason::kOccluded);
constexpr auto kOutside = static_cast<uint8_t>(CoverageReason::kOutsideField);

}  // namespace

std::vector<const RigDevice*> ModeDevices(const Rig& rig, ReconstructMode mode,
                                          const std::string& what) {
  SLSHADOW_THROW_IF(rig.cameras.empty(), what, ": rig '", rig.name, "' has no camera");
  SLSHADOW_THROW_IF(!rig.projector, what, ": rig '", rig.name,
                    "' has no projector (every mode needs the surface lit)");
  std::vector<const RigDevice*> devices = {&rig.cameras[0]};
  if (mode == ReconstructMode::kStereo) {
    SLSHADOW_THROW_IF(rig.cameras.size() < 2, what, ": stereo needs two cameras (rig '", rig.name,
                      "' has ", rig.cameras.size(), ")");
    devices.push_back(&rig.cameras[1]);
  }
  devices.push_back(&*rig.projector);
  return devices;
}

std::vector<uint8_t> OnTableMask(const TriangleMesh& cad,
                                 const std::vector<Eigen::Vector3d>& samples,
                                 const std::vector<Eigen::Vector3f>& normals,
                                 const std::optional<TurntableAxis>& table_axis,
                                 double tolerance_mm) {
  std::vector<uint8_t> on_table(samples.size(), 0);
  if (!table_axis) return on_table;
  const Eigen::Vector3d up = table_axis->direction_in_rig.normalized();
  double lowest = std::numeric_limits<double>::infinity();
  for (const Eigen::Vector3d& v : cad.vertices) lowest = std::min(lowest, up.dot(v));
  for (size_t i = 0; i < samples.size(); ++i) {
    on_table[i] =
        up.dot(normals[i].cast<double>()) < -0.99 && up.dot(samples[i]) - lowest <= tolerance_mm;
  }
  return on_table;
}

struct SightCaster::Impl {
  Scene scene;  // the CAD mesh alone; outlives the caster
  std::unique_ptr<RayCaster> caster;
  double eps = 0;  // off the surface for shadow rays
  // Embree's geometric normal times this is the mesh's outward face normal (FaceNormal).
  float normal_sign = 1;
};

SightCaster::SightCaster(const TriangleMesh& cad) : impl_(std::make_unique<Impl>()) {
  impl_->scene.name = "CAD";
  SceneObject object;
  object.name = "cad";
  object.type = ObjectType::kMesh;
  object.mesh = std::make_shared<const TriangleMesh>(cad);
  impl_->scene.objects.push_back(object);
  impl_->caster = std::make_unique<RayCaster>(impl_->scene);
  const Eigen::Vector3d extent = cad.BoundsMax() - cad.BoundsMin();
  impl_->eps = std::max(1e-3, 2e-5 * extent.norm());
  // The orientation of the hits' normals: a ray onto the first face of the mesh from just in
  // front of it.
  if (cad.NumTriangles() > 0) {
    const auto& t = cad.triangles[0];
    const Eigen::Vector3d centre =
        (cad.vertices[t[0]] + cad.vertices[t[1]] + cad.vertices[t[2]]) / 3.0;
    const Eigen::Vector3d n = cad.FaceNormal(0);
    RayPacket packet;
    for (int l = 0; l < RayPacket::kSize; ++l) packet.active[l] = l == 0;
    const Eigen::Vector3d o = centre + 10 * impl_->eps * n;
    packet.org_x[0] = static_cast<float>(o.x());
    packet.org_y[0] = static_cast<float>(o.y());
    packet.org_z[0] = static_cast<float>(o.z());
    packet.dir_x[0] = static_cast<float>(-n.x());
    packet.dir_y[0] = static_cast<float>(-n.y());
    packet.dir_z[0] = static_cast<float>(-n.z());
    packet.tnear[0] = 0;
    packet.tfar[0] = static_cast<float>(20 * impl_->eps);
    impl_->caster->Intersect(packet, TraceMode::kSingleRay, false);
    if (packet.object[0] >= 0 &&
        n.dot(Eigen::Vector3d(packet.ng_x[0], packet.ng_y[0], packet.ng_z[0])) < 0)
      impl_->normal_sign = -1;
  }
}

SightCaster::~SightCaster() = default;

std::vector<uint8_t> SightCaster::View(const std::vector<Eigen::Vector3d>& samples,
                                       const std::vector<Eigen::Vector3f>& normals,
                                       const std::vector<const RigDevice*>& devices,
                                       const Rigid3d& part_from_rig, double grazing_deg,
                                       const std::vector<uint8_t>* active) const {
  const RayCaster& caster = *impl_->caster;
  const double eps = impl_->eps;
  const double cos_grazing = std::cos(grazing_deg * M_PI / 180.0);
  const Rigid3d rig_from_part = part_from_rig.Inverse();
  std::vector<Eigen::Vector3d> centres;
  for (const RigDevice* d : devices) centres.push_back(part_from_rig * d->CenterInRig());
  std::vector<uint8_t> sight(samples.size(), kCovered);
  if (active) {
    for (size_t i = 0; i < samples.size(); ++i) {
      if (!(*active)[i]) sight[i] = kOutside;
    }
  }
  constexpr size_t kLanes = RayPacket::kSize;
  const size_t blocks = (samples.size() + kLanes - 1) / kLanes;
  tbb::parallel_for(size_t{0}, blocks, [&](size_t b) {
    const size_t first = b * kLanes, n = std::min(kLanes, samples.size() - first);
    RayPacket packet;
    for (size_t d = 0; d < devices.size(); ++d) {
      const RigDevice& device = *devices[d];
      const Eigen::Vector3d& c = centres[d];
      const double max_r2 = std::pow(device.model.width / device.model.fx(), 2) +
                            std::pow(device.model.height / device.model.fy(), 2);
      bool any = false;
      for (size_t l = 0; l < kLanes; ++l) {
        packet.active[l] = 0;
        if (l >= n || sight[first + l] == kOutside) continue;
        const Eigen::Vector3d& p = samples[first + l];
        const Eigen::Vector3d in_device = device.cam_from_rig * (rig_from_part * p);
        const double x = in_device.x() / in_device.z(), y = in_device.y() / in_device.z();
        const auto pixel = device.model.Project(in_device);
        if (in_device.z() <= 0 || x * x + y * y > max_r2 || !pixel ||
            !device.model.IsInImage(*pixel)) {
          sight[first + l] = kOutside;
          continue;
        }
        const Eigen::Vector3d nrm = normals[first + l].cast<double>();
        const Eigen::Vector3d to = c - p;
        const double cos_incidence = nrm.dot(to) / to.norm();
        if (cos_incidence <= 0) {
          sight[first + l] = std::max(sight[first + l], kOccluded);
          continue;
        }
        if (cos_incidence < cos_grazing) sight[first + l] = std::max(sight[first + l], kGrazing);
        const Eigen::Vector3d o = p + eps * nrm;
        const Eigen::Vector3d dir = (c - o) / (c - o).norm();
        packet.org_x[l] = static_cast<float>(o.x());
        packet.org_y[l] = static_cast<float>(o.y());
        packet.org_z[l] = static_cast<float>(o.z());
        packet.dir_x[l] = static_cast<float>(dir.x());
        packet.dir_y[l] = static_cast<float>(dir.y());
        packet.dir_z[l] = static_cast<float>(dir.z());
        packet.tnear[l] = 0.0f;
        packet.tfar[l] = static_cast<float>((c - o).norm() - eps);
        packet.active[l] = 1;
        any = true;
      }
      if (!any) continue;
      caster.Occluded(packet, TraceMode::kPacket16);
      for (size_t l = 0; l < n; ++l) {
        if (packet.active[l] && packet.occluded[l])
          sight[first + l] = std::max(sight[first + l], kOccluded);
      }
    }
  });
  return sight;
}

std::vector<SightCaster::LineHit> SightCaster::LineHits(const std::vector<Eigen::Vector3d>& origins,
                                                        const std::vector<Eigen::Vector3d>& dirs,
                                                        const std::vector<uint8_t>& active,
                                                        int max_hits, double skip_mm,
                                                        bool forward_only) const {
  const RayCaster& caster = *impl_->caster;
  const auto per = static_cast<size_t>(2 * max_hits);
  std::vector<LineHit> hits(origins.size() * per);
  constexpr size_t kLanes = RayPacket::kSize;
  const size_t blocks = (origins.size() + kLanes - 1) / kLanes;
  tbb::parallel_for(size_t{0}, blocks, [&](size_t b) {
    const size_t first = b * kLanes, n = std::min(kLanes, origins.size() - first);
    for (int side = 0; side < (forward_only ? 1 : 2); ++side) {
      const double sign = side == 0 ? 1.0 : -1.0;
      RayPacket packet;
      float start[kLanes];  // distance from the origin along the line where the next ray starts
      bool any = false;
      for (size_t l = 0; l < kLanes; ++l) {
        packet.active[l] = l < n && active[first + l];
        start[l] = static_cast<float>(skip_mm);
        any = any || packet.active[l];
      }
      for (int k = 0; k < max_hits && any; ++k) {
        any = false;
        for (size_t l = 0; l < n; ++l) {
          if (!packet.active[l]) continue;
          const Eigen::Vector3d& o = origins[first + l];
          const Eigen::Vector3d d = sign * dirs[first + l];
          packet.org_x[l] = static_cast<float>(o.x());
          packet.org_y[l] = static_cast<float>(o.y());
          packet.org_z[l] = static_cast<float>(o.z());
          packet.dir_x[l] = static_cast<float>(d.x());
          packet.dir_y[l] = static_cast<float>(d.y());
          packet.dir_z[l] = static_cast<float>(d.z());
          packet.tnear[l] = start[l];
          packet.tfar[l] = std::numeric_limits<float>::infinity();
        }
        caster.Intersect(packet, TraceMode::kPacket16, false);
        for (size_t l = 0; l < n; ++l) {
          if (!packet.active[l]) continue;
          if (packet.object[l] < 0) {
            packet.active[l] = 0;
            continue;
          }
          LineHit& h = hits[(first + l) * per + static_cast<size_t>(side * max_hits + k)];
          h.point =
              origins[first + l] + sign * dirs[first + l] * static_cast<double>(packet.tfar[l]);
          h.normal =
              impl_->normal_sign * Eigen::Vector3f(packet.ng_x[l], packet.ng_y[l], packet.ng_z[l]);
          h.found = 1;
          start[l] = packet.tfar[l] + static_cast<float>(impl_->eps);
          any = true;
        }
      }
    }
  });
  return hits;
}

}  // namespace slshadow::multiview::internal
