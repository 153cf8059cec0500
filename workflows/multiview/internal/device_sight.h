// Which devices of a rig see which CAD surface samples from one view, by geometry alone: the one
// copy of the rule the CAD comparison (cad_compare.h, the reasons of the uncovered surface) and
// the coverage prediction (coverage_prediction.h, before the scan) share. Internal to
// workflows/multiview/.
//
// Frames and units: the part frame (views.h), mm, degrees.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/mesh.h"
#include "core/rig.h"
#include "core/rigid3.h"
#include "reconstruct/reconstruct.h"

namespace slshadow::multiview::internal {

// The devices a reconstruction of `mode` needs, in this order: the first camera, in stereo the
// second, then the projector (every mode needs the surface lit). Throws slshadow::Error naming
// `what` (the caller, "CAD comparison") and the rig when one is missing.
std::vector<const RigDevice*> ModeDevices(const Rig& rig, ReconstructMode mode,
                                          const std::string& what);

// Per sample: the face on the turntable (the normal against the axis direction, at most
// tolerance_mm above the mesh's lowest point along it); all 0 without an axis.
std::vector<uint8_t> OnTableMask(const TriangleMesh& cad,
                                 const std::vector<Eigen::Vector3d>& samples,
                                 const std::vector<Eigen::Vector3f>& normals,
                                 const std::optional<TurntableAxis>& table_axis,
                                 double tolerance_mm);

// The CAD mesh, ray-cast with Embree (shadow rays from a sample towards a device centre).
class SightCaster {
 public:
  explicit SightCaster(const TriangleMesh& cad);  // keeps a copy
  ~SightCaster();
  SightCaster(const SightCaster&) = delete;
  SightCaster& operator=(const SightCaster&) = delete;

  // Per sample, as a CoverageReason, the worst over `devices` of one view:
  //   kOutsideField  behind a device, beyond its field or outside its image after distortion;
  //   kOccluded      facing away from a device or hidden from it by the part;
  //   kGrazing       the incidence to a device beyond grazing_deg;
  //   kCovered       seen by every device.
  // `active` (optional, one per sample): samples with 0 are not tested (kOutsideField).
  std::vector<uint8_t> View(const std::vector<Eigen::Vector3d>& samples,
                            const std::vector<Eigen::Vector3f>& normals,
                            const std::vector<const RigDevice*>& devices,
                            const Rigid3d& part_from_rig, double grazing_deg,
                            const std::vector<uint8_t>* active = nullptr) const;

  // The surface crossings of lines: for line i (through origins[i] along dirs[i], unit, part
  // frame; skipped when active[i] is 0), up to max_hits crossings of the part on each side of the
  // origin, nearest first, farther than `skip_mm` from it. Returned as hits[i * 2 * max_hits + k]
  // (k < max_hits: along dirs[i], then against it) with the face normal (outward); `found` 0
  // where none. forward_only: the side along dirs[i] alone (the other side's entries stay empty).
  struct LineHit {
    Eigen::Vector3d point = Eigen::Vector3d::Zero();
    Eigen::Vector3f normal = Eigen::Vector3f::Zero();
    uint8_t found = 0;
  };
  std::vector<LineHit> LineHits(const std::vector<Eigen::Vector3d>& origins,
                                const std::vector<Eigen::Vector3d>& dirs,
                                const std::vector<uint8_t>& active, int max_hits, double skip_mm,
                                bool forward_only = false) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace slshadow::multiview::internal
