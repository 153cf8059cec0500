#include "workflows/studies/vdi2634.h"

#include "compare/vdi2634.h"
#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "plot/plot.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <set>

namespace slshadow::studies {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr double kPi = 3.14159265358979323846;

json Vec(const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); }

std::string Num(double v, int digits = 6) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*g", digits, v);
  return buf;
}

std::string Point(const Eigen::Vector3d& p) {
  char buf[128];
  std::snprintf(buf, sizeof(buf), "(%g, %g, %g)", p.x(), p.y(), p.z());
  return buf;
}

json Pose(const Eigen::Quaterniond& q, const Eigen::Vector3d& t) {
  return {{"rotation_quat_wxyz", {q.w(), q.x(), q.y(), q.z()}}, {"translation_mm", Vec(t)}};
}

// Whether `device` sees `p` (rig frame) in front of it and within 5 % of its image border.
bool Sees(const RigDevice& device, const Eigen::Vector3d& p) {
  const Eigen::Vector3d in_cam = device.cam_from_rig * p;
  if (!(in_cam.z() > 0)) return false;
  const auto px = device.model.Project(in_cam);
  if (!px) return false;
  const double mx = 0.05 * device.model.width, my = 0.05 * device.model.height;
  return px->x() >= mx - 0.5 && px->y() >= my - 0.5 && px->x() <= device.model.width - 0.5 - mx &&
         px->y() <= device.model.height - 0.5 - my;
}

std::vector<Eigen::Vector3d> Corners(const MeasuringVolume& v) {
  std::vector<Eigen::Vector3d> out;
  for (int i = 0; i < 8; ++i) {
    const Eigen::Vector3d s((i & 1) ? 0.5 : -0.5, (i & 2) ? 0.5 : -0.5, (i & 4) ? 0.5 : -0.5);
    out.push_back(v.center_mm + s.cwiseProduct(v.size_mm));
  }
  return out;
}

// Inside the (closed) volume, with a tolerance for rounding.
bool Inside(const MeasuringVolume& v, const Eigen::Vector3d& p) {
  const Eigen::Vector3d d = (p - v.center_mm).cwiseAbs() - 0.5 * v.size_mm;
  return d.maxCoeff() <= 1e-9 * (1 + v.DiagonalMm());
}

double PositiveOr(const ConfigNode& node, const std::string& key, double fallback) {
  if (!node.Has(key)) return fallback;
  const double v = node[key].AsDouble();
  if (!(v > 0)) node[key].Fail("must be > 0 (got " + Num(v) + ")");
  return v;
}

int CountOr(const ConfigNode& node, const std::string& key, int fallback, int max) {
  if (!node.Has(key)) return fallback;
  const int64_t v = node[key].AsInt();
  if (v < 0 || v > max) {
    node[key].Fail("must be in 0.." + std::to_string(max) + " (got " + std::to_string(v) + ")");
  }
  return static_cast<int>(v);
}

}  // namespace

std::vector<const RigDevice*> StudyDevices(const Rig& rig, const std::vector<std::string>& modes) {
  std::vector<const RigDevice*> devices;
  if (!rig.cameras.empty()) devices.push_back(&rig.cameras[0]);
  if (std::find(modes.begin(), modes.end(), "stereo") != modes.end() && rig.cameras.size() > 1)
    devices.push_back(&rig.cameras[1]);
  if (rig.projector) devices.push_back(&*rig.projector);
  return devices;
}

std::string VolumeVisibilityProblem(const MeasuringVolume& volume,
                                    const std::vector<const RigDevice*>& devices) {
  std::vector<Eigen::Vector3d> points = {volume.center_mm};
  for (const auto& c : Corners(volume)) points.push_back(c);
  for (size_t i = 0; i < points.size(); ++i) {
    for (const RigDevice* d : devices) {
      if (!Sees(*d, points[i])) {
        return std::string(i == 0 ? "centre " : "corner ") + Point(points[i]) +
               " mm is not seen by " + d->name + " (within 5 % of its image border)";
      }
    }
  }
  return "";
}

