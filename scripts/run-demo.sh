#!/usr/bin/env bash
# Sets up (Debian packages), builds, and runs the main job on the embedded demo.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
BUILD_DIR=${SLSHADOW_BUILD_DIR:-build}
# ccache: rewrite absolute paths relative to the checkout so clones in other folders share hits.
export CCACHE_BASEDIR="$PWD" CCACHE_NOHASHDIR=true
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build "$BUILD_DIR" -j2 --target slshadow
"$BUILD_DIR/apps/slshadow" demo --out "${SLSHADOW_DEMO_OUT:-out/demo}"
