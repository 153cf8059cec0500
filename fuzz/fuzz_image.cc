// libFuzzer harness for the image decoders of core/image_io.h (fuzz/readers.h, docs/fuzzing.md).
#include "fuzz/readers.h"

SLSHADOW_FUZZ_HARNESS(ReadImageBytes)
