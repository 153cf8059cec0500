#include "sim/scene.h"

#include <algorithm>
#include <cmath>
#include <map>

#include <tbb/parallel_for.h>

#include "core/config.h"
#include "core/error.h"
#include "core/image_io.h"
#include "core/kdtree.h"
#include "core/pose_io.h"
#include "sim/shapes.h"

namespace slshadow {
namespace {

constexpr int kSceneFormatVersion = 1;

bool PoseIsFinite(const Rigid3d& pose) {
  return pose.rotation.coeffs().allFinite() && pose.translation.allFinite();
}

// Scene poses use the rig's pose reader and writer (core/pose_io.h).

double UnitScale(const ConfigNode& node) {
  const std::string u = node.AsString();
  static const std::map<std::string, double> units = {{"mm", 1.0},  {"cm", 10.0}, {"m", 1000.0},
                                                      {"um", 1e-3}, {"in", 25.4}, {"inch", 25.4}};
  const auto it = units.find(u);
  if (it == units.end()) node.Fail("unknown unit (use mm, cm, m, um, in)");
  return it->second;
}

double Positive(const ConfigNode& node) {
  const double v = node.AsDouble();
  if (!(v > 0)) node.Fail("must be positive");
  return v;
}

double UnitInterval(const ConfigNode& node) {
  const double v = node.AsDouble();
  if (v < 0 || v > 1) node.Fail("must be in [0, 1]");
  return v;
}

Albedo AlbedoFromConfig(const ConfigNode& node, const std::filesystem::path& base_dir) {
  Albedo a;
  if (!node.IsObject()) {
    a.value = UnitInterval(node);
    return a;
  }
  const std::string type = node.GetString("type", "uniform");
  if (type == "uniform") {
    node.RejectUnknownKeys({"type", "value"});
    a.value = UnitInterval(node["value"]);
  } else if (type == "checkerboard") {
    node.RejectUnknownKeys({"type", "square_mm", "squares_x", "squares_y", "dark", "light"});
    a.kind = Albedo::Kind::kCheckerboard;
    a.square_mm = Positive(node["square_mm"]);
    a.squares_x = static_cast<int>(node["squares_x"].AsInt());
    a.squares_y = static_cast<int>(node["squares_y"].AsInt());
    if (a.squares_x < 3) node["squares_x"].Fail("must be >= 3");
    if (a.squares_y < 3) node["squares_y"].Fail("must be >= 3");
    if (node.Has("dark")) a.dark = UnitInterval(node["dark"]);
    if (node.Has("light")) a.light = UnitInterval(node["light"]);
  } else if (type == "image") {
    node.RejectUnknownKeys({"type", "file", "pixel_mm", "light"});
    a.kind = Albedo::Kind::kImage;
    const auto file_node = node["file"];
    const std::filesystem::path file = base_dir / file_node.AsString();
    if (!std::filesystem::exists(file)) file_node.Fail("texture file not found: " + file.string());
    try {
      a.image = ReadImage(file, ImageReadMode::kGrayscale);
    } catch (const Error& e) {
      file_node.Fail(std::string("cannot read texture image: ") + e.what());
    }
    a.pixel_mm = Positive(node["pixel_mm"]);
    if (node.Has("light")) a.light = UnitInterval(node["light"]);
  } else {
    node["type"].Fail("unknown albedo type (use uniform, checkerboard or image)");
  }
  return a;
}

void ParseDefocus(const ConfigNode& node, SceneLayers::Defocus& d) {
  node.RejectUnknownKeys({"enabled", "f_number", "focus_distance_mm", "pixel_pitch_um"});
  d.enabled = node.GetBool("enabled", true);
  if (node.Has("f_number")) d.f_number = Positive(node["f_number"]);
  if (node.Has("focus_distance_mm")) d.focus_distance_mm = Positive(node["focus_distance_mm"]);
  if (node.Has("pixel_pitch_um")) d.pixel_pitch_um = Positive(node["pixel_pitch_um"]);
}

SceneLayers LayersFromConfig(const ConfigNode& node) {
  SceneLayers l;
  node.RejectUnknownKeys({"supersampling", "camera_defocus", "projector_defocus",
                          "projector_response", "vignetting", "ambient", "noise", "fill_factor"});
  if (node.Has("supersampling")) {
    const auto n = node["supersampling"];
    n.RejectUnknownKeys({"enabled", "samples_per_axis"});
    if (n.GetBool("enabled", true)) {
      l.supersampling = static_cast<int>(n["samples_per_axis"].AsInt());
      if (l.supersampling < 1 || l.supersampling > 16)
        n["samples_per_axis"].Fail("must be in 1..16");
    }
  }
  if (node.Has("camera_defocus")) ParseDefocus(node["camera_defocus"], l.camera_defocus);
  if (node.Has("projector_defocus")) ParseDefocus(node["projector_defocus"], l.projector_defocus);
  if (node.Has("projector_response")) {
    const auto n = node["projector_response"];
    n.RejectUnknownKeys({"enabled", "gamma", "lut"});
    l.response_enabled = n.GetBool("enabled", true);
    if (n.Has("gamma") == n.Has("lut")) n.Fail("give exactly one of gamma or lut");
    if (n.Has("gamma")) l.gamma = Positive(n["gamma"]);
    if (n.Has("lut")) {
      l.response_lut = n["lut"].AsDoubles(256);
      for (double v : l.response_lut) {
        if (v < 0 || v > 1) n["lut"].Fail("entries must be in [0, 1]");
      }
    }
  }
  if (node.Has("vignetting")) {
    const auto n = node["vignetting"];
    n.RejectUnknownKeys({"enabled", "model", "coefficients"});
    l.vignetting_enabled = n.GetBool("enabled", true);
    const std::string model = n.GetString("model", "cos4");
    if (model == "cos4") {
      l.vignetting_cos4 = true;
    } else if (model == "polynomial") {
      l.vignetting_cos4 = false;
      const auto c = n["coefficients"].AsDoubles(3);
      l.vignetting_coefficients = {c[0], c[1], c[2]};
    } else {
      n["model"].Fail("unknown vignetting model (use cos4 or polynomial)");
    }
  }
  if (node.Has("ambient")) {
    const auto n = node["ambient"];
    n.RejectUnknownKeys({"enabled", "level"});
    if (n.GetBool("enabled", true)) {
      l.ambient = n["level"].AsDouble();
      if (l.ambient < 0) n["level"].Fail("must be >= 0");
    }
  }
  if (node.Has("noise")) {
    const auto n = node["noise"];
    n.RejectUnknownKeys({"enabled", "full_well_e", "read_noise_e", "seed"});
    l.noise_enabled = n.GetBool("enabled", true);
    if (n.Has("full_well_e")) l.full_well_e = Positive(n["full_well_e"]);
    if (n.Has("read_noise_e")) {
      l.read_noise_e = n["read_noise_e"].AsDouble();
      if (l.read_noise_e < 0) n["read_noise_e"].Fail("must be >= 0");
    }
    if (n.Has("seed")) {
      const int64_t seed = n["seed"].AsInt();
      if (seed < 0) n["seed"].Fail("must be >= 0");
      l.seed = static_cast<uint64_t>(seed);
    }
  }
  if (node.Has("fill_factor")) {
    const auto n = node["fill_factor"];
    n.RejectUnknownKeys({"enabled", "fill_factor"});
    if (n.GetBool("enabled", true)) {
      l.fill_factor = n["fill_factor"].AsDouble();
      if (!(l.fill_factor > 0 && l.fill_factor <= 1)) n["fill_factor"].Fail("must be in (0, 1]");
    }
  }
  return l;
}

Radiometry RadiometryFromConfig(const ConfigNode& node) {
  Radiometry r;
  node.RejectUnknownKeys(
      {"exposure", "exposure_us", "reference_distance_mm", "adc_bits", "lookup"});
  if (node.Has("exposure")) r.exposure_fraction = Positive(node["exposure"]);
  if (node.Has("exposure_us")) r.exposure_us = Positive(node["exposure_us"]);
  if (node.Has("reference_distance_mm")) {  // 0: the rig's working distance (Radiometry)
    const auto n = node["reference_distance_mm"];
    r.reference_distance_mm = n.AsDouble();
    if (!(r.reference_distance_mm >= 0) || !std::isfinite(r.reference_distance_mm)) {
      n.Fail("must be >= 0 (0: the rig's working_distance_mm)");
    }
  }
  if (node.Has("adc_bits")) {
    r.adc_bits = static_cast<int>(node["adc_bits"].AsInt());
    if (r.adc_bits < 1 || r.adc_bits > 16) node["adc_bits"].Fail("must be in 1..16");
  }
  if (node.Has("lookup")) {
    const std::string lookup = node["lookup"].AsString();
    if (lookup != "bilinear" && lookup != "nearest") node["lookup"].Fail("use bilinear or nearest");
    r.bilinear_lookup = lookup == "bilinear";
  }
  return r;
}

std::filesystem::path ExistingFile(const ConfigNode& node, const std::filesystem::path& base_dir) {
  const std::filesystem::path file = base_dir / node.AsString();
  if (!std::filesystem::is_regular_file(file)) node.Fail("file not found: " + file.string());
  return file;
}

void AddObjects(const ConfigNode& node, const std::filesystem::path& base_dir, Scene& scene) {
  const std::string type = node["type"].AsString();
  SceneObject o;
  o.name = node.GetString("name", type + "_" + std::to_string(scene.objects.size()));
  o.rig_from_object =
      node.Has("rig_from_object") ? PoseFromConfig(node["rig_from_object"]) : Rigid3d();
  if (node.Has("albedo")) o.albedo = AlbedoFromConfig(node["albedo"], base_dir);
  if (node.Has("texture_offset_mm")) {
    const auto v = node["texture_offset_mm"].AsDoubles(2);
    o.albedo_offset_mm = Eigen::Vector2d(v[0], v[1]);
  }
  const std::vector<std::string> common = {"name", "type", "rig_from_object", "albedo",
                                           "texture_offset_mm"};
  auto allow = [&](std::initializer_list<const char*> extra) {
    std::vector<std::string> keys = common;
    keys.insert(keys.end(), extra.begin(), extra.end());
    node.RejectUnknownKeys(keys);
  };
  const std::string what = node.file() + ": " + node.path();
  const Eigen::Vector3d center_in_rig = o.rig_from_object.translation;
  if (type == "mesh") {
    allow({"file", "units", "allow_non_manifold"});
    const auto file = ExistingFile(node["file"], base_dir);
    TriangleMesh mesh;
    try {
      mesh = ReadMesh(file);
    } catch (const Error& e) {
      node["file"].Fail(e.what());
    }
    const double scale = node.Has("units") ? UnitScale(node["units"]) : 1.0;
    if (scale != 1.0) mesh.Transform(Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero(), scale);
    CheckSceneMesh(mesh, what + " (" + file.string() + ")",
                   node.GetBool("allow_non_manifold", false));
    o.type = ObjectType::kMesh;
    o.mesh = std::make_shared<const TriangleMesh>(std::move(mesh));
  } else if (type == "demo_part") {
    allow({"resolution_mm"});
    o.type = ObjectType::kMesh;
    const double res = node.Has("resolution_mm") ? Positive(node["resolution_mm"]) : 1.0;
    o.mesh = std::make_shared<const TriangleMesh>(MakeDemoPart(res));
    const DemoPartFeatures f = DemoPartDescription();
    const Eigen::Vector3d c = o.rig_from_object * f.sphere_center_mm;
    scene.artefacts[o.name] = {{"type", "demo_part"},
                               {"resolution_mm", res},
                               {"dome_sphere_center_in_rig_mm", {c.x(), c.y(), c.z()}},
                               {"dome_sphere_diameter_mm", 2 * f.sphere_radius_mm},
                               {"hole_diameter_mm", 2 * f.hole_radius_mm}};
  } else if (type == "occlusion_part") {
    allow({"resolution_mm"});
    o.type = ObjectType::kMesh;
    const double res = node.Has("resolution_mm") ? Positive(node["resolution_mm"]) : 1.0;
    if (res <= 0.05 || res > 5) node["resolution_mm"].Fail("must be in (0.05, 5] mm");
    o.mesh = std::make_shared<const TriangleMesh>(MakeOcclusionPart(res));
  } else if (type == "point_cloud") {
    allow({"file", "units", "radius_mm", "radius_scale"});
    const auto file = ExistingFile(node["file"], base_dir);
    PointCloud cloud;
    try {
      cloud = ReadPly(file);
    } catch (const Error& e) {
      node["file"].Fail(e.what());
    }
    if (cloud.empty()) node["file"].Fail("point cloud has no points");
    if (!cloud.HasNormals())
      node["file"].Fail("point cloud has no normals (nx, ny, nz): discs need an orientation");
    const double scale = node.Has("units") ? UnitScale(node["units"]) : 1.0;
    for (auto& p : cloud.points) p *= scale;
    if (node.Has("radius_mm")) {
      o.disc_radii_mm.assign(cloud.size(), static_cast<float>(Positive(node["radius_mm"])));
    } else {
      o.disc_radii_mm = DiscRadiiFromSpacing(
          cloud.points, node.Has("radius_scale") ? Positive(node["radius_scale"]) : 1.0);
    }
    o.type = ObjectType::kPointCloud;
    o.points = std::make_shared<const PointCloud>(std::move(cloud));
  } else if (type == "plane") {
    allow({"size_mm"});
    o.type = ObjectType::kPlane;
    const auto s = node["size_mm"].AsDoubles(2);
    if (!(s[0] > 0 && s[1] > 0)) node["size_mm"].Fail("must be positive");
    o.size_mm = Eigen::Vector3d(s[0], s[1], 0);
    const Eigen::Vector3d n = o.rig_from_object.rotation * Eigen::Vector3d::UnitZ();
    scene.artefacts[o.name] = {
        {"type", "plane"},
        {"point_in_rig_mm", {center_in_rig.x(), center_in_rig.y(), center_in_rig.z()}},
        {"normal_in_rig", {n.x(), n.y(), n.z()}},
        {"size_mm", {s[0], s[1]}}};
  } else if (type == "sphere") {
    allow({"radius_mm", "diameter_mm"});
    o.type = ObjectType::kSphere;
    if (node.Has("radius_mm") == node.Has("diameter_mm"))
      node.Fail("give exactly one of radius_mm or diameter_mm");
    o.radius_mm =
        node.Has("radius_mm") ? Positive(node["radius_mm"]) : Positive(node["diameter_mm"]) / 2;
    scene.artefacts[o.name] = {
        {"type", "sphere"},
        {"center_in_rig_mm", {center_in_rig.x(), center_in_rig.y(), center_in_rig.z()}},
        {"diameter_mm", 2 * o.radius_mm}};
  } else if (type == "cylinder") {
    allow({"radius_mm", "height_mm"});
    o.type = ObjectType::kCylinder;
    o.radius_mm = Positive(node["radius_mm"]);
    o.height_mm = Positive(node["height_mm"]);
  } else if (type == "box") {
    allow({"size_mm"});
    o.type = ObjectType::kBox;
    const auto s = node["size_mm"].AsDoubles(3);
    if (!(s[0] > 0 && s[1] > 0 && s[2] > 0)) node["size_mm"].Fail("must be positive");
    o.size_mm = Eigen::Vector3d(s[0], s[1], s[2]);
  } else if (type == "ball_bar") {
    // Two spheres with centres at local (+-distance/2, 0, 0), joined by a thin bar along x.
    allow({"radius_mm", "distance_mm", "bar_radius_mm"});
    const double r = Positive(node["radius_mm"]);
    const double dist = Positive(node["distance_mm"]);
    if (dist <= 2 * r) node["distance_mm"].Fail("must exceed the sphere diameter");
    const double bar_r = node.Has("bar_radius_mm") ? node["bar_radius_mm"].AsDouble() : r / 4;
    if (bar_r < 0 || bar_r >= r) node["bar_radius_mm"].Fail("must be in [0, radius_mm)");
    nlohmann::json centers = nlohmann::json::array();
    for (int side = -1; side <= 1; side += 2) {
      SceneObject s = o;
      s.name = o.name + (side < 0 ? "_a" : "_b");
      s.type = ObjectType::kSphere;
      s.radius_mm = r;
      s.rig_from_object = o.rig_from_object * Rigid3d(Eigen::Quaterniond::Identity(),
                                                      Eigen::Vector3d(side * dist / 2, 0, 0));
      const Eigen::Vector3d c = s.rig_from_object.translation;
      centers.push_back({c.x(), c.y(), c.z()});
      scene.objects.push_back(s);
    }
    if (bar_r > 0) {
      SceneObject bar = o;
      bar.name = o.name + "_bar";
      bar.type = ObjectType::kCylinder;
      bar.radius_mm = bar_r;
      bar.height_mm = dist - 2 * r * 0.9;  // ends inside the spheres
      bar.rig_from_object =
          o.rig_from_object *
          Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY())),
                  Eigen::Vector3d::Zero());
      scene.objects.push_back(bar);
    }
    scene.artefacts[o.name] = {{"type", "ball_bar"},
                               {"sphere_diameter_mm", 2 * r},
                               {"distance_mm", dist},
                               {"centers_in_rig_mm", centers}};
    return;
  } else {
    node["type"].Fail(
        "unknown object type (use mesh, point_cloud, plane, sphere, cylinder, box, ball_bar, "
        "demo_part, occlusion_part)");
  }
  scene.objects.push_back(std::move(o));
}

}  // namespace