MeasuringVolume AutoMeasuringVolume(const Rig& rig, const std::vector<std::string>& modes,
                                    const std::string& what) {
  const std::vector<const RigDevice*> devices = StudyDevices(rig, modes);
  SLSHADOW_THROW_IF(rig.cameras.empty(), what, ": the rig has no camera");
  const CameraModel& cam = rig.cameras[0].model;
  const double wd = rig.working_distance_mm;
  const double w = wd * cam.width / cam.fx(), h = wd * cam.height / cam.fy();
  MeasuringVolume v;
  v.center_mm = rig.WorkingPointInRig();
  const Eigen::Vector3d shape(w, h, 0.5 * w);
  const auto fits = [&](double s) {
    MeasuringVolume t = v;
    t.size_mm = s * shape;
    return VolumeVisibilityProblem(t, devices).empty();
  };
  SLSHADOW_THROW_IF(!fits(1e-6), what, ": the devices do not all see the working point ",
                    Point(v.center_mm), " mm (",
                    VolumeVisibilityProblem(MeasuringVolume{v.center_mm, 1e-6 * shape}, devices),
                    "); give vdi2634.volume");
  double lo = 1e-6, hi = 1.0;
  while (fits(hi) && hi < 64) hi *= 2;
  for (int i = 0; i < 60; ++i) {
    const double mid = 0.5 * (lo + hi);
    (fits(mid) ? lo : hi) = mid;
  }
  for (int k = 0; k < 3; ++k) v.size_mm[k] = std::floor(0.9 * lo * shape[k]);
  SLSHADOW_THROW_IF(v.size_mm.minCoeff() < 1, what,
                    ": the devices share too small a view of the working point for a measuring "
                    "volume; give vdi2634.volume");
  return v;
}

json Vdi2634Study::ToJson() const {
  json placements_json = json::array();
  for (const auto& p : placements) {
    placements_json.push_back({{"label", p.label},
                               {"artefact", p.artefact},
                               {"description", p.description},
                               {"geometry", p.geometry}});
  }
  return {{"volume",
           {{"center_mm", Vec(volume.center_mm)},
            {"size_mm", Vec(volume.size_mm)},
            {"diagonal_mm", volume.DiagonalMm()},
            {"from_rig", volume_from_rig}}},
          {"placements", placements_json},
          {"options", options},
          {"mpe", mpe}};
}

