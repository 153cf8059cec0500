// libFuzzer harness for the stl reader (fuzz/readers.h, docs/fuzzing.md).
#include "fuzz/readers.h"

SLSHADOW_FUZZ_HARNESS(ReadStlBytes)
