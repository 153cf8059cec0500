#!/usr/bin/env bash
# Regenerates tests/reconstruct/data/kamino_slshadow_rig.yaml, a regression fixture: slshadow's own
# projector-camera calibration of ../shared/data/kamino-procam-graycode (five poses), its
# calibration evidence dropped. The tests that read it judge the reconstruction against the board
# itself (OpenCV's corners and solvePnP), not against this file's own figures.
#   scripts/regenerate_kamino_rig.sh           calibrate again and print how the result differs
#                                              from the committed fixture (rig show, both)
#   scripts/regenerate_kamino_rig.sh --write   also replace the fixture (header kept, body JSON,
#                                              which YAML reads as it is)
# SLSHADOW_BIN names the binary (default build/apps/slshadow).
set -euo pipefail
cd "$(dirname "$0")/.."
WRITE=0
for arg in "$@"; do
  case "$arg" in
    --write) WRITE=1 ;;
    *) echo "usage: scripts/regenerate_kamino_rig.sh [--write]" >&2; exit 2 ;;
  esac
done
BIN=${SLSHADOW_BIN:-build/apps/slshadow}
DATA=../shared/data/kamino-procam-graycode
FIXTURE=tests/reconstruct/data/kamino_slshadow_rig.yaml
[ -x "$BIN" ] || { echo "regenerate_kamino_rig: no binary at $BIN (build it, or set SLSHADOW_BIN)" >&2; exit 1; }
[ -d "$DATA" ] || { echo "regenerate_kamino_rig: no data at $DATA" >&2; exit 1; }
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
# The command the fixture's header names.
"$BIN" calibrate projector --target config/targets/kamino-procam-graycode.yaml \
  --patterns config/patterns/kamino_opencv_graycode.yaml --shadow-threshold 40 --contrast-threshold 5 \
  --min-views 5 --no-cross-validation --out "$WORK/procam.json" \
  --captures "$DATA/capture_0" "$DATA/capture_1" "$DATA/capture_2" "$DATA/capture_3" "$DATA/capture_4"
python3 - "$WORK/procam.json" "$WORK/rig.json" <<'PY'
import json, sys
rig = json.load(open(sys.argv[1]))
rig.pop("calibration", None)
json.dump(rig, open(sys.argv[2], "w"), indent=1)
PY
"$BIN" rig show "$FIXTURE" > "$WORK/committed.txt"
"$BIN" rig show "$WORK/rig.json" > "$WORK/regenerated.txt"
if diff -u "$WORK/committed.txt" "$WORK/regenerated.txt"; then
  echo "regenerate_kamino_rig: the calibration gives the committed fixture's geometry"
fi
if [ "$WRITE" = 1 ]; then
  { sed -n '/^#/p' "$FIXTURE"; cat "$WORK/rig.json"; echo; } > "$WORK/fixture.yaml"
  mv "$WORK/fixture.yaml" "$FIXTURE"
  echo "regenerate_kamino_rig: wrote $FIXTURE"
fi
