#include "compare/vdi2634.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <random>
#include <sstream>

#include <Eigen/Dense>

#include "core/config.h"
#include "core/error.h"
#include "core/statistics.h"

namespace slshadow::compare {
namespace {

// Sphere through 4 points (algebraic); false when degenerate.
bool SphereFrom4(const Eigen::Vector3d* p, SphereFit* fit) {
  Eigen::Matrix4d a;
  Eigen::Vector4d b;
  for (int i = 0; i < 4; ++i) {
    a.row(i) << p[i].x(), p[i].y(), p[i].z(), 1.0;
    b[i] = -p[i].squaredNorm();
  }
  Eigen::FullPivLU<Eigen::Matrix4d> lu(a);
  if (lu.rank() < 4) return false;
  const Eigen::Vector4d x = lu.solve(b);
  fit->center = -0.5 * x.head<3>();
  const double r2 = fit->center.squaredNorm() - x[3];
  if (!(r2 > 0)) return false;
  fit->radius = std::sqrt(r2);
  return true;
}

// Residuals of points to a shape: radial (sphere) or signed normal (plane).
std::vector<double> SphereResiduals(const std::vector<Eigen::Vector3d>& pts, const SphereFit& s) {
  std::vector<double> r(pts.size());
  for (size_t i = 0; i < pts.size(); ++i) r[i] = (pts[i] - s.center).norm() - s.radius;
  return r;
}
std::vector<double> PlaneResiduals(const std::vector<Eigen::Vector3d>& pts, const PlaneFit& p) {
  std::vector<double> r(pts.size());
  for (size_t i = 0; i < pts.size(); ++i) r[i] = p.normal.dot(pts[i] - p.point);
  return r;
}

// Keeps the points with |residual| <= gate.
std::vector<Eigen::Vector3d> Gate(const std::vector<Eigen::Vector3d>& pts,
                                  const std::vector<double>& res, double gate) {
  std::vector<Eigen::Vector3d> out;
  for (size_t i = 0; i < pts.size(); ++i)
    if (std::abs(res[i]) <= gate) out.push_back(pts[i]);
  return out;
}

// Drops the `fraction` of points with the largest |residual| (VDI/VDE 2634-2 allows 0.3 %).
std::vector<double> Exclude(std::vector<double> res, double fraction) {
  if (fraction <= 0 || res.empty()) return res;
  const auto drop = static_cast<size_t>(std::floor(fraction * static_cast<double>(res.size())));
  std::sort(res.begin(), res.end(), [](double a, double b) { return std::abs(a) < std::abs(b); });
  res.resize(res.size() - drop);
  return res;
}

double Range(const std::vector<double>& v) {
  if (v.empty()) return 0.0;
  const auto [lo, hi] = std::minmax_element(v.begin(), v.end());
  return *hi - *lo;
}

Eigen::Vector3d ReadVec3(const ConfigNode& n) {
  const auto v = n.AsDoubles(3);
  return {v[0], v[1], v[2]};
}

}  // namespace

bool FitSphere(const std::vector<Eigen::Vector3d>& pts, SphereFit* fit) {
  if (pts.size() < 4) return false;
  // Algebraic start on centred coordinates: |p|^2 + D.p + E = 0.
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : pts) mean += p;
  mean /= static_cast<double>(pts.size());
  Eigen::MatrixXd a(static_cast<long>(pts.size()), 4);
  Eigen::VectorXd b(static_cast<long>(pts.size()));
  for (size_t i = 0; i < pts.size(); ++i) {
    const Eigen::Vector3d q = pts[i] - mean;
    a.row(static_cast<long>(i)) << q.x(), q.y(), q.z(), 1.0;
    b[static_cast<long>(i)] = -q.squaredNorm();
  }
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(a);
  if (qr.rank() < 4) return false;
  const Eigen::Vector4d x = qr.solve(b);
  Eigen::Vector3d c = -0.5 * x.head<3>();
  const double r2 = c.squaredNorm() - x[3];
  if (!(r2 > 0)) return false;
  double r = std::sqrt(r2);
  // Gauss-Newton on e_i = |q_i - c| - r.
  for (int it = 0; it < 50; ++it) {
    Eigen::Matrix4d jtj = Eigen::Matrix4d::Zero();
    Eigen::Vector4d jte = Eigen::Vector4d::Zero();
    for (const auto& p : pts) {
      const Eigen::Vector3d d = p - mean - c;
      const double n = d.norm();
      if (n == 0) continue;
      Eigen::Vector4d j;
      j << -d / n, -1.0;
      const double e = n - r;
      jtj += j * j.transpose();
      jte += j * e;
    }
    const Eigen::Vector4d step = jtj.ldlt().solve(-jte);
    c += step.head<3>();
    r += step[3];
    if (step.norm() < 1e-14 * std::max(1.0, r)) break;
  }
  fit->center = c + mean;
  fit->radius = r;
  double s2 = 0;
  for (double e : SphereResiduals(pts, *fit)) s2 += e * e;
  fit->rms_mm = std::sqrt(s2 / static_cast<double>(pts.size()));
  return std::isfinite(r) && r > 0;
}

