#!/usr/bin/env bash
# Regenerates the fuzz corpora that are not kept in git.
#
# The repository keeps a small seed corpus per target (≤ 50 files each in
# fuzz/corpus/TARGET/: the original seeds plus a spread of the merged set,
# smallest to largest), enough for `cargo test --test e2e fuzz_corpus::` to
# replay every parser on structured input. A fuzzing campaign wants the full
# coverage-rich set back; this script rebuilds it in two steps:
#
#   1. seeds from a freshly generated fleet (fuzz/make_corpus.py: a few rows
#      of every contract table, every built-in machine config, a replay
#      candump log, the drive EDS);
#   2. libFuzzer runs of every target for SECONDS each, growing
#      fuzz/corpus/TARGET/ in place, then a merge (-merge=1) that keeps only
#      the inputs adding coverage.
#
# Usage: fuzz/regenerate-corpus.sh [SECONDS] [TARGET...]
#   SECONDS  per target, default 600 (the figures in docs/reliability.md)
#   TARGET   default: all six (parquet_table observations run_toml
#            machine_config candump eds)
#
# Needs: a nightly toolchain, `cargo install cargo-fuzz`, python3 with
# pyarrow (for step 1). The first `--dev` build instruments every dependency
# (polars included) and takes long (35 min on 2 cores). New files are named
# by their SHA-1, as libFuzzer names them; do not commit the grown corpus —
# commit a finding as one file (and its fix) instead. Back to the committed
# seeds: git checkout fuzz/corpus && git clean -fdq fuzz/corpus
set -euo pipefail

secs=${1:-600}
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(parquet_table observations run_toml machine_config candump eds)

here=$(cd "$(dirname "$0")" && pwd)
repo=$(dirname "$here")
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# 1. Seeds from a generated fleet.
cd "$repo"
for p in robot guideway gantry form mill; do
    cargo run --release -q -- generate "$p" --runs 1 --seed 1 --out "$tmp/fleet"
done
obs="$tmp/observations.parquet"
cargo run --release -q -- generate observations --runs 4 --seed 1 --out "$obs"
run=$(find "$tmp/fleet" -name run.toml | head -n 1)
cargo run --release -q -- replay --run "$(dirname "$run")" --bus "log:$tmp/replay.log" >/dev/null
python3 "$here/make_corpus.py" "$tmp/fleet" "$obs" "$tmp/replay.log"

# 2. Grow and merge each corpus.
cd "$here"
for t in "${targets[@]}"; do
    mkdir -p "corpus/$t" "$tmp/merged/$t"
    cargo +nightly fuzz run --dev -s none "$t" "corpus/$t" -- \
        -max_total_time="$secs" -timeout=300
    cargo +nightly fuzz run --dev -s none "$t" "$tmp/merged/$t" "corpus/$t" -- -merge=1
    rm -f corpus/"$t"/*
    cp "$tmp/merged/$t"/* "corpus/$t/"
    echo "$t: $(ls "corpus/$t" | wc -l) files"
done
