// libFuzzer harness for the opencv_calibration reader (fuzz/readers.h, docs/fuzzing.md).
#include "fuzz/readers.h"

SLSHADOW_FUZZ_HARNESS(ReadOpenCvCalibrationBytes)
