#include "workflows/multiview/views.h"

#include <cmath>
#include <set>

#include "core/config.h"
#include "core/enum_names.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/pose_io.h"
#include "core/string_printf.h"

namespace slshadow::multiview {
namespace fs = std::filesystem;

namespace {

constexpr int kViewsVersion = 1;
constexpr double kMaxTableDeg = 3600;

// Why `name` cannot name a view folder, or empty when it can.
std::string NameProblem(const std::string& name) {
  if (name.empty()) return "must not be empty";
  if (name.size() > 64) return "longer than 64 characters";
  if (name == "." || name == "..") return "must not be '.' or '..'";
  for (const char c : name) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '-' || c == '.';
    if (!ok) return "only letters, digits, '_', '-' and '.' may name a view folder";
  }
  return "";
}

// A view's own keys (a views file's entries; a project manifest's views add theirs).
const std::vector<std::string>& ViewSpecKeys() {
  static const std::vector<std::string> keys = {"name", "table_deg", "part_from_rig_guess",
                                                "placed_on_table"};
  return keys;
}

ViewSpec ViewFromConfig(const ConfigNode& node, size_t index) {
  node.RejectUnknownKeys(ViewSpecKeys());
  ViewSpec view;
  view.name = node.GetString("name", DefaultViewName(index));
  if (node.Has("name")) {
    const std::string problem = NameProblem(view.name);
    if (!problem.empty()) node["name"].Fail(problem);
  }
  if (node.Has("table_deg")) {
    const auto a = node["table_deg"];
    view.table_deg = a.AsDouble();
    if (std::abs(*view.table_deg) > kMaxTableDeg) a.Fail("table angle beyond +-3600 degrees");
  }
  if (node.Has("part_from_rig_guess")) {
    if (view.table_deg)
      node["part_from_rig_guess"].Fail(
          "a table view's pose follows from the turntable axis; give a guess only for a view "
          "placed by hand (no table_deg)");
    view.part_from_rig_guess = PoseFromConfig(node["part_from_rig_guess"]);
  }
  if (node.Has("placed_on_table")) {
    if (view.table_deg)
      node["placed_on_table"].Fail(
          "a table view stands on the table anyway; placed_on_table is for a view placed by hand "
          "(no table_deg)");
    view.placed_on_table = node["placed_on_table"].AsBool();
  }
  return view;
}

nlohmann::json ViewToJson(const ViewSpec& view) {
  nlohmann::json j = {{"name", view.name}};
  if (view.table_deg) j["table_deg"] = *view.table_deg;
  if (view.part_from_rig_guess) j["part_from_rig_guess"] = PoseToJson(*view.part_from_rig_guess);
  if (view.placed_on_table) j["placed_on_table"] = true;
  return j;
}

}  // namespace

bool ViewSpec::operator==(const ViewSpec& other) const {
  const auto same_pose = [](const std::optional<Rigid3d>& a, const std::optional<Rigid3d>& b) {
    if (a.has_value() != b.has_value()) return false;
    return !a || (a->rotation.coeffs() == b->rotation.coeffs() && a->translation == b->translation);
  };
  return name == other.name && table_deg == other.table_deg &&
         same_pose(part_from_rig_guess, other.part_from_rig_guess) &&
         placed_on_table == other.placed_on_table;
}

