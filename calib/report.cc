#include "calib/report.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <memory>

#include "calib/calibration_io.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/pose_io.h"
#include "core/statistics.h"
#include "plot/plot.h"

namespace slshadow {
namespace {

// A chart stream holding the PLplot lock: colour 2 outliers, 3 bars and vectors, 4 points.
struct Chart {
  std::unique_lock<std::mutex> lock = plot::LockPlplot();
  std::unique_ptr<plstream> pls;
  plstream* operator->() const { return pls.get(); }
};

Chart OpenPng(const std::filesystem::path& file, int width, int height) {
  Chart chart;
  chart.pls = plot::OpenPng(file, width, height, {{200, 0, 0}, {40, 90, 200}, {150, 150, 150}});
  return chart;
}

void PerViewChart(const std::filesystem::path& path, const CalibrationSummary& s) {
  const int n = static_cast<int>(s.views.size());
  double ymax = 0;
  for (const auto& v : s.views) {
    if (std::isfinite(v.rms_px)) ymax = std::max(ymax, v.rms_px);
  }
  ymax = std::max(ymax * 1.15, 0.1);
  auto pls = OpenPng(path, std::max(700, 40 * n + 200), 600);
  pls->schr(0, 1.0);
  pls->env(-0.5, n - 0.5, 0, ymax, 0, 0);
  pls->lab("view (index; devices in turn, see summary.json)", "RMS reprojection error (px)",
           "per-view RMS (red: outlier views)");
  for (int i = 0; i < n; ++i) {
    const auto& v = s.views[static_cast<size_t>(i)];
    if (!std::isfinite(v.rms_px)) continue;
    PLFLT xs[4] = {i - 0.4, i - 0.4, i + 0.4, i + 0.4};
    PLFLT ys[4] = {0, v.rms_px, v.rms_px, 0};
    pls->col0(v.outlier ? 2 : 3);
    pls->fill(4, xs, ys);
  }
  pls->col0(1);
  pls->lsty(2);
  PLFLT xs[2] = {-0.5, n - 0.5}, ys[2] = {s.rms_px, s.rms_px};
  pls->line(2, xs, ys);
  pls->lsty(1);
  char note[128];
  std::snprintf(note, sizeof(note), "overall RMS %.3f px (dashed)", s.rms_px);
  pls->mtex("t", -1.5, 0.98, 1.0, note);
}

void ResidualChart(const std::filesystem::path& path, const CalibrationInput& input,
                   const CalibrationResult& result, int device) {
  const auto& dev = input.devices[static_cast<size_t>(device)];
  // Magnify so the 95th-percentile residual is drawn 1/25 of the image width long.
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> arrows;
  std::vector<double> lengths;
  for (const auto& v : input.views) {
    if (v.device != device || !result.rig_from_board[static_cast<size_t>(v.pose)]) continue;
    const auto proj = Reproject(result, v);
    for (size_t i = 0; i < proj.size(); ++i) {
      arrows.emplace_back(v.pixels_px[i], proj[i] - v.pixels_px[i]);
      lengths.push_back((proj[i] - v.pixels_px[i]).norm());
    }
  }
  double p95 = 1;
  if (!lengths.empty()) {
    std::sort(lengths.begin(), lengths.end());
    p95 = std::max(1e-6, lengths[PercentileRank(lengths.size(), 95)]);  // core/statistics.h
  }
  const double mag = dev.width / 25.0 / p95;
  const double scale = std::min(1.0, 1000.0 / dev.width);
  auto pls = OpenPng(path, static_cast<int>(dev.width * scale) + 160,
                     static_cast<int>(dev.height * scale) + 130);
  pls->adv(0);
  pls->vpor(0.1, 0.95, 0.1, 0.9);
  pls->wind(-0.5, dev.width - 0.5, dev.height - 0.5, -0.5);
  pls->box("bcnst", 0, 0, "bcnstv", 0, 0);
  char title[160];
  std::snprintf(title, sizeof(title), "%s: residuals (projected - observed) x%.0f",
                dev.name.c_str(), mag);
  pls->lab("image x (px)", "image y (px)", title);
  pls->col0(4);
  for (const auto& [p, r] : arrows) {
    PLFLT x[1] = {p.x()}, y[1] = {p.y()};
    pls->poin(1, x, y, 1);
  }
  pls->col0(3);
  for (const auto& [p, r] : arrows)
    pls->join(p.x(), p.y(), p.x() + mag * r.x(), p.y() + mag * r.y());
  pls->col0(1);
  char note[128];
  std::snprintf(note, sizeof(note), "95%% of residuals below %.3f px", p95);
  pls->mtex("t", -1.5, 0.98, 1.0, note);
}

void MapChart(const std::filesystem::path& path, const PixelMap& map, int width, int height,
              const std::string& title, const std::string& bar_label) {
  const int nx = map.values.cols, ny = map.values.rows;
  double hi = 0;
  for (int r = 0; r < ny; ++r) {
    for (int c = 0; c < nx; ++c) {
      const float v = map.values.at<float>(r, c);
      if (std::isfinite(v)) hi = std::max(hi, static_cast<double>(v));
    }
  }
  // Colour range clipped at the 95th percentile so the bulk of the image is readable (the image
  // corners, where data are extrapolated, would otherwise own the whole scale).
  if (std::isfinite(map.p95) && map.p95 > 0) hi = std::min(hi, map.p95);
  hi = hi > 0 ? hi : 1.0;
  const double lo = 0;
  const double scale = std::min(1.0, 1000.0 / width);
  const int page_w = static_cast<int>(width * scale) + 330,
            page_h = static_cast<int>(height * scale) + 150;
  auto pls = OpenPng(path, page_w, page_h);
  plot::SetHeatColorMap(*pls.pls);
  pls->adv(0);
  const double vx0 = 135.0 / page_w, vx1 = vx0 + width * scale / page_w;
  const double vy0 = 80.0 / page_h, vy1 = vy0 + height * scale / page_h;
  pls->vpor(vx0, vx1, vy0, vy1);
  pls->wind(-0.5, width - 0.5, height - 0.5, -0.5);
  std::vector<std::vector<PLFLT>> cols(static_cast<size_t>(nx),
                                       std::vector<PLFLT>(static_cast<size_t>(ny)));
  std::vector<const PLFLT*> ptrs(static_cast<size_t>(nx));
  for (int x = 0; x < nx; ++x) {
    for (int y = 0; y < ny; ++y) {
      const float v = map.values.at<float>(y, x);
      cols[static_cast<size_t>(x)][static_cast<size_t>(y)] =
          std::isfinite(v) ? std::clamp<double>(v, lo, hi) : lo - 10 * hi;
    }
    ptrs[static_cast<size_t>(x)] = cols[static_cast<size_t>(x)].data();
  }
  // Cells cover [c * cell - 0.5, (c + 1) * cell - 0.5).
  const double x1 = nx * map.cell_px - 0.5, y1 = ny * map.cell_px - 0.5;
  pls->imagefr(ptrs.data(), nx, ny, -0.5, x1, y1, -0.5, lo, hi, lo, hi, nullptr, nullptr);
  pls->col0(1);
  pls->box("bcnst", 0, 0, "bcnstv", 0, 0);
  pls->lab("image x (px)", "image y (px)", title.c_str());
  plot::HeatColorBar(*pls.pls, lo, hi, bar_label + " (clipped at the 95th percentile)", 0.04, 0.04);
}

std::string SafeName(const std::string& s) {
  std::string out;
  for (char c : s)
    out += (std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_') ? c : '_';
  return out.empty() ? "device" : out;
}

std::string FullText(const CalibrationReport& r) {
  std::string text = r.result->summary.FullReport();
  for (size_t d = 0; d < r.result->devices.size(); ++d) {
    const auto& m = r.result->devices[d].model;
    char line[400];
    std::snprintf(line, sizeof(line),
                  "%s: fx %.4f fy %.4f cx %.4f cy %.4f k1 %.6f k2 %.6f p1 %.7f p2 %.7f k3 %.6f\n",
                  r.result->devices[d].name.c_str(), m.fx(), m.fy(), m.cx(), m.cy(), m.k1(), m.k2(),
                  m.p1(), m.p2(), m.k3());
    text += line;
    const QuotedCovariance q = PreferredCovariance(*r.result, static_cast<int>(d));
    if (q.available) {
      const auto& c = q.covariance;
      std::snprintf(line, sizeof(line), "%s: 1-sigma fx %.4f fy %.4f cx %.4f cy %.4f (%s)\n",
                    r.result->devices[d].name.c_str(), std::sqrt(c(0, 0)), std::sqrt(c(1, 1)),
                    std::sqrt(c(2, 2)), std::sqrt(c(3, 3)), q.reason.c_str());
      text += line;
      if (q.view_correlated) {
        const auto& s = r.result->intrinsics_covariance[d];
        std::snprintf(line, sizeof(line),
                      "%s: 1-sigma, standard covariance (independent errors, optimistic here): fx "
                      "%.4f fy %.4f cx %.4f cy %.4f\n",
                      r.result->devices[d].name.c_str(), std::sqrt(s(0, 0)), std::sqrt(s(1, 1)),
                      std::sqrt(s(2, 2)), std::sqrt(s(3, 3)));
        text += line;
      }
    }
    if (d > 0) {
      const auto& t = r.result->devices[d].cam_from_rig;
      std::snprintf(line, sizeof(line), "%s: baseline to %s %.4f mm, t = (%.4f, %.4f, %.4f) mm\n",
                    r.result->devices[d].name.c_str(), r.result->devices[0].name.c_str(),
                    t.translation.norm(), t.translation.x(), t.translation.y(), t.translation.z());
      text += line;
    }
  }
  if (r.findings.empty()) text += "no findings: the data set looks sufficient\n";
  for (const auto& f : r.findings) text += f.Text() + "\n";
  return text;
}

}  // namespace

nlohmann::json CalibrationReportJson(const CalibrationReport& r) {
  SLSHADOW_CHECK(r.input && r.options && r.result);
  nlohmann::json j = CalibrationEvidenceToJson(*r.input, *r.options, *r.result, r.cross_validation);
  j["format"] = "slshadow-calibration-report";
  j["findings"] = nlohmann::json::array();
  for (const auto& f : r.findings) {
    j["findings"].push_back({{"severity", ToString(f.severity)},
                             {"device", f.device},
                             {"problem", f.problem},
                             {"advice", f.advice}});
  }
  j["devices_result"] = nlohmann::json::array();
  for (size_t d = 0; d < r.result->devices.size(); ++d) {
    const auto& dev = r.result->devices[d];
    nlohmann::json dj = {{"name", dev.name}, {"params", dev.model.params}};
    dj["cam_from_rig"] = PoseToJson(dev.cam_from_rig);
    const QuotedCovariance q = PreferredCovariance(*r.result, static_cast<int>(d));
    if (q.available) {
      std::vector<double> sigma, standard;
      for (int i = 0; i < CameraModel::kNumParams; ++i) {
        sigma.push_back(std::sqrt(q.covariance(i, i)));
        standard.push_back(std::sqrt(r.result->intrinsics_covariance[d](i, i)));
      }
      dj["params_sigma"] = sigma;  // from the covariance named in "covariance_used"
      dj["params_sigma_standard"] = standard;
      dj["covariance_used"] = q.view_correlated ? "view-correlated" : "standard";
      dj["covariance_reason"] = q.reason;
      const PixelMap u = ProjectionUncertaintyMap(dev.model, q.covariance, 16);
      auto num = [](double x) { return std::isfinite(x) ? nlohmann::json(x) : nlohmann::json(); };
      dj["projection_uncertainty"] = {{"median_px", num(u.median)},
                                      {"p95_px", num(u.p95)},
                                      {"max_px", num(u.max)},
                                      {"covariance", dj["covariance_used"]}};
    }
    j["devices_result"].push_back(dj);
  }
  j["extra"] = r.extra;
  return j;
}

void WriteCalibrationReport(const std::filesystem::path& dir, const CalibrationReport& r,
                            bool overwrite) {
  SLSHADOW_CHECK(r.input && r.options && r.result);
  const std::filesystem::path staged = TemporarySibling(dir);
  std::error_code created;
  std::filesystem::create_directories(staged, created);
  SLSHADOW_THROW_IF(created, staged.string(), ": cannot create folder: ", created.message());
  try {
    // Checked writes: a full disk fails the report instead of committing truncated text.
    WriteTextFileAtomically(staged / "summary.json", CalibrationReportJson(r).dump(2) + "\n");
    WriteTextFileAtomically(staged / "report.txt", FullText(r));
    PerViewChart(staged / "per_view_rms.png", r.result->summary);
    for (size_t d = 0; d < r.result->devices.size(); ++d) {
      const auto& dev = r.result->devices[d];
      const std::string name = SafeName(dev.name);
      ResidualChart(staged / ("residuals_" + name + ".png"), *r.input, *r.result,
                    static_cast<int>(d));
      const QuotedCovariance q = PreferredCovariance(*r.result, static_cast<int>(d));
      if (q.available && q.covariance.norm() > 0) {
        const PixelMap u = ProjectionUncertaintyMap(dev.model, q.covariance, 16);
        char title[240];
        std::snprintf(
            title, sizeof(title),
            "%s: projection uncertainty (1 sigma, worst direction, %s covariance), median %.3f px",
            dev.name.c_str(), q.view_correlated ? "view-correlated" : "standard", u.median);
        MapChart(staged / ("uncertainty_" + name + ".png"), u, dev.model.width, dev.model.height,
                 title, "px");
      }
      if (r.cross_validation && d < r.cross_validation->difference.size()) {
        const PixelMap& c = r.cross_validation->difference[d];
        char title[200];
        std::snprintf(title, sizeof(title),
                      "%s: cross-validation (even vs odd poses), median %.3f px", dev.name.c_str(),
                      c.median);
        MapChart(staged / ("cross_validation_" + name + ".png"), c, dev.model.width,
                 dev.model.height, title, "px");
      }
    }
    CommitDirectory(staged, dir, overwrite);
  } catch (...) {
    std::error_code ec;
    std::filesystem::remove_all(staged, ec);
    throw;
  }
}

}  // namespace slshadow
