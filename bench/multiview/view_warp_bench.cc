// How much of a table angle each view's own cloud carries (issue 32, the pose errors with sensor
// noise): each view's reconstruction placed at its TRUE pose, its signed distance d to the CAD,
// and from it
//   - the table turn that best explains d alone: theta_v = sum g d / sum g^2, with
//     g = n . (u x (p - c)) the CAD surface's motion along its normal per radian of table turn
//     (u, c the turntable axis in the part frame). Registration between views can only see the
//     difference of two views' theta_v (over their overlap), so a view's theta_v relative to the
//     anchor's is an error no registration of these clouds can remove;
//   - its 1-sigma if the point errors were independent (sqrt(sum g^2 d^2) / sum g^2) and
//     clustered over cubic cells of 2, 5, 10, 20 mm (the same with the cells' sums of g d), so
//     that correlated errors show as a sigma that grows with the cell;
//   - the autocorrelation of d over distance (mean of d_i d_j / var d, pairs binned by |p_i -
//   p_j|);
//   - a Cramer-Rao bound for the table angle against the CAD from the view's own noise.
// Reads a `slshadow merge --reconstructions DIR` folder (DIR/<view>/cloud.ply, rig frame), the
// model's report.json (each view's part_from_rig_true and, for comparison, the merge's
// table_angle_correction_deg, the signed error of the fitted angle), the project's project.json
// (the turntable axis) and the CAD mesh. Figures:
// docs/benchmarks/log/2026-12-07-rotation-noise-2.md.
//
//   build/bench/multiview/view_warp_bench --recon DIR --report MODEL/report.json
//       --project PROJECT/project.json --cad cad.ply [--crop-mm 0.5] [--max-abs-mm 0.15]
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Cholesky>
#include <nlohmann/json.hpp>

#include "bench/multiview/report_pose.h"
#include "compare/distances.h"
#include "compare/mesh_distance.h"
#include "core/kdtree.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "core/rigid3.h"

using slshadow::Rigid3d;

namespace {

Eigen::Vector3d Vec(const nlohmann::json& j) {
  return Eigen::Vector3d(j[0].get<double>(), j[1].get<double>(), j[2].get<double>());
}

constexpr double kDeg = 180.0 / M_PI;

struct Args {
  std::string recon, report, project, cad;
  double crop_mm = 0.5, max_abs_mm = 0.15;
};

}  // namespace

