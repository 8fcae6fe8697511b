#!/usr/bin/env bash
# The scale figures of docs/scale.md, reproducible on one machine:
#   scripts/measure-scale.sh target/release/sparkout /tmp/scale 500 1000 2000
#
# For each N: a generated fleet of N runs (GENERATOR, default servo: ≈ 14 600
# observation rows per run; robot: runs with 1 MHz AE logs, ≈ 30 MB each)
# with a real effect (EFFECT, default servo_lag for servo and wheel_wear for
# robot; EFFECT= for none); SHARDS shards (default 4; BALANCE=size for
# `--balance size`, default hash) run one after another, each with `--jobs 1`,
# then `aggregate`; and a single-node `run --jobs 1`. The sharded night's
# time is the slowest shard's wall time plus aggregate's (what a cluster
# with one node per shard would see). Every step's wall time and peak RSS
# come from /usr/bin/time; `aggregate`'s line adds where its time went (its
# progress lines, timestamped in WORK/nN/aggregate.log). The single node's
# fleet outputs are compared byte for byte with the aggregate's. One line
# per measurement, then a
# summary line per N; cost exponents between consecutive N at the end.
# Disk: ≈ 10 GB under WORK for 500 + 1 000 + 2 000 servo runs, ≈ 6 GB for
# 200 robot runs (fleets, shards, single-node outputs); remove WORK
# afterwards.
set -euo pipefail
export SPARKOUT_LOG=${SPARKOUT_LOG:-warn}
bin=$(realpath "$1"); work=$2; shift 2
shards=${SHARDS:-4}
generator=${GENERATOR:-servo}
case "$generator" in
  servo) effect=${EFFECT-servo_lag} ;;
  robot) effect=${EFFECT-wheel_wear} ;;
  *) effect=${EFFECT-} ;;
esac
balance=${BALANCE:-hash}
single=${SINGLE:-1}
# Runs `$@` under /usr/bin/time; exit code 2 (some runs rejected, listed
# in failures.json) counts as success. Prints "<wall s> <peak MB>".
timed() {
  local f rc=0
  f=$(mktemp)
  /usr/bin/time -f '%e %M' -o "$f" "$@" >/dev/null 2>&1 || rc=$?
  if [ "$rc" -ne 0 ] && [ "$rc" -ne 2 ]; then
    echo "failed ($rc): $*" >&2
    exit 1
  fi
  # /usr/bin/time writes "Command exited with non-zero status N" first.
  awk 'END { printf "%.1f %.0f\n", $1, $2 / 1024 }' "$f"
  rm -f "$f"
}
# `timed`, with the command's log (SPARKOUT_LOG=info) written to $1, each
# line prefixed with the second it arrived, and a last line "<second> END".
timed_logged() {
  local log=$1 f rc
  shift
  f=$(mktemp)
  set +e
  SPARKOUT_LOG=info /usr/bin/time -f '%e %M' -o "$f" "$@" 2>&1 >/dev/null |
    perl -MTime::HiRes=time -ne '$| = 1; printf "%.2f %s", time, $_' >"$log"
  rc=${PIPESTATUS[0]}
  set -e
  perl -MTime::HiRes=time -e 'printf "%.2f END\n", time' >>"$log"
  if [ "$rc" -ne 0 ] && [ "$rc" -ne 2 ]; then
    echo "failed ($rc): $*" >&2
    exit 1
  fi
  # /usr/bin/time writes "Command exited with non-zero status N" first.
  awk 'END { printf "%.1f %.0f\n", $1, $2 / 1024 }' "$f"
  rm -f "$f"
}
# Where `aggregate`'s time went, from the progress lines of its log.
phases() {
  awk '/ gathering [0-9]+ shard/ { g = $1 } / joining observations/ { j = $1 }
       / diagnosing the sim-to-real gap$/ { d = $1 } / writing the diagnosis/ { w = $1 }
       / writing the fleet report/ { r = $1 } / END$/ { e = $1 }
       END { if (g && j && d && w && r && e)
               printf "gathering shards %.1f s, join %.1f s, diagnosis %.1f s, writing the diagnosis %.1f s, report and index %.1f s\n",
                 j - g, d - j, w - d, r - w, e - r }' "$1"
}
declare -A night agg_mb single_s
ns=()
for n in "$@"; do
  ns+=("$n")
  d="$work/n$n"
  rm -rf "$d"; mkdir -p "$d"
  "$bin" generate "$generator" --runs "$n" --seed 7 --out "$d/runs" \
    ${effect:+--effect "$effect"} >/dev/null
  slowest=0
  list=()
  for i in $(seq 0 $((shards - 1))); do
    read -r s mb < <(timed "$bin" run --input "$d/runs" --out "$d/shard-$i" \
      --shard "$i/$shards" --balance "$balance" --jobs 1)
    echo "n=$n shard $i/$shards ${s} s ${mb} MB"
    slowest=$(awk -v a="$slowest" -v b="$s" 'BEGIN { print (b > a) ? b : a }')
    list+=("$d/shard-$i")
  done
  read -r a amb < <(timed_logged "$d/aggregate.log" "$bin" aggregate --shards "${list[@]}" --out "$d/agg")
  echo "n=$n aggregate ${a} s ${amb} MB ($(phases "$d/aggregate.log"))"
  rows=$(python3 -c 'import json,sys; print(sum(p["n"] for p in json.load(open(sys.argv[1]))["per_observable"]))' "$d/agg/fleet/diagnosis.json")
  night[$n]=$(awk -v a="$slowest" -v b="$a" 'BEGIN { printf "%.1f", a + b }')
  agg_mb[$n]=$amb
  line="n=$n rows=$rows sharded_night=${night[$n]} s (slowest shard $slowest + aggregate $a) aggregate_peak=${amb} MB"
  if [ "$single" = 1 ]; then
    read -r s smb < <(timed "$bin" run --input "$d/runs" --out "$d/single" --jobs 1)
    single_s[$n]=$s
    for f in fleet/diagnosis.json fleet/observations.parquet; do
      cmp -s "$d/agg/$f" "$d/single/$f" || echo "n=$n $f DIFFERS between single node and shards"
    done
    line="$line single=${s} s (${smb} MB) speedup=$(awk -v a="$s" -v b="${night[$n]}" 'BEGIN { printf "%.2f", a / b }')"
  fi
  echo "$line"
done
# Cost exponents: log(t2/t1) / log(n2/n1) between consecutive sizes.
for ((k = 1; k < ${#ns[@]}; k++)); do
  n1=${ns[k-1]}; n2=${ns[k]}
  exp() { awk -v a="$1" -v b="$2" -v m="$n1" -v n="$n2" 'BEGIN { printf "%.2f", log(b / a) / log(n / m) }'; }
  out="exponent $n1→$n2: sharded night $(exp "${night[$n1]}" "${night[$n2]}"), aggregate memory $(exp "${agg_mb[$n1]}" "${agg_mb[$n2]}")"
  [ "$single" = 1 ] && out="$out, single node $(exp "${single_s[$n1]}" "${single_s[$n2]}")"
  echo "$out"
done