double Albedo::Evaluate(double x_mm, double y_mm) const {
  switch (kind) {
    case Kind::kUniform:
      return value;
    case Kind::kCheckerboard: {
      const int a = static_cast<int>(std::floor(x_mm / square_mm)) + 1;
      const int b = static_cast<int>(std::floor(y_mm / square_mm)) + 1;
      if (a < 0 || b < 0 || a >= squares_x || b >= squares_y) return light;
      return (a + b) % 2 == 0 ? dark : light;
    }
    case Kind::kImage: {
      // Pixel centres at (u + 0.5) * pixel_mm.
      const double u = x_mm / pixel_mm - 0.5, v = y_mm / pixel_mm - 0.5;
      if (u < -0.5 || v < -0.5 || u > image.cols - 0.5 || v > image.rows - 0.5) return light;
      const int u0 = std::clamp(static_cast<int>(std::floor(u)), 0, image.cols - 1);
      const int v0 = std::clamp(static_cast<int>(std::floor(v)), 0, image.rows - 1);
      const int u1 = std::min(u0 + 1, image.cols - 1), v1 = std::min(v0 + 1, image.rows - 1);
      const double fu = std::clamp(u - u0, 0.0, 1.0), fv = std::clamp(v - v0, 0.0, 1.0);
      const double top = (1 - fu) * image.at<uint8_t>(v0, u0) + fu * image.at<uint8_t>(v0, u1);
      const double bottom = (1 - fu) * image.at<uint8_t>(v1, u0) + fu * image.at<uint8_t>(v1, u1);
      return ((1 - fv) * top + fv * bottom) / 255.0;
    }
  }
  return value;
}

