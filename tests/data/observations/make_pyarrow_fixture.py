# Writes pyarrow_two_machines.parquet: a paired-observations table
# (docs/formats.md section 7) written by pyarrow with its defaults (snappy,
# dictionary-encoded text, statistics), in row groups of 500 rows. Two
# machines whose runs share ids, an observable in µm with a scale error on
# m2 alone, a velocity without x_mm, an int covariate and a covariate that
# is null on every row. Re-run to regenerate: python3 make_pyarrow_fixture.py
import math
import random

import pyarrow as pa
import pyarrow.parquet as pq

rng = random.Random(5)
cols = {k: [] for k in ["machine", "run", "observable", "unit", "sim", "real",
                        "x_mm", "segment", "t_s", "temp_c"]}
for m in ["m1", "m2"]:
    for r in range(6):
        for i in range(150):
            x = float(i * 37 % 150)
            for o in ["a_um", "b"]:
                cols["machine"].append(m)
                cols["run"].append(f"r{r}")
                cols["observable"].append(o)
                cols["t_s"].append(i * 0.1)
                cols["segment"].append(i // 30)
                cols["temp_c"].append(None)
                cols["sim"].append(0.0)
                if o == "a_um":
                    k = 0.05 if m == "m2" else 0.0
                    cols["unit"].append("um")
                    cols["real"].append(k * x + 0.3 * rng.gauss(0, 1))
                    cols["x_mm"].append(x)
                else:
                    cols["unit"].append(None)
                    cols["real"].append(1e-3 * math.sin(0.2 * i) + 1e-4 * rng.gauss(0, 1))
                    cols["x_mm"].append(None)
t = pa.table({
    **{k: pa.array(cols[k], pa.string()) for k in ["machine", "run", "observable", "unit"]},
    **{k: pa.array(cols[k], pa.float64()) for k in ["sim", "real", "x_mm", "t_s", "temp_c"]},
    "segment": pa.array(cols["segment"], pa.int64()),
})
pq.write_table(t, "pyarrow_two_machines.parquet", row_group_size=500)
