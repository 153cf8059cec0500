#include "core/error.h"

#include <cstdio>
#include <cstdlib>

namespace slshadow::internal {

void CheckFailed(const char* file, int line, const char* expr, const std::string& msg) {
  std::fprintf(stderr, "slshadow internal error at %s:%d: check failed: %s %s\n", file, line, expr,
               msg.c_str());
  std::abort();
}

}  // namespace slshadow::internal
