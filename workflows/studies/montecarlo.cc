#include "workflows/studies/montecarlo.h"

#include "compare/charts.h"
#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/npy.h"
#include "core/point_cloud.h"
#include "reconstruct/dense_grid.h"

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>

namespace slshadow::studies {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr double kPi = 3.14159265358979323846;
const std::array<const char*, 9> kParamNames = {"fx", "fy", "cx", "cy", "k1",
                                                "k2", "p1", "p2", "k3"};

std::string Num(double v, int digits = 6) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*g", digits, v);
  return buf;
}

// The 9x9 intrinsics covariance of device `name` from a rig's calibration evidence
// (calib/calibration_io.h: `devices[].name`, `intrinsics_covariance[]`), or none.
std::optional<Eigen::Matrix<double, 9, 9>> EvidenceCovariance(const json& calibration,
                                                              const std::string& name) {
  if (!calibration.is_object() || !calibration.contains("intrinsics_covariance") ||
      !calibration.contains("devices")) {
    return std::nullopt;
  }
  const json& devices = calibration.at("devices");
  const json& cov = calibration.at("intrinsics_covariance");
  for (size_t d = 0; d < devices.size() && d < cov.size(); ++d) {
    if (devices[d].value("name", "") != name) continue;
    if (!cov[d].is_array() || cov[d].size() != 81) return std::nullopt;
    Eigen::Matrix<double, 9, 9> m;
    for (int r = 0; r < 9; ++r) {
      for (int c = 0; c < 9; ++c) m(r, c) = cov[d][static_cast<size_t>(9 * r + c)].get<double>();
    }
    return 0.5 * (m + m.transpose());
  }
  return std::nullopt;
}

void PerturbDevice(RigDevice* device, const std::array<double, 9>& sigma, const json& calibration,
                   bool move, const RigSigma& rs, std::mt19937_64& rng,
                   std::vector<std::string>* used_covariance) {
  std::normal_distribution<double> g(0.0, 1.0);
  std::array<double, 9> z{};
  for (double& v : z) v = g(rng);
  const auto cov = EvidenceCovariance(calibration, device->name);
  if (cov) {
    // x = V sqrt(max(lambda, 0)) z: a positive semi-definite covariance (held parameters: 0 rows).
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 9, 9>> eig(*cov);
    Eigen::Matrix<double, 9, 1> zz;
    for (int i = 0; i < 9; ++i)
      zz[i] = z[static_cast<size_t>(i)] * std::sqrt(std::max(0.0, eig.eigenvalues()[i]));
    const Eigen::Matrix<double, 9, 1> dx = eig.eigenvectors() * zz;
    for (int i = 0; i < 9; ++i) device->model.params[static_cast<size_t>(i)] += dx[i];
    if (used_covariance) used_covariance->push_back(device->name);
  } else {
    for (size_t i = 0; i < 9; ++i) device->model.params[i] += sigma[i] * z[i];
  }
  std::array<double, 6> p{};
  for (double& v : p) v = g(rng);
  if (!move) return;
  const double s = rs.rotation_deg * kPi / 180;
  const Eigen::Vector3d w(s * p[0], s * p[1], s * p[2]);
  const Eigen::Quaterniond dq = QuaternionFromRotationVector(w);
  const Eigen::Vector3d dt = rs.translation_mm * Eigen::Vector3d(p[3], p[4], p[5]);
  device->cam_from_rig =
      Rigid3d(dq * device->cam_from_rig.rotation, dq * device->cam_from_rig.translation + dt);
}

std::array<double, 9> SigmaFromConfig(const ConfigNode& node) {
  std::array<double, 9> s{};
  std::vector<std::string> names(kParamNames.begin(), kParamNames.end());
  node.RejectUnknownKeys(names);
  for (size_t i = 0; i < 9; ++i) {
    if (!node.Has(kParamNames[i])) continue;
    s[i] = node[kParamNames[i]].AsDouble();
    if (!(s[i] >= 0)) node[kParamNames[i]].Fail("must be >= 0");
  }
  return s;
}