int main(int argc, char** argv) {
  Args a;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i], v = argv[i + 1];
    if (k == "--recon")
      a.recon = v;
    else if (k == "--report")
      a.report = v;
    else if (k == "--project")
      a.project = v;
    else if (k == "--cad")
      a.cad = v;
    else if (k == "--crop-mm")
      a.crop_mm = std::stod(v);
    else if (k == "--max-abs-mm")
      a.max_abs_mm = std::stod(v);
    else {
      std::fprintf(stderr, "view_warp_bench: unknown option %s\n", k.c_str());
      return 2;
    }
  }
  if (a.recon.empty() || a.report.empty() || a.project.empty() || a.cad.empty()) {
    std::fprintf(stderr,
                 "usage: view_warp_bench --recon DIR --report report.json --project project.json "
                 "--cad cad.ply\n");
    return 2;
  }
  nlohmann::json report, project;
  std::ifstream(a.report) >> report;
  std::ifstream(a.project) >> project;
  const auto& tt = project.at("rig").at("turntable");
  const Eigen::Vector3d u_rig = Vec(tt.at("axis_direction")).normalized();
  const Eigen::Vector3d c_rig = Vec(tt.at("axis_point_mm"));
  const slshadow::TriangleMesh cad = slshadow::ReadMesh(a.cad);
  const slshadow::compare::MeshDistance md(cad);

  std::printf(
      "view     points  rms_mm   mean_mm  theta_v_deg  sig_iid  sig_2mm  sig_5mm  sig_10mm "
      "sig_20mm  6dof_u_deg  merge_corr_deg\n");
  const std::vector<double> edges = {0, 0.25, 0.5, 1, 2, 4, 8, 16, 32, 64, 128};
  std::vector<double> corr_sum(edges.size() - 1, 0), corr_n(edges.size() - 1, 0);
  std::vector<double> theta_v, merge_corr, sig_iid;
  for (const auto& view : report.at("views")) {
    if (!view.value("merged", false) || !view.contains("part_from_rig_true")) continue;
    const std::string name = view.at("name");
    const Rigid3d truth = slshadow::bench::ReportPose(view.at("part_from_rig_true"));
    const slshadow::PointCloud cloud = slshadow::ReadPly(a.recon + "/" + name + "/cloud.ply");
    std::vector<Eigen::Vector3d> pts;
    for (const auto& p : cloud.points)
      if (u_rig.dot(p - c_rig) >= a.crop_mm) pts.push_back(truth * p);
    const Eigen::Vector3d u = truth.rotation * u_rig, c = truth * c_rig;
    const slshadow::compare::C2MResult c2m = slshadow::compare::CloudToMesh(pts, md);
    std::vector<Eigen::Vector3d> p_ok;
    std::vector<double> d, g;
    std::vector<Eigen::Matrix<double, 6, 1>> jac;
    for (size_t i = 0; i < pts.size(); ++i) {
      const double di = c2m.signed_distances_mm[i];
      if (std::abs(di) > a.max_abs_mm) continue;
      const auto& tri = cad.triangles[c2m.triangles[i]];
      const Eigen::Vector3d n = (cad.vertices[tri[1]] - cad.vertices[tri[0]])
                                    .cross(cad.vertices[tri[2]] - cad.vertices[tri[0]])
                                    .normalized();
      p_ok.push_back(pts[i]);
      d.push_back(di);
      g.push_back(n.dot(u.cross(pts[i] - c)));
      Eigen::Matrix<double, 6, 1> j;
      j.head<3>() = pts[i].cross(n);
      j.tail<3>() = n;
      jac.push_back(j);
    }
    const size_t m = d.size();
    double sgg = 0, sgd = 0, sggdd = 0, sdd = 0, sd = 0;
    Eigen::Matrix<double, 6, 6> h = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> b = Eigen::Matrix<double, 6, 1>::Zero();
    for (size_t i = 0; i < m; ++i) {
      sgg += g[i] * g[i];
      sgd += g[i] * d[i];
      sggdd += g[i] * g[i] * d[i] * d[i];
      sdd += d[i] * d[i];
      sd += d[i];
      h += jac[i] * jac[i].transpose();
      b += jac[i] * d[i];
    }
    const double th = sgd / sgg;
    // Residuals after the 1-DOF turn, for the sandwich sigmas.
    std::vector<double> r(m);
    for (size_t i = 0; i < m; ++i) r[i] = d[i] - th * g[i];
    double srr = 0;
    for (size_t i = 0; i < m; ++i) srr += g[i] * g[i] * r[i] * r[i];
    const double s_iid = std::sqrt(srr) / sgg;
    std::vector<double> s_cl;
    for (double cell : {2.0, 5.0, 10.0, 20.0}) {
      std::map<std::tuple<int, int, int>, double> sums;
      for (size_t i = 0; i < m; ++i) {
        const auto key = std::make_tuple(static_cast<int>(std::floor(p_ok[i].x() / cell)),
                                         static_cast<int>(std::floor(p_ok[i].y() / cell)),
                                         static_cast<int>(std::floor(p_ok[i].z() / cell)));
        sums[key] += g[i] * r[i];
      }
      double s = 0;
      for (const auto& [k, v] : sums) s += v * v;
      s_cl.push_back(std::sqrt(s) / sgg);
    }
    // The 6-DOF point-to-plane fit to the CAD: a view registered to the truth alone; its rotation
    // about u (the cloud's rotation vector x, d ~ J x).
    const Eigen::Matrix<double, 6, 1> x = h.ldlt().solve(b);
    const double rot_u = x.head<3>().dot(u);
    const double mean = sd / static_cast<double>(m);
    const double var = sdd / static_cast<double>(m) - mean * mean;
    // Autocorrelation: 3000 random points, all their pairs; plus each one's 48 nearest points.
    std::mt19937 rng(7);
    std::vector<size_t> idx(m);
    for (size_t i = 0; i < m; ++i) idx[i] = i;
    std::shuffle(idx.begin(), idx.end(), rng);
    idx.resize(std::min<size_t>(3000, m));
    auto add = [&](size_t i, size_t j) {
      const double dist = (p_ok[i] - p_ok[j]).norm();
      for (size_t k = 0; k + 1 < edges.size(); ++k) {
        if (dist >= edges[k] && dist < edges[k + 1]) {
          corr_sum[k] += (d[i] - mean) * (d[j] - mean) / var;
          corr_n[k] += 1;
          break;
        }
      }
    };
    for (size_t x1 = 0; x1 < idx.size(); ++x1)
      for (size_t x2 = x1 + 1; x2 < idx.size(); ++x2) add(idx[x1], idx[x2]);
    slshadow::KdTree tree(p_ok);
    std::vector<slshadow::Neighbor> nn;
    for (size_t x1 = 0; x1 < idx.size(); ++x1) {
      tree.KNearest(p_ok[idx[x1]], 48, &nn);
      for (const auto& q : nn)
        if (q.index != idx[x1]) add(idx[x1], q.index);
    }
    const double corr = view.value("table_angle_correction_deg", 0.0);
    theta_v.push_back(th * kDeg);
    merge_corr.push_back(corr);
    sig_iid.push_back(s_iid * kDeg);
    std::printf("%-8s %6zu  %.4f  %+.5f  %+.5f     %.5f  %.5f  %.5f  %.5f  %.5f   %+.5f    %+.5f\n",
                name.c_str(), m, std::sqrt(var), mean, th * kDeg, s_iid * kDeg, s_cl[0] * kDeg,
                s_cl[1] * kDeg, s_cl[2] * kDeg, s_cl[3] * kDeg, rot_u * kDeg, corr);
  }
  // theta_v relative to the anchor (the first view) against the merge's errors.
  if (!theta_v.empty()) {
    double sxy = 0, sxx = 0, syy = 0, rms_rel = 0;
    for (size_t i = 1; i < theta_v.size(); ++i) {
      const double rel = theta_v[i] - theta_v[0];
      sxy += rel * merge_corr[i];
      sxx += rel * rel;
      syy += merge_corr[i] * merge_corr[i];
      rms_rel += rel * rel;
    }
    const double k = static_cast<double>(theta_v.size() - 1);
    double rms_v = 0, rms_iid = 0;
    for (size_t i = 0; i < theta_v.size(); ++i) {
      rms_v += theta_v[i] * theta_v[i];
      rms_iid += sig_iid[i] * sig_iid[i];
    }
    std::printf(
        "theta_v: RMS %.5f deg (independent-error 1-sigma RMS %.5f deg); relative to the anchor "
        "RMS %.5f deg; merge's angle errors RMS %.5f deg; correlation(theta_v - theta_anchor, "
        "merge error) %+.3f, regression slope %+.3f\n",
        std::sqrt(rms_v / static_cast<double>(theta_v.size())),
        std::sqrt(rms_iid / static_cast<double>(theta_v.size())), std::sqrt(rms_rel / k),
        std::sqrt(syy / k), sxy / std::sqrt(sxx * syy), sxy / sxx);
  }
  std::printf("autocorrelation of d over distance (all views):\n");
  for (size_t k = 0; k + 1 < edges.size(); ++k)
    if (corr_n[k] > 0)
      std::printf("  %6.2f-%6.2f mm: %+.3f  (%.0f pairs)\n", edges[k], edges[k + 1],
                  corr_sum[k] / corr_n[k], corr_n[k]);
  return 0;
}
