#!/usr/bin/env bash
# Submit a nightly sparkout batch as a Slurm job array of N shards plus one
# aggregate job that starts when every shard succeeded.
#   deploy/slurm/submit.sh INPUT WORK OUT N [sbatch options...]
# INPUT, WORK and OUT must be on a filesystem every node sees. Config flags
# for both steps go in SPARKOUT_ARGS (e.g. SPARKOUT_ARGS="--config nightly.toml").
set -euo pipefail
if [ $# -lt 4 ]; then
    echo "usage: $0 INPUT WORK OUT N [sbatch options...]" >&2
    exit 1
fi
input=$(realpath "$1"); work=$(realpath -m "$2"); out=$(realpath -m "$3"); n=$4; shift 4
here=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$work"
# The night's run set, listed once now: every shard partitions this list
# however late it starts (runs arriving meanwhile belong to the next night).
"${SPARKOUT_BIN:-sparkout}" snapshot --input "$input" --out "$work/night.json" >&2
export SPARKOUT_INPUT="$input" SPARKOUT_WORK="$work" SPARKOUT_OUT="$out" SPARKOUT_SHARDS="$n"
array=$(sbatch --parsable --export=ALL --chdir="$work" --array="0-$((n - 1))" "$@" "$here/nightly.sbatch")
array=${array%%;*}
# --kill-on-invalid-dep: a failed shard makes the dependency unsatisfiable;
# without it the aggregate job would stay pending forever instead of failing
# the night.
agg=$(sbatch --parsable --export=ALL --chdir="$work" --dependency="afterok:$array" --kill-on-invalid-dep=yes "$@" "$here/aggregate.sbatch")
agg=${agg%%;*}
echo "shards: job $array (array 0-$((n - 1))); aggregate: job $agg (afterok)"
echo "$agg"