void ViewsFile::Check(const std::string& what) const {
  SLSHADOW_THROW_IF(views.empty(), what, ": views: at least one view is required");
  std::set<std::string> names;
  for (size_t i = 0; i < views.size(); ++i) {
    const ViewSpec& v = views[i];
    const std::string field = StringPrintf("%s: views[%zu]", what.c_str(), i);
    const std::string problem = NameProblem(v.name);
    SLSHADOW_THROW_IF(!problem.empty(), field, ".name: ", problem, " (got '", v.name, "')");
    SLSHADOW_THROW_IF(!names.insert(v.name).second, field, ".name: duplicate view name (got '",
                      v.name, "')");
    if (v.table_deg) {
      SLSHADOW_THROW_IF(!std::isfinite(*v.table_deg) || std::abs(*v.table_deg) > kMaxTableDeg,
                        field, ".table_deg: must be finite, within +-3600 degrees (got ",
                        *v.table_deg, ")");
      SLSHADOW_THROW_IF(v.part_from_rig_guess.has_value(), field,
                        ".part_from_rig_guess: only for views placed by hand (this view has "
                        "table_deg ",
                        *v.table_deg, ")");
      SLSHADOW_THROW_IF(v.placed_on_table, field,
                        ".placed_on_table: only for views placed by hand (this view has table_deg ",
                        *v.table_deg, ")");
    }
    if (v.part_from_rig_guess) {
      SLSHADOW_THROW_IF(!v.part_from_rig_guess->rotation.coeffs().allFinite() ||
                            !v.part_from_rig_guess->translation.allFinite(),
                        field, ".part_from_rig_guess: must be finite");
    }
  }
}

std::string DefaultViewName(size_t index) { return StringPrintf("view_%02zu", index); }

ViewsFile FullTurnViews(int count, double start_deg) {
  SLSHADOW_THROW_IF(count < 1 || count > 1000, "views: count must be in 1..1000 (got ", count, ")");
  ViewsFile views;
  for (int i = 0; i < count; ++i) {
    ViewSpec v;
    v.name = count > 100 ? StringPrintf("view_%03d", i) : DefaultViewName(static_cast<size_t>(i));
    v.table_deg = start_deg + 360.0 * i / count;
    views.views.push_back(v);
  }
  views.Check("full turn");
  return views;
}

ViewsFile ViewsFromConfig(const ConfigNode& node) {
  node.RejectUnknownKeys({"format", "version", "views"});
  if (node.Has("format") && node["format"].AsString() != "slshadow-views")
    node["format"].Fail("expected \"slshadow-views\"");
  if (node.Has("version") && node["version"].AsInt() != kViewsVersion)
    node["version"].Fail("unsupported views format version (this slshadow reads version 1)");
  ViewsFile views;
  const auto list = node["views"];
  if (!list.IsArray()) list.Fail("must be a list of views");
  if (list.size() == 0) list.Fail("at least one view is required");
  for (size_t i = 0; i < list.size(); ++i) {
    views.views.push_back(ViewFromConfig(list.at(i), i));
    for (size_t j = 0; j < i; ++j) {
      if (views.views[j].name == views.views[i].name) {
        if (list.at(i).Has("name")) list.at(i)["name"].Fail("duplicate view name");
        list.at(i).Fail("its default name " + views.views[i].name + " is taken by views[" +
                        std::to_string(j) + "]");
      }
    }
  }
  views.Check(node.file());
  return views;
}

ViewsFile LoadViews(const fs::path& path) { return ViewsFromConfig(ConfigNode::LoadFile(path)); }

nlohmann::json ViewsToJson(const ViewsFile& views) {
  nlohmann::json j = {{"format", "slshadow-views"}, {"version", kViewsVersion}};
  j["views"] = nlohmann::json::array();
  for (const ViewSpec& v : views.views) j["views"].push_back(ViewToJson(v));
  return j;
}

void SaveViews(const ViewsFile& views, const fs::path& path) {
  views.Check(path.string());
  const nlohmann::json j = ViewsToJson(views);
  WriteTextFileAtomically(path, path.extension() == ".json"
                                    ? j.dump(2) + "\n"
                                    : "# slshadow views (docs/formats.md)\n" + JsonToYaml(j));
}

// ---- Project.

constexpr EnumName<ViewState> kViewStateNames[] = {{ViewState::kComplete, "complete"},
                                                   {ViewState::kMissing, "missing"}};

std::string ToString(ViewState value) { return EnumToString(value, kViewStateNames); }

ViewState ViewStateFromString(const std::string& name) {
  return EnumFromString("view state", name, kViewStateNames);
}

