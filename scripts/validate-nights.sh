#!/usr/bin/env bash
# The trend's alert rule measured from the CLI (docs/diagnosis.md "History
# and trend"):
#   1. `sparkout validate --nights`: generated observation nights — false
#      alerts per 100 stationary night-fleets, detection delay of 20/40/100 %
#      steps and a drift in the form machine's wear rate, an event.
#   2. Machine fleets through `sparkout run --history`: six stationary nights
#      of servo (servo_lag), form (wheel_wear), gantry (thermal_bow) and
#      guide-way (thermal_infeed) fleets at their default sizes, only the
#      seeds changing; then a seventh night whose form wheel wears 40 %
#      faster (k_mm_per_mm3 1.5e-5 → 2.1e-5), in a copy of the history, and
#      a 20 % step (1.8e-5) held for three nights in another copy.
# Usage: scripts/validate-nights.sh [OUT_DIR]   (SPARKOUT=path/to/sparkout,
# RUNS=runs per machine type, default 4; SKIP_VALIDATE=1 skips step 1).
# Writes only under OUT_DIR.
set -euo pipefail
BIN=${SPARKOUT:-target/release/sparkout}
OUT=${1:-sparkout-nights}
RUNS=${RUNS:-4}
[ -x "$BIN" ] || { echo "no $BIN: build it (cargo build --release) or set SPARKOUT" >&2; exit 1; }
mkdir -p "$OUT"

if [ "${SKIP_VALIDATE:-0}" != 1 ]; then
    echo "== sparkout validate --nights"
    "$BIN" validate --nights --out "$OUT/validate"
fi

# One night's fleet: every machine type, seeds from the night number; the
# form wheel's wear rate as given.
fleet() { # DIR NIGHT K_FORM
    local dir=$1 n=$2 k=$3
    rm -rf "$dir"
    "$BIN" generate servo --runs "$RUNS" --seed $((100 + n)) --out "$dir" --effect servo_lag >/dev/null
    "$BIN" generate form --runs "$RUNS" --seed $((200 + n)) --out "$dir" \
        --effect "wheel_wear=k_mm_per_mm3=$k" >/dev/null
    "$BIN" generate gantry --runs "$RUNS" --seed $((300 + n)) --out "$dir" --effect thermal_bow >/dev/null
    "$BIN" generate guideway --runs "$RUNS" --seed $((400 + n)) --out "$dir" --effect thermal_infeed >/dev/null
}

night() { # HISTORY NIGHT_NUMBER K_FORM
    local h=$1 n=$2 k=$3
    local d; d=$(printf '2026-11-%02d' "$n")
    fleet "$OUT/runs" "$n" "$k"
    local t0=$SECONDS
    "$BIN" run --input "$OUT/runs" --out "$OUT/out-$(basename "$h")-$n" --history "$h" --night "$d" \
        > "$OUT/run-$(basename "$h")-$n.log" 2>&1
    echo "night $d (k = $k): $((SECONDS - t0)) s"
}

echo "== six stationary nights of servo, form, gantry and guide-way fleets ($RUNS runs each)"
rm -rf "$OUT/history"
for n in 1 2 3 4 5 6; do night "$OUT/history" "$n" 1.5e-5; done
"$BIN" trend --history "$OUT/history" --out "$OUT/trend-stationary" | tee "$OUT/trend-stationary.txt"

echo "== a seventh night: the form wheel wears 40 % faster"
rm -rf "$OUT/history40"; cp -a "$OUT/history" "$OUT/history40"
night "$OUT/history40" 7 2.1e-5
"$BIN" trend --history "$OUT/history40" --out "$OUT/trend-step40" | tee "$OUT/trend-step40.txt"

echo "== nights 7-9: the form wheel wears 20 % faster"
rm -rf "$OUT/history20"; cp -a "$OUT/history" "$OUT/history20"
for n in 7 8 9; do night "$OUT/history20" "$n" 1.8e-5; done
"$BIN" trend --history "$OUT/history20" --out "$OUT/trend-step20" | tee "$OUT/trend-step20.txt"

echo "== night 7 with a wheel change recorded: the 40 % step starts a new baseline"
rm -rf "$OUT/historyev"; cp -a "$OUT/history" "$OUT/historyev"
fleet "$OUT/runs" 7 2.1e-5
"$BIN" run --input "$OUT/runs" --out "$OUT/out-ev-7" --history "$OUT/historyev" --night 2026-11-07 \
    --event "machine=form-grinder,kind=wheel_change,note=new wheel" > "$OUT/run-ev-7.log" 2>&1
"$BIN" trend --history "$OUT/historyev" --out "$OUT/trend-event" | tee "$OUT/trend-event.txt"