std::string ToString(ObjectType type) {
  switch (type) {
    case ObjectType::kMesh:
      return "mesh";
    case ObjectType::kPointCloud:
      return "point_cloud";
    case ObjectType::kPlane:
      return "plane";
    case ObjectType::kSphere:
      return "sphere";
    case ObjectType::kCylinder:
      return "cylinder";
    case ObjectType::kBox:
      return "box";
  }
  return "unknown";
}

double SceneLayers::Defocus::SigmaPx(double fx_px, double d_mm) const {
  const double f_mm = fx_px * pixel_pitch_um * 1e-3;
  if (!(d_mm > f_mm) || !(focus_distance_mm > f_mm)) return 0;
  const double c_mm = (f_mm / f_number) * f_mm * std::abs(d_mm - focus_distance_mm) /
                      (d_mm * (focus_distance_mm - f_mm));
  return c_mm / (pixel_pitch_um * 1e-3) / 4;
}

void SceneLayers::Check(const std::string& what) const {
  SLSHADOW_THROW_IF(supersampling < 1 || supersampling > 16, what,
                    ": layers.supersampling.samples_per_axis must be in 1..16 (got ", supersampling,
                    ")");
  for (const auto* d : {&camera_defocus, &projector_defocus}) {
    SLSHADOW_THROW_IF(
        d->enabled && !(d->f_number > 0 && d->focus_distance_mm > 0 && d->pixel_pitch_um > 0), what,
        ": defocus needs positive f_number, focus_distance_mm and pixel_pitch_um");
  }
  SLSHADOW_THROW_IF(!(gamma > 0), what, ": layers.projector_response.gamma must be positive (got ",
                    gamma, ")");
  SLSHADOW_THROW_IF(!response_lut.empty() && response_lut.size() != 256, what,
                    ": layers.projector_response.lut needs 256 entries (got ", response_lut.size(),
                    ")");
  SLSHADOW_THROW_IF(!(ambient >= 0), what, ": layers.ambient.level must be >= 0 (got ", ambient,
                    ")");
  SLSHADOW_THROW_IF(!(full_well_e > 0) || !(read_noise_e >= 0), what,
                    ": layers.noise needs full_well_e > 0 and read_noise_e >= 0");
  SLSHADOW_THROW_IF(!(fill_factor > 0 && fill_factor <= 1), what,
                    ": layers.fill_factor must be in (0, 1] (got ", fill_factor, ")");
}

