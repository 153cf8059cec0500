// The message of the slshadow::Error that `f` throws, or "" when it throws none: for tests that
// check a bad input's one-line error word for word.
#pragma once

#include <functional>
#include <string>

#include <gtest/gtest.h>

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

// The exception of type E (e.g. a device error carrying its fault kind) that `f` throws; a test
// failure and `none` when it throws none.
template <typename E>
E ExceptionOf(const std::function<void()>& f, E none) {
  try {
    f();
  } catch (const E& e) {
    return e;
  }
  ADD_FAILURE() << "no exception of the expected type thrown";
  return none;
}

}  // namespace slshadow::testing