bool FitPlane(const std::vector<Eigen::Vector3d>& pts, PlaneFit* fit) {
  if (pts.size() < 3) return false;
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (const auto& p : pts) c += p;
  c /= static_cast<double>(pts.size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& p : pts) cov += (p - c) * (p - c).transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  if (!(eig.eigenvalues()[1] > 0)) return false;  // collinear
  fit->point = c;
  fit->normal = eig.eigenvectors().col(0);
  double s2 = 0;
  for (double e : PlaneResiduals(pts, *fit)) s2 += e * e;
  fit->rms_mm = std::sqrt(s2 / static_cast<double>(pts.size()));
  return true;
}

void ArtefactSpec::Check(const std::string& what) const {
  SLSHADOW_THROW_IF(!(search_margin_mm > 0), what, ": search_margin_mm: must be > 0 (got ",
                    search_margin_mm, ")");
  std::map<std::string, int> names;
  for (size_t i = 0; i < spheres.size(); ++i) {
    SLSHADOW_THROW_IF(!(spheres[i].calibrated_diameter_mm > 0), what, ": spheres[", i,
                      "].diameter_mm: must be > 0 (got ", spheres[i].calibrated_diameter_mm, ")");
    SLSHADOW_THROW_IF(names.count(spheres[i].name), what, ": spheres[", i, "].name: duplicate '",
                      spheres[i].name, "'");
    names[spheres[i].name] = static_cast<int>(i);
  }
  for (size_t i = 0; i < pairs.size(); ++i) {
    for (const auto* s : {&pairs[i].sphere_a, &pairs[i].sphere_b}) {
      SLSHADOW_THROW_IF(!names.count(*s), what, ": sphere_pairs[", i, "].spheres: unknown sphere '",
                        *s, "'");
    }
    SLSHADOW_THROW_IF(!(pairs[i].calibrated_distance_mm > 0), what, ": sphere_pairs[", i,
                      "].distance_mm: must be > 0 (got ", pairs[i].calibrated_distance_mm, ")");
  }
  for (size_t i = 0; i < planes.size(); ++i) {
    SLSHADOW_THROW_IF(!(planes[i].half_size_mm > 0), what, ": planes[", i,
                      "].half_size_mm: must be > 0 (got ", planes[i].half_size_mm, ")");
    SLSHADOW_THROW_IF(!(planes[i].nominal_normal.norm() > 0), what, ": planes[", i,
                      "].normal: must not be zero");
  }
}

ArtefactSpec LoadArtefactSpec(const std::filesystem::path& path) {
  return ArtefactSpecFromConfig(ConfigNode::LoadFile(path));
}