Vdi2634Study Vdi2634StudyFromConfig(const ConfigNode& node, const Rig& rig,
                                    const std::vector<std::string>& modes) {
  node.RejectUnknownKeys(
      {"volume", "sphere", "ball_bar", "plane", "albedo", "search_margin_mm", "options", "mpe"});
  const std::string what = node.file() + ": " + node.path();
  Vdi2634Study study;
  const std::vector<const RigDevice*> devices = StudyDevices(rig, modes);
  if (node.Has("volume")) {
    const ConfigNode v = node["volume"];
    v.RejectUnknownKeys({"center_mm", "size_mm"});
    const auto c = v["center_mm"].AsDoubles(3), s = v["size_mm"].AsDoubles(3);
    study.volume.center_mm = {c[0], c[1], c[2]};
    study.volume.size_mm = {s[0], s[1], s[2]};
    if (!(study.volume.size_mm.minCoeff() > 0)) v["size_mm"].Fail("must be positive");
    const std::string problem = VolumeVisibilityProblem(study.volume, devices);
    if (!problem.empty()) v.Fail(problem);
  } else {
    study.volume = AutoMeasuringVolume(rig, modes, what);
    study.volume_from_rig = true;
  }
  const MeasuringVolume& vol = study.volume;
  const Eigen::Vector3d c = vol.center_mm, half = 0.5 * vol.size_mm;
  const double l0 = vol.DiagonalMm();
  const double albedo = node.Has("albedo") ? node["albedo"].AsDouble() : 0.8;
  if (!(albedo > 0 && albedo <= 1)) node["albedo"].Fail("must be in (0, 1]");
  const double margin = PositiveOr(node, "search_margin_mm", 2.0);
  compare::Vdi2634Options options;
  if (node.Has("options")) options = compare::Vdi2634OptionsFromConfig(node["options"]);
  study.options = compare::Vdi2634OptionsToJson(options);
  study.mpe = nullptr;
  if (node.Has("mpe")) {
    const ConfigNode m = node["mpe"];
    m.RejectUnknownKeys({"pf_mm", "ps_mm", "sd_mm", "f_mm"});
    study.mpe = json::object();
    for (const std::string& k : m.Keys()) study.mpe[k] = PositiveOr(m, k, 0);
  }
  const auto artefact_file = [&](json spheres, json pairs, json planes) {
    return json{{"search_margin_mm", margin},
                {"spheres", std::move(spheres)},
                {"sphere_pairs", std::move(pairs)},
                {"planes", std::move(planes)}};
  };

  // Sphere: centre, then the corners (inset by the radius), opposite corners one after another.
  {
    const ConfigNode n = node.Has("sphere") ? node["sphere"]
                                            : ConfigNode::FromJson(json::object(), node.file(),
                                                                   node.path() + ".sphere");
    n.RejectUnknownKeys({"diameter_mm", "positions"});
    const double d = PositiveOr(n, "diameter_mm", std::round(0.1 * l0 * 10) / 10);
    const int count = CountOr(n, "positions", 9, 9);
    const double r = d / 2;
    if (count > 1 && !(r < half.minCoeff())) {
      n["diameter_mm"].Fail("a sphere of " + Num(d) + " mm does not fit in the corners of the " +
                            Point(vol.size_mm) + " mm volume");
    }
    const std::array<std::array<int, 3>, 8> corners = {{{-1, -1, -1},
                                                        {1, 1, 1},
                                                        {1, -1, 1},
                                                        {-1, 1, -1},
                                                        {-1, 1, 1},
                                                        {1, -1, -1},
                                                        {1, 1, -1},
                                                        {-1, -1, 1}}};
    for (int k = 0; k < count; ++k) {
      Vdi2634Placement p;
      p.label = "sphere_" + std::to_string(k + 1);
      p.artefact = "sphere";
      Eigen::Vector3d at = c;
      if (k == 0) {
        p.description = "centre of the volume";
      } else {
        const auto& s = corners[static_cast<size_t>(k - 1)];
        const Eigen::Vector3d sign(s[0], s[1], s[2]);
        at = c + sign.cwiseProduct(half - Eigen::Vector3d::Constant(r));
        p.description = std::string("corner (") + (s[0] < 0 ? "-x" : "+x") + ", " +
                        (s[1] < 0 ? "-y" : "+y") + ", " + (s[2] < 0 ? "-z near" : "+z far") + ")";
      }
      p.object = {{"name", "sphere"},
                  {"type", "sphere"},
                  {"diameter_mm", d},
                  {"albedo", albedo},
                  {"rig_from_object", Pose(Eigen::Quaterniond::Identity(), at)}};
      p.artefacts = artefact_file(
          json::array({{{"name", "sphere"}, {"center_mm", Vec(at)}, {"diameter_mm", d}}}),
          json::array(), json::array());
      p.geometry = {{"center_mm", Vec(at)}, {"diameter_mm", d}};
      study.placements.push_back(std::move(p));
    }
  }

  // Ball bar: centred, along the 4 space diagonals, x, and the 2 diagonals of the xy mid-plane.
  {
    const ConfigNode n = node.Has("ball_bar") ? node["ball_bar"]
                                              : ConfigNode::FromJson(json::object(), node.file(),
                                                                     node.path() + ".ball_bar");
    n.RejectUnknownKeys({"sphere_diameter_mm", "length_mm", "bar_radius_mm", "orientations"});
    const double d = PositiveOr(n, "sphere_diameter_mm", std::round(0.1 * l0 * 10) / 10);
    const int count = CountOr(n, "orientations", 7, 7);
    const double r = d / 2;
    const double bar_r = n.Has("bar_radius_mm") ? n["bar_radius_mm"].AsDouble() : 0.0;
    if (!(bar_r >= 0 && bar_r < r)) n["bar_radius_mm"].Fail("must be in [0, sphere radius)");
    const std::array<Eigen::Vector3d, 7> dirs = {Eigen::Vector3d(half.x(), half.y(), half.z()),
                                                 Eigen::Vector3d(-half.x(), half.y(), half.z()),
                                                 Eigen::Vector3d(half.x(), -half.y(), half.z()),
                                                 Eigen::Vector3d(half.x(), half.y(), -half.z()),
                                                 Eigen::Vector3d(1, 0, 0),
                                                 Eigen::Vector3d(half.x(), half.y(), 0),
                                                 Eigen::Vector3d(half.x(), -half.y(), 0)};
    const std::array<const char*, 7> names = {"space diagonal (-x -y -z) to (+x +y +z)",
                                              "space diagonal (+x -y -z) to (-x +y +z)",
                                              "space diagonal (-x +y -z) to (+x -y +z)",
                                              "space diagonal (-x -y +z) to (+x +y -z)",
                                              "along x, mid-plane",
                                              "xy diagonal (-x -y) to (+x +y), mid-depth",
                                              "xy diagonal (-x +y) to (+x -y), mid-depth"};
    // The longest bar every selected orientation holds inside the volume.
    double fit = std::numeric_limits<double>::infinity();
    for (int k = 0; k < count; ++k) {
      const Eigen::Vector3d u = dirs[static_cast<size_t>(k)].normalized();
      for (int i = 0; i < 3; ++i) {
        if (std::abs(u[i]) > 1e-12) fit = std::min(fit, 2 * (half[i] - r) / std::abs(u[i]));
      }
    }
    const double fallback = std::floor(std::min(2.0 / 3.0 * l0, fit));
    const double length = PositiveOr(n, "length_mm", fallback);
    if (count > 0 && (length > fit * (1 + 1e-12) || length <= d)) {
      (n.Has("length_mm") ? n["length_mm"] : n)
          .Fail("a ball bar of " + Num(length) + " mm with spheres of " + Num(d) +
                " mm must be longer than a sphere's diameter and fit in every orientation inside "
                "the " +
                Point(vol.size_mm) + " mm volume (at most " + Num(fit) + " mm)");
    }
    for (int k = 0; k < count; ++k) {
      const Eigen::Vector3d u = dirs[static_cast<size_t>(k)].normalized();
      const Eigen::Quaterniond q = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitX(), u);
      const Eigen::Vector3d a = c - 0.5 * length * u, b = c + 0.5 * length * u;
      Vdi2634Placement p;
      p.label = "bar_" + std::to_string(k + 1);
      p.artefact = "ball_bar";
      p.description = names[static_cast<size_t>(k)];
      p.object = {{"name", "ball_bar"},           {"type", "ball_bar"},     {"radius_mm", r},
                  {"distance_mm", length},        {"bar_radius_mm", bar_r}, {"albedo", albedo},
                  {"rig_from_object", Pose(q, c)}};
      p.artefacts = artefact_file(
          json::array({{{"name", "a"}, {"center_mm", Vec(a)}, {"diameter_mm", d}},
                       {{"name", "b"}, {"center_mm", Vec(b)}, {"diameter_mm", d}}}),
          json::array({{{"name", "bar"}, {"spheres", {"a", "b"}}, {"distance_mm", length}}}),
          json::array());
      p.geometry = {{"center_mm", Vec(c)},
                    {"direction", Vec(u)},
                    {"length_mm", length},
                    {"sphere_diameter_mm", d}};
      study.placements.push_back(std::move(p));
    }
  }

  // Plane: frontal at the centre, tilted about y and about x, at the front and the back.
  {
    const ConfigNode n = node.Has("plane") ? node["plane"]
                                           : ConfigNode::FromJson(json::object(), node.file(),
                                                                  node.path() + ".plane");
    n.RejectUnknownKeys({"size_mm", "tilt_deg", "positions"});
    const double tilt_deg = n.Has("tilt_deg") ? n["tilt_deg"].AsDouble() : 25.0;
    if (!(tilt_deg > 0 && tilt_deg < 80)) n["tilt_deg"].Fail("must be in (0, 80)");
    const double t = tilt_deg * kPi / 180;
    const int count = CountOr(n, "positions", 7, 7);
    double length = std::floor(0.9 * std::min(vol.size_mm.x(), vol.size_mm.z() / std::sin(t)));
    double width = std::floor(0.9 * std::min(vol.size_mm.y(), vol.size_mm.z() / std::sin(t)));
    if (n.Has("size_mm")) {
      const auto s = n["size_mm"].AsDoubles(2);
      if (!(s[0] > 0 && s[1] > 0)) n["size_mm"].Fail("must be positive");
      length = s[0];
      width = s[1];
    }
    struct Where {
      Eigen::Quaterniond q;
      Eigen::Vector3d at;
      std::string description;
    };
    const std::vector<Where> where = {
        {Eigen::Quaterniond::Identity(), c, "centre, facing the first camera"},
        {Eigen::Quaterniond(Eigen::AngleAxisd(t, Eigen::Vector3d::UnitY())), c,
         "centre, tilted +" + Num(tilt_deg) + " deg about y"},
        {Eigen::Quaterniond(Eigen::AngleAxisd(-t, Eigen::Vector3d::UnitY())), c,
         "centre, tilted -" + Num(tilt_deg) + " deg about y"},
        {Eigen::Quaterniond(Eigen::AngleAxisd(t, Eigen::Vector3d::UnitX())), c,
         "centre, tilted +" + Num(tilt_deg) + " deg about x"},
        {Eigen::Quaterniond(Eigen::AngleAxisd(-t, Eigen::Vector3d::UnitX())), c,
         "centre, tilted -" + Num(tilt_deg) + " deg about x"},
        {Eigen::Quaterniond::Identity(), c - Eigen::Vector3d(0, 0, half.z()),
         "front face of the volume (near)"},
        {Eigen::Quaterniond::Identity(), c + Eigen::Vector3d(0, 0, half.z()),
         "back face of the volume (far)"}};
    for (int k = 0; k < count; ++k) {
      const Where& w = where[static_cast<size_t>(k)];
      const Eigen::Matrix3d rot = w.q.toRotationMatrix();
      for (int i = 0; i < 4; ++i) {
        const Eigen::Vector3d corner =
            w.at +
            rot * Eigen::Vector3d((i & 1 ? 0.5 : -0.5) * length, (i & 2 ? 0.5 : -0.5) * width, 0);
        if (!Inside(vol, corner)) {
          (n.Has("size_mm") ? n["size_mm"] : n)
              .Fail("a plane of " + Num(length) + " x " + Num(width) + " mm at position " +
                    std::to_string(k + 1) + " (" + w.description + ") leaves the " +
                    Point(vol.size_mm) + " mm volume at " + Point(corner) + " mm");
        }
      }
      const Eigen::Vector3d normal = rot * Eigen::Vector3d::UnitZ();
      Vdi2634Placement p;
      p.label = "plane_" + std::to_string(k + 1);
      p.artefact = "plane";
      p.description = w.description;
      p.object = {{"name", "plane"},
                  {"type", "plane"},
                  {"size_mm", {length, width}},
                  {"albedo", albedo},
                  {"rig_from_object", Pose(w.q, w.at)}};
      p.artefacts =
          artefact_file(json::array(), json::array(),
                        json::array({{{"name", "plane"},
                                      {"point_mm", Vec(w.at)},
                                      {"normal", Vec(normal)},
                                      {"half_size_mm", 0.5 * std::hypot(length, width)}}}));
      p.geometry = {
          {"center_mm", Vec(w.at)}, {"normal", Vec(normal)}, {"size_mm", {length, width}}};
      study.placements.push_back(std::move(p));
    }
  }
  if (study.placements.empty()) node.Fail("places no artefact (every count is 0)");
  for (const auto& p : study.placements) {
    // The artefact file each job reads, through its codec.
    compare::ArtefactSpecFromConfig(ConfigNode::FromJson(p.artefacts, what, p.label));
  }
  return study;
}

