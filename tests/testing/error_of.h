// The message of the slshadow::Error that `f` throws, or "" when it throws none: for tests that
// check a bad input's one-line error word for word.
#pragma once

#include <functional>
#include <string>

#include "core/error.h"

namespace slshadow::testing {

inline std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

}  // namespace slshadow::testing