void Radiometry::Check(const std::string& what) const {
  SLSHADOW_THROW_IF(!(exposure_fraction > 0) || !std::isfinite(exposure_fraction), what,
                    ": radiometry.exposure must be positive (got ", exposure_fraction, ")");
  SLSHADOW_THROW_IF(!(reference_distance_mm >= 0), what,
                    ": radiometry.reference_distance_mm must be >= 0 (got ", reference_distance_mm,
                    ")");
  SLSHADOW_THROW_IF(adc_bits < 1 || adc_bits > 16, what,
                    ": radiometry.adc_bits must be in 1..16 (got ", adc_bits, ")");
}

void CheckSceneMesh(const TriangleMesh& mesh, const std::string& what, bool allow_non_manifold) {
  mesh.Check(what, /*reject_degenerate=*/true);
  if (!allow_non_manifold) {
    const size_t bad = mesh.CountNonManifoldEdges();
    SLSHADOW_THROW_IF(bad > 0, what, ": mesh has ", bad,
                      " non-manifold edges (shared by more than two triangles); repair it or set "
                      "allow_non_manifold: true");
  }
}

void Scene::Check(const std::string& what) const {
  SLSHADOW_THROW_IF(objects.empty(), what, ": scene has no objects");
  radiometry.Check(what);
  layers.Check(what);
  for (size_t i = 0; i < objects.size(); ++i) {
    const SceneObject& o = objects[i];
    const std::string w = what + ": objects[" + std::to_string(i) + "] '" + o.name + "'";
    SLSHADOW_THROW_IF(!PoseIsFinite(o.rig_from_object), w, ": rig_from_object is not finite");
    SLSHADOW_THROW_IF(std::abs(o.rig_from_object.rotation.norm() - 1) > 1e-6, w,
                      ": rotation is not a unit quaternion");
    switch (o.type) {
      case ObjectType::kMesh:
        SLSHADOW_THROW_IF(!o.mesh, w, ": mesh missing");
        o.mesh->Check(w, true);
        break;
      case ObjectType::kPointCloud:
        SLSHADOW_THROW_IF(!o.points || o.points->empty(), w, ": point cloud is empty");
        SLSHADOW_THROW_IF(o.points->normals.size() != o.points->size(), w,
                          ": point cloud needs one normal per point");
        SLSHADOW_THROW_IF(o.disc_radii_mm.size() != o.points->size(), w,
                          ": point cloud needs one disc radius per point");
        for (float r : o.disc_radii_mm)
          SLSHADOW_THROW_IF(!(r > 0) || !std::isfinite(r), w,
                            ": disc radius must be positive (got ", r, ")");
        break;
      case ObjectType::kPlane:
        SLSHADOW_THROW_IF(!(o.size_mm.x() > 0 && o.size_mm.y() > 0) || !o.size_mm.allFinite(), w,
                          ": plane size must be positive");
        break;
      case ObjectType::kSphere:
        SLSHADOW_THROW_IF(!(o.radius_mm > 0) || !std::isfinite(o.radius_mm), w,
                          ": sphere radius must be positive (got ", o.radius_mm, ")");
        break;
      case ObjectType::kCylinder:
        SLSHADOW_THROW_IF(!(o.radius_mm > 0 && o.height_mm > 0), w,
                          ": cylinder radius and height must be positive");
        break;
      case ObjectType::kBox:
        SLSHADOW_THROW_IF(!(o.size_mm.minCoeff() > 0) || !o.size_mm.allFinite(), w,
                          ": box size must be positive");
        break;
    }
    if (o.albedo.kind == Albedo::Kind::kImage)
      SLSHADOW_THROW_IF(o.albedo.image.empty() || o.albedo.image.type() != CV_8UC1, w,
                        ": image albedo needs an 8-bit grey image");
    if (o.albedo.kind == Albedo::Kind::kCheckerboard)
      SLSHADOW_THROW_IF(
          o.albedo.squares_x < 3 || o.albedo.squares_y < 3 || !(o.albedo.square_mm > 0), w,
          ": checkerboard needs >= 3 x 3 squares of positive size");
  }
}

