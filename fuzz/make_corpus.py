"""Seed corpora for the cargo-fuzz targets (docs/reliability.md "Fuzzing";
fuzz/regenerate-corpus.sh runs it, then grows the corpora by fuzzing).

Usage: python3 fuzz/make_corpus.py FLEET_ROOT OBSERVATIONS.parquet CANDUMP.log
where FLEET_ROOT holds one generated run of every plugin
(`sparkout generate robot|guideway|gantry|form|mill --runs 1 --out FLEET_ROOT`),
OBSERVATIONS from `sparkout generate observations`, CANDUMP from
`sparkout replay --bus log:FILE`. Seeds are small (a few rows per table):
the fuzzer mutates structure, not volume.
"""
import glob
import io
import os
import sys

import pyarrow.parquet as pq

# Order of ALL_TABLES in pipeline/src/contracts/schema.rs: the first byte of
# a parquet_table input picks the table.
TABLES = ["ae", "motion", "probe", "plan", "passes", "topography",
          "guideway", "profile", "tracker", "thermal"]
MACHINES = ["kr16-lab", "aplm-gantry", "guideway-grinder", "xfyz-mill", "form-grinder"]

here = os.path.dirname(os.path.abspath(__file__))
root, obs, log = sys.argv[1:4]


def out(target, name, data):
    d = os.path.join(here, "corpus", target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def small_parquet(path, rows, compression):
    t = pq.read_table(path).slice(0, rows)
    buf = io.BytesIO()
    pq.write_table(t, buf, compression=compression)
    return buf.getvalue()


for i, name in enumerate(TABLES):
    for path in sorted(glob.glob(os.path.join(root, "*", "*", name + ".parquet")))[:1]:
        for comp in ["zstd", "snappy", "none"]:
            out("parquet_table", f"{name}-{comp}", bytes([i]) + small_parquet(path, 24, comp))
out("observations", "obs-zstd", small_parquet(obs, 40, "zstd"))
out("observations", "obs-snappy", small_parquet(obs, 40, "snappy"))
for path in sorted(glob.glob(os.path.join(root, "*", "*", "run.toml"))):
    out("run_toml", os.path.basename(os.path.dirname(os.path.dirname(path))),
        open(path, "rb").read())
cfg = os.path.join(here, "..", "configs")
for i, m in enumerate(MACHINES):
    out("machine_config", m, bytes([i]) + open(os.path.join(cfg, "machines", m + ".toml"), "rb").read())
with open(log, "rb") as f:
    out("candump", "replay-head", b"".join(f.readline() for _ in range(64)))
out("eds", "cia402_drive", open(os.path.join(cfg, "can", "cia402_drive.eds"), "rb").read())