ArtefactSpec ArtefactSpecFromConfig(const ConfigNode& root) {
  root.RejectUnknownKeys(
      {"format", "version", "search_margin_mm", "spheres", "sphere_pairs", "planes"});
  ArtefactSpec spec;
  spec.search_margin_mm = root.GetDouble("search_margin_mm", spec.search_margin_mm);
  if (root.Has("spheres")) {
    const ConfigNode s = root["spheres"];
    for (size_t i = 0; i < s.size(); ++i) {
      const ConfigNode e = s.at(i);
      e.RejectUnknownKeys({"name", "center_mm", "diameter_mm"});
      spec.spheres.push_back(
          {e["name"].AsString(), ReadVec3(e["center_mm"]), e["diameter_mm"].AsDouble()});
    }
  }
  if (root.Has("sphere_pairs")) {
    const ConfigNode s = root["sphere_pairs"];
    for (size_t i = 0; i < s.size(); ++i) {
      const ConfigNode e = s.at(i);
      e.RejectUnknownKeys({"name", "spheres", "distance_mm"});
      const ConfigNode names = e["spheres"];
      if (names.size() != 2) names.Fail("must name exactly two spheres");
      spec.pairs.push_back({e["name"].AsString(), names.at(0).AsString(), names.at(1).AsString(),
                            e["distance_mm"].AsDouble()});
    }
  }
  if (root.Has("planes")) {
    const ConfigNode s = root["planes"];
    for (size_t i = 0; i < s.size(); ++i) {
      const ConfigNode e = s.at(i);
      e.RejectUnknownKeys({"name", "point_mm", "normal", "half_size_mm"});
      spec.planes.push_back({e["name"].AsString(), ReadVec3(e["point_mm"]),
                             ReadVec3(e["normal"]).normalized(), e["half_size_mm"].AsDouble()});
    }
  }
  spec.Check(root.path().empty() ? root.file() : root.file() + ": " + root.path());
  return spec;
}

nlohmann::json ArtefactSpecToJson(const ArtefactSpec& spec) {
  auto vec = [](const Eigen::Vector3d& v) { return nlohmann::json::array({v.x(), v.y(), v.z()}); };
  nlohmann::json j = {{"search_margin_mm", spec.search_margin_mm}};
  j["spheres"] = nlohmann::json::array();
  for (const auto& s : spec.spheres) {
    j["spheres"].push_back({{"name", s.name},
                            {"center_mm", vec(s.nominal_center_mm)},
                            {"diameter_mm", s.calibrated_diameter_mm}});
  }
  j["sphere_pairs"] = nlohmann::json::array();
  for (const auto& p : spec.pairs) {
    j["sphere_pairs"].push_back({{"name", p.name},
                                 {"spheres", {p.sphere_a, p.sphere_b}},
                                 {"distance_mm", p.calibrated_distance_mm}});
  }
  j["planes"] = nlohmann::json::array();
  for (const auto& p : spec.planes) {
    j["planes"].push_back({{"name", p.name},
                           {"point_mm", vec(p.nominal_point_mm)},
                           {"normal", vec(p.nominal_normal)},
                           {"half_size_mm", p.half_size_mm}});
  }
  return j;
}

nlohmann::json Vdi2634OptionsToJson(const Vdi2634Options& o) {
  return {{"exclude_fraction", o.exclude_fraction},
          {"ransac_iterations", o.ransac_iterations},
          {"min_points", o.min_points},
          {"seed", o.seed}};
}

Vdi2634Options Vdi2634OptionsFromConfig(const ConfigNode& node) {
  node.RejectUnknownKeys({"exclude_fraction", "ransac_iterations", "min_points", "seed"});
  Vdi2634Options o;
  o.exclude_fraction = node.GetDouble("exclude_fraction", o.exclude_fraction);
  o.ransac_iterations = static_cast<int>(node.GetInt("ransac_iterations", o.ransac_iterations));
  o.min_points = static_cast<int>(node.GetInt("min_points", o.min_points));
  const int64_t seed = node.GetInt("seed", o.seed);
  if (seed < 0 || seed > 0xffffffffLL) node["seed"].Fail("must be in [0, 2^32 - 1]");
  o.seed = static_cast<unsigned>(seed);
  try {
    o.Check();
  } catch (const Error& e) {
    SLSHADOW_THROW(node.file(), ": ", node.path(), ": ", e.what());
  }
  return o;
}

void Vdi2634Options::Check() const {
  SLSHADOW_THROW_IF(!(exclude_fraction >= 0 && exclude_fraction <= 0.003),
                    "vdi2634.exclude_fraction: must be in [0, 0.003] (got ", exclude_fraction, ")");
  SLSHADOW_THROW_IF(ransac_iterations < 1, "vdi2634.ransac_iterations: must be >= 1 (got ",
                    ransac_iterations, ")");
  SLSHADOW_THROW_IF(min_points < 4, "vdi2634.min_points: must be >= 4 (got ", min_points, ")");
}

