#!/usr/bin/env bash
# Smoke test of the Slurm recipe on this machine: a single-node
# Slurm (munge + slurmctld + slurmd on localhost, state in a temp dir) runs
# a 4-shard nightly of a generated fleet through submit.sh, and its fleet
# outputs are compared byte for byte with a single-node `sparkout run`.
#   deploy/slurm/smoke.sh [path/to/sparkout]
# Needs root and Debian's slurm-wlm + munge (`apt-get install -y slurm-wlm
# munge`); exits 0 with "SKIPPED" where they are not installed.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
bin=$(realpath "${1:-$here/../../target/debug/sparkout}")
for tool in slurmctld slurmd munged sbatch squeue; do
    if ! command -v "$tool" >/dev/null; then
        echo "SKIPPED: $tool not installed (apt-get install -y slurm-wlm munge)"
        exit 0
    fi
done
[ -x "$bin" ] || { echo "no sparkout binary at $bin (cargo build first)" >&2; exit 1; }
d=$(mktemp -d /tmp/sparkout-slurm.XXXXXX)
cleanup() {
    for p in slurmd slurmctld; do
        [ -f "$d/$p.pid" ] && kill "$(cat "$d/$p.pid")" 2>/dev/null || true
    done
    [ -f "$d/munged.pid" ] && kill "$(cat "$d/munged.pid")" 2>/dev/null || true
}
trap cleanup EXIT
mkdir -p "$d/state" "$d/spool" "$d/munge"
# munge: a fresh key and socket of our own, so a system munged is untouched.
dd if=/dev/urandom of="$d/munge/munge.key" bs=1024 count=1 status=none
chmod 0400 "$d/munge/munge.key"
munged --force -S "$d/munge/socket" --key-file "$d/munge/munge.key" \
    --pid-file "$d/munged.pid" --log-file "$d/munge/munged.log" --seed-file "$d/munge/seed"
cpus=$(nproc)
mem=$(( $(awk '/MemTotal/ {print int($2 / 1024)}' /proc/meminfo) / 2 ))
cat > "$d/slurm.conf" <<CONF
ClusterName=sparkoutsmoke
SlurmctldHost=localhost
AuthType=auth/munge
AuthInfo=socket=$d/munge/socket
CredType=cred/munge
SlurmUser=root
SlurmdUser=root
StateSaveLocation=$d/state
SlurmdSpoolDir=$d/spool
SlurmctldPidFile=$d/slurmctld.pid
SlurmdPidFile=$d/slurmd.pid
SlurmctldLogFile=$d/slurmctld.log
SlurmdLogFile=$d/slurmd.log
SlurmctldPort=16817
SlurmdPort=16818
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
MpiDefault=none
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
NodeName=localhost CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=smoke Nodes=localhost Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF="$d/slurm.conf"
slurmctld -f "$SLURM_CONF"
slurmd -f "$SLURM_CONF" -N localhost
for _ in $(seq 30); do
    sinfo -h -o %T 2>/dev/null | grep -q idle && break
    sleep 1
done
sinfo
# A fleet of two machine types, and the single-node reference.
"$bin" generate servo --runs 6 --seed 11 --out "$d/runs" --effect servo_lag=k_s=0.004 >/dev/null
"$bin" generate mill --runs 4 --seed 12 --out "$d/runs" >/dev/null
# From the same working directory as the Slurm jobs: without --machines,
# machine configs are looked up under ./configs/machines, so the cwd matters.
mkdir -p "$d/work"
( cd "$d/work" && "$bin" run --input "$d/runs" --out "$d/out" >/dev/null )
mkdir -p "$d/single"
( cd "$d/out" && cp -r fleet index.html failures.json manifest.json "$d/single/" )
rm -rf "$d/out"
# The same night through Slurm: 4 array tasks, then the aggregate.
export SPARKOUT_BIN="$bin"
agg=$("$here/submit.sh" "$d/runs" "$d/work" "$d/out" 4 --mem=1G --cpus-per-task=1 | tail -1)
for _ in $(seq 600); do
    if [ -z "$(squeue -h 2>/dev/null)" ]; then break; fi
    sleep 1
done
state=$(scontrol show job "$agg" 2>/dev/null | grep -o 'JobState=[A-Z]*' || true)
echo "aggregate job $agg: ${state:-finished}"
status=0
for f in fleet/observations.parquet fleet/diagnosis.json fleet/diagnosis.parquet \
         fleet/report.html index.html failures.json manifest.json; do
    if cmp -s "$d/single/$f" "$d/out/$f"; then
        echo "identical: $f"
    else
        echo "DIFFERENT: $f"
        status=1
    fi
done
if [ "$status" -eq 0 ]; then
    echo "PASS: a 4-shard Slurm nightly equals the single-node run"
    # Kept only when it failed, for its logs; the daemons stop first
    # (cleanup), then the folder goes.
    trap 'cleanup; rm -rf "$d"' EXIT
else
    echo "FAIL: see $d/work/*.log and $d/*.log"
fi
exit "$status"
