// The Pareto fronts and labels of a study's merge (workflows/studies/internal/sweep_pareto.h).
#include "workflows/studies/internal/sweep_pareto.h"

#include "core/file_util.h"
#include "plot/plot.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <cstdio>
#include <initializer_list>

namespace slshadow::studies::internal {
namespace fs = std::filesystem;
using nlohmann::json;

std::string CsvField(const json& v, int digits) {
  std::string s;
  if (v.is_string()) {
    s = v.get<std::string>();
  } else if (v.is_null()) {
    s = "";  // a figure a job could not have (e.g. the error of an empty cloud)
  } else if (v.is_number_float()) {
    char buf[64];
    std::snprintf(buf, sizeof(buf), "%.*g", digits, v.get<double>());
    s = buf;
  } else {
    s = v.dump();
  }
  if (s.find_first_of(",\"\n") != std::string::npos) {
    std::string q = "\"";
    for (char c : s) q += (c == '"') ? std::string("\"\"") : std::string(1, c);
    q += '"';
    return q;
  }
  return s;
}

void MarkFront(std::vector<FrontPoint>& points, bool higher_is_better) {
  // As good: lower (or higher) or equal; better: strictly.
  const auto at_least = [&](double a, double b) { return higher_is_better ? a >= b : a <= b; };
  for (auto& p : points) {
    p.on_front = true;
    for (const auto& q : points) {
      if (q.group != p.group || &q == &p) continue;
      if (q.time_s <= p.time_s && at_least(q.value, p.value) &&
          (q.time_s < p.time_s || q.value != p.value)) {
        p.on_front = false;
        break;
      }
    }
  }
}

namespace {

// The groups in order of appearance.
std::vector<std::string> FrontGroups(const std::vector<FrontPoint>& points) {
  std::vector<std::string> groups;
  for (const auto& p : points) {
    if (std::find(groups.begin(), groups.end(), p.group) == groups.end()) groups.push_back(p.group);
  }
  return groups;
}

}  // namespace

std::vector<size_t> FrontInKeyOrder(const std::vector<FrontPoint>& points) {
  std::vector<size_t> front;
  for (const std::string& g : FrontGroups(points)) {
    const size_t first = front.size();
    for (size_t i = 0; i < points.size(); ++i) {
      if (points[i].group == g && points[i].on_front) front.push_back(i);
    }
    std::stable_sort(front.begin() + static_cast<std::ptrdiff_t>(first), front.end(),
                     [&](size_t a, size_t b) { return points[a].time_s < points[b].time_s; });
  }
  return front;
}

void KeyFront(std::vector<FrontPoint>& points) {
  const std::vector<std::string> groups = FrontGroups(points);
  std::vector<std::string> letters;
  for (size_t g = 0; g < groups.size(); ++g)
    letters.push_back(std::string(1, static_cast<char>('A' + g % 26)));
  bool initials = true;
  std::string seen;
  for (const auto& p : points) initials = initials && p.group == p.mode && !p.mode.empty();
  for (const auto& g : groups) {
    const char c =
        static_cast<char>(std::toupper(static_cast<unsigned char>(g.empty() ? '?' : g[0])));
    initials = initials && seen.find(c) == std::string::npos;
    seen += c;
  }
  if (initials) {
    for (size_t g = 0; g < groups.size(); ++g) letters[g] = std::string(1, seen[g]);
  }
  size_t rank = 0;
  const FrontPoint* previous = nullptr;
  for (const size_t i : FrontInKeyOrder(points)) {
    FrontPoint* p = &points[i];
    rank = previous && previous->group == p->group ? rank + 1 : 1;
    const size_t g =
        static_cast<size_t>(std::find(groups.begin(), groups.end(), p->group) - groups.begin());
    p->key = letters[g] + std::to_string(rank);
    previous = p;
  }
}

namespace {
constexpr std::initializer_list<std::array<int, 3>> kFrontPalette = {
    {40, 90, 200},   {200, 60, 0},  {30, 150, 60}, {150, 40, 160},
    {120, 120, 120}, {220, 160, 0}, {0, 170, 190}, {120, 60, 20}};

}  // namespace

void WriteFrontChart(const fs::path& path, const std::vector<FrontPoint>& points,
                     const std::string& study, const FrontChartText& text) {
  double xmax = 0, ymax = 0;
  for (const auto& p : points) {
    xmax = std::max(xmax, p.time_s);
    ymax = std::max(ymax, p.value);
  }
  const std::vector<std::string> groups = FrontGroups(points);
  std::vector<const FrontPoint*> keyed;  // in key order
  for (const size_t i : FrontInKeyOrder(points)) keyed.push_back(&points[i]);
  // 700 px for the chart, 20 px per key line below it.
  constexpr double kChart = 700, kLine = 20;
  const double height = kChart + kLine * static_cast<double>(keyed.size() + 1);
  const double bottom = (kChart * 0.12 + kLine * static_cast<double>(keyed.size() + 1)) / height;
  const double top = 1 - kChart * 0.1 / height;
  const auto lock = plot::LockPlplot();
  for (const char* ext : {".png", ".svg"}) {
    fs::path file = path;
    file += ext;
    WriteFileAtomically(file, [&](const fs::path& tmp) {
      const int h = static_cast<int>(height);
      auto pls = std::string(ext) == ".png" ? plot::OpenPng(tmp, 1000, h, kFrontPalette)
                                            : plot::OpenSvg(tmp, 1000, h, kFrontPalette);
      pls->adv(0);
      pls->vpor(0.12, 0.95, bottom, top);
      pls->wind(0, xmax * 1.1 + 1e-9, 0,
                ymax * (1.15 + 0.07 * static_cast<double>(groups.size() > 2 ? groups.size() : 0)) +
                    1e-12);
      pls->col0(1);
      pls->box("bcnst", 0, 0, "bcnstv", 0, 0);
      pls->lab(text.x_label.c_str(), text.y_label.c_str(), "");
      // The title, smaller when long: about 64 characters fit the page at full size.
      const std::string title =
          study + ": " + text.title + ", Pareto front per " +
          (points.empty() || points[0].group == points[0].mode ? "mode" : "group");
      pls->schr(0, std::min(1.0, 64.0 / static_cast<double>(title.size())));
      pls->mtex("t", 2.0, 0.5, 0.5, title.c_str());
      pls->schr(0, 1.0);
      for (size_t m = 0; m < groups.size(); ++m) {
        pls->col0(static_cast<PLINT>(2 + m % 8));
        std::vector<PLFLT> xs, ys;
        for (const FrontPoint* p : keyed) {
          if (p->group != groups[m]) continue;
          xs.push_back(p->time_s);
          ys.push_back(p->value);
        }
        if (xs.size() > 1) pls->line(static_cast<PLINT>(xs.size()), xs.data(), ys.data());
        for (const auto& p : points) {
          if (p.group != groups[m]) continue;
          PLFLT x = p.time_s, y = p.value;
          pls->ssym(0, p.on_front ? 2.5 : 1.0);
          pls->poin(1, &x, &y, p.on_front ? 17 : 4);
        }
        pls->schr(0, 0.75);
        for (const FrontPoint* p : keyed) {
          if (p->group == groups[m]) pls->ptex(p->time_s, p->value, 1, 0, -0.25, p->key.c_str());
        }
        pls->schr(0, groups.size() > 2 ? 0.75 : 1.0);
        pls->mtex("t", -1.5 - (groups.size() > 2 ? 1.2 : 1.5) * static_cast<double>(m), 0.98, 1.0,
                  (groups[m] + " (filled: on the front)").c_str());
      }
      // The key, in page coordinates below the chart: one line per key, its text in one piece
      // (columns would overlap for long group names), smaller when the longest line would not fit
      // (about 90 characters at 0.7 from the key's column to the page's edge).
      pls->vpor(0, 1, 0, 1);
      pls->wind(0, 1, 0, height);
      std::vector<std::string> lines;
      size_t longest = 1;
      for (const FrontPoint* p : keyed) {
        char figures[96];
        std::snprintf(figures, sizeof(figures), "%.3f s  %.4f%s", p->time_s, p->value,
                      text.value_unit.c_str());
        lines.push_back(p->group + "  " + figures + "  " + p->described);
        longest = std::max(longest, lines.back().size());
      }
      pls->schr(0, std::min(0.7, 0.7 * 90.0 / static_cast<double>(longest)));
      for (size_t k = 0; k < keyed.size(); ++k) {
        const FrontPoint& p = *keyed[k];
        const size_t m =
            static_cast<size_t>(std::find(groups.begin(), groups.end(), p.group) - groups.begin());
        pls->col0(static_cast<PLINT>(2 + m % 8));
        const double y = kLine * (static_cast<double>(keyed.size() - k) - 0.3);
        pls->ptex(0.03, y, 1, 0, 0, p.key.c_str());
        pls->col0(1);
        pls->ptex(0.08, y, 1, 0, 0, lines[k].c_str());
      }
    });
  }
}

std::string ParamsLabel(const json& params, const std::vector<std::string>& axes,
                        const std::string& skip, bool named) {
  std::string label;
  for (const auto& a : axes) {
    if (a == skip) continue;
    if (!label.empty()) label += ' ';
    if (named) label += a + '=';
    const json& v = params.at(a);
    if (v.is_string() && v.get<std::string>().find_first_of("/.") != std::string::npos) {
      // config/demo/scene.yaml reads better as its folder's name.
      const fs::path file(v.get<std::string>());
      const std::string stem = file.stem().string();
      label += (stem == "scene" || stem == "rig" || stem == "patterns") &&
                       !file.parent_path().filename().empty()
                   ? file.parent_path().filename().string()
                   : stem;
    } else {
      label += CsvField(v);
    }
  }
  return label;
}

}  // namespace slshadow::studies::internal
