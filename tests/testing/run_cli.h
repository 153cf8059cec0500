// Runs `slshadow ARGS...` through the command table in-process, as a user's command line would
// (tests linking slshadow::app). Returns the exit code main() would.
#pragma once

#include <string>
#include <vector>

#include "apps/commands.h"

namespace slshadow::testing {

inline int RunCli(std::vector<std::string> args) {
  args.insert(args.begin(), "slshadow");
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  return app::Main(static_cast<int>(argv.size()), argv.data());
}

}  // namespace slshadow::testing
