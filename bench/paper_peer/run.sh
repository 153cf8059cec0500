#!/usr/bin/env bash
# Same-run peer for the simulator benchmark (docs/benchmarks.md, "Same-run peer: the
# digital-model paper's approach"): the paper's Python/Open3D virtual scanner
# (paper_scanner.py) and slshadow's BM_PaperWorkloadWritten on the same workload (slshadow before
# and after the peer; /3 renders the part alone as the peer's part-alone run does, /0 the part and
# its table), then the ratios of their times.
#
#   bash bench/paper_peer/run.sh        # N = 2500000 points on the part (~31 % holes), the part
#                                       # alone, then part + table at the same point density
#   PEER_POINTS="1200000 2500000" PEER_TABLE_DENSITY=0 bash bench/paper_peer/run.sh
#   BUILD=/work/main/build bash bench/paper_peer/run.sh   # reuse another build folder
#
# Needs python3-open3d (scripts/setup.sh). Run it on a quiet machine (load average < 1): both
# sides are wall-clock times.
set -euo pipefail
SRC="$(cd "$(dirname "$0")/../.." && pwd)"
BUILD="${BUILD:-$SRC/build-peer}"
POINTS="${PEER_POINTS:-2500000}"
# Point density on the table relative to the part's; 0: the part alone (the paper's object cloud).
TABLE_DENSITIES="${PEER_TABLE_DENSITY:-0 1}"
WORK="$BUILD/paper_peer"
PY=/usr/bin/python3   # Debian's python3, where python3-open3d lives

echo "== $(date -u '+%F %T UTC'); $(uptime)"
cmake -S "$SRC" -B "$BUILD" -G Ninja -DSLSHADOW_WERROR=ON > /dev/null
cmake --build "$BUILD" -j2 --target export_bench_part sim_bench > /dev/null

echo "== export: the demo part at ~1 M triangles, posed as config/demo/scene.yaml, rig frame"
rm -rf "$WORK"
mkdir -p "$WORK"
"$BUILD/bench/sim/export_bench_part" "$SRC" "$WORK/scene"

# slshadow runs before and after the peers: the machine's speed drifts within minutes, so the
# ratio is quoted against both (and their mean).
run_slshadow() {
  echo "== slshadow: sim_bench BM_PaperWorkloadWritten/0 (part and table) and /3 (part alone), PGM written ($(uptime))"
  "$BUILD/bench/sim/sim_bench" --benchmark_filter='BM_PaperWorkloadWritten/(0|3)' --benchmark_repetitions=3 \
    --benchmark_report_aggregates_only=true --benchmark_out="$1" --benchmark_out_format=json
}
run_slshadow "$WORK/slshadow_before.json"

for td in $TABLE_DENSITIES; do
  echo "== peer: paper_scanner.py, 22 patterns x 2 cameras, N = $POINTS, table density x$td ($(uptime))"
  # shellcheck disable=SC2086
  /usr/bin/time -f 'peer process: %e s wall, %U s user, %S s sys, %M KB peak' \
    "$PY" "$SRC/bench/paper_peer/paper_scanner.py" --scene "$WORK/scene" --rig "$SRC/config/demo/rig.yaml" \
    --out "$WORK/images" --points $POINTS --table-density "$td" --json "$WORK/peer_table$td.json"
  rm -rf "$WORK/images"
done

run_slshadow "$WORK/slshadow_after.json"

echo "== ratio ($(uptime))"
"$PY" - "$WORK/slshadow_before.json" "$WORK/slshadow_after.json" "$WORK"/peer_table*.json <<'PYEOF'
import json, sys
def median_seconds(path, arg):
    bench = json.load(open(path))
    med = [b for b in bench["benchmarks"] if b.get("aggregate_name") == "median"
           and b["run_name"].startswith("BM_PaperWorkloadWritten/%d/" % arg)][0]
    scale = {"ns": 1e-9, "us": 1e-6, "ms": 1e-3, "s": 1.0}[med.get("time_unit", "ns")]
    return med["real_time"] * scale, med.get("cpu_s", float("nan"))
# Like for like: the peer's part-alone run against slshadow's part alone (arg 3), the peer's part +
# table run against slshadow's part and table (arg 0); also the part-alone peer against slshadow
# with the table (slshadow doing more than the peer).
sl = {}
for arg, what in ((3, "part alone"), (0, "part and table")):
    before, after = median_seconds(sys.argv[1], arg), median_seconds(sys.argv[2], arg)
    sl[arg] = (before[0], after[0])
    print("slshadow %s: median %.3f s wall before the peers, %.3f s after (cpu_s %.3f, %.3f)"
          % (what, before[0], after[0], before[1], after[1]))
for path in sys.argv[3:]:
    table = not path.endswith("peer_table0.json")
    for r in json.load(open(path)):
        s = r["seconds"]
        print("%s N=%d (%d points): peer %.2f s (sample %.2f, hpr %.2f, project %.2f, images %.2f; + load %.2f), "
              "holes %.1f %%" % (path.rsplit("/", 1)[-1], r["points_part"], r["points_total"], s["total"], s["sample"],
              s["hpr"], s["project"], s["images"], s["load"], 100 * r["hole_fraction"]))
        for arg in ((0,) if table else (3, 0)):
            b, a = sl[arg]
            print("  ratio against slshadow %s: %.0fx (%.0fx against the run before, %.0fx after)"
                  % ("part and table" if arg == 0 else "part alone (same scene)", 2 * s["total"] / (b + a),
                     s["total"] / b, s["total"] / a))
PYEOF
