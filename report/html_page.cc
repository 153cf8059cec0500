// HTML building blocks of the report page (report/internal/html_page.h).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <set>

#include "core/file_util.h"
#include "plot/plot.h"
#include "report/internal/html_page.h"

namespace slshadow::report::internal {
namespace fs = std::filesystem;
using nlohmann::json;

std::string Joined(const char* const chunks[]) {
  std::string out;
  for (size_t i = 0; chunks[i] != nullptr; ++i) out += chunks[i];
  return out;
}

std::string HtmlEscape(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  for (const char c : text) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      case '\'':
        out += "&#39;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

std::string FormatNumber(double v) {
  if (!std::isfinite(v)) return std::isnan(v) ? "NaN" : (v > 0 ? "inf" : "-inf");
  char buf[64];
  if (v == std::trunc(v) && std::abs(v) < 1e15) {
    std::snprintf(buf, sizeof(buf), "%.0f", v);
  } else {
    std::snprintf(buf, sizeof(buf), "%.6g", v);
  }
  return buf;
}

namespace {

bool IsShortScalarList(const json& v) {
  if (!v.is_array() || v.size() > 16) return false;
  return std::all_of(v.begin(), v.end(), [](const json& e) { return e.is_primitive(); });
}

bool IsScalarList(const json& v) {
  return v.is_array() && !v.empty() &&
         std::all_of(v.begin(), v.end(), [](const json& e) { return e.is_primitive(); });
}

std::string Child(const std::string& pointer, const std::string& key) {
  std::string k;
  for (const char c : key) {
    if (c == '~') {
      k += "~0";
    } else if (c == '/') {
      k += "~1";
    } else {
      k += c;
    }
  }
  return pointer + "/" + k;
}

std::string Label(const std::string& key) {
  std::string out = key;
  std::replace(out.begin(), out.end(), '_', ' ');
  return out;
}

void FlattenRows(const json& object, const std::string& src, const std::string& pointer,
                 const std::string& prefix, const std::vector<std::string>& skip,
                 std::string* rows) {
  for (const auto& [key, v] : object.items()) {
    if (std::find(skip.begin(), skip.end(), key) != skip.end()) continue;
    const std::string p = Child(pointer, key);
    const std::string label = prefix.empty() ? Label(key) : prefix + " / " + Label(key);
    if (v.is_object()) {
      FlattenRows(v, src, p, label, {}, rows);
    } else if (v.is_primitive() || IsScalarList(v)) {
      *rows += "<tr><th>" + HtmlEscape(label) + "</th>" + ValueCell(v, src, p) + "</tr>\n";
    }
  }
}

std::string Nested(const json& v, const std::string& src, const std::string& pointer, int depth) {
  if (v.is_primitive() || IsScalarList(v) || depth > 8) return ValueCell(v, src, pointer);
  std::string out = "<td><table class=\"nested\">";
  if (v.is_object()) {
    for (const auto& [key, e] : v.items())
      out += "<tr><th>" + HtmlEscape(key) + "</th>" +
             Nested(e, src, Child(pointer, key), depth + 1) + "</tr>";
  } else {
    for (size_t i = 0; i < v.size(); ++i)
      out += "<tr><th>[" + std::to_string(i) + "]</th>" +
             Nested(v[i], src, Child(pointer, std::to_string(i)), depth + 1) + "</tr>";
  }
  return out + "</table></td>";
}

}  // namespace

std::string FormatValue(const json& v) {
  if (v.is_null()) return "null";
  if (v.is_boolean()) return v.get<bool>() ? "true" : "false";
  if (v.is_number()) return FormatNumber(v.get<double>());
  if (v.is_string()) return v.get<std::string>();
  if (IsShortScalarList(v)) {
    std::string out = "[";
    for (size_t i = 0; i < v.size(); ++i) out += (i ? ", " : "") + FormatValue(v[i]);
    return out + "]";
  }
  if (v.is_array()) return "(" + std::to_string(v.size()) + " values)";
  return "(" + std::to_string(v.size()) + " fields)";
}

std::string ValueCell(const json& v, const std::string& src, const std::string& pointer) {
  const bool number = v.is_number();
  return std::string("<td class=\"v") + (number ? " num" : "") + "\" title=\"" +
         HtmlEscape(src + " " + pointer) + "\" data-src=\"" + HtmlEscape(src) + "\" data-key=\"" +
         HtmlEscape(pointer) + "\" data-value=\"" + HtmlEscape(v.dump()) + "\">" +
         HtmlEscape(FormatValue(v)) + "</td>";
}

std::string KeyValueTable(const json& object, const std::string& src, const std::string& pointer,
                          const std::vector<std::string>& skip) {
  if (!object.is_object()) return "";
  std::string rows;
  FlattenRows(object, src, pointer, "", skip, &rows);
  if (rows.empty()) return "";
  return "<table class=\"kv\">\n" + rows + "</table>\n";
}

std::string ArrayTable(const json& array, const std::string& src, const std::string& pointer,
                       const std::vector<std::string>& skip) {
  if (!array.is_array() || array.empty()) return "";
  std::vector<std::string> columns;
  std::set<std::string> seen;
  for (const auto& e : array) {
    if (!e.is_object()) continue;
    for (const auto& [key, v] : e.items()) {
      if (std::find(skip.begin(), skip.end(), key) != skip.end()) continue;
      if ((v.is_primitive() || IsShortScalarList(v)) && seen.insert(key).second)
        columns.push_back(key);
    }
  }
  if (columns.empty()) return "";
  // A row's name first (JSON objects list their keys alphabetically).
  std::stable_partition(columns.begin(), columns.end(), [](const std::string& c) {
    return c == "name" || c == "mode" || c == "camera" || c == "cause";
  });
  std::string out = "<table class=\"grid\">\n<tr>";
  for (const auto& c : columns) out += "<th>" + HtmlEscape(Label(c)) + "</th>";
  out += "</tr>\n";
  for (size_t i = 0; i < array.size(); ++i) {
    out += "<tr>";
    const std::string row = Child(pointer, std::to_string(i));
    for (const auto& c : columns) {
      if (array[i].is_object() && array[i].contains(c)) {
        out += ValueCell(array[i][c], src, Child(row, c));
      } else {
        out += "<td></td>";
      }
    }
    out += "</tr>\n";
  }
  return out + "</table>\n";
}

std::string FullRecord(const json& j, const std::string& src, const std::string& title) {
  return "<details class=\"record\"><summary>" + HtmlEscape(title) +
         "</summary>\n<table class=\"nested top\"><tr><th>" + HtmlEscape(src) + "</th>" +
         Nested(j, src, "", 0) + "</tr></table></details>\n";
}

std::string ColourBarHtml(const ColourScale& scale, const std::string& layer_id) {
  std::string gradient = "linear-gradient(to top";
  for (int k = 0; k <= 8; ++k) {
    const auto c = plot::HeatColor(k / 8.0);
    gradient += ", rgb(" + std::to_string(c[0]) + "," + std::to_string(c[1]) + "," +
                std::to_string(c[2]) + ") " + std::to_string(k * 100 / 8) + "%";
  }
  gradient += ")";
  const double range = scale.hi > scale.lo ? scale.hi - scale.lo : 1.0;
  std::string out =
      "<div class=\"cbar\" data-layer=\"" + HtmlEscape(layer_id) + "\"><div class=\"cbar-title\">" +
      HtmlEscape(scale.label) +
      "</div><div class=\"cbar-body\"><div class=\"cbar-grad\" style=\"background:" + gradient +
      "\"></div>";
  for (int k = 0; k <= 4; ++k) {
    const double v = scale.lo + range * k / 4.0;
    out += "<span class=\"tick\" style=\"bottom:" + std::to_string(k * 25) + "%\">" +
           HtmlEscape(FormatNumber(std::abs(v) < 1e-12 * range ? 0.0 : v)) + "</span>";
  }
  for (const double m : scale.marks) {
    if (!(m > scale.lo && m < scale.hi)) continue;
    char pct[32];
    std::snprintf(pct, sizeof(pct), "%.3f", 100.0 * (m - scale.lo) / range);
    out += "<div class=\"mark\" style=\"bottom:" + std::string(pct) + "%\" title=\"" +
           HtmlEscape(FormatNumber(m)) + " mm\"></div>";
  }
  out += "</div>";
  if (!scale.note.empty()) out += "<div class=\"cbar-note\">" + HtmlEscape(scale.note) + "</div>";
  return out + "</div>\n";
}

std::string ImageFigure(const fs::path& png, const std::string& caption,
                        std::vector<std::string>* notes) {
  std::error_code ec;
  if (!fs::exists(png, ec)) {
    const std::string note = png.filename().string() + " is missing";
    if (notes) notes->push_back(note);
    return "<figure class=\"missing\"><figcaption>" + HtmlEscape(caption) + ": " +
           HtmlEscape(note) + "</figcaption></figure>\n";
  }
  const std::string bytes = ReadTextFile(png);
  return "<figure><img alt=\"" + HtmlEscape(caption) + "\" src=\"data:image/png;base64," +
         Base64(bytes.data(), bytes.size()) + "\"><figcaption>" + HtmlEscape(caption) +
         "</figcaption></figure>\n";
}

}  // namespace slshadow::report::internal
