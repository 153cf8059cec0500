// Real against virtual across the views of a turntable scan (issue 33; `slshadow shadow PROJECT`):
// every view against its twin at the pose the turntable gives it, the diagnosis across views, and
// the merged real scan against the merged twin on the CAD surface.
//
//  1. The part's placement on the table, rig_from_part0 (the part file's frame into the rig frame
//     at commanded table angle 0): given, or, without it, registered on the first complete view
//     (global registration + ICP, as `slshadow shadow` does for one scan) and carried back by the
//     turntable model.
//  2. Each complete view runs the one-scan shadow (workflows' RunShadow: reconstruct, the pose
//     refined from axis.RigFromTableTurn(commanded) * rig_from_part0, the physics fit, the twin's
//     re-scan, the comparison and the diagnosis), its report in OUT/views/<name>/. A calibration
//     error shows in this step, in every view alike.
//  3. The diagnosis across views (workflows/multiview/view_drift.h) on the views' refined poses:
//  the
//     turntable axis off, the angle scale off, or the part slipped between two views, or none.
//  4. Merged: every view's real cloud and twin cloud carried into the part frame by the view's
//     refined pose and compared with the part's surface (workflows/multiview/cad_compare.h, the
//     table face excluded): signed C2M and coverage by reason for the real scan and for the twin,
//     and, per CAD vertex both cover, real minus twin (where the real scan departs from physics).
//  5. OUT/report.json (docs/formats.md "Multi-view shadow report") and OUT/summary.txt, with the
//     per-view reports, written into a staged folder renamed into place at the end (nothing
//     half-written on an error).
//
// Frames: the rig frame (the first camera's), the part frame (the part file's), mm, degrees for
// table angles. The part file holds what turns with the table (e.g. the part and the table disc,
// so the twin renders the table the real views see); the CAD comparison uses its surface without
// the face on the table.
#pragma once

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/rig.h"
#include "core/rigid3.h"
#include "workflows/multiview/cad_compare.h"
#include "workflows/multiview/view_drift.h"
#include "workflows/twin/twin.h"

namespace slshadow::multiview {

struct ProjectShadowOptions {
  // Every view's one-scan shadow; its rig_from_part is ignored (the turntable model gives each
  // view's start) and its `overwrite` applies to OUT.
  twin::ShadowOptions view;
  // The part at commanded angle 0, rig_from_part0; absent: registered on the first complete view.
  std::optional<Rigid3d> rig_from_part0;
  // The diagnosis across views; empty probe points: the part surface's bounding-box corners.
  ViewDriftOptions drift;
  CadCompareOptions cad;
  // The merged comparison leaves out points less than this above the table plane (the plane
  // through the axis point perpendicular to the axis, where the part stands), in the real and the
  // twin clouds alike, as `slshadow merge` does. Negative: keep every point.
  double table_crop_mm = 0.5;
  // Called before each view's shadow starts (name, index, count).
  std::function<void(const std::string&, size_t, size_t)> on_view;
  void Check() const;  // throws slshadow::Error naming the bad field
};

struct ProjectShadowView {
  std::string name;
  double table_deg = 0;
  Rigid3d rig_from_part;   // refined by the view's pose stage
  double sigma_mm = 0;     // the pose's 1-sigma translation (worst direction)
  std::string verdict;     // the view's own diagnosis in one line
  nlohmann::json figures;  // the view's report: pose, clouds' C2M, diagnosis
};

struct ProjectShadowResult {
  nlohmann::json report;  // what report.json holds
  std::vector<ProjectShadowView> views;
  ViewDriftDiagnosis drift;
  std::string Summary() const;  // the one-screen summary (summary.txt)
};

// The part of a turntable project: a mesh file (as LoadShadowPart reads it), or a scene file whose
// meshes and planes are the part's surface (registration and C2M) and whose other objects (the
// table disc, a cylinder) the twin renders but does not compare. Throws slshadow::Error naming the
// file when it cannot be read or has no mesh or plane.
twin::ShadowPart LoadTurntablePart(const std::filesystem::path& path);

// Runs the job on the project folder (rig from its manifest unless `rig` is given, e.g. a later
// calibration; it must have a turntable axis). Needs at least 3 complete table views; hand-placed
// views are left out and named. Throws slshadow::Error on bad input; nothing is written then.
ProjectShadowResult RunProjectShadow(const std::filesystem::path& project_dir,
                                     const twin::ShadowPart& part,
                                     const ProjectShadowOptions& options,
                                     const std::filesystem::path& out_dir,
                                     const Rig* rig = nullptr);

}  // namespace slshadow::multiview
