#!/usr/bin/env bash
# A sweep through a real single-node Slurm started here, for tests/studies/sweep_test.cc:
# MUNGE and Slurm (Debian's munge and slurm-wlm) are configured in WORK (state, logs, slurm.conf)
# and a short-named folder in /tmp (key, sockets, spool: socket paths must stay under 108 bytes;
# removed on exit); no system-wide file is written. slurmctld and slurmd are started on 127.0.0.1,
# `sbatch --array=0-(N-1)` runs the shards of JOBS (`slshadow sweep run JOBS --shard I/N`) and a
# merge job depending on them (afterok) writes RESULT; every daemon is stopped on exit.
# Run it inside a private network namespace (`unshare -n`: only loopback) so that nothing leaves
# the machine. There it brings `lo` up and gives it a second address (10.254.77.1/32): Slurm
# resolves with AI_ADDRCONFIG, which returns no IPv4 address while only 127.0.0.0/8 is configured.
# Exit 0: merged; 77: Slurm or MUNGE could not start here (the reason on stderr, logs in WORK);
# anything else: a failure of the sweep under Slurm.
# usage: slurm_sweep.sh SLSHADOW JOBS RESULT WORK SHARDS
set -uo pipefail
SLSHADOW=$1 JOBS=$2 RESULT=$3 WORK=$4 SHARDS=$5
skip() { echo "slurm_sweep: $*" >&2; exit 77; }

for tool in munged slurmctld slurmd sbatch scontrol sinfo; do
  command -v "$tool" > /dev/null || skip "$tool is not installed (scripts/setup.sh installs munge and slurm-wlm)"
done
if [ "$(ip -o link show 2> /dev/null | wc -l)" = 1 ]; then  # a private namespace: lo only
  ip link set lo up && ip addr add 10.254.77.1/32 dev lo ||
    skip "cannot configure the loopback interface of the private network namespace"
fi
mkdir -p "$WORK"/{state,log} || skip "cannot create $WORK"
# Sockets (MUNGE's, slurmstepd's in the spool) need paths under 108 bytes: a short private folder.
RUN=$(mktemp -d /tmp/slsw.XXXXXX) || skip "cannot create a folder in /tmp"
mkdir -p "$RUN"/{munge,spool}
chmod 700 "$WORK" "$RUN" "$RUN/munge"

pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2> /dev/null; done
  for p in "${pids[@]}"; do wait "$p" 2> /dev/null; done
  rm -rf "$RUN"
}
trap cleanup EXIT

# MUNGE: a key of our own, its socket in WORK.
dd if=/dev/urandom of="$RUN/munge/munge.key" bs=1024 count=1 status=none && chmod 400 "$RUN/munge/munge.key" ||
  skip "cannot write a MUNGE key in $WORK"
munged --foreground --force --socket="$RUN/munge/munge.sock" --key-file="$RUN/munge/munge.key" \
  --pid-file="$RUN/munge/munged.pid" --seed-file="$RUN/munge/munged.seed" \
  --log-file="$WORK/log/munged.log" > "$WORK/log/munged.out" 2>&1 &
pids+=($!)
for _ in $(seq 50); do [ -S "$RUN/munge/munge.sock" ] && break; sleep 0.1; done
[ -S "$RUN/munge/munge.sock" ] || skip "munged did not start (see $WORK/log/munged.log, munged.out): $(tail -n 2 "$WORK/log/munged.out" "$WORK/log/munged.log" 2> /dev/null | tr '\n' ' ')"

# Slurm: one node (this host, 127.0.0.1), one partition; ports from the PID so that concurrent
# runs do not collide.
node=$(hostname -s)
cpus=$(nproc)
port=$((20000 + ($$ % 20000)))
user=$(id -un)
cat > "$WORK/slurm.conf" << EOF
ClusterName=slshadowtest
SlurmctldHost=$node(127.0.0.1)
SlurmctldPort=$port
SlurmdPort=$((port + 1))
SlurmUser=$user
SlurmdUser=$user
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$RUN/munge/munge.sock
StateSaveLocation=$WORK/state
SlurmdSpoolDir=$RUN/spool
SlurmctldPidFile=$WORK/slurmctld.pid
SlurmdPidFile=$WORK/slurmd.pid
SlurmctldLogFile=$WORK/log/slurmctld.log
SlurmdLogFile=$WORK/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
SchedulerType=sched/backfill
MpiDefault=none
MailProg=/bin/true
ReturnToService=2
SlurmdTimeout=60
NodeName=$node NodeAddr=127.0.0.1 CPUs=$cpus State=UNKNOWN
PartitionName=local Nodes=$node Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF="$WORK/slurm.conf"
slurmctld -D -i -f "$SLURM_CONF" > "$WORK/log/slurmctld.out" 2>&1 &
pids+=($!)
slurmd -D -N "$node" -f "$SLURM_CONF" > "$WORK/log/slurmd.out" 2>&1 &
pids+=($!)
up=""
deadline=$((SECONDS + 60))
while [ $SECONDS -lt $deadline ]; do
  if timeout 5 sinfo -h -N -o '%T' 2> /dev/null | grep -Eq '^(idle|mixed|allocated)'; then up=1; break; fi
  sleep 0.5
done
[ -n "$up" ] || skip "the single-node Slurm did not come up within 60 s (node state '$(timeout 5 sinfo -h -N -o '%T' 2>&1 | head -n 1)'; last log lines: $(tail -q -n 2 "$WORK/log/slurmctld.log" "$WORK/log/slurmd.log" 2> /dev/null | tr '\n' ' ')"

# The recipe of docs/sweeps.md: shards as an array, the merge as a dependent job.
run=$(sbatch --parsable --array=0-$((SHARDS - 1)) --cpus-per-task=1 --output="$WORK/log/shard-%a.out" \
  --wrap "'$SLSHADOW' sweep run '$JOBS' --shard \${SLURM_ARRAY_TASK_ID}/$SHARDS") || {
  echo "slurm_sweep: sbatch of the shards failed" >&2; exit 1; }
merge=$(sbatch --parsable --dependency=afterok:"$run" --output="$WORK/log/merge.out" \
  --wrap "'$SLSHADOW' sweep merge '$JOBS' --out '$RESULT'") || {
  echo "slurm_sweep: sbatch of the merge failed" >&2; exit 1; }
# Wait for the merge (at most 15 min); a job Slurm could not launch is requeued and held: fail.
state=""
deadline=$((SECONDS + 900))
while [ $SECONDS -lt $deadline ]; do
  state=$(scontrol show job "$merge" -o 2> /dev/null | grep -o 'JobState=[A-Z_]*' | cut -d= -f2)
  case "$state" in
    COMPLETED) break ;;
    FAILED | CANCELLED | TIMEOUT | NODE_FAIL | OUT_OF_MEMORY | BOOT_FAIL | DEADLINE) break ;;
  esac
  if scontrol show job "$run" -o 2> /dev/null | grep -q 'launch_failed_requeued_held'; then
    state="shards not launched"; break
  fi
  sleep 1
done
if [ "$state" != COMPLETED ]; then
  echo "slurm_sweep: the merge job ended as '$state'; logs:" >&2
  tail -q -n 5 "$WORK"/log/shard-*.out "$WORK/log/merge.out" "$WORK/log/slurmd.log" >&2 2> /dev/null
  exit 1
fi
# Each array task ran its shard with the thread budget Slurm gave it.
grep -h "threads:" "$WORK"/log/shard-*.out
exit 0
