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
# Settings a night would otherwise find wrong only at its end (aggregate
# refuses them after every shard ran), or that sbatch would reject with a
# message about array ranges: refused here, before anything is submitted.
refuse() {
    echo "$0: $*" >&2
    exit 2
}
case "$n" in
    '' | *[!0-9]* | 0 | 0*) refuse "N must be a whole number of shards, 1 or more (got '$n')" ;;
esac
# `a` is `b` or lies below it.
within() { case "$1/" in "$2"/*) return 0 ;; esac; return 1; }
if within "$out" "$input" || within "$input" "$out"; then
    refuse "OUT $out and INPUT $input overlap: the night's outputs go to a directory of their own, beside the input (e.g. $(dirname "$input")/out)"
fi
if [ "$out" = "$work" ] || within "$work" "$out"; then
    refuse "OUT $out holds WORK $work, where the shards write: give the night's output a directory of its own (e.g. $work/out)"
fi
case "$out/" in
    "$work"/shard-*) refuse "OUT $out lies inside a shard's directory under WORK $work: give it a directory of its own (e.g. $work/out)" ;;
esac
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
