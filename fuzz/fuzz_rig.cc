// libFuzzer harness for the rig reader (fuzz/readers.h, docs/fuzzing.md).
#include "fuzz/readers.h"

SLSHADOW_FUZZ_HARNESS(ReadRigBytes)
