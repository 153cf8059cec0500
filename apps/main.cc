#include "apps/commands.h"

int main(int argc, char** argv) { return slshadow::app::Main(argc, argv); }
