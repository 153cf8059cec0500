#!/usr/bin/env bash
# Sets up (Debian packages), builds with warnings as errors, and runs the whole test suite.
# This is the README's test command and the only thing .ci/run calls.
#   scripts/run-tests.sh             Release build in build/, then a few seconds of every libFuzzer
#                                    harness (fuzz/, built in build-fuzz/ when clang is present)
#   scripts/run-tests.sh --sanitize  the whole suite built with AddressSanitizer + UBSan in
#                                    build-sanitize/ (docs/fuzzing.md "Sanitizers")
set -euo pipefail
cd "$(dirname "$0")/.."
SANITIZE=0
for arg in "$@"; do
  case "$arg" in
    --sanitize) SANITIZE=1 ;;
    *) echo "usage: scripts/run-tests.sh [--sanitize]" >&2; exit 2 ;;
  esac
done
bash scripts/setup.sh
# The shared data (../shared/data, read in place, never copied) is part of a prepared machine:
# the real-data tests fail without it. Each folder is checked against its SHA256SUMS here, so a
# missing or changed file is named before the build instead of failing tests one by one.
for data in kamino-procam-graycode opencv-charuco-tutorial opencv-stereo-chessboard; do
  if ! (cd "../shared/data/$data" 2>/dev/null && sha256sum --quiet --strict -c SHA256SUMS); then
    echo "run-tests: ../shared/data/$data is missing or differs from its SHA256SUMS" >&2
    exit 1
  fi
done
# The tree is formatted (.clang-format): a file that is not fails the run, listed by name; fix
# with scripts/format.sh --apply. SLSHADOW_CHECK_FORMAT=0 skips the check (e.g. mid-edit).
SLSHADOW_CHECK_FORMAT=${SLSHADOW_CHECK_FORMAT:-1}
if [ "$SLSHADOW_CHECK_FORMAT" = 1 ]; then
  bash scripts/format.sh --check
fi
# The suite, then every skipped GoogleTest case listed with its reason: a skip that is not on
# tests/skip_allowlist.txt fails the run (scripts/check_skips.py reads the XML reports).
run_ctest() {
  local dir=$1 timeout=$2
  rm -rf "$dir/gtest-results"
  mkdir -p "$dir/gtest-results"
  (cd "$dir" && GTEST_OUTPUT="xml:$PWD/gtest-results/" ctest --output-on-failure -j2 --timeout "$timeout")
  python3 scripts/check_skips.py "$dir/gtest-results" tests/skip_allowlist.txt
}
# ccache: rewrite absolute paths relative to the checkout so clones in other folders share hits.
export CCACHE_BASEDIR="$PWD" CCACHE_NOHASHDIR=true
if [ "$SANITIZE" = 1 ]; then
  BUILD_DIR=${SLSHADOW_BUILD_DIR:-build-sanitize}
  cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release -DCMAKE_CXX_FLAGS_RELEASE="-O2 -DNDEBUG" \
    -DSLSHADOW_WERROR=ON -DSLSHADOW_SANITIZE=ON -DSLSHADOW_BUILD_BENCHMARKS=OFF
  cmake --build "$BUILD_DIR" -j2
  # Leaks of third-party libraries at exit are suppressed by name (scripts/lsan.supp); any report
  # of ASan or UBSan fails the test that triggered it.
  export ASAN_OPTIONS="detect_leaks=1:abort_on_error=0:halt_on_error=1:detect_stack_use_after_return=0${ASAN_OPTIONS:+:$ASAN_OPTIONS}"
  export LSAN_OPTIONS="suppressions=$PWD/scripts/lsan.supp:print_suppressions=0${LSAN_OPTIONS:+:$LSAN_OPTIONS}"
  export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1${UBSAN_OPTIONS:+:$UBSAN_OPTIONS}"
  run_ctest "$BUILD_DIR" 3000
  exit 0
fi
BUILD_DIR=${SLSHADOW_BUILD_DIR:-build}
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release -DSLSHADOW_WERROR=ON
cmake --build "$BUILD_DIR" -j2
run_ctest "$BUILD_DIR" 1500
# Fuzz smoke: every harness for a few seconds from its seeds (clang's libFuzzer; skipped without).
if command -v clang++ >/dev/null; then
  FUZZ_DIR=${SLSHADOW_FUZZ_BUILD_DIR:-build-fuzz}
  cmake -S . -B "$FUZZ_DIR" -G Ninja -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_BUILD_TYPE=Release \
    -DCMAKE_CXX_FLAGS_RELEASE="-O1 -DNDEBUG" -DSLSHADOW_BUILD_TESTS=OFF -DSLSHADOW_BUILD_BENCHMARKS=OFF \
    -DSLSHADOW_BUILD_FUZZERS=ON
  cmake --build "$FUZZ_DIR" -j2 --target fuzzers
  (cd "$FUZZ_DIR" && ctest --output-on-failure -j2 -L fuzz_smoke)
else
  echo "run-tests: clang++ not found, fuzz smoke runs skipped"
fi
