#include "core/rig.h"

#include <cmath>
#include <cstdio>
#include <set>
#include <sstream>

#include <algorithm>

#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/pose_io.h"

namespace slshadow {
namespace {

constexpr int kRigFormatVersion = 1;

RigDevice DeviceFromConfig(const ConfigNode& node, bool is_projector) {
  node.RejectUnknownKeys({"name", "width", "height", "intrinsics", "distortion", "cam_from_rig"});
  RigDevice d;
  d.name = is_projector ? node.GetString("name", "projector") : node["name"].AsString();
  if (d.name.empty()) node["name"].Fail("name must not be empty");
  const auto w = node["width"];
  d.model.width = static_cast<int>(w.AsInt());
  const auto h = node["height"];
  d.model.height = static_cast<int>(h.AsInt());
  if (d.model.width <= 0 || d.model.width > 100000) w.Fail("must be a positive number of pixels");
  if (d.model.height <= 0 || d.model.height > 100000) h.Fail("must be a positive number of pixels");
  const auto intr = node["intrinsics"];
  intr.RejectUnknownKeys({"fx", "fy", "cx", "cy"});
  const char* names[] = {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"};
  for (int i = 0; i < 4; ++i) d.model.params[i] = intr[names[i]].AsDouble();
  if (d.model.fx() <= 0) intr["fx"].Fail("focal length must be positive");
  if (d.model.fy() <= 0) intr["fy"].Fail("focal length must be positive");
  if (node.Has("distortion")) {
    const auto dist = node["distortion"];
    dist.RejectUnknownKeys({"k1", "k2", "p1", "p2", "k3"});
    for (int i = 4; i < 9; ++i) d.model.params[i] = dist.GetDouble(names[i], 0.0);
  }
  d.cam_from_rig = node.Has("cam_from_rig") ? PoseFromConfig(node["cam_from_rig"]) : Rigid3d();
  return d;
}

nlohmann::json DeviceToJson(const RigDevice& d) {
  nlohmann::json j;
  j["name"] = d.name;
  j["width"] = d.model.width;
  j["height"] = d.model.height;
  j["intrinsics"] = {
      {"fx", d.model.fx()}, {"fy", d.model.fy()}, {"cx", d.model.cx()}, {"cy", d.model.cy()}};
  const auto& p = d.model.params;
  j["distortion"] = {{"k1", p[4]}, {"k2", p[5]}, {"p1", p[6]}, {"p2", p[7]}, {"k3", p[8]}};
  j["cam_from_rig"] = PoseToJson(d.cam_from_rig);
  return j;
}

TurntableAxis TurntableFromConfig(const ConfigNode& node) {
  node.RejectUnknownKeys({"axis_direction", "axis_point_mm", "angle_offset_deg", "angle_scale",
                          "sigma_direction_deg", "sigma_point_mm", "sigma_angle_offset_deg",
                          "sigma_angle_scale"});
  TurntableAxis t;
  const auto dir_node = node["axis_direction"];
  const auto d = dir_node.AsDoubles(3);
  const Eigen::Vector3d dir(d[0], d[1], d[2]);
  if (!dir.allFinite() || dir.norm() < 1e-9) dir_node.Fail("must be a non-zero finite vector");
  t.direction_in_rig = dir.normalized();
  const auto p_node = node["axis_point_mm"];
  const auto p = p_node.AsDoubles(3);
  t.point_in_rig_mm = Eigen::Vector3d(p[0], p[1], p[2]);
  if (!t.point_in_rig_mm.allFinite()) p_node.Fail("must be finite");
  t.angle_offset_deg = node.GetDouble("angle_offset_deg", 0.0);
  t.angle_scale = node.GetDouble("angle_scale", 1.0);
  if (!std::isfinite(t.angle_offset_deg)) node["angle_offset_deg"].Fail("must be finite");
  if (!(t.angle_scale > 0.5 && t.angle_scale < 2.0))
    node["angle_scale"].Fail("must be a number in (0.5, 2) (true angle = scale x commanded)");
  const char* sigma_names[] = {"sigma_direction_deg", "sigma_point_mm", "sigma_angle_offset_deg",
                               "sigma_angle_scale"};
  double* sigmas[] = {&t.sigma_direction_deg, &t.sigma_point_mm, &t.sigma_angle_offset_deg,
                      &t.sigma_angle_scale};
  for (int i = 0; i < 4; ++i) {
    *sigmas[i] = node.GetDouble(sigma_names[i], 0.0);
    if (!(*sigmas[i] >= 0) || !std::isfinite(*sigmas[i]))
      node[sigma_names[i]].Fail("must be a finite number >= 0");
  }
  return t;
}

nlohmann::json TurntableToJson(const TurntableAxis& t) {
  nlohmann::json j;
  j["axis_direction"] = {t.direction_in_rig.x(), t.direction_in_rig.y(), t.direction_in_rig.z()};
  j["axis_point_mm"] = {t.point_in_rig_mm.x(), t.point_in_rig_mm.y(), t.point_in_rig_mm.z()};
  j["angle_offset_deg"] = t.angle_offset_deg;
  j["angle_scale"] = t.angle_scale;
  j["sigma_direction_deg"] = t.sigma_direction_deg;
  j["sigma_point_mm"] = t.sigma_point_mm;
  j["sigma_angle_offset_deg"] = t.sigma_angle_offset_deg;
  j["sigma_angle_scale"] = t.sigma_angle_scale;
  return j;
}

}  // namespace

Rigid3d TurntableAxis::RigFromTableTurn(double commanded_deg) const {
  const double angle_rad = TrueAngleDeg(commanded_deg) * M_PI / 180.0;
  const Eigen::Quaterniond r(Eigen::AngleAxisd(angle_rad, direction_in_rig.normalized()));
  // x' = R (x - p) + p
  return Rigid3d(r, point_in_rig_mm - (r * point_in_rig_mm));
}

const RigDevice& Rig::Camera(const std::string& name) const {
  const int i = CameraIndex(name);
  if (i < 0) {
    std::string known;
    for (const auto& c : cameras) known += (known.empty() ? "" : ", ") + c.name;
    SLSHADOW_THROW("rig '", this->name, "': no camera named '", name, "' (cameras: ", known, ")");
  }
  return cameras[i];
}

int Rig::CameraIndex(const std::string& name) const {
  for (size_t i = 0; i < cameras.size(); ++i) {
    if (cameras[i].name == name) return static_cast<int>(i);
  }
  return -1;
}

const RigDevice& Rig::Device(const std::string& name) const {
  if (projector && projector->name == name) return *projector;
  return Camera(name);
}

double Rig::BaselineMm(const RigDevice& a, const RigDevice& b) const {
  return (a.CenterInRig() - b.CenterInRig()).norm();
}

Eigen::Vector3d Rig::WorkingPointInRig() const {
  SLSHADOW_CHECK(!cameras.empty());
  return cameras[0].CenterInRig() + working_distance_mm * cameras[0].AxisInRig();
}

double Rig::TriangulationAngleRad(const RigDevice& a, const RigDevice& b,
                                  const Eigen::Vector3d& point_in_rig) {
  const Eigen::Vector3d ra = (point_in_rig - a.CenterInRig()).normalized();
  const Eigen::Vector3d rb = (point_in_rig - b.CenterInRig()).normalized();
  return std::acos(std::clamp(ra.dot(rb), -1.0, 1.0));
}

double Rig::OverlapAtWorkingDistance(const RigDevice& a, const RigDevice& b, int samples) const {
  // Plane through the working point, perpendicular to the first camera's axis.
  const Eigen::Vector3d n = cameras[0].AxisInRig();
  const Eigen::Vector3d p0 = WorkingPointInRig();
  int inside = 0, total = 0;
  for (int iy = 0; iy < samples; ++iy) {
    for (int ix = 0; ix < samples; ++ix) {
      const Eigen::Vector2d px((ix + 0.5) * a.model.width / samples - 0.5,
                               (iy + 0.5) * a.model.height / samples - 0.5);
      const auto ray_in_cam = a.model.Unproject(px);
      if (!ray_in_cam) continue;
      ++total;
      const Eigen::Vector3d dir = a.cam_from_rig.rotation.conjugate() * *ray_in_cam;
      const Eigen::Vector3d origin = a.CenterInRig();
      const double denom = dir.dot(n);
      if (std::abs(denom) < 1e-12) continue;
      const double s = (p0 - origin).dot(n) / denom;
      if (s <= 0) continue;
      const auto pix_b = b.model.Project(b.cam_from_rig * (origin + s * dir));
      if (pix_b && b.model.IsInImage(*pix_b)) ++inside;
    }
  }
  return total > 0 ? static_cast<double>(inside) / total : 0.0;
}

void Rig::Check(const std::string& what) const {
  SLSHADOW_THROW_IF(cameras.empty(), what, ": cameras: a rig needs at least one camera");
  SLSHADOW_THROW_IF(!(working_distance_mm > 0) || !std::isfinite(working_distance_mm), what,
                    ": working_distance_mm: must be a positive number (got ", working_distance_mm,
                    ")");
  std::set<std::string> names;
  auto check_device = [&](const RigDevice& d, const std::string& where) {
    SLSHADOW_THROW_IF(!names.insert(d.name).second, what, ": ", where,
                      ".name: duplicate device name '", d.name, "'");
    d.model.Check(what + ": " + where);
    SLSHADOW_THROW_IF(
        !d.cam_from_rig.translation.allFinite() || !d.cam_from_rig.rotation.coeffs().allFinite(),
        what, ": ", where, ".cam_from_rig: pose must be finite");
  };
  for (size_t i = 0; i < cameras.size(); ++i)
    check_device(cameras[i], "cameras[" + std::to_string(i) + "]");
  if (projector) check_device(*projector, "projector");
  if (turntable) {
    SLSHADOW_THROW_IF(!turntable->direction_in_rig.allFinite() ||
                          std::abs(turntable->direction_in_rig.norm() - 1.0) > 1e-6,
                      what, ": turntable.axis_direction: must be a finite unit vector");
    SLSHADOW_THROW_IF(!turntable->point_in_rig_mm.allFinite(), what,
                      ": turntable.axis_point_mm: must be finite");
  }
}

Rig RigFromConfig(const ConfigNode& node) {
  node.RejectUnknownKeys({"format", "version", "name", "working_distance_mm", "cameras",
                          "projector", "calibration", "turntable"});
  if (node.Has("format") && node["format"].AsString() != "slshadow-rig") {
    node["format"].Fail("expected \"slshadow-rig\"");
  }
  if (node.Has("version") && node["version"].AsInt() != kRigFormatVersion) {
    node["version"].Fail("unsupported rig format version (this slshadow reads version 1)");
  }
  Rig rig;
  rig.name = node.GetString("name", "rig");
  if (node.Has("working_distance_mm")) {
    const auto wd = node["working_distance_mm"];
    rig.working_distance_mm = wd.AsDouble();
    if (rig.working_distance_mm <= 0) wd.Fail("must be positive");
  }
  const auto cams = node["cameras"];
  if (cams.size() == 0) cams.Fail("a rig needs at least one camera");
  for (size_t i = 0; i < cams.size(); ++i) {
    rig.cameras.push_back(DeviceFromConfig(cams.at(i), false));
    for (size_t j = 0; j < i; ++j) {
      if (rig.cameras[j].name == rig.cameras[i].name)
        cams.at(i)["name"].Fail("duplicate camera name");
    }
  }
  if (node.Has("projector")) rig.projector = DeviceFromConfig(node["projector"], true);
  if (node.Has("calibration")) rig.calibration = node["calibration"].json();
  if (node.Has("turntable")) rig.turntable = TurntableFromConfig(node["turntable"]);
  rig.Check(node.file());
  return rig;
}

nlohmann::json RigToJson(const Rig& rig) {
  nlohmann::json j;
  j["format"] = "slshadow-rig";
  j["version"] = kRigFormatVersion;
  j["name"] = rig.name;
  j["working_distance_mm"] = rig.working_distance_mm;
  j["cameras"] = nlohmann::json::array();
  for (const auto& c : rig.cameras) j["cameras"].push_back(DeviceToJson(c));
  if (rig.projector) j["projector"] = DeviceToJson(*rig.projector);
  if (!rig.calibration.is_null()) j["calibration"] = rig.calibration;
  if (rig.turntable) j["turntable"] = TurntableToJson(*rig.turntable);
  return j;
}

Rig LoadRig(const std::filesystem::path& path) { return RigFromConfig(ConfigNode::LoadFile(path)); }

void SaveRig(const Rig& rig, const std::filesystem::path& path) {
  rig.Check(path.string());
  const nlohmann::json j = RigToJson(rig);
  const std::string text = path.extension() == ".json"
                               ? j.dump(2) + "\n"
                               : "# slshadow rig (docs/formats.md)\n" + JsonToYaml(j);
  WriteTextFileAtomically(path, text);
}

std::string DescribeRig(const Rig& rig) {
  std::ostringstream out;
  char buf[512];
  constexpr double kDeg = 180.0 / M_PI;
  out << "rig '" << rig.name << "': " << rig.cameras.size() << " camera(s)"
      << (rig.projector ? ", 1 projector" : ", no projector") << ", working distance "
      << rig.working_distance_mm << " mm\n\n";
  std::vector<const RigDevice*> devices;
  for (const auto& c : rig.cameras) devices.push_back(&c);
  if (rig.projector) devices.push_back(&*rig.projector);
  out << "device        kind       resolution    fx        fy        cx        cy       k1       "
         "FOV h x v (deg)   centre in rig (mm)\n";
  for (const auto* d : devices) {
    const Eigen::Vector3d c = d->CenterInRig() + Eigen::Vector3d::Zero();  // no "-0.0"

    std::snprintf(buf, sizeof(buf),
                  "%-13s %-10s %5dx%-7d %-9.2f %-9.2f %-9.2f %-8.2f %-8.4f %6.2f x %-8.2f (%.1f, "
                  "%.1f, %.1f)\n",
                  d->name.c_str(), rig.projector && d == &*rig.projector ? "projector" : "camera",
                  d->model.width, d->model.height, d->model.fx(), d->model.fy(), d->model.cx(),
                  d->model.cy(), d->model.params[CameraModel::kK1],
                  d->model.HorizontalFovRad() * kDeg, d->model.VerticalFovRad() * kDeg, c.x(),
                  c.y(), c.z());
    out << buf;
  }
  const Eigen::Vector3d wp = rig.WorkingPointInRig();
  std::snprintf(buf, sizeof(buf), "\nworking point in rig frame: (%.1f, %.1f, %.1f) mm\n", wp.x(),
                wp.y(), wp.z());
  out << buf;
  out << "pair                     baseline (mm)  triangulation angle (deg)  overlap at working "
         "distance\n";
  for (size_t i = 0; i < devices.size(); ++i) {
    for (size_t j = i + 1; j < devices.size(); ++j) {
      const auto& a = *devices[i];
      const auto& b = *devices[j];
      std::snprintf(buf, sizeof(buf), "%-24s %13.2f  %25.2f  %26.1f%%\n",
                    (a.name + " - " + b.name).c_str(), rig.BaselineMm(a, b),
                    Rig::TriangulationAngleRad(a, b, wp) * kDeg,
                    100.0 * rig.OverlapAtWorkingDistance(a, b));
      out << buf;
    }
  }
  return out.str();
}

}  // namespace slshadow