Vdi2634Result EvaluateVdi2634(const PointCloud& cloud, const ArtefactSpec& spec,
                              const Vdi2634Options& options) {
  options.Check();
  spec.Check("artefact spec");
  Vdi2634Result result;
  std::mt19937 rng(options.seed);
  const double margin = spec.search_margin_mm;
  std::map<std::string, const SphereFigures*> by_name;
  result.spheres.reserve(spec.spheres.size());
  for (const SphereArtefact& a : spec.spheres) {
    SphereFigures f;
    f.name = a.name;
    const double r0 = a.calibrated_diameter_mm / 2;
    std::vector<Eigen::Vector3d> cand;
    for (const auto& p : cloud.points) {
      if (std::abs((p - a.nominal_center_mm).norm() - r0) <= margin) cand.push_back(p);
    }
    if (static_cast<int>(cand.size()) >= options.min_points) {
      // RANSAC: 4-point spheres with a radius near the calibrated one; most points within margin
      // / 4.
      std::uniform_int_distribution<size_t> pick(0, cand.size() - 1);
      const double band = margin / 4;
      SphereFit best;
      size_t best_n = 0;
      for (int it = 0; it < options.ransac_iterations; ++it) {
        const Eigen::Vector3d s[4] = {cand[pick(rng)], cand[pick(rng)], cand[pick(rng)],
                                      cand[pick(rng)]};
        SphereFit h;
        if (!SphereFrom4(s, &h) || std::abs(h.radius - r0) > margin) continue;
        size_t n = 0;
        for (const auto& p : cand) n += std::abs((p - h.center).norm() - h.radius) <= band ? 1 : 0;
        if (n > best_n) {
          best_n = n;
          best = h;
        }
      }
      SphereFit fit;
      if (best_n >= 4 && FitSphere(Gate(cand, SphereResiduals(cand, best), band), &fit)) {
        // Robust gate: 5 sigma from the MAD of all candidates' residuals to the refined fit.
        const auto res = SphereResiduals(cand, fit);
        std::vector<double> abs_res(res.size());
        for (size_t i = 0; i < res.size(); ++i) abs_res[i] = std::abs(res[i]);
        const double sigma = 1.4826 * Median(abs_res);
        const auto pts = Gate(cand, res, std::max(5.0 * sigma, 1e-9 * r0));
        if (static_cast<int>(pts.size()) >= options.min_points && FitSphere(pts, &fit)) {
          const auto final_res = Exclude(SphereResiduals(pts, fit), options.exclude_fraction);
          f.found = true;
          f.points = final_res.size();
          f.fit = fit;
          f.pf_mm = Range(final_res);
          f.ps_mm = 2 * fit.radius - a.calibrated_diameter_mm;
        }
      }
    }
    result.spheres.push_back(f);
  }
  for (const auto& s : result.spheres) by_name[s.name] = &s;
  for (const SpherePair& p : spec.pairs) {
    PairFigures f;
    f.name = p.name;
    const SphereFigures* a = by_name[p.sphere_a];
    const SphereFigures* b = by_name[p.sphere_b];
    if (a && b && a->found && b->found) {
      f.found = true;
      f.measured_distance_mm = (a->fit.center - b->fit.center).norm();
      f.sd_mm = f.measured_distance_mm - p.calibrated_distance_mm;
    }
    result.pairs.push_back(f);
  }
  for (const PlaneArtefact& a : spec.planes) {
    PlaneFigures f;
    f.name = a.name;
    const Eigen::Vector3d n0 = a.nominal_normal.normalized();
    std::vector<Eigen::Vector3d> cand;
    for (const auto& p : cloud.points) {
      const Eigen::Vector3d d = p - a.nominal_point_mm;
      const double h = d.dot(n0);
      if (std::abs(h) <= margin && (d - h * n0).norm() <= a.half_size_mm) cand.push_back(p);
    }
    if (static_cast<int>(cand.size()) >= options.min_points) {
      std::uniform_int_distribution<size_t> pick(0, cand.size() - 1);
      const double band = margin / 4;
      PlaneFit best;
      size_t best_n = 0;
      for (int it = 0; it < options.ransac_iterations; ++it) {
        const Eigen::Vector3d p0 = cand[pick(rng)], p1 = cand[pick(rng)], p2 = cand[pick(rng)];
        const Eigen::Vector3d n = (p1 - p0).cross(p2 - p0);
        if (n.norm() < 1e-12) continue;
        PlaneFit h;
        h.point = p0;
        h.normal = n.normalized();
        if (std::abs(h.normal.dot(n0)) < std::cos(20.0 * M_PI / 180.0)) continue;
        size_t count = 0;
        for (const auto& p : cand) count += std::abs(h.normal.dot(p - p0)) <= band ? 1 : 0;
        if (count > best_n) {
          best_n = count;
          best = h;
        }
      }
      PlaneFit fit;
      if (best_n >= 3 && FitPlane(Gate(cand, PlaneResiduals(cand, best), band), &fit)) {
        const auto res = PlaneResiduals(cand, fit);
        std::vector<double> abs_res(res.size());
        for (size_t i = 0; i < res.size(); ++i) abs_res[i] = std::abs(res[i]);
        const double sigma = 1.4826 * Median(abs_res);
        const auto pts = Gate(cand, res, std::max(5.0 * sigma, 1e-9 * a.half_size_mm));
        if (static_cast<int>(pts.size()) >= options.min_points && FitPlane(pts, &fit)) {
          if (fit.normal.dot(n0) < 0) fit.normal = -fit.normal;
          const auto final_res = Exclude(PlaneResiduals(pts, fit), options.exclude_fraction);
          f.found = true;
          f.points = final_res.size();
          f.fit = fit;
          f.f_mm = Range(final_res);
        }
      }
    }
    result.planes.push_back(f);
  }
  return result;
}

