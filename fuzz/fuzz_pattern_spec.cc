// libFuzzer harness for the pattern_spec reader (fuzz/readers.h, docs/fuzzing.md).
#include "fuzz/readers.h"

SLSHADOW_FUZZ_HARNESS(ReadPatternSpecBytes)