// ---------------------------------------------------------------------------------------------
// Merge.

namespace {

std::string Field(const json& v) {
  if (v.is_null()) return "";
  if (v.is_number_float()) return Num(v.get<double>(), 10);
  if (v.is_boolean()) return v.get<bool>() ? "1" : "0";
  if (v.is_string()) {
    const std::string s = v.get<std::string>();
    if (s.find_first_of(",\"\n") == std::string::npos) return s;
    std::string q = "\"";
    for (char ch : s) q += ch == '"' ? std::string("\"\"") : std::string(1, ch);
    return q + "\"";
  }
  return v.dump();
}

// The figures of one row: what its artefact gives.
struct Figures {
  bool found = false;
  json points, pf, ps, diameter, sd, distance, f;
};

Figures RowFigures(const std::string& artefact, const json& r) {
  Figures f;
  if (r.is_null()) return f;
  if (artefact == "sphere") {
    const json& s = r.at("spheres").at(0);
    f.found = s.at("found").get<bool>();
    f.points = s.at("points");
    if (f.found) {
      f.pf = s.at("pf_mm");
      f.ps = s.at("ps_mm");
      f.diameter = s.at("diameter_mm");
    }
  } else if (artefact == "ball_bar") {
    const json& p = r.at("sphere_pairs").at(0);
    f.found = p.at("found").get<bool>();
    f.points = std::min(r.at("spheres").at(0).at("points").get<int64_t>(),
                        r.at("spheres").at(1).at("points").get<int64_t>());
    if (f.found) {
      f.sd = p.at("sd_mm");
      f.distance = p.at("distance_mm");
    }
  } else {
    const json& p = r.at("planes").at(0);
    f.found = p.at("found").get<bool>();
    f.points = p.at("points");
    if (f.found) f.f = p.at("f_mm");
  }
  return f;
}

struct Overall {
  double value = 0;
  std::string at;
  bool any = false;
};

// Keeps the larger (signed: the larger magnitude) of `v` and the current value.
void Keep(Overall* o, double v, const std::string& at, bool signed_value) {
  const bool larger = signed_value ? std::abs(v) > std::abs(o->value) : v > o->value;
  if (!o->any || larger) {
    o->value = v;
    o->at = at;
    o->any = true;
  }
}

constexpr std::initializer_list<std::array<int, 3>> kPalette = {
    {40, 90, 200}, {200, 60, 0}, {30, 150, 60}, {150, 40, 160}, {120, 120, 120}, {220, 160, 0}};

}  // namespace