Scene SceneFromConfig(const ConfigNode& node, const std::filesystem::path& base_dir) {
  node.RejectUnknownKeys({"format", "version", "name", "radiometry", "layers", "objects"});
  if (node.Has("format") && node["format"].AsString() != "slshadow-scene")
    node["format"].Fail("expected slshadow-scene");
  if (node.Has("version") && node["version"].AsInt() != kSceneFormatVersion)
    node["version"].Fail("unsupported version (this build reads 1)");
  Scene scene;
  scene.name = node.GetString("name", "scene");
  if (node.Has("radiometry")) scene.radiometry = RadiometryFromConfig(node["radiometry"]);
  if (node.Has("layers")) scene.layers = LayersFromConfig(node["layers"]);
  const auto objects = node["objects"];
  if (objects.size() == 0) objects.Fail("scene has no objects");
  for (size_t i = 0; i < objects.size(); ++i) AddObjects(objects.at(i), base_dir, scene);
  scene.Check(node.file());
  scene.source_config = node.json();
  std::error_code ec;
  scene.source_dir = std::filesystem::absolute(base_dir, ec);
  return scene;
}

Scene LoadScene(const std::filesystem::path& path) {
  const ConfigNode root = ConfigNode::LoadFile(path);
  return SceneFromConfig(root, path.parent_path());
}

