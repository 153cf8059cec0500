#include "core/config.h"

#include <cmath>
#include <fstream>
#include <sstream>

#include <yaml-cpp/yaml.h>

#include "core/error.h"
#include "core/file_util.h"

namespace slshadow {
namespace {

// yaml-cpp keeps scalars untyped; quoted scalars carry the tag "!". Plain scalars become null,
// booleans, integers or doubles when they parse as such (YAML 1.2 core schema), else strings.
nlohmann::json ScalarToJson(const YAML::Node& node) {
  const std::string& s = node.Scalar();
  if (node.Tag() == "!") return s;
  if (s.empty() || s == "~" || s == "null" || s == "Null" || s == "NULL") return nullptr;
  if (s == "true" || s == "True" || s == "TRUE") return true;
  if (s == "false" || s == "False" || s == "FALSE") return false;
  if (s == ".nan" || s == ".NaN" || s == ".NAN") return std::nan("");
  if (s == ".inf" || s == "+.inf" || s == ".Inf") return HUGE_VAL;
  if (s == "-.inf" || s == "-.Inf") return -HUGE_VAL;
  {
    std::istringstream in(s);
    long long i;
    if (in >> i && in.eof()) return i;
  }
  {
    char* end = nullptr;
    const double d = std::strtod(s.c_str(), &end);
    if (end != s.c_str() && *end == '\0') return d;
  }
  return s;
}

nlohmann::json YamlToJson(const YAML::Node& node) {
  switch (node.Type()) {
    case YAML::NodeType::Null:
    case YAML::NodeType::Undefined:
      return nullptr;
    case YAML::NodeType::Scalar:
      return ScalarToJson(node);
    case YAML::NodeType::Sequence: {
      nlohmann::json out = nlohmann::json::array();
      for (const auto& child : node) out.push_back(YamlToJson(child));
      return out;
    }
    case YAML::NodeType::Map: {
      nlohmann::json out = nlohmann::json::object();
      for (const auto& kv : node) out[kv.first.as<std::string>()] = YamlToJson(kv.second);
      return out;
    }
  }
  return nullptr;
}

// Offset of the first byte that is not part of a well-formed UTF-8 sequence, or npos.
size_t FirstInvalidUtf8(const std::string& text) {
  const auto* p = reinterpret_cast<const unsigned char*>(text.data());
  const size_t n = text.size();
  for (size_t i = 0; i < n;) {
    const unsigned char c = p[i];
    size_t len = 0;
    uint32_t cp = 0;
    if (c < 0x80) {
      ++i;
      continue;
    } else if ((c & 0xE0) == 0xC0) {
      len = 2, cp = c & 0x1Fu;
    } else if ((c & 0xF0) == 0xE0) {
      len = 3, cp = c & 0x0Fu;
    } else if ((c & 0xF8) == 0xF0) {
      len = 4, cp = c & 0x07u;
    } else {
      return i;
    }
    if (i + len > n) return i;
    for (size_t k = 1; k < len; ++k) {
      if ((p[i + k] & 0xC0) != 0x80) return i;
      cp = (cp << 6) | (p[i + k] & 0x3Fu);
    }
    const uint32_t min_cp = len == 2 ? 0x80 : len == 3 ? 0x800 : 0x10000;
    if (cp < min_cp || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return i;
    i += len;
  }
  return std::string::npos;
}

std::string Abbreviate(const nlohmann::json& json) {
  if (json.is_number_float() && !std::isfinite(json.get<double>())) {
    const double v = json.get<double>();
    return std::isnan(v) ? "NaN" : (v > 0 ? "inf" : "-inf");
  }
  // Invalid UTF-8 in a value is shown replaced (U+FFFD) rather than failing the message.
  std::string s = json.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  if (s.size() > 60) s = s.substr(0, 57) + "...";
  return s;
}

void EmitYaml(const nlohmann::json& json, YAML::Emitter& out) {
  if (json.is_object()) {
    out << YAML::BeginMap;
    for (auto it = json.begin(); it != json.end(); ++it) {
      out << YAML::Key << it.key() << YAML::Value;
      EmitYaml(it.value(), out);
    }
    out << YAML::EndMap;
  } else if (json.is_array()) {
    bool flat = true;
    for (const auto& v : json) flat = flat && v.is_primitive();
    if (flat) out << YAML::Flow;
    out << YAML::BeginSeq;
    for (const auto& v : json) EmitYaml(v, out);
    out << YAML::EndSeq;
  } else if (json.is_string()) {
    out << YAML::DoubleQuoted << json.get<std::string>();
  } else if (json.is_boolean()) {
    out << (json.get<bool>() ? "true" : "false");
  } else if (json.is_number_integer()) {
    out << json.get<long long>();
  } else if (json.is_number_unsigned()) {
    out << json.get<unsigned long long>();
  } else if (json.is_number_float()) {
    std::ostringstream s;
    s.precision(17);
    s << json.get<double>();
    std::string str = s.str();
    if (str.find_first_of(".eEn") == std::string::npos) str += ".0";
    out << str;
  } else {
    out << YAML::Null;
  }
}

}  // namespace

ConfigNode::ConfigNode(std::shared_ptr<const nlohmann::json> root, const nlohmann::json* json,
                       std::shared_ptr<const std::string> file, std::string path)
    : root_(std::move(root)), json_(json), file_(std::move(file)), path_(std::move(path)) {}

ConfigNode ConfigNode::FromJson(nlohmann::json json, const std::string& file,
                                const std::string& path) {
  auto root = std::make_shared<const nlohmann::json>(std::move(json));
  return ConfigNode(root, root.get(), std::make_shared<const std::string>(file), path);
}

ConfigNode ConfigNode::ParseYaml(const std::string& text, const std::string& file) {
  // Text must be UTF-8 (as JSON's is): every string read here may be written back into JSON.
  if (const size_t bad = FirstInvalidUtf8(text); bad != std::string::npos) {
    SLSHADOW_THROW(file, ": not valid UTF-8 text (byte ", bad, ")");
  }
  nlohmann::json json;
  try {
    // A mapping key that is itself a list or mapping fails in YamlToJson's as<std::string>().
    json = YamlToJson(YAML::Load(text));
  } catch (const YAML::Exception& e) {
    if (e.mark.is_null()) SLSHADOW_THROW(file, ": not valid YAML: ", e.msg);
    SLSHADOW_THROW(file, ": not valid YAML at line ", e.mark.line + 1, ", column ",
                   e.mark.column + 1, ": ", e.msg);
  }
  return FromJson(std::move(json), file);
}

ConfigNode ConfigNode::LoadFile(const std::filesystem::path& path) {
  const std::string text = ReadTextFile(path);
  const std::string ext = path.extension().string();
  if (ext == ".json") {
    try {
      return FromJson(nlohmann::json::parse(text), path.string());
    } catch (const nlohmann::json::exception& e) {  // parse_error, or out_of_range for 1e309
      SLSHADOW_THROW(path.string(), ": not valid JSON: ", e.what());
    }
  }
  return ParseYaml(text, path.string());
}

std::string ConfigNode::Describe() const {
  return *file_ + ": " + (path_.empty() ? std::string("(top level)") : path_);
}

void ConfigNode::Fail(const std::string& problem) const {
  SLSHADOW_THROW(Describe(), ": ", problem, " (got ", Abbreviate(*json_), ")");
}

bool ConfigNode::Has(const std::string& key) const {
  return json_->is_object() && json_->contains(key) && !(*json_)[key].is_null();
}

ConfigNode ConfigNode::operator[](const std::string& key) const {
  if (!json_->is_object()) Fail("expected a mapping with field '" + key + "'");
  const std::string child_path = path_.empty() ? key : path_ + "." + key;
  auto it = json_->find(key);
  if (it == json_->end() || it->is_null()) {
    SLSHADOW_THROW(*file_, ": ", child_path, ": missing required field");
  }
  return ConfigNode(root_, &*it, file_, child_path);
}

ConfigNode ConfigNode::at(size_t index) const {
  if (!json_->is_array()) Fail("expected a list");
  if (index >= json_->size()) {
    SLSHADOW_THROW(Describe(), ": list has ", json_->size(), " entries, entry ", index,
                   " is missing");
  }
  return ConfigNode(root_, &(*json_)[index], file_, path_ + "[" + std::to_string(index) + "]");
}

size_t ConfigNode::size() const {
  if (!json_->is_array()) Fail("expected a list");
  return json_->size();
}

std::vector<std::string> ConfigNode::Keys() const {
  if (!json_->is_object()) Fail("expected a mapping");
  std::vector<std::string> keys;
  for (auto it = json_->begin(); it != json_->end(); ++it) keys.push_back(it.key());
  return keys;
}

double ConfigNode::AsDouble() const {
  if (!json_->is_number()) Fail("expected a number");
  const double v = json_->get<double>();
  if (!std::isfinite(v)) Fail("must be a finite number");
  return v;
}

int64_t ConfigNode::AsInt() const {
  if (json_->is_number_integer() || json_->is_number_unsigned()) return json_->get<int64_t>();
  if (json_->is_number_float()) {
    const double v = json_->get<double>();
    if (std::isfinite(v) && v == std::floor(v) && std::abs(v) < 9e15)
      return static_cast<int64_t>(v);
  }
  Fail("expected a whole number");
}

bool ConfigNode::AsBool() const {
  if (!json_->is_boolean()) Fail("expected true or false");
  return json_->get<bool>();
}

std::string ConfigNode::AsString() const {
  if (!json_->is_string()) Fail("expected a string");
  return json_->get<std::string>();
}

std::vector<double> ConfigNode::AsDoubles(size_t expected_size) const {
  if (!json_->is_array()) Fail("expected a list of numbers");
  if (expected_size != 0 && json_->size() != expected_size) {
    Fail("expected a list of " + std::to_string(expected_size) + " numbers");
  }
  std::vector<double> out;
  for (size_t i = 0; i < json_->size(); ++i) out.push_back(at(i).AsDouble());
  return out;
}

double ConfigNode::GetDouble(const std::string& key, double fallback) const {
  return Has(key) ? (*this)[key].AsDouble() : fallback;
}
int64_t ConfigNode::GetInt(const std::string& key, int64_t fallback) const {
  return Has(key) ? (*this)[key].AsInt() : fallback;
}
bool ConfigNode::GetBool(const std::string& key, bool fallback) const {
  return Has(key) ? (*this)[key].AsBool() : fallback;
}
std::string ConfigNode::GetString(const std::string& key, const std::string& fallback) const {
  return Has(key) ? (*this)[key].AsString() : fallback;
}

void ConfigNode::RejectUnknownKeys(const std::vector<std::string>& allowed) const {
  if (!json_->is_object()) Fail("expected a mapping");
  for (auto it = json_->begin(); it != json_->end(); ++it) {
    bool known = false;
    for (const auto& a : allowed) known = known || it.key() == a;
    if (!known) {
      std::string list;
      for (const auto& a : allowed) list += (list.empty() ? "" : ", ") + a;
      SLSHADOW_THROW(*file_, ": ", path_.empty() ? it.key() : path_ + "." + it.key(),
                     ": unknown field (known fields here: ", list, ")");
    }
  }
}

void ConfigNode::RejectUnknownKeys(std::initializer_list<const char*> allowed) const {
  RejectUnknownKeys(std::vector<std::string>(allowed.begin(), allowed.end()));
}

std::string JsonToYaml(const nlohmann::json& json) {
  YAML::Emitter out;
  out.SetIndent(2);
  EmitYaml(json, out);
  return std::string(out.c_str()) + "\n";
}

}  // namespace slshadow
