#!/usr/bin/env bash
# Reproducible: for each N, a generated servo fleet of N runs
# (≈ 14 600 observation rows per run) in 8 shards as local processes
# (`--jobs 1` each), then `aggregate`; for N = $SINGLE_AT also a single-node
# `run` (its fleet outputs compared with the aggregate's) and its no-change
# re-run (every stage cached). Prints one line per measurement. No effect is
# injected unless EFFECT is set.
#   scripts/measure-scale.sh target/release/sparkout /tmp/scale 500 1000 2000
set -euo pipefail
export SPARKOUT_LOG=${SPARKOUT_LOG:-warn}
bin=$(realpath "$1"); work=$2; shift 2
single_at=${SINGLE_AT:-1000}
shards=${SHARDS:-8}
now() { date +%s.%N; }
secs() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.1f", b - a }'; }
ok2() { "$@" >/dev/null || [ $? -eq 2 ]; }
for n in "$@"; do
  d="$work/n$n"
  rm -rf "$d"; mkdir -p "$d"
  t=$(now)
  # EFFECT (e.g. servo_lag=k_s=0.004) makes the diagnosis select effects:
  # far more work (every catalogue candidate × folds × rounds).
  "$bin" generate servo --runs "$n" --seed 7 --out "$d/runs" ${EFFECT:+--effect "$EFFECT"} >/dev/null
  echo "n=$n generate $(secs "$t" "$(now)") s"
  t=$(now)
  pids=()
  for i in $(seq 0 $((shards - 1))); do
    ok2 "$bin" run --input "$d/runs" --out "$d/shard-$i" --shard "$i/$shards" --jobs 1 &
    pids+=($!)
  done
  for p in "${pids[@]}"; do wait "$p"; done
  echo "n=$n shards($shards) $(secs "$t" "$(now)") s"
  list=()
  for i in $(seq 0 $((shards - 1))); do list+=("$d/shard-$i"); done
  t=$(now)
  ok2 "$bin" aggregate --shards "${list[@]}" --out "$d/agg"
  echo "n=$n aggregate $(secs "$t" "$(now)") s"
  rows=$(python3 -c 'import json,sys; print(sum(p["n"] for p in json.load(open(sys.argv[1]))["per_observable"]))' "$d/agg/fleet/diagnosis.json")
  echo "n=$n observation_rows $rows"
  if [ "$n" = "$single_at" ]; then
    t=$(now)
    ok2 "$bin" run --input "$d/runs" --out "$d/single"
    echo "n=$n single $(secs "$t" "$(now)") s"
    t=$(now)
    ok2 "$bin" run --input "$d/runs" --out "$d/single"
    echo "n=$n cached_rerun $(secs "$t" "$(now)") s"
    for f in fleet/diagnosis.json fleet/observations.parquet; do
      cmp -s "$d/agg/$f" "$d/single/$f" && echo "n=$n $f identical" || echo "n=$n $f DIFFERS"
    done
  fi
done