ViewsFile ProjectManifest::Views() const {
  ViewsFile file;
  for (const ProjectView& v : views) file.views.push_back(v.spec);
  return file;
}

const ProjectView* ProjectManifest::Find(const std::string& name) const {
  for (const ProjectView& v : views) {
    if (v.spec.name == name) return &v;
  }
  return nullptr;
}

void ProjectManifest::Check(const std::string& what) const {
  Views().Check(what);
  rig.Check(what + ": rig");
  for (size_t i = 0; i < views.size(); ++i) {
    const ProjectView& v = views[i];
    SLSHADOW_THROW_IF(v.spec.OnTable() && !rig.turntable, what, ": views[", i, "] ('", v.spec.name,
                      "'): a table view, but the rig has no turntable axis (rig.turntable)");
    SLSHADOW_THROW_IF(v.state == ViewState::kComplete && v.source.empty(), what, ": views[", i,
                      "].source: a complete view needs its image source");
  }
}

ProjectManifest NewProject(const Rig& rig, const nlohmann::json& patterns, const ViewsFile& views,
                           nlohmann::json provenance) {
  ProjectManifest project;
  project.created = UtcTimestamp();
  project.rig = rig;
  project.patterns = patterns;
  project.provenance = std::move(provenance);
  for (const ViewSpec& v : views.views) {
    ProjectView view;
    view.spec = v;
    project.views.push_back(std::move(view));
  }
  project.Check("new project");
  return project;
}

nlohmann::json ProjectToJson(const ProjectManifest& project) {
  nlohmann::json j = {{"format", "slshadow-project"}, {"version", ProjectManifest::kVersion},
                      {"created", project.created},   {"rig", RigToJson(project.rig)},
                      {"patterns", project.patterns}, {"provenance", project.provenance}};
  j["views"] = nlohmann::json::array();
  for (const ProjectView& v : project.views) {
    nlohmann::json view = ViewToJson(v.spec);
    view["folder"] = v.Folder().generic_string();
    view["state"] = ToString(v.state);
    view["source"] = v.source;
    view["completed"] = v.completed;
    if (!v.provenance.is_null()) view["provenance"] = v.provenance;
    j["views"].push_back(std::move(view));
  }
  return j;
}

ProjectManifest ProjectFromConfig(const ConfigNode& node) {
  node.RejectUnknownKeys(
      {"format", "version", "created", "rig", "patterns", "provenance", "views"});
  if (node["format"].AsString() != "slshadow-project")
    node["format"].Fail("expected \"slshadow-project\"");
  if (node["version"].AsInt() != ProjectManifest::kVersion)
    node["version"].Fail("unsupported project format version (this slshadow reads version 1)");
  ProjectManifest project;
  project.created = node.GetString("created", "");
  project.rig = RigFromConfig(node["rig"]);
  project.patterns = node["patterns"].json();
  if (!project.patterns.is_object()) node["patterns"].Fail("must be a pattern spec (a mapping)");
  if (node.Has("provenance")) project.provenance = node["provenance"].json();
  const auto list = node["views"];
  if (!list.IsArray() || list.size() == 0) list.Fail("must be a non-empty list of views");
  for (size_t i = 0; i < list.size(); ++i) {
    const auto v = list.at(i);
    std::vector<std::string> keys = ViewSpecKeys();
    keys.insert(keys.end(), {"folder", "state", "source", "completed", "provenance"});
    v.RejectUnknownKeys(keys);
    ProjectView view;
    {
      // The spec's own keys, read as the views file reads them; the name is required here.
      nlohmann::json spec = v.json();
      for (const char* key : {"folder", "state", "source", "completed", "provenance"})
        spec.erase(key);
      view.spec = ViewFromConfig(ConfigNode::FromJson(spec, node.file(), v.path()), i);
      v["name"].AsString();
    }
    const auto state = v["state"];
    try {
      view.state = ViewStateFromString(state.AsString());
    } catch (const Error& e) {
      state.Fail(e.what());
    }
    view.source = v.GetString("source", "");
    view.completed = v.GetString("completed", "");
    if (v.Has("provenance")) {
      view.provenance = v["provenance"].json();
      if (!view.provenance.is_object() && !view.provenance.is_null())
        v["provenance"].Fail("must be a mapping (how the view was scanned)");
    }
    if (v.Has("folder") && v["folder"].AsString() != view.Folder().generic_string())
      v["folder"].Fail("must be views/<name> (" + view.Folder().generic_string() + ")");
    project.views.push_back(std::move(view));
  }
  project.Check(node.file());
  return project;
}

