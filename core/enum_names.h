// The names of an enum that appears in a file, on the command line or in a message, from one table
// (docs/conventions.md, "Enum names"; as COLMAP's MAKE_ENUM_CLASS and Ceres' StringTo... pairs).
// A module keeps its two free functions and writes them over a table of every value:
//
//   constexpr EnumName<TriangulationMethod> kTriangulationMethodNames[] = {
//       {TriangulationMethod::kMidpoint, "midpoint"}, {TriangulationMethod::kDlt, "dlt"}, ...};
//   std::string ToString(TriangulationMethod m) { return EnumToString(m,
//   kTriangulationMethodNames); } TriangulationMethod TriangulationMethodFromString(const
//   std::string& name) {
//     return EnumFromString("triangulation method", name, kTriangulationMethodNames);
//   }
//
// so every name error reads the same:
// `triangulation method: unknown name (got 'hartley'; expected midpoint, dlt or optimal)`.
// A table another file reads with (EnumFromConfig: a config reader elsewhere in the module) is
// declared `inline constexpr` in the enum's header, beside the two functions.
#pragma once

#include <cstddef>
#include <optional>
#include <string>

#include "core/error.h"

namespace slshadow {

template <typename E>
struct EnumName {
  E value;
  const char* name;
};

// The name of `value` in `names`; "unknown" for a value the table lacks (a bug: tables list
// every value).
template <typename E, size_t N>
std::string EnumToString(E value, const EnumName<E> (&names)[N]) {
  for (const EnumName<E>& n : names) {
    if (n.value == value) return n.name;
  }
  return "unknown";
}

// The value named `name` in `names`, or nothing.
template <typename E, size_t N>
std::optional<E> EnumFromStringIfKnown(const std::string& name, const EnumName<E> (&names)[N]) {
  for (const EnumName<E>& n : names) {
    if (name == n.name) return n.value;
  }
  return std::nullopt;
}

// The accepted names as a message lists them: "a", "a or b", "a, b or c".
template <typename E, size_t N>
std::string EnumNamesList(const EnumName<E> (&names)[N]) {
  std::string out;
  for (size_t i = 0; i < N; ++i) {
    if (i > 0) out += i + 1 == N ? " or " : ", ";
    out += names[i].name;
  }
  return out;
}

// "unknown name (got '<name>'; expected <EnumNamesList>)": the message of an unknown name, for
// callers that prefix it themselves (ConfigNode::Fail adds the file and the field).
template <typename E, size_t N>
std::string UnknownEnumName(const std::string& name, const EnumName<E> (&names)[N]) {
  return "unknown name (got '" + name + "'; expected " + EnumNamesList(names) + ")";
}

// The value named `name` in `names`; throws slshadow::Error
// "<what>: unknown name (got '<name>'; expected a, b or c)" for any other name.
template <typename E, size_t N>
E EnumFromString(const std::string& what, const std::string& name, const EnumName<E> (&names)[N]) {
  if (const std::optional<E> value = EnumFromStringIfKnown(name, names)) return *value;
  SLSHADOW_THROW(what, ": ", UnknownEnumName(name, names));
}

// The value a config field names (`node`: a ConfigNode, core/config.h); any other name fails
// through ConfigNode::Fail, which names the file and the field:
// `<file>: <field>: unknown name (expected a, b or c) (got "<name>")`.
template <typename Node, typename E, size_t N>
E EnumFromConfig(const Node& node, const EnumName<E> (&names)[N]) {
  if (const std::optional<E> value = EnumFromStringIfKnown(node.AsString(), names)) return *value;
  node.Fail("unknown name (expected " + EnumNamesList(names) + ")");
}

}  // namespace slshadow