std::vector<std::string> WriteVdi2634Results(const fs::path& out_dir,
                                             const std::vector<Vdi2634Row>& rows,
                                             const json& plan_vdi2634, const std::string& study) {
  std::map<std::string, json> placement;  // label -> placement
  std::vector<std::string> order;         // labels in plan order
  for (const auto& p : plan_vdi2634.at("placements")) {
    placement[p.at("label").get<std::string>()] = p;
    order.push_back(p.at("label").get<std::string>());
  }
  const json& mpe = plan_vdi2634.at("mpe");
  const bool series =
      std::any_of(rows.begin(), rows.end(), [](const Vdi2634Row& r) { return !r.series.empty(); });

  std::string csv = std::string("id,") + (series ? "series," : "") +
                    "position,artefact,mode,found,points,pf_mm,ps_mm,diameter_mm,sd_mm,"
                    "distance_mm,f_mm\n";
  // Per series and mode, in order of appearance.
  std::vector<std::string> groups;
  std::map<std::string, std::array<Overall, 4>> overall;  // PF, PS, SD, F
  std::map<std::string, int> not_found;
  // Chart data: group -> figure -> (position index within its artefact, value).
  std::map<std::string, std::array<std::vector<std::pair<double, double>>, 4>> chart;
  std::map<std::string, int> index_of;  // label -> 1-based index within its artefact
  {
    std::map<std::string, int> counts;
    for (const auto& l : order)
      index_of[l] = ++counts[placement[l].at("artefact").get<std::string>()];
  }
  for (const auto& r : rows) {
    const auto it = placement.find(r.position);
    SLSHADOW_THROW_IF(it == placement.end(), "sweep merge: position '", r.position, "' of job ",
                      r.id, " is not in the plan's vdi2634 placements");
    const std::string artefact = it->second.at("artefact").get<std::string>();
    const Figures f = RowFigures(artefact, r.figures);
    csv += r.id + ',' + (series ? Field(r.series) + ',' : "") + r.position + ',' + artefact + ',' +
           r.mode + ',' + (f.found ? "1" : "0") + ',' + Field(f.points) + ',' + Field(f.pf) + ',' +
           Field(f.ps) + ',' + Field(f.diameter) + ',' + Field(f.sd) + ',' + Field(f.distance) +
           ',' + Field(f.f) + '\n';
    const std::string group = (r.series.empty() ? "" : r.series + ", ") + r.mode;
    if (std::find(groups.begin(), groups.end(), group) == groups.end()) groups.push_back(group);
    auto& o = overall[group];
    not_found[group] += f.found ? 0 : 1;
    if (!f.found) continue;
    const double x = index_of[r.position];
    auto& c = chart[group];
    if (artefact == "sphere") {
      Keep(&o[0], f.pf.get<double>(), r.position, false);
      Keep(&o[1], f.ps.get<double>(), r.position, true);
      c[0].emplace_back(x, f.pf.get<double>());
      c[1].emplace_back(x, f.ps.get<double>());
    } else if (artefact == "ball_bar") {
      Keep(&o[2], f.sd.get<double>(), r.position, true);
      c[2].emplace_back(x, f.sd.get<double>());
    } else {
      Keep(&o[3], f.f.get<double>(), r.position, false);
      c[3].emplace_back(x, f.f.get<double>());
    }
  }
  const std::array<const char*, 4> keys = {"pf_mm", "ps_mm", "sd_mm", "f_mm"};
  const std::array<const char*, 4> names = {"PF", "PS", "SD", "F"};
  std::string summary_csv = std::string(series ? "series," : "") + "mode";
  for (const char* k : keys) summary_csv += std::string(",") + k + ',' + k + "_at";
  summary_csv += ",not_found";
  if (mpe.is_object()) {
    for (const char* k : keys) summary_csv += std::string(",mpe_") + k;
    summary_csv += ",pass";
  }
  summary_csv += '\n';
  std::vector<std::string> lines;
  for (const auto& g : groups) {
    const size_t comma = g.rfind(", ");
    const std::string s = comma == std::string::npos ? "" : g.substr(0, comma);
    const std::string mode = comma == std::string::npos ? g : g.substr(comma + 2);
    summary_csv += (series ? Field(s) + ',' : "") + mode;
    std::string line = g + ":";
    bool pass = not_found[g] == 0;
    for (size_t k = 0; k < 4; ++k) {
      const Overall& o = overall[g][k];
      summary_csv += ',' + (o.any ? Num(o.value, 10) : "") + ',' + o.at;
      if (o.any) line += std::string(" ") + names[k] + " " + Num(o.value, 4) + " mm (" + o.at + ")";
      if (mpe.is_object() && mpe.contains(keys[k]) && o.any) {
        pass = pass && std::abs(o.value) <= mpe.at(keys[k]).get<double>();
      }
    }
    summary_csv += ',' + std::to_string(not_found[g]);
    if (not_found[g] > 0) line += ", " + std::to_string(not_found[g]) + " artefacts not found";
    if (mpe.is_object()) {
      for (const char* k : keys) summary_csv += ',' + (mpe.contains(k) ? Field(mpe.at(k)) : "");
      summary_csv += std::string(",") + (pass ? "1" : "0");
      line += pass ? "; within the MPE" : "; NOT within the MPE";
    }
    summary_csv += '\n';
    lines.push_back(line);
  }
  std::string positions =
      "position,artefact,description,center_x_mm,center_y_mm,center_z_mm,"
      "direction_or_normal_x,direction_or_normal_y,direction_or_normal_z,"
      "size\n";
  for (const auto& l : order) {
    const json& p = placement[l];
    const json& g = p.at("geometry");
    const json dir = g.contains("direction") ? g.at("direction")
                                             : (g.contains("normal") ? g.at("normal") : json());
    std::string size;
    if (g.contains("diameter_mm"))
      size = "diameter " + Num(g.at("diameter_mm").get<double>()) + " mm";
    if (g.contains("length_mm"))
      size = "length " + Num(g.at("length_mm").get<double>()) + " mm, spheres " +
             Num(g.at("sphere_diameter_mm").get<double>()) + " mm";
    if (g.contains("size_mm"))
      size = Num(g.at("size_mm")[0].get<double>()) + " x " + Num(g.at("size_mm")[1].get<double>()) +
             " mm";
    positions += l + ',' + p.at("artefact").get<std::string>() + ',' + Field(p.at("description"));
    for (int i = 0; i < 3; ++i) positions += ',' + Num(g.at("center_mm")[i].get<double>(), 10);
    for (int i = 0; i < 3; ++i)
      positions += ',' + (dir.is_null() ? "" : Num(dir[i].get<double>(), 10));
    positions += ',' + Field(size) + '\n';
  }
  WriteTextFileAtomically(out_dir / "vdi2634.csv", csv);
  WriteTextFileAtomically(out_dir / "vdi2634_summary.csv", summary_csv);
  WriteTextFileAtomically(out_dir / "positions.csv", positions);

  // The chart: four panels, the figure against the position index, one line per series and mode.
  const std::array<const char*, 4> titles = {
      "PF probing error, form (mm)", "PS probing error, size (mm)", "SD sphere-spacing error (mm)",
      "F flatness error (mm)"};
  const std::array<const char*, 4> xlabels = {"sphere position", "sphere position",
                                              "ball bar orientation", "plane position"};
  const std::array<const char*, 4> artefacts = {"sphere", "sphere", "ball_bar", "plane"};
  const auto lock = plot::LockPlplot();
  for (const char* ext : {".png", ".svg"}) {
    fs::path file = out_dir / "vdi2634";
    file += ext;
    WriteFileAtomically(file, [&](const fs::path& tmp) {
      auto pls = std::string(ext) == ".png" ? plot::OpenPng(tmp, 1200, 900, kPalette)
                                            : plot::OpenSvg(tmp, 1200, 900, kPalette);
      pls->adv(0);
      for (size_t k = 0; k < 4; ++k) {
        int n = 0;
        for (const auto& l : order) n += placement[l].at("artefact") == artefacts[k] ? 1 : 0;
        const bool signed_fig = k == 1 || k == 2;
        double ymax = 0;
        for (const auto& [g, data] : chart) {
          for (const auto& [x, y] : data[k]) ymax = std::max(ymax, std::abs(y));
        }
        const double limit =
            mpe.is_object() && mpe.contains(keys[k]) ? mpe.at(keys[k]).get<double>() : 0.0;
        ymax = std::max(ymax, limit) * 1.25 + 1e-6;
        const double x0 = k % 2 == 0 ? 0.09 : 0.59, y0 = k < 2 ? 0.54 : 0.09;
        pls->schr(0, 0.8);
        pls->vpor(x0, x0 + 0.37, y0, y0 + 0.32);
        pls->wind(0.5, std::max(n, 1) + 0.5, signed_fig ? -ymax : 0, ymax);
        pls->col0(1);
        pls->box("bcnt", 1, 0, "bcnstv", 0, 0);
        pls->lab(xlabels[k], "mm", titles[k]);
        if (signed_fig) {
          const PLFLT zx[2] = {0.5, std::max(n, 1) + 0.5}, zy[2] = {0, 0};
          pls->lsty(2);
          pls->line(2, zx, zy);
          pls->lsty(1);
        }
        if (limit > 0) {
          pls->col0(1);
          pls->lsty(3);
          for (const double sgn : {1.0, -1.0}) {
            if (sgn < 0 && !signed_fig) continue;
            const PLFLT lx[2] = {0.5, std::max(n, 1) + 0.5}, ly[2] = {sgn * limit, sgn * limit};
            pls->line(2, lx, ly);
          }
          pls->lsty(1);
        }
        for (size_t gi = 0; gi < groups.size(); ++gi) {
          const auto it = chart.find(groups[gi]);
          if (it == chart.end()) continue;
          std::vector<PLFLT> xs, ys;
          for (const auto& [x, y] : it->second[k]) {
            xs.push_back(x);
            ys.push_back(y);
          }
          pls->col0(static_cast<PLINT>(2 + gi % 6));
          if (xs.size() > 1) pls->line(static_cast<PLINT>(xs.size()), xs.data(), ys.data());
          if (!xs.empty()) pls->poin(static_cast<PLINT>(xs.size()), xs.data(), ys.data(), 17);
          pls->schr(0, 0.6);
          pls->mtex("t", -1.3 - 1.2 * static_cast<double>(gi), 0.02, 0.0, groups[gi].c_str());
          pls->schr(0, 0.8);
        }
      }
      pls->col0(1);
      pls->schr(0, 0.9);
      pls->vpor(0.0, 1.0, 0.0, 1.0);
      pls->mtex("t", -1.2, 0.5, 0.5,
                (study + ": virtual VDI/VDE 2634-2 acceptance test" +
                 (mpe.is_object() ? " (dashed: MPE)" : ""))
                    .c_str());
    });
  }
  return lines;
}

}  // namespace slshadow::studies
