// What workflows/studies/sweep_merge.cc and workflows/studies/whole_part.cc share to write a
// study's tables and Pareto fronts: CSV fields, job labels, the front of time against one figure
// and its chart. Included only by those two and workflows/studies/sweep_pareto.cc.
#pragma once

#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <vector>

namespace slshadow::studies::internal {

// A JSON value as a CSV field: floats with `digits` significant digits (17: exact round trip),
// null empty, quoted when needed.
std::string CsvField(const nlohmann::json& v, int digits = 10);

// The axis values of a job as a label ("graycode_phase 4 midpoint", or named: "codec=graycode_phase
// steps=4 triangulation=midpoint"), `skip` left out; files axes by their file's stem, not their
// path (scene.yaml, rig.yaml, patterns.yaml by their folder's name).
std::string ParamsLabel(const nlohmann::json& params, const std::vector<std::string>& axes,
                        const std::string& skip, bool named = false);

// Per group (the mode, or the mode and a value of the study's `pareto.by` axis): a job is on the
// Pareto front of (time, figure) when no other job of that group is at least as fast and as good
// and better in one of the two.
struct FrontPoint {
  std::string id, mode, group, label;
  std::string described;  // the axes as name=value
  std::string key;        // on the front: its group's letter and rank by time ("P1"), else empty
  double time_s = 0;
  double value = 0;  // the figure: RMS mm (lower is better) or a coverage (higher is better)
  bool on_front = false;
};

// Marks the front of each group: lower values are better, or higher with `higher_is_better`.
void MarkFront(std::vector<FrontPoint>& points, bool higher_is_better = false);
// The indices of the front's points in key order: by group (in order of appearance), then by
// time, fastest first.
std::vector<size_t> FrontInKeyOrder(const std::vector<FrontPoint>& points);
// Keys of the front's points: per group a letter (the mode's initial, "P" and "S", when the groups
// are the modes and their initials differ; else A, B, ...), then the rank by time, fastest 1.
void KeyFront(std::vector<FrontPoint>& points);

// What a front chart says: its axes' labels, its title after the study's name, and the unit after
// a point's figure in the key lines ("0.123 s  0.0456 mm").
struct FrontChartText {
  std::string x_label = "decode (cameras the mode reads) + reconstruct time (s)";
  std::string y_label = "RMS deviation (mm)";
  std::string title = "time against error";
  std::string value_unit = " mm";
};

// The chart as `path`.png and `path`.svg (the same drawing), each written atomically: every job
// of every group, the front's points filled, joined and marked with their keys, and below the
// chart one line per key: its time, figure and combination.
void WriteFrontChart(const std::filesystem::path& path, const std::vector<FrontPoint>& points,
                     const std::string& study, const FrontChartText& text);

}  // namespace slshadow::studies::internal
