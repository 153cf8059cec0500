// Reading configuration files (YAML or JSON) with errors that name the file, the field and the
// value. Every loader in slshadow (rig, scene, pattern spec, target, ImageSet manifest) reads
// through ConfigNode, so a missing or malformed field always reads like
//   config/demo/rig.yaml: cameras[1].intrinsics.fx: must be positive (got -3)
#pragma once

#include <filesystem>
#include <initializer_list>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace slshadow {

class ConfigNode {
 public:
  // Parses a .yaml/.yml or .json file. Throws slshadow::Error when it cannot be read or parsed.
  static ConfigNode LoadFile(const std::filesystem::path& path);
  // Parses YAML text; `file` is only used in messages.
  static ConfigNode ParseYaml(const std::string& text, const std::string& file);
  // Wraps an already parsed tree; `file` and `path` are only used in messages.
  static ConfigNode FromJson(nlohmann::json json, const std::string& file,
                             const std::string& path = "");

  const std::string& file() const { return *file_; }
  // Dotted field path from the root, e.g. "cameras[1].intrinsics.fx" (empty for the root).
  const std::string& path() const { return path_; }
  const nlohmann::json& json() const { return *json_; }

  bool IsObject() const { return json_->is_object(); }
  bool IsArray() const { return json_->is_array(); }
  bool Has(const std::string& key) const;
  // Required member; throws "file: path.key: missing" when absent.
  ConfigNode operator[](const std::string& key) const;
  // Array element; throws when out of range or not an array.
  ConfigNode at(size_t index) const;
  size_t size() const;                    // number of array elements (throws if not an array)
  std::vector<std::string> Keys() const;  // object keys (throws if not an object)

  // Typed values. Numbers must be finite; AsInt rejects fractions.
  double AsDouble() const;
  int64_t AsInt() const;
  bool AsBool() const;
  std::string AsString() const;
  std::vector<double> AsDoubles(size_t expected_size = 0) const;  // 0: any size

  // Optional members with defaults.
  double GetDouble(const std::string& key, double fallback) const;
  int64_t GetInt(const std::string& key, int64_t fallback) const;
  bool GetBool(const std::string& key, bool fallback) const;
  std::string GetString(const std::string& key, const std::string& fallback) const;

  // Throws naming the first key of this object that is not in `allowed` (catches typos such as
  // an unknown layer name instead of silently ignoring them).
  void RejectUnknownKeys(std::initializer_list<const char*> allowed) const;
  void RejectUnknownKeys(const std::vector<std::string>& allowed) const;

  // Throws slshadow::Error: "file: path: problem (got value)".
  [[noreturn]] void Fail(const std::string& problem) const;

 private:
  ConfigNode(std::shared_ptr<const nlohmann::json> root, const nlohmann::json* json,
             std::shared_ptr<const std::string> file, std::string path);
  std::string Describe() const;

  std::shared_ptr<const nlohmann::json> root_;  // keeps the tree alive
  const nlohmann::json* json_;
  std::shared_ptr<const std::string> file_;
  std::string path_;
};

// Converts a JSON tree to YAML text (block style; numbers with full round-trip precision).
std::string JsonToYaml(const nlohmann::json& json);

}  // namespace slshadow
