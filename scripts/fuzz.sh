#!/usr/bin/env bash
# Runs one libFuzzer harness of fuzz/ (docs/fuzzing.md) for SECONDS, niced, from its seed corpus.
#   scripts/fuzz.sh NAME [SECONDS] [extra libFuzzer flags...]
# NAME is a harness (rig, scene, pattern_spec, target, devices, manifest, ply, stl, obj, npy,
# image, opencv_calibration). The clang build folder (default build-fuzz, $SLSHADOW_FUZZ_BUILD_DIR) is
# configured and the harness built when needed. The growing corpus stays in
# <build>/fuzz/corpus/NAME, crashes land in <build>/fuzz/artifacts/NAME/, the log in
# <build>/fuzz/logs/NAME.log; the last lines printed are libFuzzer's final stats (executions,
# coverage as "cov" edges and "ft" features).
set -euo pipefail
cd "$(dirname "$0")/.."
NAME=${1:?usage: scripts/fuzz.sh NAME [SECONDS] [libFuzzer flags...]}
SECONDS_TO_RUN=${2:-60}
shift $(( $# >= 2 ? 2 : 1 ))
BUILD_DIR=${SLSHADOW_FUZZ_BUILD_DIR:-build-fuzz}
export CCACHE_BASEDIR="$PWD" CCACHE_NOHASHDIR=true
if [ ! -f "$BUILD_DIR/build.ninja" ]; then
  cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_CXX_COMPILER=clang++ -DCMAKE_BUILD_TYPE=Release \
    -DCMAKE_CXX_FLAGS_RELEASE="-O1 -DNDEBUG" -DSLSHADOW_BUILD_TESTS=OFF -DSLSHADOW_BUILD_BENCHMARKS=OFF \
    -DSLSHADOW_BUILD_FUZZERS=ON
fi
cmake --build "$BUILD_DIR" -j2 --target "fuzz_$NAME"
F="$BUILD_DIR/fuzz"
mkdir -p "$F/corpus/$NAME" "$F/artifacts/$NAME" "$F/logs"
DICT=()
if [ -f "fuzz/dict/$NAME.dict" ]; then DICT=(-dict="fuzz/dict/$NAME.dict"); fi
set +e
nice -n 10 "$F/fuzz_$NAME" -max_total_time="$SECONDS_TO_RUN" -rss_limit_mb=2048 -timeout=20 \
  -print_final_stats=1 "${DICT[@]}" -artifact_prefix="$F/artifacts/$NAME/" "$@" \
  "$F/corpus/$NAME" "$F/seeds/$NAME" >"$F/logs/$NAME.log" 2>&1
rc=$?
set -e
grep -E "^#[0-9]+ +(DONE|INITED)|^stat::number_of_executed_units|^stat::peak_rss_mb|ERROR|SUMMARY" "$F/logs/$NAME.log" | tail -8
exit $rc
