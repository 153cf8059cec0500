#!/usr/bin/env bash
# Scans per minute of one study on this machine and how they scale with shards: the study run as
# one process (all cores), then as S shards through GNU parallel (S at once, CORES/S threads each),
# for S in SHARDS; each run plans the jobs afresh, and the merged results.csv must equal the one
# process's byte for byte. A "scan" is one job (both modes reconstructed and compared).
# usage: scripts/bench_sweep_shards.sh STUDY.yaml [SHARDS="2"] [SLSHADOW=build/apps/slshadow]
set -euo pipefail
STUDY=$(realpath "$1")
SHARDS=${2:-2}
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
cp "$(realpath "${3:-build/apps/slshadow}")" "$WORK/slshadow"  # a rebuild must not change it
BIN="$WORK/slshadow"
CORES=$(nproc)
run() {  # name, then the command that runs the shards of $WORK/$name/jobs
  local name=$1; shift
  "$BIN" sweep plan "$STUDY" --out "$WORK/$name/jobs" > /dev/null
  local t0 t1
  t0=$(date +%s.%N)
  "$@" > /dev/null
  t1=$(date +%s.%N)
  "$BIN" sweep merge "$WORK/$name/jobs" --out "$WORK/$name/result" > /dev/null
  local jobs
  jobs=$(ls "$WORK/$name/jobs/jobs" | wc -l)
  python3 -c "import sys; n, t = int(sys.argv[1]), float(sys.argv[3]) - float(sys.argv[2]); \
print(f'{sys.argv[4]:<40} {n:4d} jobs {t:8.1f} s {60 * n / t:7.2f} scans/min')" "$jobs" "$t0" "$t1" "$name"
}
echo "study $(basename "$STUDY"), $CORES cores, load average $(cut -d' ' -f1-3 /proc/loadavg)"
run one_process "$BIN" sweep run "$WORK/one_process/jobs" --threads "$CORES"
for s in $SHARDS; do
  threads=$(( CORES / s > 0 ? CORES / s : 1 ))
  run "parallel_${s}_shards_${threads}_threads" parallel --will-cite --halt now,fail=1 -j "$s" \
    "$BIN" sweep run "$WORK/parallel_${s}_shards_${threads}_threads/jobs" --shard {}/"$s" \
    --threads "$threads" ::: $(seq 0 $((s - 1)))
  cmp -s "$WORK/one_process/result/results.csv" "$WORK/parallel_${s}_shards_${threads}_threads/result/results.csv" ||
    { echo "results.csv of $s shards differs from the one process's" >&2; exit 1; }
done
echo "merged results.csv identical byte for byte in every run"
