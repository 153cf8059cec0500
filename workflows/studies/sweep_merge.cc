// MergeSweep (workflows/studies/sweep.h): every job's result into results.csv / .json, timings.csv,
// the time-against-error chart with its Pareto front, and the charts and tables of the study keys
// curves, effects, vdi2634 and monte_carlo.
#include "compare/compare.h"
#include "core/error.h"
#include "core/file_util.h"
#include "plot/plot.h"
#include "workflows/pipeline/significance.h"
#include "workflows/studies/internal/sweep_files.h"
#include "workflows/studies/internal/sweep_pareto.h"
#include "workflows/studies/montecarlo.h"
#include "workflows/studies/sweep.h"
#include "workflows/studies/vdi2634.h"
#include "workflows/studies/whole_part.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <initializer_list>
#include <limits>
#include <map>
#include <string>
#include <vector>

namespace slshadow::studies {
namespace fs = std::filesystem;
using nlohmann::json;
using namespace internal;  // NOLINT: the jobs folder's formats,
                           // workflows/studies/internal/sweep_files.h

namespace {

// One curve: a metric of one mode and one combination of the other axes, against the x axis.
struct Curve {
  std::string series, mode;
  std::vector<std::pair<double, json>> points;  // (x, the mode's accuracy), worst last
};

// Where a curve first crosses `limit`: linearly interpolated between the last x inside and the
// first x beyond; "at_first" when the first x is already beyond, "never" when no x is.
struct BreakPoint {
  std::string status;
  double x = 0;
};
// A figure of a mode's accuracy; NaN when the job has none (null: nothing was reconstructed).
double Figure(const json& accuracy, const std::string& metric) {
  const json& v = accuracy.at(metric);
  return v.is_null() ? std::numeric_limits<double>::quiet_NaN() : v.get<double>();
}

// A curve is beyond its limit where the figure is past it or missing (no cloud: broken). The break
// is linearly interpolated between the last x inside and the first beyond (in the curve's order,
// the perturbation growing) when both figures exist, else at that first x beyond.
BreakPoint FindBreak(const Curve& c, const std::string& metric, double limit) {
  const bool above = BreaksAbove(metric);
  const auto beyond = [&](double v) { return std::isnan(v) || (above ? v > limit : v < limit); };
  for (size_t i = 0; i < c.points.size(); ++i) {
    const double v = Figure(c.points[i].second, metric);
    if (!beyond(v)) continue;
    if (i == 0) return {"at_first", c.points[0].first};
    const double x0 = c.points[i - 1].first, x1 = c.points[i].first;
    const double v0 = Figure(c.points[i - 1].second, metric);
    const double t = !std::isnan(v) && v != v0 ? (limit - v0) / (v - v0) : 1.0;
    return {"broke", x0 + std::clamp(t, 0.0, 1.0) * (x1 - x0)};
  }
  return {"never", 0};
}

// curves_<metric>.png / .svg for each metric: every curve, the limit as a dashed line.
void WriteCurveCharts(const fs::path& out_dir, const std::vector<Curve>& curves,
                      const std::string& x_axis, const std::vector<std::string>& metrics,
                      const json& limits, const std::string& study) {
  const auto lock = plot::LockPlplot();
  const std::initializer_list<std::array<int, 3>> palette = {
      {40, 90, 200}, {200, 60, 0}, {30, 150, 60}, {150, 40, 160}, {120, 120, 120}, {220, 160, 0}};
  for (const std::string& metric : metrics) {
    double xmin = 1e300, xmax = -1e300, ymax = 0;
    for (const auto& c : curves) {
      for (const auto& [x, m] : c.points) {
        xmin = std::min(xmin, x);
        xmax = std::max(xmax, x);
        const double v = Figure(m, metric);
        if (!std::isnan(v)) ymax = std::max(ymax, v);
      }
    }
    if (limits.contains(metric)) ymax = std::max(ymax, limits.at(metric).get<double>());
    if (!(xmax > xmin)) xmax = xmin + 1;
    const double ytop = metric.find("coverage") != std::string::npos ? 1.05 : ymax * 1.15 + 1e-12;
    for (const char* ext : {".png", ".svg"}) {
      const fs::path file = out_dir / ("curves_" + metric + ext);
      WriteFileAtomically(file, [&](const fs::path& tmp) {
        auto pls = std::string(ext) == ".png" ? plot::OpenPng(tmp, 1000, 700, palette)
                                              : plot::OpenSvg(tmp, 1000, 700, palette);
        pls->env(xmin, xmax, 0, ytop, 0, 0);
        pls->lab(x_axis.c_str(), metric.c_str(),
                 (study + ": " + metric + " against " + x_axis).c_str());
        if (limits.contains(metric)) {
          const PLFLT lx[2] = {xmin, xmax};
          const PLFLT ly[2] = {limits.at(metric).get<double>(), limits.at(metric).get<double>()};
          pls->lsty(3);
          pls->line(2, lx, ly);
          pls->lsty(1);
        }
        for (size_t k = 0; k < curves.size(); ++k) {
          const Curve& c = curves[k];
          std::vector<PLFLT> xs, ys;
          for (const auto& [x, m] : c.points) {
            if (std::isnan(Figure(m, metric))) continue;  // nothing reconstructed: no point
            xs.push_back(x);
            ys.push_back(Figure(m, metric));
          }
          pls->col0(static_cast<PLINT>(2 + k % 6));
          pls->lsty(c.mode == "stereo" ? 2 : 1);
          if (!xs.empty()) pls->line(static_cast<PLINT>(xs.size()), xs.data(), ys.data());
          if (!xs.empty()) pls->poin(static_cast<PLINT>(xs.size()), xs.data(), ys.data(), 17);
          pls->lsty(1);
          pls->schr(0, 0.7);
          pls->mtex("t", -1.5 - 1.3 * static_cast<double>(k), 0.02, 0.0,
                    (c.series.empty() ? c.mode : c.series + ", " + c.mode).c_str());
          pls->schr(0, 1.0);
        }
      });
    }
  }
}

// A figure's standard uncertainty (`<metric>_sigma`): NaN when the job's result predates it or the
// cloud was too small for bands.
double FigureSigma(const json& accuracy, const std::string& metric) {
  const std::string key =
      metric.substr(0, metric.size() - 3) + "_sigma_mm";  // rms_mm -> rms_sigma_mm
  return accuracy.contains(key) ? Figure(accuracy, key) : std::nan("");
}

// A figure's values on the image bands (`<metric>` rms_mm -> rms_bands_mm); empty when the job's
// result predates them.
std::vector<double> FigureBands(const json& accuracy, const std::string& metric) {
  const std::string key = metric.substr(0, metric.size() - 3) + "_bands_mm";
  std::vector<double> bands;
  if (!accuracy.contains(key)) return bands;
  for (const json& v : accuracy.at(key))
    bands.push_back(v.is_null() ? std::nan("") : v.get<double>());
  return bands;
}

// A layer's effect on RMS and p95: figures of `with` minus those of `without`, judged by
// workflows/pipeline/significance.h (the rule `slshadow shadow` keeps fitted layers by): needed
// when either change exceeds max(3 sigma, tolerance). Sigma is that of the change: paired, from the
// change on each image band (BandSigma of the band differences) when both jobs have bands, else the
// two figures' uncertainties combined (unknown ones count as 0). A missing figure (nothing
// reconstructed on one side) is a change beyond any tolerance.
struct LayerEffect {
  double d_rms = 0, d_p95 = 0, threshold_rms = 0, threshold_p95 = 0;
  bool needed = false;
};
LayerEffect MeasureLayerEffect(const json& with, const json& without, double tolerance) {
  LayerEffect e;
  const auto one = [&](const std::string& metric, double* delta, double* threshold) {
    *delta = Figure(with, metric) - Figure(without, metric);
    const std::vector<double> a = FigureBands(with, metric), b = FigureBands(without, metric);
    double sigma = 0;
    if (!a.empty() && a.size() == b.size()) {
      std::vector<double> d(a.size());
      for (size_t i = 0; i < a.size(); ++i) d[i] = a[i] - b[i];
      sigma = pipeline::BandSigma(d);
    } else {
      const auto known = [](double s) { return std::isnan(s) ? 0.0 : s; };
      sigma = std::hypot(known(FigureSigma(with, metric)), known(FigureSigma(without, metric)));
    }
    if (std::isnan(sigma)) sigma = 0;
    *threshold = pipeline::SignificanceThreshold(sigma, tolerance);
    return std::isnan(*delta) || pipeline::Significant(*delta, sigma, tolerance);
  };
  const bool rms = one("rms_mm", &e.d_rms, &e.threshold_rms);
  const bool p95 = one("p95_mm", &e.d_p95, &e.threshold_p95);
  e.needed = rms || p95;
  return e;
}

std::string OptionalField(double v) { return std::isnan(v) ? "" : CsvField(json(v)); }

// Study 3 (study key `effects`): effects.csv (per job and mode: its figures, their
// uncertainties, the effect of its value against the baseline or, for one-layer-off values,
// of that layer in the full model) and layers.csv (per series, mode and value: both effects,
// whether the scene needs the value at the tolerance, and its cost).
void WriteEffects(const json& spec, const std::vector<std::string>& axes,
                  const std::vector<json>& results, const fs::path& out_dir,
                  SweepMergeSummary* summary) {
  const std::string axis = spec.at("axis").get<std::string>();
  const json& baseline = spec.at("baseline");
  const json full = spec.value("full", json());
  const double tolerance = spec.at("tolerance_mm").get<double>();
  // series + mode -> value -> the job's accuracy (and its timing)
  std::map<std::string, std::map<json, std::pair<json, json>>> jobs;
  const auto key = [](const std::string& series, const std::string& mode) {
    return series + '\n' + mode;
  };
  for (const auto& r : results) {
    for (const auto& m : r.at("modes")) {
      jobs[key(ParamsLabel(r.at("params"), axes, axis), m.at("mode").get<std::string>())]
          [r.at("params").at(axis)] = {m, r.at("timing")};
    }
  }
  const auto find = [&](const std::string& k, const json& value) -> const std::pair<json, json>* {
    const auto s = jobs.find(k);
    if (s == jobs.end()) return nullptr;
    const auto v = s->second.find(value);
    return v == s->second.end() ? nullptr : &v->second;
  };
  const auto without_label = [](const json& value) {
    return json("without_" + value.get<std::string>());
  };
  const auto is_off = [&](const json& value) {
    return !full.is_null() && value.is_string() &&
           value.get<std::string>().rfind("without_", 0) == 0;
  };
  // What the cost compares: the CPU seconds of the model (geometry + noise-free images + noise,
  // as if not reused) of jobs that record them, else their render seconds.
  const auto model_cpu_s = [](const json& timing) {
    return timing.contains("model_cpu_s") ? timing.at("model_cpu_s").get<double>()
                                          : timing.at("render_s").get<double>();
  };

  std::string effects = "series,mode," + CsvField(axis) +
                        ",kind,rms_mm,rms_sigma_mm,p95_mm,p95_sigma_mm,d_rms_mm,d_p95_mm,"
                        "threshold_rms_mm,threshold_p95_mm,needed,render_s,model_cpu_s\n";
  std::string layers = "series,mode," + CsvField(axis) +
                       ",alone_d_rms_mm,alone_d_p95_mm,alone_needed,off_d_rms_mm,off_d_p95_mm,"
                       "off_threshold_rms_mm,off_threshold_p95_mm,off_needed,needed,cost_ms\n";
  for (const auto& r : results) {
    const std::string series = ParamsLabel(r.at("params"), axes, axis);
    const json& value = r.at("params").at(axis);
    for (const auto& m : r.at("modes")) {
      const std::string mode = m.at("mode").get<std::string>();
      const std::string k = key(series, mode);
      std::string kind = "alone", d_rms, d_p95, t_rms, t_p95, needed;
      const std::pair<json, json>* against = find(k, baseline);
      if (value == baseline) {
        kind = "baseline";
        against = nullptr;
      } else if (!full.is_null() && value == full) {
        kind = "full";
      } else if (is_off(value)) {
        kind = "off";
        against = find(k, full);
      }
      if (against) {
        // alone / full: this job against the baseline; off: the full model against this job.
        const LayerEffect e = kind == "off" ? MeasureLayerEffect(against->first, m, tolerance)
                                            : MeasureLayerEffect(m, against->first, tolerance);
        d_rms = OptionalField(e.d_rms);
        d_p95 = OptionalField(e.d_p95);
        t_rms = OptionalField(e.threshold_rms);
        t_p95 = OptionalField(e.threshold_p95);
        needed = e.needed ? "1" : "0";
      }
      effects += CsvField(series) + ',' + mode + ',' + CsvField(value) + ',' + kind + ',' +
                 CsvField(m.at("rms_mm")) + ',' + OptionalField(FigureSigma(m, "rms_mm")) + ',' +
                 CsvField(m.at("p95_mm")) + ',' + OptionalField(FigureSigma(m, "p95_mm")) + ',' +
                 d_rms + ',' + d_p95 + ',' + t_rms + ',' + t_p95 + ',' + needed + ',' +
                 CsvField(r.at("timing").at("render_s")) + ',' +
                 CsvField(json(model_cpu_s(r.at("timing")))) + '\n';
      if (kind != "alone") continue;
      // The layer's row: alone against the baseline; off against the full model when planned.
      const std::pair<json, json>* base = find(k, baseline);
      if (!base) continue;
      const LayerEffect alone = MeasureLayerEffect(m, base->first, tolerance);
      const std::pair<json, json>* whole = full.is_null() ? nullptr : find(k, full);
      const std::pair<json, json>* off =
          whole && value.is_string() ? find(k, without_label(value)) : nullptr;
      std::string off_fields = ",,,,";  // the five off columns, empty without the full model
      LayerEffect shown = alone;
      double cost = model_cpu_s(r.at("timing")) - model_cpu_s(base->second);
      if (off) {
        shown = MeasureLayerEffect(whole->first, off->first, tolerance);
        off_fields = OptionalField(shown.d_rms) + ',' + OptionalField(shown.d_p95) + ',' +
                     OptionalField(shown.threshold_rms) + ',' + OptionalField(shown.threshold_p95) +
                     ',' + (shown.needed ? "1" : "0");
        cost = model_cpu_s(whole->second) - model_cpu_s(off->second);
      }
      layers += CsvField(series) + ',' + mode + ',' + CsvField(value) + ',' +
                OptionalField(alone.d_rms) + ',' + OptionalField(alone.d_p95) + ',' +
                (alone.needed ? "1" : "0") + ',' + off_fields + ',' + (shown.needed ? "1" : "0") +
                ',' + CsvField(json(1000 * cost), 4) + '\n';
      char figures[160];
      std::snprintf(figures, sizeof(figures), "RMS %+.4f mm, p95 %+.4f mm (thresholds %.4f, %.4f)",
                    shown.d_rms, shown.d_p95, shown.threshold_rms, shown.threshold_p95);
      char costs[48];
      std::snprintf(costs, sizeof(costs), "%.0f CPU ms", 1000 * cost);
      summary->effects.push_back((series.empty() ? "" : series + ", ") + mode + ": " +
                                 CsvField(value) + (shown.needed ? " needed" : " not needed") +
                                 " at " + CsvField(json(tolerance)) + " mm; " +
                                 (off ? "off in the full model" : "on alone") + ": " + figures +
                                 "; costs " + costs);
    }
  }
  WriteTextFileAtomically(out_dir / "effects.csv", effects);
  WriteTextFileAtomically(out_dir / "layers.csv", layers);
}

// A whole-part study's merge (workflows/studies/whole_part.h): results.json as any study's, its
// own results.csv, pareto.csv and charts, and timings.csv with the per-mode stages.
SweepMergeSummary MergeWholePart(const json& plan, const std::vector<std::string>& axes,
                                 const std::vector<json>& results, const fs::path& out_dir) {
  json merged = {
      {"format", "slshadow-sweep-results"},      {"version", kVersion}, {"study", plan.at("study")},
      {"study_config", plan.at("study_config")}, {"axes", axes},        {"jobs", json::array()}};
  std::vector<std::string> modes;
  for (const auto& m : results.at(0).at("modes")) modes.push_back(m.at("mode").get<std::string>());
  std::string timings = "id,render_s";
  for (const auto& m : modes) {
    for (const char* k : {"reconstruct_s", "merge_s", "cad_compare_s", "reference_s"})
      timings += ',' + m + '_' + k;
  }
  timings += ",total_s,cpu_s\n";
  for (const auto& r : results) {
    merged["jobs"].push_back(
        {{"id", r.at("id")}, {"params", r.at("params")}, {"modes", r.at("modes")}});
    const json& t = r.at("timing");
    timings += JobName(r.at("id").get<int>()) + ',' + CsvField(t.at("render_s"));
    for (const auto& m : modes) {
      for (const char* k : {"reconstruct_s", "merge_s", "cad_compare_s", "reference_s"})
        timings += ',' + CsvField(t.at(k).at(m));
    }
    timings += ',' + CsvField(t.at("total_s")) + ',' + CsvField(t.at("cpu_s")) + '\n';
  }
  std::error_code ec;
  fs::create_directories(out_dir, ec);
  SLSHADOW_THROW_IF(ec, out_dir.string(), ": cannot create folder: ", ec.message());
  WriteTextFileAtomically(out_dir / "results.json", merged.dump(2) + "\n");
  WriteTextFileAtomically(out_dir / "timings.csv", timings);
  const WholePartMerge whole =
      WriteWholePartResults(out_dir, axes, results, plan.at("study").get<std::string>());
  SweepMergeSummary summary;
  summary.whole_part = true;
  summary.rows = whole.rows;
  summary.front = whole.rms_front;
  summary.coverage_front = whole.coverage_front;
  summary.jobs = static_cast<int>(results.size());
  summary.out_dir = out_dir;
  return summary;
}

}  // namespace

SweepMergeSummary MergeSweep(const fs::path& jobs_dir, const fs::path& out_dir) {
  const json plan = ReadPlan(jobs_dir);
  const int n = plan.at("jobs").get<int>();
  const std::vector<std::string> axes = plan.at("axes").get<std::vector<std::string>>();
  std::vector<json> results;
  std::vector<std::string> missing;
  for (int id = 0; id < n; ++id) {
    std::error_code ec;
    const fs::path file = ResultFile(jobs_dir, id);
    if (!fs::exists(file, ec)) {
      missing.push_back(JobName(id));
      continue;
    }
    json r = ReadJsonFile(file);
    SLSHADOW_THROW_IF(
        !r.is_object() || r.value("format", "") != kResultFormat || r.value("id", -1) != id,
        file.string(), ": not the result of job ", id);
    results.push_back(std::move(r));
  }
  if (!missing.empty()) {
    std::string list;
    for (size_t i = 0; i < missing.size() && i < 10; ++i) {
      if (i) list += ", ";
      list += missing[i];
    }
    SLSHADOW_THROW(jobs_dir.string(), ": ", missing.size(), " of ", n, " jobs have no result (",
                   list, missing.size() > 10 ? ", ..." : "", "); run their shards first");
  }
  if (plan.value("whole_part", false)) return MergeWholePart(plan, axes, results, out_dir);

  const std::vector<std::string> metrics = {"points",  "coverage", "visible_coverage",
                                            "mean_mm", "rms_mm",   "p95_mm",
                                            "max_mm",  "outliers", "outlier_fraction"};
  std::string csv = "id";
  for (const auto& a : axes) {
    csv += ',';
    csv += CsvField(a);
  }
  csv += ",mode";
  for (const auto& m : metrics) {
    csv += ',';
    csv += m;
  }
  csv += "\n";
  std::string timings =
      "id,setup_s,render_s,decode_s,reconstruct_s,compare_s,total_s,cpu_s,setup_cpu_s,render_cpu_s,"
      "decode_cpu_s,reconstruct_cpu_s,compare_cpu_s\n";
  json merged = {
      {"format", "slshadow-sweep-results"},      {"version", kVersion}, {"study", plan.at("study")},
      {"study_config", plan.at("study_config")}, {"axes", axes},        {"jobs", json::array()}};
  SweepMergeSummary summary;
  for (const auto& r : results) {
    const std::string id = JobName(r.at("id").get<int>());
    for (const auto& m : r.at("modes")) {
      csv += id;
      for (const auto& a : axes) {
        csv += ',';
        csv += CsvField(r.at("params").at(a));
      }
      csv += ',';
      csv += CsvField(m.at("mode"));
      for (const auto& k : metrics) {
        csv += ',';
        csv += CsvField(m.at(k));
      }
      csv += "\n";
      ++summary.rows;
    }
    const json& t = r.at("timing");
    timings += id;
    for (const char* k :
         {"setup_s", "render_s", "decode_s", "reconstruct_s", "compare_s", "total_s", "cpu_s",
          "setup_cpu_s", "render_cpu_s", "decode_cpu_s", "reconstruct_cpu_s", "compare_cpu_s"}) {
      timings += ',';
      timings += t.contains(k) ? CsvField(t.at(k)) : std::string();  // older results: empty
    }
    timings += "\n";
    merged["jobs"].push_back(
        {{"id", r.at("id")}, {"params", r.at("params")}, {"modes", r.at("modes")}});
  }
  std::error_code ec;
  fs::create_directories(out_dir, ec);
  SLSHADOW_THROW_IF(ec, out_dir.string(), ": cannot create folder: ", ec.message());
  WriteTextFileAtomically(out_dir / "results.csv", csv);
  WriteTextFileAtomically(out_dir / "results.json", merged.dump(2) + "\n");
  WriteTextFileAtomically(out_dir / "timings.csv", timings);

  // Time against error: decode + reconstruct time (the method's cost; rendering and comparing are
  // the study's) against RMS, per mode, with the Pareto front. Measured times: not reproducible.
  const json& config = plan.at("study_config");
  const json pareto_spec = config.value("pareto", json::object());
  const std::string by = pareto_spec.value("by", std::string());
  // Wall seconds by default; CPU seconds (all threads) with pareto.time: cpu, which a loaded
  // machine disturbs less. Results from before method_cpu_s have only wall seconds.
  const bool cpu_time = pareto_spec.value("time", std::string("wall")) == "cpu";
  std::vector<FrontPoint> points;
  for (const auto& r : results) {
    const std::string label = ParamsLabel(r.at("params"), axes, by);
    const std::string by_value = by.empty() ? "" : ParamsLabel(r.at("params"), {by}, "");
    const json& t = r.at("timing");
    for (const auto& m : r.at("modes")) {
      if (m.at("rms_mm").is_null()) continue;  // nothing reconstructed: not on the chart
      FrontPoint p;
      p.id = JobName(r.at("id").get<int>());
      p.mode = m.at("mode").get<std::string>();
      p.label = label.empty() ? p.id : label;
      p.described = label.empty() ? "job " + p.id : ParamsLabel(r.at("params"), axes, by, true);
      p.group = by.empty() ? p.mode : p.mode + " " + by_value;
      p.time_s = t.at(cpu_time && t.contains("method_cpu_s") ? "method_cpu_s" : "method_s")
                     .at(p.mode)
                     .get<double>();
      p.value = m.at("rms_mm").get<double>();
      points.push_back(p);
    }
  }
  MarkFront(points);
  KeyFront(points);
  std::string front_csv =
      std::string("id,mode,label,time_s,rms_mm,on_front") + (by.empty() ? "" : ",group") + ",key\n";
  for (const auto& p : points) {
    front_csv += p.id + ',' + p.mode + ',' + CsvField(p.label) + ',' + CsvField(p.time_s, 17) +
                 ',' + CsvField(p.value, 17) + ',' + (p.on_front ? "1" : "0") +
                 (by.empty() ? "" : "," + CsvField(p.group)) + ',' + p.key + '\n';
  }
  for (const size_t i : FrontInKeyOrder(points)) {
    const FrontPoint& p = points[i];
    summary.front.push_back(p.key + " " + p.group + ": " + p.id + " (" + p.described + ")");
  }
  WriteTextFileAtomically(out_dir / "pareto.csv", front_csv);
  FrontChartText chart;
  if (cpu_time)
    chart.x_label = "decode (cameras the mode reads) + reconstruct, CPU s (all threads)";
  WriteFrontChart(out_dir / "time_vs_rms", points, plan.at("study").get<std::string>(), chart);

  // Curves against one axis and break points (study key `curves`): from the accuracy figures
  // only, so as reproducible as results.csv.
  if (config.contains("curves")) {
    const json& spec = config.at("curves");
    const std::string x_axis = spec.at("x").get<std::string>();
    const json limits = spec.value("limits", json::object());
    std::vector<std::string> metrics;
    for (const auto& m : kCurveMetrics) {
      if (limits.contains(m)) metrics.push_back(m);
    }
    if (metrics.empty()) metrics = {"p95_mm", "visible_coverage"};
    std::vector<Curve> curves;
    std::map<std::string, size_t> index;
    for (const auto& r : results) {
      const std::string series = ParamsLabel(r.at("params"), axes, x_axis);
      const double x = r.at("params").at(x_axis).get<double>();
      for (const auto& m : r.at("modes")) {
        const std::string mode = m.at("mode").get<std::string>();
        const auto it = index.emplace(series + '\n' + mode, curves.size()).first;
        if (it->second == curves.size()) curves.push_back({series, mode, {}});
        curves[it->second].points.emplace_back(x, m);
      }
    }
    // Points in the order the perturbation grows: by increasing x, or decreasing with
    // `worse: decreasing` (e.g. albedo: darker is worse).
    const bool decreasing = spec.value("worse", std::string("increasing")) == "decreasing";
    for (auto& c : curves) {
      std::stable_sort(c.points.begin(), c.points.end(), [&](const auto& a, const auto& b) {
        return decreasing ? a.first > b.first : a.first < b.first;
      });
    }
    std::string breaks = "series,mode,metric,limit,status," + CsvField(x_axis) + "\n";
    for (const auto& c : curves) {
      for (const auto& metric : metrics) {
        if (!limits.contains(metric)) continue;
        const double limit = limits.at(metric).get<double>();
        const BreakPoint b = FindBreak(c, metric, limit);
        breaks += CsvField(c.series) + ',' + c.mode + ',' + metric + ',' + CsvField(json(limit)) +
                  ',' + b.status + ',' + (b.status == "never" ? "" : CsvField(json(b.x))) + '\n';
        summary.break_points.push_back(
            (c.series.empty() ? "" : c.series + ", ") + c.mode + ": " + metric +
            (BreaksAbove(metric) ? " > " : " < ") + CsvField(json(limit)) + " " +
            (b.status == "never" ? "nowhere in the sweep"
                                 : (b.status == "at_first" ? "already at " : "at ") + x_axis +
                                       " = " + CsvField(json(b.x), 4)));
      }
    }
    WriteTextFileAtomically(out_dir / "break_points.csv", breaks);
    WriteCurveCharts(out_dir, curves, x_axis, metrics, limits, plan.at("study").get<std::string>());
  }
  // Effects of one axis's values against a baseline value, and with `full`, of each value
  // switched off in the full model (study key `effects`).
  if (config.contains("effects"))
    WriteEffects(config.at("effects"), axes, results, out_dir, &summary);
  // Study 5: the acceptance test's table, summary and chart.
  if (plan.contains("vdi2634")) {
    std::vector<Vdi2634Row> rows;
    for (const auto& r : results) {
      for (const auto& m : r.at("modes")) {
        rows.push_back({JobName(r.at("id").get<int>()),
                        ParamsLabel(r.at("params"), axes, "position"),
                        r.at("params").at("position").get<std::string>(),
                        m.at("mode").get<std::string>(), m.value("vdi2634", json())});
      }
    }
    summary.acceptance =
        WriteVdi2634Results(out_dir, rows, plan.at("vdi2634"), plan.at("study").get<std::string>());
  }
  // Study 4: the uncertainty from the samples' grids, checked against the replicates.
  if (plan.contains("monte_carlo")) {
    std::vector<int> ids;
    std::vector<std::string> sets;
    for (const auto& r : results) {
      ids.push_back(r.at("id").get<int>());
      sets.push_back(r.at("monte_carlo").at("set").get<std::string>());
    }
    summary.uncertainty = WriteMonteCarloResults(
        jobs_dir, out_dir, ids, sets, results.at(0).at("monte_carlo").at("viewpoint_in_rig_mm"),
        plan.at("study").get<std::string>());
  }
  summary.jobs = n;
  summary.out_dir = out_dir;
  return summary;
}

}  // namespace slshadow::studies
