// Multi-view scans as files: the views file (what to scan: commanded turntable angles, or views
// placed by hand) and the project folder (what was scanned: one ImageSet per view and a manifest
// listing the views, their angles, provenance and state). Formats: docs/formats.md, "Views YAML"
// and "Multi-view project".
//
//   PROJECT/project.json           the manifest (ProjectManifest)
//   PROJECT/views/<name>/          one ImageSet per view (docs/formats.md "ImageSet")
//
// Frames and units: the rig frame (the first camera's), mm, degrees for table angles. The part
// frame of a multi-view scan is the rig frame at commanded table angle 0: a point x_rig seen in a
// view at commanded angle a lies at part_from_rig * x_rig with
// part_from_rig = axis.RigFromTableTurn(a).Inverse() (core/rig.h TurntableAxis).
#pragma once

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/rig.h"
#include "core/rigid3.h"

namespace slshadow {
class ConfigNode;
}  // namespace slshadow

namespace slshadow::multiview {

// One view to scan.
struct ViewSpec {
  // Unique within its file; names the view's ImageSet folder, so letters, digits, '_', '-' and
  // '.' only (not "." or ".."), at most 64 characters.
  std::string name;
  // Commanded turntable angle, degrees (what the table controller is told); nullopt: a view
  // placed by hand ("move the part, press Enter").
  std::optional<double> table_deg;
  // Hand-placed views only: a guess of the view's part_from_rig (the header's part frame); the
  // merge registers hand-placed views without one globally.
  std::optional<Rigid3d> part_from_rig_guess;
  // Hand-placed views only: the part was put down on the turntable's top, the table standing
  // still (e.g. turned over by hand between two turns). The table plane is then where it is in
  // every table view (fixed in the rig frame), and the merge crops it as it does in table views.
  // False: the part rests on something else, nothing is cropped.
  bool placed_on_table = false;
  bool OnTable() const { return table_deg.has_value(); }
  // A table view, or a view placed by hand on the table: its points on the table plane are the
  // table's.
  bool StandsOnTable() const { return OnTable() || placed_on_table; }
  bool operator==(const ViewSpec&) const;
};

struct ViewsFile {
  std::vector<ViewSpec> views;
  // Throws slshadow::Error naming `what`, the view and the field: no views, an invalid or
  // duplicate name, a non-finite or out-of-range (|a| > 3600) angle, a guess on a table view, a
  // non-finite guess.
  void Check(const std::string& what) const;
};

// `count` table views evenly spaced over a full turn from start_deg, named view_00, view_01, ...
// (two digits, three from 100 views). Throws on count < 1 or > 1000.
ViewsFile FullTurnViews(int count, double start_deg = 0.0);

// The default name of the index-th view: "view_00" (at least two digits).
std::string DefaultViewName(size_t index);

// Reading and writing VIEWS.yaml (docs/formats.md "Views YAML"). Unknown keys are rejected; the
// result is Check()ed. Throws slshadow::Error naming the file, the field and the value.
ViewsFile ViewsFromConfig(const ConfigNode& node);
ViewsFile LoadViews(const std::filesystem::path& path);  // .yaml/.yml/.json
nlohmann::json ViewsToJson(const ViewsFile& views);
void SaveViews(const ViewsFile& views, const std::filesystem::path& path);  // atomically

// ---- The project folder.

enum class ViewState { kComplete, kMissing };
std::string ToString(ViewState state);                   // "complete", "missing"
ViewState ViewStateFromString(const std::string& name);  // throws slshadow::Error

struct ProjectView {
  ViewSpec spec;
  ViewState state = ViewState::kMissing;
  std::string source;     // "virtual" or "device" (the ImageSet's image source), empty if missing
  std::string completed;  // ISO 8601 UTC time the view's ImageSet was committed, empty if missing
  // How a device scan took the view (`slshadow scan`, workflows/multiview/scan.h): commanded and
  // read-back table angles, the devices, times (docs/formats.md "Multi-view project"); null for
  // virtual views and views not yet scanned. Round-tripped untouched.
  nlohmann::json provenance;
  // The view's ImageSet folder relative to the project: views/<name>.
  std::filesystem::path Folder() const { return std::filesystem::path("views") / spec.name; }
};

struct ProjectManifest {
  static constexpr int kVersion = 1;
  std::string created;      // ISO 8601 UTC
  Rig rig;                  // with its turntable axis when the views are on a table
  nlohmann::json patterns;  // the pattern spec every view is scanned with
  // How the project was made: {"generator": "slshadow simulate --views", "scene": {config,
  // base_dir, summary} or null, "simulate": {...} or null, "views_file": path or ""}; free-form
  // beyond these keys.
  nlohmann::json provenance = nlohmann::json::object();
  std::vector<ProjectView> views;

  // The views as a views file (what a resume scans again).
  ViewsFile Views() const;
  const ProjectView* Find(const std::string& name) const;
  // Throws slshadow::Error naming `what`: invalid views (ViewsFile::Check), an invalid rig, table
  // views without a turntable axis in the rig, a complete view without a source.
  void Check(const std::string& what) const;
};

// A manifest for `views` with every view missing.
ProjectManifest NewProject(const Rig& rig, const nlohmann::json& patterns, const ViewsFile& views,
                           nlohmann::json provenance);

// PROJECT/project.json. Load validates the manifest (ProjectManifest::Check) and, for every view
// it says is complete, that views/<name>/manifest.json exists; throws slshadow::Error naming
// project.json, the field and the value otherwise. Save writes atomically.
ProjectManifest LoadProject(const std::filesystem::path& project_dir);
void SaveProject(const ProjectManifest& project, const std::filesystem::path& project_dir);
nlohmann::json ProjectToJson(const ProjectManifest& project);
ProjectManifest ProjectFromConfig(const ConfigNode& node);

// What of the rig, the pattern spec and the views differs from those `project` was started with:
// "rig", "pattern spec", "views (their number)", "views[i]"; empty when nothing does.
std::string ProjectInputsMismatch(const ProjectManifest& project, const Rig& rig,
                                  const nlohmann::json& patterns, const ViewsFile& views);

// The start of every run that writes a project (`slshadow scan`, `slshadow simulate --views`).
// Without PROJECT/project.json: a new manifest (NewProject of rig, patterns, views and
// `provenance`), saved, with views/ created; PROJECT must be absent or empty. With it: only when
// `resume`, the manifest as stored (read without LoadProject's folder checks: a complete view
// whose folder was lost is redone), refused when `mismatch(manifest)` names what differs from
// this run (empty: nothing); the caller saves it. Throws slshadow::Error naming PROJECT or its
// project.json: "already holds a project (pass --resume to <resume_action>)", "<what> differs
// from this run's; ...", "exists and is not a multi-view project ...".
struct StartedProject {
  ProjectManifest manifest;
  bool resumed = false;  // read from PROJECT/project.json
};
StartedProject StartOrResumeProject(
    const std::filesystem::path& project_dir, const Rig& rig, const nlohmann::json& patterns,
    const ViewsFile& views, const nlohmann::json& provenance, bool resume,
    const std::string& resume_action,
    const std::function<std::string(const ProjectManifest&)>& mismatch);

}  // namespace slshadow::multiview
