#!/usr/bin/env python3
"""Write datasets/samples/umich_cnc/ from the original UMich CNC mill
tool-wear CSVs (Kaggle "CNC Mill Tool Wear", CC0): every row of all 18
experiments, only the columns the `umich_cnc` import mapping reads (plus the
machining phase, for reference), values copied as text (byte-identical
numbers), gzip-compressed with a fixed mtime so the output is reproducible.

usage: umich_cnc_sample.py SRC_DIR OUT_DIR
"""
import csv
import gzip
import io
import shutil
import sys
from pathlib import Path

AXES = ["X1", "Y1", "Z1"]
SIGNALS = ["ActualPosition", "ActualVelocity", "ActualAcceleration",
           "CommandPosition", "CommandVelocity", "CommandAcceleration"]
KEEP = [""] + [f"{a}_{s}" for a in AXES for s in SIGNALS] + [
    "M1_sequence_number", "M1_CURRENT_FEEDRATE", "Machining_Process"]


def main(src: Path, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for i in range(1, 19):
        name = f"experiment_{i:02d}.csv"
        with open(src / name, newline="") as f:
            rows = list(csv.reader(f))
        idx = [rows[0].index(c) for c in KEEP]
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        for r in rows:
            w.writerow([r[j] for j in idx])
        data = buf.getvalue().encode()
        with open(out / (name + ".gz"), "wb") as raw:
            with gzip.GzipFile(filename=name, mode="wb", fileobj=raw,
                               compresslevel=9, mtime=0) as g:
                g.write(data)
    shutil.copy(src / "experiments.csv", out / "experiments.csv")


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
