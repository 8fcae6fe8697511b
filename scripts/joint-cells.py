#!/usr/bin/env python3
"""How far a fleet's observation rows pool into joint cells of their covariates.

The figures of docs/design.md §8 ("Joint cells do not pool either"):

    python3 scripts/joint-cells.py OUT/fleet/observations.parquet following_error_x

For each covariate set and each B, every row of the observable falls into the
cell of B equal bins across each covariate's fleet range (a constant
covariate: one bin); printed are the cells counted per run (summed over the
runs) and over the whole fleet, each as a share of the rows. A share near 1
means the cells are as many as the rows: a per-run statistic on that grid
is as large as the run's rows.

Needs pyarrow and numpy (`pip install pyarrow numpy`); not used by the
product or its tests.
"""

import sys

import numpy as np
import pyarrow.parquet as pq

SETS = {
    "all": None,  # every covariate of the file
    "no-time": "-t_s",  # every covariate but t_s
    "speed": "cmd_v_mm_s,cmd_a_mm_s2",
}
BINS = (16, 64, 256, 1024)
# Columns that are keys or values, never covariates (docs/formats.md §7).
NOT_COVARIATES = {"machine", "run", "observable", "unit", "sim", "real", "real_u", "segment"}


def covariate_sets(table):
    covs = [
        f.name
        for f in table.schema
        if f.name not in NOT_COVARIATES and str(f.type) in ("double", "float")
    ]
    for name, spec in SETS.items():
        if spec is None:
            yield name, covs
        elif spec.startswith("-"):
            yield name, [c for c in covs if c != spec[1:]]
        else:
            wanted = spec.split(",")
            if all(c in covs for c in wanted):
                yield name, wanted


def cell_bins(table, covs, bins):
    """A row per observation row: its bin of each covariate."""
    n = table.num_rows
    out = np.zeros((n, len(covs)), dtype=np.int32)
    for k, c in enumerate(covs):
        v = table[c].to_numpy()
        lo, hi = v.min(), v.max()
        if hi > lo:
            out[:, k] = np.minimum(((v - lo) / (hi - lo) * bins).astype(np.int64), bins - 1)
    return out


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    path, observable = sys.argv[1], sys.argv[2]
    table = pq.read_table(path, filters=[("observable", "=", observable)])
    n = table.num_rows
    if n == 0:
        sys.exit(f"{path}: no rows of observable {observable}")
    runs = np.unique(table["run"].to_numpy(), return_inverse=True)[1]
    print(f"{observable}: {n} rows, {runs.max() + 1} runs")
    for name, covs in covariate_sets(table):
        for bins in BINS:
            cells = cell_bins(table, covs, bins)
            per_run = np.unique(np.column_stack([runs, cells]), axis=0).shape[0]
            fleet = np.unique(cells, axis=0).shape[0]
            print(
                f"{name:8} ({len(covs)} covariates) B={bins:5}: "
                f"per run {per_run / n:.3f}, fleet-wide {fleet / n:.4f}"
            )


if __name__ == "__main__":
    main()