std::string Vdi2634Result::Summary() const {
  std::ostringstream o;
  char buf[256];
  o << "VDI/VDE 2634-2\n";
  for (const auto& s : spheres) {
    if (!s.found) {
      o << "  sphere " << s.name << ": not found\n";
      continue;
    }
    std::snprintf(buf, sizeof(buf), "  sphere %-10s %7zu pts  D %.4f mm  PF %.4f mm  PS %+.4f mm\n",
                  s.name.c_str(), s.points, 2 * s.fit.radius, s.pf_mm, s.ps_mm);
    o << buf;
  }
  for (const auto& p : pairs) {
    if (!p.found) {
      o << "  pair   " << p.name << ": a sphere was not found\n";
      continue;
    }
    std::snprintf(buf, sizeof(buf), "  pair   %-10s L %.4f mm  SD %+.4f mm\n", p.name.c_str(),
                  p.measured_distance_mm, p.sd_mm);
    o << buf;
  }
  for (const auto& p : planes) {
    if (!p.found) {
      o << "  plane  " << p.name << ": not found\n";
      continue;
    }
    std::snprintf(buf, sizeof(buf), "  plane  %-10s %7zu pts  F %.4f mm\n", p.name.c_str(),
                  p.points, p.f_mm);
    o << buf;
  }
  return o.str();
}

nlohmann::json Vdi2634Result::ToJson() const {
  nlohmann::json j;
  j["spheres"] = nlohmann::json::array();
  for (const auto& s : spheres) {
    j["spheres"].push_back({{"name", s.name},
                            {"found", s.found},
                            {"points", s.points},
                            {"center_mm", {s.fit.center.x(), s.fit.center.y(), s.fit.center.z()}},
                            {"diameter_mm", 2 * s.fit.radius},
                            {"rms_mm", s.fit.rms_mm},
                            {"pf_mm", s.pf_mm},
                            {"ps_mm", s.ps_mm}});
  }
  j["sphere_pairs"] = nlohmann::json::array();
  for (const auto& p : pairs) {
    j["sphere_pairs"].push_back({{"name", p.name},
                                 {"found", p.found},
                                 {"distance_mm", p.measured_distance_mm},
                                 {"sd_mm", p.sd_mm}});
  }
  j["planes"] = nlohmann::json::array();
  for (const auto& p : planes) {
    j["planes"].push_back({{"name", p.name},
                           {"found", p.found},
                           {"points", p.points},
                           {"normal", {p.fit.normal.x(), p.fit.normal.y(), p.fit.normal.z()}},
                           {"rms_mm", p.fit.rms_mm},
                           {"f_mm", p.f_mm}});
  }
  return j;
}

}  // namespace slshadow::compare
