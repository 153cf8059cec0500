// Study 5: a virtual VDI/VDE 2634 part 2 acceptance test as a sweep (workflows/studies/sweep.h).
// The study key `vdi2634` (docs/formats.md "Study YAML", docs/studies/vdi2634_quick/README.md)
// places the guideline's artefacts through the rig's measuring volume:
//
//   sphere    probing error PF (form) and PS (size): at the volume's centre and its 8 corners
//             (each inset by the sphere's radius), `positions` of them in that order;
//   ball bar  sphere-spacing error SD: centred in the volume along its 4 space diagonals, then
//             along x and the two diagonals of the xy mid-plane, `orientations` of the 7;
//   plane     flatness error F: at the centre facing the first camera, tilted by +-tilt_deg about
//             y and about x, then moved to the front and to the back of the volume, `positions`
//             of the 7.
//
// Each placement is one value of an implicit first axis `position` (one geometry group each):
// a scene holding the artefact alone (the study's scene supplies radiometry and layers), and
// the artefact file (compare/vdi2634.h) that segments and fits it. Each job's result holds per
// mode the figures of compare::EvaluateVdi2634; `sweep merge` tabulates them per position and
// overall (max PF, PS and SD of largest magnitude, max F), and charts them.
#pragma once

#include "core/rig.h"

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <vector>

namespace slshadow {
class ConfigNode;
}  // namespace slshadow

namespace slshadow::studies {

// An axis-aligned box in the rig frame (the first camera's frame).
struct MeasuringVolume {
  Eigen::Vector3d center_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d size_mm = Eigen::Vector3d::Zero();
  double DiagonalMm() const { return size_mm.norm(); }  // L0
};

// The devices a study's modes use (the first camera; the second with stereo; the projector,
// which lights every scan). `modes` as in a job ("projector", "stereo").
std::vector<const RigDevice*> StudyDevices(const Rig& rig, const std::vector<std::string>& modes);

// The first corner (or the centre) of `volume` that some device does not see within 5 % of its
// image border, as "corner (x, y, z) mm outside <device>"; empty when every device sees all.
std::string VolumeVisibilityProblem(const MeasuringVolume& volume,
                                    const std::vector<const RigDevice*>& devices);

// The default measuring volume of a rig: centred on the working point (Rig::WorkingPointInRig),
// width : height : depth = the first camera's image width : height : half its width at the
// working distance, scaled to the largest box whose corners every device sees within 5 % of its
// border, then 90 % of that, rounded down to whole mm. Throws slshadow::Error naming `what` when
// the devices do not share a view of the working point.
MeasuringVolume AutoMeasuringVolume(const Rig& rig, const std::vector<std::string>& modes,
                                    const std::string& what);

// One placement of an artefact.
struct Vdi2634Placement {
  std::string label;         // "sphere_1", "bar_3", "plane_2": the value of the axis `position`
  std::string artefact;      // "sphere", "ball_bar", "plane"
  std::string description;   // where, in words ("corner (-x, -y, -z)", "space diagonal ...")
  nlohmann::json object;     // the scene object (scene YAML tree)
  nlohmann::json artefacts;  // the artefact file tree (compare/vdi2634.h) of this placement
  nlohmann::json geometry;   // centre(s), direction or normal, sizes: for positions.csv
};

struct Vdi2634Study {
  MeasuringVolume volume;
  bool volume_from_rig = false;
  std::vector<Vdi2634Placement> placements;
  nlohmann::json options;  // compare::Vdi2634Options as JSON
  nlohmann::json mpe;      // maximum permissible errors {pf_mm, ps_mm, sd_mm, f_mm} or null
  // What the plan records (volume, sizes, placements without the scene objects).
  nlohmann::json ToJson() const;
};

// Reads the study key `vdi2634` (`node`) for `rig` and `modes`: the volume (given, or
// AutoMeasuringVolume), artefact sizes (defaults relative to the volume's diagonal L0) and
// placements, each checked to lie inside the volume and the volume to be seen by every device.
// Throws slshadow::Error naming the file, the field and the value.
Vdi2634Study Vdi2634StudyFromConfig(const ConfigNode& node, const Rig& rig,
                                    const std::vector<std::string>& modes);

// ---- Merge.

// One job's figures in one mode (the `vdi2634` entry a job's result holds per mode).
struct Vdi2634Row {
  std::string id, series, position, mode;
  nlohmann::json figures;  // compare::Vdi2634Result::ToJson(), or null: nothing reconstructed
};

// Writes at `out_dir` vdi2634.csv (per position and mode: points, found, PF, PS, SD, F and the
// fitted size), vdi2634_summary.csv (per series and mode: the overall PF, PS, SD and F, the
// position each comes from, pass / fail against the study's MPE when given), positions.csv (the
// placements) and vdi2634.png / .svg (the four figures per position, one panel each). Returns one
// line per series and mode for the command to print.
std::vector<std::string> WriteVdi2634Results(const std::filesystem::path& out_dir,
                                             const std::vector<Vdi2634Row>& rows,
                                             const nlohmann::json& plan_vdi2634,
                                             const std::string& study);

}  // namespace slshadow::studies