json SigmaToJson(const std::array<double, 9>& s) {
  json j = json::object();
  for (size_t i = 0; i < 9; ++i) j[kParamNames[i]] = s[i];
  return j;
}

}  // namespace

Rig SampleRig(const Rig& rig, const RigSigma& sigma, uint64_t seed,
              std::vector<std::string>* used_covariance) {
  Rig out = rig;
  std::mt19937_64 rng(seed);
  for (size_t i = 0; i < out.cameras.size(); ++i) {
    PerturbDevice(&out.cameras[i], sigma.camera, rig.calibration, i > 0, sigma, rng,
                  used_covariance);
  }
  if (out.projector) {
    PerturbDevice(&*out.projector, sigma.projector, rig.calibration, true, sigma, rng,
                  used_covariance);
  }
  out.Check("sampled rig (seed " + std::to_string(seed) + ")");
  return out;
}

json MonteCarloStudy::ToJson() const {
  return {{"samples", samples},
          {"replicates", replicates},
          {"seed", seed},
          {"sigma",
           {{"camera", SigmaToJson(sigma.camera)},
            {"projector", SigmaToJson(sigma.projector)},
            {"rotation_deg", sigma.rotation_deg},
            {"translation_mm", sigma.translation_mm}}},
          {"covariance_devices", covariance_devices}};
}

MonteCarloStudy MonteCarloStudyFromConfig(const ConfigNode& node, const Rig& rig) {
  node.RejectUnknownKeys({"samples", "replicates", "seed", "sigma"});
  MonteCarloStudy s;
  const int64_t samples = node["samples"].AsInt(), replicates = node["replicates"].AsInt();
  if (samples < 2 || samples > 100000) node["samples"].Fail("must be in 2..100000");
  if (replicates < 1 || replicates > 100000) node["replicates"].Fail("must be in 1..100000");
  s.samples = static_cast<int>(samples);
  s.replicates = static_cast<int>(replicates);
  const int64_t seed = node.GetInt("seed", 1);
  if (seed < 0) node["seed"].Fail("must be >= 0");
  s.seed = static_cast<uint64_t>(seed);
  if (node.Has("sigma")) {
    const ConfigNode n = node["sigma"];
    n.RejectUnknownKeys({"camera", "projector", "rotation_deg", "translation_mm"});
    if (n.Has("camera")) s.sigma.camera = SigmaFromConfig(n["camera"]);
    s.sigma.projector = n.Has("projector") ? SigmaFromConfig(n["projector"]) : s.sigma.camera;
    s.sigma.rotation_deg = n.GetDouble("rotation_deg", 0);
    s.sigma.translation_mm = n.GetDouble("translation_mm", 0);
    if (!(s.sigma.rotation_deg >= 0)) n["rotation_deg"].Fail("must be >= 0");
    if (!(s.sigma.translation_mm >= 0)) n["translation_mm"].Fail("must be >= 0");
  }
  for (int k = 0; k < s.samples + s.replicates; ++k) {
    // Seeds of the rig sample and of the sensor noise: distinct per job, fixed by the study seed.
    const uint64_t rig_seed = s.seed * 0x9E3779B97F4A7C15ULL + 2 * static_cast<uint64_t>(k) + 1;
    const uint64_t noise_seed = s.seed * 100003ULL + static_cast<uint64_t>(k) + 1;
    std::vector<std::string> used;
    Rig sampled;
    try {
      sampled = SampleRig(rig, s.sigma, rig_seed, &used);
    } catch (const Error& e) {
      node.Fail(std::string("a sampled rig is not valid (standard deviations too large?): ") +
                e.what());
    }
    if (k == 0) s.covariance_devices = used;
    s.jobs.push_back({{"sample", k},
                      {"set", k < s.samples ? "prediction" : "replicate"},
                      {"noise_seed", noise_seed & 0xffffffffULL},
                      {"reconstruct_rig", RigToJson(sampled)}});
  }
  return s;
}

