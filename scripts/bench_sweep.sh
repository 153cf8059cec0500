#!/usr/bin/env bash
# A noise sweep of the demo (N seeds, both modes) as one `slshadow sweep` against N separate
# `slshadow simulate` + `slshadow reconstruct` runs (both modes), in one run on this machine.
# Same work per seed (render both cameras; projector mode from the left camera, stereo left-right),
# except that the sweep also compares both clouds with the ground truth; the separate runs skip the
# ground truth (--no-ground-truth) and write PGM, the fastest encoding.
# usage: scripts/bench_sweep.sh [N=100] [SLSHADOW=build/apps/slshadow]
set -euo pipefail
N=${1:-100}
BIN=$(realpath "${2:-build/apps/slshadow}")
SRC=$(cd "$(dirname "$0")/.." && pwd)
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
sed "s/count: 100/count: $N/" "$SRC/config/studies/noise_demo.yaml" > "$WORK/study.yaml"

t0=$(date +%s.%N)
"$BIN" sweep plan "$WORK/study.yaml" --out "$WORK/jobs" > /dev/null
"$BIN" sweep run "$WORK/jobs"
"$BIN" sweep merge "$WORK/jobs" --out "$WORK/result" > /dev/null
t1=$(date +%s.%N)

for seed in $(seq 1 "$N"); do
  { cat "$SRC/config/demo/scene.yaml"
    echo "layers:"
    echo "  noise: {full_well_e: 10000, read_noise_e: 6, seed: $seed}"; } > "$WORK/scene.yaml"
  "$BIN" simulate --rig "$SRC/config/demo/rig.yaml" --scene "$WORK/scene.yaml" \
    --patterns "$SRC/config/demo/patterns.yaml" --out "$WORK/scan" --encoding pgm --no-ground-truth \
    --overwrite --quiet
  "$BIN" reconstruct "$WORK/scan" --out "$WORK/projector.ply" --mode projector --cameras left --quiet > /dev/null
  "$BIN" reconstruct "$WORK/scan" --out "$WORK/stereo.ply" --mode stereo --quiet > /dev/null
done
t2=$(date +%s.%N)
python3 - "$N" "$t0" "$t1" "$t2" <<'PY'
import sys
n, t0, t1, t2 = int(sys.argv[1]), *map(float, sys.argv[2:])
sweep, separate = t1 - t0, t2 - t1
print(f"{n} noise seeds of the demo: sweep {sweep:.1f} s ({60*n/sweep:.1f} scans/min), "
      f"separate simulate + reconstruct {separate:.1f} s ({60*n/separate:.1f} scans/min): {separate/sweep:.2f}x")
PY
