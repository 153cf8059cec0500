#include "apps/commands.h"
#include "core/file_util.h"

int main(int argc, char** argv) {
  // Ctrl-C or SIGTERM removes unfinished outputs and leaves existing files untouched.
  slshadow::InstallInterruptCleanup();
  return slshadow::app::Main(argc, argv);
}
