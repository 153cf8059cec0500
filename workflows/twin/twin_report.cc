// The report folder of `slshadow shadow` (workflows/twin/internal/twin_report.h) and the text
// summary (ShadowResult::Summary).
#include "workflows/twin/internal/twin_report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <utility>

#include "compare/charts.h"
#include "compare/statistics.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/image_io.h"
#include "core/string_printf.h"
#include "plot/plot.h"
#include "workflows/twin/twin.h"

namespace slshadow::twin {
namespace fs = std::filesystem;

namespace internal {
namespace {

// A camera-image map (CV_32FC1, NaN where unknown) as a chart with a colour bar: symmetric at the
// 99th percentile of |value| over the finite pixels (at least `floor`), `marks` drawn on the bar
// and described by `mark_note`. Returns the colour range used.
double WriteMapChart(const fs::path& path, const cv::Mat& values, const std::string& title,
                     const std::string& unit, const std::vector<double>& marks,
                     const std::string& mark_note, double floor) {
  compare::ValueImage img;
  img.width = values.cols;
  img.height = values.rows;
  img.values.assign(values.begin<float>(), values.end<float>());
  std::vector<float> finite;
  for (size_t i = 0; i < img.values.size(); i += 7) {
    if (std::isfinite(img.values[i])) finite.push_back(std::abs(img.values[i]));
  }
  double range = floor;
  if (!finite.empty()) {
    const size_t k =
        std::min(finite.size() - 1, static_cast<size_t>(0.99 * static_cast<double>(finite.size())));
    std::nth_element(finite.begin(), finite.begin() + static_cast<std::ptrdiff_t>(k), finite.end());
    range = std::max(floor, static_cast<double>(finite[k]));
  }
  compare::MapChart chart;
  chart.title = title;
  chart.colorbar_label = unit;
  chart.lo = -range;
  chart.hi = range;
  chart.marks = marks;
  chart.max_width_px = 640;  // smaller than compare's maps: four maps per camera, block means
  chart.max_height_px = 440;
  char buf[160];
  std::snprintf(buf, sizeof(buf), "range +-%.3g (99 %% of pixels); white: not compared", range);
  chart.notes = {buf};
  bool any_in = false;
  for (double m : marks) any_in = any_in || std::abs(m) < range;
  if (!mark_note.empty())
    chart.notes.push_back(mark_note + (any_in ? ": lines on the bar" : ": beyond the range"));
  compare::WriteDeviationMapPng(path, img, chart);
  return range;
}

// Per frame, per camera: the share of compared pixels within 5 % of full scale (points joined by
// lines, one colour per camera), the 95 % goal dashed.
void WriteFrameAgreementChart(const fs::path& path, const nlohmann::json& cameras) {
  const auto lock = plot::LockPlplot();
  WriteFileAtomically(path, [&](const fs::path& tmp) {
    auto pls = plot::OpenPng(tmp, 1100, 600,
                             {{200, 30, 30}, {30, 90, 200}, {30, 150, 60}, {120, 120, 120}});
    size_t frames = 0;
    double lowest = 95;
    for (const auto& c : cameras) {
      frames = std::max(frames, c["patterns"].size());
      for (const auto& f : c["patterns"])
        lowest = std::min(lowest, 100 * f["within_5pct"].get<double>());
    }
    const double ymin = std::max(0.0, std::floor((lowest - 2) / 5) * 5 - 0.15 * (100 - lowest));
    pls->env(-0.5, static_cast<double>(frames) - 0.5, ymin, 100.5, 0, 0);
    pls->lab("frame (spec order)", "pixels within 5 % of full scale (%)",
             "real vs twin intensity, per frame");
    const PLFLT gx[2] = {-0.5, static_cast<double>(frames) - 0.5}, gy[2] = {95, 95};
    pls->col0(5);
    pls->lsty(2);
    pls->line(2, gx, gy);
    pls->lsty(1);
    for (size_t c = 0; c < cameras.size(); ++c) {
      std::vector<PLFLT> x, y;
      for (const auto& f : cameras[c]["patterns"]) {
        x.push_back(f["index"].get<double>());
        y.push_back(100 * f["within_5pct"].get<double>());
      }
      pls->col0(static_cast<PLINT>(2 + c % 3));
      pls->line(static_cast<PLINT>(x.size()), x.data(), y.data());
      pls->poin(static_cast<PLINT>(x.size()), x.data(), y.data(), 17);
      char name[128];
      std::snprintf(name, sizeof(name), "%s: %.1f %% over all frames",
                    cameras[c]["camera"].get<std::string>().c_str(),
                    100 * cameras[c]["within_5pct_all_frames"].get<double>());
      pls->mtex("b", -1.0 - 1.3 * static_cast<double>(cameras.size() - 1 - c), 0.98, 1.0, name);
    }
    pls->col0(5);
    pls->mtex("b", -1.0, 0.02, 0.0, "dashed: the 95 % goal");
  });
}

}  // namespace

void WriteShadowMaps(const fs::path& maps_dir, const std::vector<std::string>& cameras,
                     const PatternSpec& spec, const DiagnoseOptions& diagnose, double fs_dn,
                     const ShadowMaps& maps, nlohmann::json* maps_json) {
  for (size_t c = 0; c < cameras.size(); ++c) {
    const std::string& n = cameras[c];
    const double cal = diagnose.calibration_field_px;
    const double residual_range = WriteMapChart(
        maps_dir / (n + "_projector_residual.png"), maps.residual[c],
        n + ": decoded projector " + (spec.code_x ? "x" : "y") + " - twin truth", "projector px",
        {-cal, cal}, "+-" + StringPrintf("%.2f", cal) + " px (calibration-field threshold)", 0.05);
    const double white_range =
        WriteMapChart(maps_dir / (n + "_white_difference.png"), maps.white_difference[c],
                      n + ": white level, real - twin", "DN", {-0.05 * fs_dn, 0.05 * fs_dn},
                      "+-" + StringPrintf("%.4g", 0.05 * fs_dn) + " DN (5 % of full scale)", 1.0);
    cv::Mat ratio = maps.modulation[c] - 1.0f;
    const double mr = diagnose.multipath_ratio;
    const double modulation_range = WriteMapChart(
        maps_dir / (n + "_modulation_ratio.png"), ratio, n + ": fringe modulation, real / twin - 1",
        "relative", {mr - 1}, StringPrintf("%.2f", mr - 1) + " (multipath threshold)", 0.05);
    WriteImage(maps_dir / (n + "_validity.png"), maps.validity[c]);
    maps_json->push_back(
        {{"camera", n},
         {"projector_residual", "maps/" + n + "_projector_residual.png"},
         {"projector_residual_range_px", residual_range},
         {"white_difference", "maps/" + n + "_white_difference.png"},
         {"white_difference_range_dn", white_range},
         {"modulation_ratio", "maps/" + n + "_modulation_ratio.png"},
         {"modulation_ratio_range", modulation_range},
         {"validity", "maps/" + n + "_validity.png"},
         {"validity_legend",
          "green: valid in both; red: real only; blue: twin only; black: neither"}});
  }
}

void WriteShadowClouds(const fs::path& clouds_dir, std::vector<ModeClouds>* clouds) {
  for (auto& mc : *clouds) {
    std::vector<float> d(mc.real_c2m.begin(), mc.real_c2m.end());
    mc.real.SetScalar("c2m_part_mm", std::move(d));
    WritePly(clouds_dir / ("real_" + mc.mode + ".ply"), mc.real);
    std::vector<float> e(mc.twin_c2m.begin(), mc.twin_c2m.end());
    mc.twin.SetScalar("c2m_part_mm", std::move(e));
    WritePly(clouds_dir / ("twin_" + mc.mode + ".ply"), mc.twin);
  }
}

void WriteShadowCharts(const fs::path& staging, const std::vector<ModeClouds>& clouds,
                       const std::vector<std::vector<double>>& mode_diffs,
                       const std::vector<double>& mode_lod95, nlohmann::json* report_json) {
  nlohmann::json& report = *report_json;
  WriteFrameAgreementChart(staging / "charts" / "intensity_per_frame.png",
                           report["images"]["cameras"]);
  report["charts"] = {{"intensity_per_frame", "charts/intensity_per_frame.png"}};
  for (size_t m = 0; m < clouds.size(); ++m) {
    std::vector<double> finite;
    for (double d : mode_diffs[m]) {
      if (std::isfinite(d)) finite.push_back(d);
    }
    if (finite.size() < 10) continue;
    const compare::DistanceStats st = compare::ComputeStats(finite, true, mode_lod95[m], 60);
    compare::HistogramChart hc;
    hc.title = clouds[m].mode + ": real - twin deviation from the part";
    hc.x_label = "real C2M - twin C2M at the nearest twin point (mm)";
    hc.is_signed = true;
    hc.threshold_mm = mode_lod95[m];
    const double beyond = 100.0 * static_cast<double>(st.outliers) / static_cast<double>(st.count);
    hc.notes = {std::to_string(st.count) + " points on the part",
                "RMS " + StringPrintf("%.4f mm", st.rms_mm),
                "dashed: LoD95 " + StringPrintf("%.4f mm", mode_lod95[m]),
                "beyond LoD95: " + StringPrintf("%.2f %%", beyond)};
    const std::string file = "charts/real_vs_twin_" + clouds[m].mode + ".png";
    compare::WriteHistogramPng(staging / file, st.histogram, hc);
    report["charts"]["real_vs_twin_" + clouds[m].mode] = file;
  }
}

nlohmann::json StagesToJson(const std::vector<StageMeasurement>& stages) {
  nlohmann::json out = nlohmann::json::array();
  for (const auto& s : stages) {
    out.push_back({{"name", s.name},
                   {"wall_s", s.wall_s},
                   {"cpu_s", s.cpu_s},
                   {"peak_rss_mb", s.peak_rss_mb}});
  }
  return out;
}

}  // namespace internal

std::string ShadowResult::Summary() const {
  std::string out = "slshadow shadow: " + report.value("image_set", std::string()) + " vs part " +
                    report.value("part", std::string()) + "\n\n";
  char buf[512];
  const auto& pose = report["pose"];
  std::snprintf(buf, sizeof(buf), "pose (%s): fitness %.3f, inlier RMSE %.4f mm",
                pose["source"].get<std::string>().c_str(), pose["fitness"].get<double>(),
                pose["inlier_rmse_mm"].get<double>());
  out += buf;
  if (pose.contains("registration") && !pose["registration"].value("ran", true))
    out += "; ICP not run: the given pose is within the refinement's basin";
  if (pose.contains("refinement")) {
    const auto& ref = pose["refinement"];
    const auto& u = ref["uncertainty"];
    std::snprintf(buf, sizeof(buf), "; uncertainty (1 sigma) %.4f mm, %.4f deg",
                  u["sigma_translation_mm"].get<double>(), u["sigma_rotation_deg"].get<double>());
    out += buf;
    if (ref.contains("moved_from_given")) {
      const auto& mv = ref["moved_from_given"];
      std::snprintf(buf, sizeof(buf),
                    "; moved %.4f mm, %.4f deg from the given pose (%.1f sigma)%s",
                    mv["translation_at_centre_mm"].get<double>(), mv["rotation_deg"].get<double>(),
                    mv["sigmas"].get<double>(),
                    ref["kept_start"].get<bool>() ? ", kept: no step improved on it" : "");
      out += buf;
    }
    for (const auto& w : u["weak_directions"])
      out += "\n  not constrained by the part's surface: " + w.get<std::string>();
  }
  out += "\n\n";
  out += "physics (layer, kept?, value +- sigma, why):\n" + physics.Table() + "\n";
  out += "images (per camera, over the twin's lit part pixels):\n";
  for (const auto& c : report["images"]["cameras"]) {
    const auto& pc = c["projector_coordinates"];
    std::snprintf(
        buf, sizeof(buf),
        "  %-8s intensity within 5%% FS: %.1f%% of pixel-frames (worst frame %.1f%%); decoded vs "
        "twin truth "
        "%.3f px RMS (twin's own decoding %.3f px), real vs twin decoded %.3f px RMS; valid both "
        "%lld, real only "
        "%lld, twin only %lld\n",
        c["camera"].get<std::string>().c_str(), 100 * c["within_5pct_all_frames"].get<double>(),
        100 * c["within_5pct_worst_frame"].get<double>(), pc["real_vs_truth_rms_px"].get<double>(),
        pc["twin_vs_truth_rms_px"].get<double>(), pc["real_vs_twin_decoded_rms_px"].get<double>(),
        static_cast<long long>(pc["valid_both"].get<int64_t>()),
        static_cast<long long>(pc["valid_real_only"].get<int64_t>()),
        static_cast<long long>(pc["valid_twin_only"].get<int64_t>()));
    out += buf;
  }
  out += "\nclouds (signed C2M to the part, mm):\n";
  for (const auto& m : report["clouds"]["modes"]) {
    std::snprintf(
        buf, sizeof(buf),
        "  %-9s real %7lld pts mean %+.4f RMS %.4f | twin %7lld pts mean %+.4f RMS %.4f | real - "
        "twin RMS %.4f, "
        "%.2f%% beyond LoD95 %.4f\n",
        m["mode"].get<std::string>().c_str(),
        static_cast<long long>(m["real_vs_part"]["count"].get<int64_t>()),
        m["real_vs_part"]["mean_mm"].get<double>(), m["real_vs_part"]["rms_mm"].get<double>(),
        static_cast<long long>(m["twin_vs_part"]["count"].get<int64_t>()),
        m["twin_vs_part"]["mean_mm"].get<double>(), m["twin_vs_part"]["rms_mm"].get<double>(),
        m["real_vs_twin"]["rms_mm"].get<double>(),
        100 * m["real_vs_twin_significant_fraction"].get<double>(), m["lod95_mm"].get<double>());
    out += buf;
  }
  out += "\n" + diagnosis.Summary();
  out += "\n" + FormatStageTable(stages);
  return out;
}

}  // namespace slshadow::twin
