#!/usr/bin/env bash
# A noise sweep of the demo (N seeds, both modes) as one `slshadow sweep` against N separate
# `slshadow simulate` + `slshadow reconstruct` runs (both modes), in one run on this machine.
# Same work per seed (render both cameras with that seed's sensor noise; projector mode from the
# left camera, stereo left-right), except that the sweep also compares both clouds with the ground
# truth; the separate runs skip the ground truth (--no-ground-truth) and write PGM, the fastest
# encoding. Prints wall and CPU seconds (user + system, all threads and processes) of each side
# and their ratios, CPU also split into user and system time. Optional: THREADS (sweep run
# --threads; default: all cores).
# usage: scripts/bench_sweep.sh [N=100] [SLSHADOW=build/apps/slshadow]
set -euo pipefail
N=${1:-100}
SRC=$(cd "$(dirname "$0")/.." && pwd)
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
# A copy: a rebuild during the run must not change (or remove) the binary under measurement.
cp "$(realpath "${2:-build/apps/slshadow}")" "$WORK/slshadow"
BIN="$WORK/slshadow"
sed "s/count: 100/count: $N/" "$SRC/config/studies/noise_demo.yaml" > "$WORK/study.yaml"
threads=()
if [ -n "${THREADS:-}" ]; then threads=(--threads "$THREADS"); fi

cat > "$WORK/sweep.sh" << EOS
set -e
"$BIN" sweep plan "$WORK/study.yaml" --out "$WORK/jobs" > /dev/null
"$BIN" sweep run "$WORK/jobs" ${threads[@]+"${threads[@]}"} > /dev/null
"$BIN" sweep merge "$WORK/jobs" --out "$WORK/result" > /dev/null
EOS
cat > "$WORK/separate.sh" << EOS
set -e
for seed in \$(seq 1 $N); do
  { cat "$SRC/config/demo/scene.yaml"
    echo "layers:"
    echo "  noise: {full_well_e: 10000, read_noise_e: 6, seed: \$seed}"; } > "$WORK/scene.yaml"
  "$BIN" simulate --rig "$SRC/config/demo/rig.yaml" --scene "$WORK/scene.yaml" \\
    --patterns "$SRC/config/demo/patterns.yaml" --out "$WORK/scan" --encoding pgm --no-ground-truth \\
    --overwrite --quiet
  "$BIN" reconstruct "$WORK/scan" --out "$WORK/projector.ply" --mode projector --cameras left --quiet > /dev/null
  "$BIN" reconstruct "$WORK/scan" --out "$WORK/stereo.ply" --mode stereo --quiet > /dev/null
done
EOS
/usr/bin/time -f "%e %U %S" -o "$WORK/sweep.time" bash "$WORK/sweep.sh"
/usr/bin/time -f "%e %U %S" -o "$WORK/separate.time" bash "$WORK/separate.sh"
python3 - "$N" "$WORK/sweep.time" "$WORK/separate.time" "$WORK/result/timings.csv" << 'PY'
import csv, sys
n = int(sys.argv[1])
def read(path):
    return tuple(map(float, open(path).read().split()[-3:]))  # wall, user, system
(sw, su, ss), (pw, pu, ps) = read(sys.argv[2]), read(sys.argv[3])
sc, pc = su + ss, pu + ps
print(f"{n} noise seeds of the demo, both modes:")
print(f"  sweep (plan + run + merge; also compares)  wall {sw:8.1f} s  CPU {sc:8.1f} s "
      f"(user {su:.1f}, system {ss:.1f})  {60 * n / sw:5.1f} scans/min")
print(f"  separate simulate + 2 x reconstruct        wall {pw:8.1f} s  CPU {pc:8.1f} s "
      f"(user {pu:.1f}, system {ps:.1f})  {60 * n / pw:5.1f} scans/min")
print(f"  ratio separate / sweep: wall {pw / sw:.2f}x, CPU {pc / sc:.2f}x, user CPU {pu / su:.2f}x")
# System time is mostly the kernel faulting in fresh memory: separate processes allocate every
# buffer anew, a sweep keeps them from job to job; its cost per page differs between machines.
rows = list(csv.DictReader(open(sys.argv[4])))
stages = ["setup", "render", "decode", "reconstruct", "compare"]
later = rows[1:] or rows
print("  sweep per job after the first (mean of %d), wall / CPU s:" % len(later))
print("   " + "  ".join(f"{s} {sum(float(r[s + '_s']) for r in later) / len(later):.2f}"
                        f"/{sum(float(r[s + '_cpu_s']) for r in later) / len(later):.2f}"
                        for s in stages))
print(f"  first job (sets up the geometry group and the noise-free images): "
      f"{float(rows[0]['total_s']):.2f} s wall")
PY