nlohmann::json SceneToJson(const Scene& scene) {
  nlohmann::json j;
  j["name"] = scene.name;
  const Radiometry& r = scene.radiometry;
  j["radiometry"] = {{"exposure", r.exposure_fraction},
                     {"exposure_us", r.exposure_us},
                     {"reference_distance_mm", r.reference_distance_mm},
                     {"adc_bits", r.adc_bits},
                     {"lookup", r.bilinear_lookup ? "bilinear" : "nearest"}};
  const SceneLayers& l = scene.layers;
  nlohmann::json layers = nlohmann::json::object();
  if (l.supersampling > 1) layers["supersampling"] = {{"samples_per_axis", l.supersampling}};
  auto defocus = [](const SceneLayers::Defocus& d) {
    return nlohmann::json{{"f_number", d.f_number},
                          {"focus_distance_mm", d.focus_distance_mm},
                          {"pixel_pitch_um", d.pixel_pitch_um}};
  };
  if (l.camera_defocus.enabled) layers["camera_defocus"] = defocus(l.camera_defocus);
  if (l.projector_defocus.enabled) layers["projector_defocus"] = defocus(l.projector_defocus);
  if (l.response_enabled) {
    layers["projector_response"] = l.response_lut.empty() ? nlohmann::json{{"gamma", l.gamma}}
                                                          : nlohmann::json{{"lut", l.response_lut}};
  }
  if (l.vignetting_enabled) {
    layers["vignetting"] =
        l.vignetting_cos4
            ? nlohmann::json{{"model", "cos4"}}
            : nlohmann::json{{"model", "polynomial"}, {"coefficients", l.vignetting_coefficients}};
  }
  if (l.ambient > 0) layers["ambient"] = {{"level", l.ambient}};
  if (l.noise_enabled)
    layers["noise"] = {
        {"full_well_e", l.full_well_e}, {"read_noise_e", l.read_noise_e}, {"seed", l.seed}};
  if (l.fill_factor < 1) layers["fill_factor"] = {{"fill_factor", l.fill_factor}};
  j["layers"] = layers;
  nlohmann::json objects = nlohmann::json::array();
  for (const auto& o : scene.objects) {
    nlohmann::json oj = {{"name", o.name},
                         {"type", ToString(o.type)},
                         {"rig_from_object", PoseToJson(o.rig_from_object)}};
    switch (o.type) {
      case ObjectType::kMesh:
        oj["triangles"] = o.mesh ? o.mesh->NumTriangles() : 0;
        break;
      case ObjectType::kPointCloud:
        oj["points"] = o.points ? o.points->size() : 0;
        break;
      case ObjectType::kPlane:
        oj["size_mm"] = {o.size_mm.x(), o.size_mm.y()};
        break;
      case ObjectType::kSphere:
        oj["radius_mm"] = o.radius_mm;
        break;
      case ObjectType::kCylinder:
        oj["radius_mm"] = o.radius_mm;
        oj["height_mm"] = o.height_mm;
        break;
      case ObjectType::kBox:
        oj["size_mm"] = {o.size_mm.x(), o.size_mm.y(), o.size_mm.z()};
        break;
    }
    switch (o.albedo.kind) {
      case Albedo::Kind::kUniform:
        oj["albedo"] = o.albedo.value;
        break;
      case Albedo::Kind::kCheckerboard:
        oj["albedo"] = {{"type", "checkerboard"},          {"square_mm", o.albedo.square_mm},
                        {"squares_x", o.albedo.squares_x}, {"squares_y", o.albedo.squares_y},
                        {"dark", o.albedo.dark},           {"light", o.albedo.light}};
        break;
      case Albedo::Kind::kImage:
        oj["albedo"] = {{"type", "image"},
                        {"pixel_mm", o.albedo.pixel_mm},
                        {"size_px", {o.albedo.image.cols, o.albedo.image.rows}}};
        break;
    }
    objects.push_back(oj);
  }
  j["objects"] = objects;
  j["artefacts"] = scene.artefacts;
  return j;
}

std::vector<float> DiscRadiiFromSpacing(const std::vector<Eigen::Vector3d>& points, double scale) {
  std::vector<float> radii(points.size(), 1.0f);
  if (points.size() < 2) return radii;
  const KdTree tree(points, 16);
  const int k = static_cast<int>(std::min<size_t>(5, points.size()));  // the point + 4 neighbours
  tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 1024),
                    [&](const tbb::blocked_range<size_t>& range) {
                      std::vector<Neighbor> near;
                      for (size_t i = range.begin(); i < range.end(); ++i) {
                        tree.KNearest(points[i], k, &near);
                        double sum = 0;
                        int count = 0;
                        for (const Neighbor& n : near) {
                          if (n.index == i) continue;
                          sum += std::sqrt(n.distance_sq);
                          ++count;
                        }
                        radii[i] =
                            static_cast<float>(count > 0 && sum > 0 ? scale * sum / count : 1.0);
                      }
                    });
  return radii;
}

}  // namespace slshadow