ProjectManifest LoadProject(const fs::path& project_dir) {
  const fs::path file = project_dir / "project.json";
  std::error_code ec;
  SLSHADOW_THROW_IF(!fs::exists(file, ec), file.string(),
                    ": not found (is this a multi-view project folder?)");
  ProjectManifest project = ProjectFromConfig(ConfigNode::LoadFile(file));
  for (size_t i = 0; i < project.views.size(); ++i) {
    const ProjectView& v = project.views[i];
    SLSHADOW_THROW_IF(v.state == ViewState::kComplete &&
                          !fs::exists(project_dir / v.Folder() / "manifest.json", ec),
                      file.string(), ": views[", i, "].state: complete, but ",
                      (v.Folder() / "manifest.json").string(), " is missing");
  }
  return project;
}

void SaveProject(const ProjectManifest& project, const fs::path& project_dir) {
  project.Check((project_dir / "project.json").string());
  WriteTextFileAtomically(project_dir / "project.json", ProjectToJson(project).dump(1) + "\n");
}

std::string ProjectInputsMismatch(const ProjectManifest& project, const Rig& rig,
                                  const nlohmann::json& patterns, const ViewsFile& views) {
  if (RigToJson(project.rig) != RigToJson(rig)) return "rig";
  if (project.patterns != patterns) return "pattern spec";
  const ViewsFile stored = project.Views();
  if (stored.views.size() != views.views.size()) return "views (their number)";
  for (size_t i = 0; i < views.views.size(); ++i) {
    if (!(stored.views[i] == views.views[i])) return "views[" + std::to_string(i) + "]";
  }
  return "";
}

StartedProject StartOrResumeProject(
    const fs::path& project_dir, const Rig& rig, const nlohmann::json& patterns,
    const ViewsFile& views, const nlohmann::json& provenance, bool resume,
    const std::string& resume_action,
    const std::function<std::string(const ProjectManifest&)>& mismatch) {
  std::error_code ec;
  StartedProject started;
  const fs::path manifest = project_dir / "project.json";
  if (fs::exists(manifest, ec)) {
    SLSHADOW_THROW_IF(!resume, project_dir.string(), ": already holds a project (pass --resume to ",
                      resume_action, ")");
    // Not LoadProject: a complete view whose folder was lost since is done again.
    started.manifest = ProjectFromConfig(ConfigNode::LoadFile(manifest));
    started.resumed = true;
    const std::string what = mismatch ? mismatch(started.manifest) : std::string();
    SLSHADOW_THROW_IF(!what.empty(), manifest.string(), ": ", what,
                      " differs from this run's; resume only with the inputs the project was "
                      "started with");
    return started;
  }
  SLSHADOW_THROW_IF(fs::exists(project_dir, ec) && !fs::is_empty(project_dir, ec),
                    project_dir.string(),
                    ": exists and is not a multi-view project (no project.json); choose another "
                    "folder");
  started.manifest = NewProject(rig, patterns, views, provenance);
  fs::create_directories(project_dir / "views", ec);
  SLSHADOW_THROW_IF(ec, project_dir.string(), ": cannot create the folder: ", ec.message());
  SaveProject(started.manifest, project_dir);
  return started;
}

}  // namespace slshadow::multiview
