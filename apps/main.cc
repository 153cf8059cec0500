#include "apps/commands.h"
#include "core/file_util.h"
#include "core/huge_pages.h"

int main(int argc, char** argv) {
  // Large buffers on transparent huge pages: re-executes this program once with glibc's tunable
  // set (core/huge_pages.h), before anything else happens.
  slshadow::ReexecWithHugePages(argv);
  // Ctrl-C or SIGTERM removes unfinished outputs and leaves existing files untouched.
  slshadow::InstallInterruptCleanup();
  return slshadow::app::Main(argc, argv);
}