fs::path MonteCarloGridFile(const fs::path& jobs_dir, int id) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%06d.grid.npy", id);
  return jobs_dir / "results" / buf;
}

void WriteMonteCarloGrid(const fs::path& file, const DenseGrid& grid) {
  cv::Mat m(grid.height, grid.width, CV_32FC3);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int y = 0; y < grid.height; ++y) {
    for (int x = 0; x < grid.width; ++x) {
      const size_t i =
          static_cast<size_t>(y) * static_cast<size_t>(grid.width) + static_cast<size_t>(x);
      const bool ok = grid.reason[i] == static_cast<uint8_t>(RejectReason::kAccepted);
      const Eigen::Vector3d& p = grid.point_in_rig[i];
      m.at<cv::Vec3f>(y, x) = ok ? cv::Vec3f(static_cast<float>(p.x()), static_cast<float>(p.y()),
                                             static_cast<float>(p.z()))
                                 : cv::Vec3f(nan, nan, nan);
    }
  }
  WriteFileAtomically(file, [&](const fs::path& tmp) { WriteNpy(tmp, m); });
}

std::vector<std::string> WriteMonteCarloResults(const fs::path& jobs_dir, const fs::path& out_dir,
                                                const std::vector<int>& ids,
                                                const std::vector<std::string>& sets,
                                                const json& viewpoint, const std::string& study) {
  std::vector<cv::Mat> pred, rep;
  for (size_t k = 0; k < ids.size(); ++k) {
    const fs::path file = MonteCarloGridFile(jobs_dir, ids[k]);
    std::error_code ec;
    SLSHADOW_THROW_IF(!fs::exists(file, ec), file.string(),
                      ": missing (the job's result exists without its grid: remove the result "
                      "and run its shard again)");
    cv::Mat m = ReadNpy(file, 3);
    SLSHADOW_THROW_IF(m.type() != CV_32FC3, file.string(), ": not a float32 rows x cols x 3 grid");
    if (!pred.empty() || !rep.empty()) {
      const cv::Mat& first = pred.empty() ? rep[0] : pred[0];
      SLSHADOW_THROW_IF(m.size() != first.size(), file.string(), ": grid size differs");
    }
    (sets[k] == "prediction" ? pred : rep).push_back(m);
  }
  SLSHADOW_THROW_IF(pred.size() < 2 || rep.empty(), jobs_dir.string(),
                    ": needs >= 2 prediction and >= 1 replicate grids");
  const Eigen::Vector3d vp(viewpoint[0].get<double>(), viewpoint[1].get<double>(),
                           viewpoint[2].get<double>());
  const int rows = pred[0].rows, cols = pred[0].cols;
  const double n = static_cast<double>(pred.size());
  PointCloud cloud;
  std::vector<float> u_field;
  compare::ValueImage map;
  map.width = cols;
  map.height = rows;
  map.values.assign(static_cast<size_t>(rows) * static_cast<size_t>(cols),
                    std::numeric_limits<float>::quiet_NaN());
  std::string csv = "row,col,x_mm,y_mm,z_mm,range_mm,u_mm,replicate_sd_mm\n";
  size_t covered = 0, trials = 0;
  std::vector<double> us, ratios;
  for (int y = 0; y < rows; ++y) {
    for (int x = 0; x < cols; ++x) {
      bool ok = true;
      const auto at = [&](const cv::Mat& m) {
        const cv::Vec3f v = m.at<cv::Vec3f>(y, x);
        return Eigen::Vector3d(v[0], v[1], v[2]);
      };
      for (const auto& m : pred) ok = ok && std::isfinite(at(m).x());
      for (const auto& m : rep) ok = ok && std::isfinite(at(m).x());
      if (!ok) continue;
      Eigen::Vector3d mean = Eigen::Vector3d::Zero();
      double md = 0;
      for (const auto& m : pred) {
        mean += at(m) / n;
        md += (at(m) - vp).norm() / n;
      }
      double ss = 0;
      for (const auto& m : pred) ss += std::pow((at(m) - vp).norm() - md, 2);
      const double u = std::sqrt(ss / (n - 1));
      double rs = 0, rm = 0;
      for (const auto& m : rep) rm += (at(m) - vp).norm() / static_cast<double>(rep.size());
      for (const auto& m : rep) {
        const double d = (at(m) - vp).norm();
        rs += std::pow(d - rm, 2);
        covered += std::abs(d - md) <= 2 * u ? 1 : 0;
        ++trials;
      }
      const double rsd = rep.size() > 1 ? std::sqrt(rs / static_cast<double>(rep.size() - 1)) : 0.0;
      cloud.points.push_back(mean);
      u_field.push_back(static_cast<float>(u));
      map.values[static_cast<size_t>(y) * static_cast<size_t>(cols) + static_cast<size_t>(x)] =
          static_cast<float>(u);
      us.push_back(u);
      if (u > 0 && rep.size() > 1) ratios.push_back(rsd / u);
      csv += std::to_string(y) + ',' + std::to_string(x) + ',' + Num(mean.x(), 10) + ',' +
             Num(mean.y(), 10) + ',' + Num(mean.z(), 10) + ',' + Num(md, 10) + ',' + Num(u, 10) +
             ',' + Num(rsd, 10) + '\n';
    }
  }
  SLSHADOW_THROW_IF(us.empty(), jobs_dir.string(),
                    ": no pixel has a point in every job; nothing to estimate");
  const auto quantile = [](std::vector<double> v, double q) {
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size())))];
  };
  const double coverage = static_cast<double>(covered) / static_cast<double>(trials);
  const double med = quantile(us, 0.5), p95 = quantile(us, 0.95),
               umax = *std::max_element(us.begin(), us.end());
  const double ratio = ratios.empty() ? 0.0 : quantile(ratios, 0.5);
  const bool within = coverage >= 0.90 && coverage <= 0.98;
  cloud.SetScalar("u_mm", u_field);
  WriteFileAtomically(out_dir / "uncertainty.ply",
                      [&](const fs::path& tmp) { WritePly(tmp, cloud); });
  WriteTextFileAtomically(out_dir / "uncertainty.csv", csv);
  const std::string summary =
      "pixels,prediction_samples,replicates,median_u_mm,p95_u_mm,max_u_mm,coverage_2sigma,"
      "coverage_within_90_98,median_replicate_sd_over_u\n" +
      std::to_string(us.size()) + ',' + std::to_string(pred.size()) + ',' +
      std::to_string(rep.size()) + ',' + Num(med, 10) + ',' + Num(p95, 10) + ',' + Num(umax, 10) +
      ',' + Num(coverage, 10) + ',' + (within ? "1" : "0") + ',' + Num(ratio, 10) + '\n';
  WriteTextFileAtomically(out_dir / "uncertainty_summary.csv", summary);
  compare::MapChart chart;
  chart.title = study + ": standard uncertainty of the range, Monte Carlo";
  chart.colorbar_label = "u (mm)";
  chart.lo = 0;
  chart.hi = p95 > 0 ? p95 : 1e-6;
  chart.notes = {std::to_string(pred.size()) + " samples; colour range 0 to the 95th percentile",
                 "2-sigma coverage of " + std::to_string(rep.size()) +
                     " replicates: " + Num(100 * coverage, 4) + " %"};
  compare::WriteDeviationMapPng(out_dir / "uncertainty.png", map, chart);
  return {std::to_string(us.size()) + " pixels with a point in all " +
              std::to_string(pred.size() + rep.size()) + " jobs: u median " + Num(med, 4) +
              " mm, p95 " + Num(p95, 4) + " mm, max " + Num(umax, 4) + " mm",
          "2-sigma coverage of the " + std::to_string(rep.size()) + " replicate scans: " +
              Num(100 * coverage, 4) + " % (" + (within ? "within" : "NOT within") +
              " 90..98 %); median replicate sd / u = " + Num(ratio, 4)};
}

}  // namespace slshadow::studies
