"""Reference for benches/ae_ingest.rs: numpy + pyarrow streaming ae.parquet by
row group through an RMS envelope and threshold events (the same detector
shape: 1 ms RMS window, threshold mean + 8 sigma of the envelope over the
first 5 ms, hysteresis 0.5, minimum dwell 0.5 ms), on the very files the Rust
bench writes. It is a timing reference: contacts split by a row-group
boundary may be counted differently from the Rust detector.

    pip install numpy pyarrow
    cargo bench --bench ae_ingest            # writes target/bench-data/ae_50000000_{zstd,snappy}.parquet
    python3 benches/reference/ae_ingest.py [target/bench-data/ae_50000000_zstd.parquet ...]
"""
import glob
import sys
import time

import numpy as np
import pyarrow.parquet as pq

FS = 1e6
WINDOW = int(1e-3 * FS)
NOISE = int(5e-3 * FS)
MIN_DWELL = int(0.5e-3 * FS)


def ingest(path):
    pf = pq.ParquetFile(path)
    carry = np.zeros(0)
    thr = None
    events = 0
    above_prev = False
    run = 0
    for batch in pf.iter_batches(batch_size=pf.metadata.row_group(0).num_rows, columns=["t_s", "ae_v"]):
        t = batch.column(0).to_numpy()
        v = batch.column(1).to_numpy().astype(np.float64)
        if not np.all(np.isfinite(v)) or np.any(np.diff(t) < 0):
            raise ValueError("bad input")
        x = np.concatenate([carry, v * v])
        c = np.cumsum(x)
        env = np.sqrt((c[WINDOW:] - c[:-WINDOW]) / WINDOW)
        carry = x[-WINDOW:]
        if thr is None:
            floor = env[:NOISE]
            thr = floor.mean() + 8.0 * floor.std()
        # Hysteresis as segments: a contact is a run of env > 0.5 thr that
        # reaches thr and lasts at least the minimum dwell (vectorised).
        low = np.concatenate([[above_prev], env > 0.5 * thr, [False]]).astype(np.int8)
        d = np.diff(low)
        starts = np.flatnonzero(d == 1)
        ends = np.flatnonzero(d == -1)
        if above_prev:
            starts = np.concatenate([[0], starts])
        ends = ends[: len(starts)]
        if len(starts):
            peaks = np.maximum.reduceat(env, np.minimum(starts, len(env) - 1))
            events += int(np.count_nonzero((peaks > thr) & (ends - starts >= MIN_DWELL)))
        above_prev = bool(env[-1] > 0.5 * thr)
        run += len(env)
    return events, pf.metadata.num_rows


paths = sys.argv[1:] or sorted(glob.glob("target/bench-data/ae_*.parquet"))
for p in paths:
    ingest(p)  # warm the page cache
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        ev, n = ingest(p)
        times.append(time.perf_counter() - t0)
    med = float(np.median(times))
    print(f"{p}: {n} samples, {ev} onsets, median {med:.3f} s = {n / med / 1e6:.1f} M samples/s")
