// Errors in slshadow follow a three-tier policy (DESIGN.md "Errors"):
//  (a) a broken internal invariant is a bug: SLSHADOW_CHECK aborts with file:line;
//  (b) bad input at a library boundary (file, config field, argument) throws slshadow::Error
//      whose message names the file, the field and the offending value;
//  (c) an expected numerical failure (pixel in shadow, ray miss, no convergence) is a mask,
//      std::optional or a count, never an exception.
#pragma once

#include <sstream>
#include <stdexcept>
#include <string>

namespace slshadow {

// Bad input. what() is one line meant for the user: "FILE: FIELD: problem (got VALUE)".
class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& message) : std::runtime_error(message) {}
};

namespace internal {
[[noreturn]] void CheckFailed(const char* file, int line, const char* expr, const std::string& msg);

template <typename... Args>
std::string Concat(const Args&... args) {
  std::ostringstream out;
  (out << ... << args);
  return out.str();
}
}  // namespace internal

}  // namespace slshadow

// Internal invariant; aborts (tier a).
#define SLSHADOW_CHECK(expr)                                                       \
  do {                                                                             \
    if (!(expr)) ::slshadow::internal::CheckFailed(__FILE__, __LINE__, #expr, ""); \
  } while (0)

// Bad input (tier b): throws slshadow::Error with the concatenated message parts.
#define SLSHADOW_THROW(...) throw ::slshadow::Error(::slshadow::internal::Concat(__VA_ARGS__))

#define SLSHADOW_THROW_IF(cond, ...)       \
  do {                                     \
    if (cond) SLSHADOW_THROW(__VA_ARGS__); \
  } while (0)
