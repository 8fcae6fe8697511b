"""Reference for benches/fft_removal.rs: scipy.signal.fftconvolve ("same")
of a 2048 x 2048 dwell map with the disc tool's 201 x 201 influence function
(100 mm radius on a 1 mm grid), the same sizes and kernel as the Rust bench.

    pip install numpy scipy
    python3 benches/reference/fftconvolve.py             # 2048 x 2048, median of 5
    python3 benches/reference/fftconvolve.py --scaling   # N = 512 ... 4096, best of 3
"""
import sys
import time

import numpy as np
from scipy.signal import fftconvolve

N = 2048
R = 100.0
k_p, p, n_rev, v_lin = 1.7097e-8, 389.93, 2.5, 1000.0
h = int(R)
yy, xx = np.mgrid[-h : h + 1, -h : h + 1].astype(float)
rho = np.hypot(xx, yy)
ker = np.where(rho <= R, k_p * p * np.sqrt(v_lin**2 + (2 * np.pi * n_rev * rho) ** 2), 0.0)
rng = np.random.default_rng(0)

if "--scaling" in sys.argv:
    prev = None
    for n in (512, 1024, 2048, 4096):
        d = rng.random((n, n)) * 0.01
        fftconvolve(d, ker, mode="same")  # warm-up
        best = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            fftconvolve(d, ker, mode="same")
            best = min(best, time.perf_counter() - t0)
        exp = "" if prev is None else f"  exponent {np.log(best / prev[1]) / np.log(n / prev[0]):.2f}"
        print(f"scipy fftconvolve scaling N = {n:4d}: {best * 1e3:8.1f} ms{exp}")
        prev = (n, best)
    sys.exit(0)

dwell = rng.random((N, N)) * 0.01

fftconvolve(dwell, ker, mode="same")  # warm-up
times = []
for _ in range(5):
    t0 = time.perf_counter()
    fftconvolve(dwell, ker, mode="same")
    times.append(time.perf_counter() - t0)
print(f"scipy.signal.fftconvolve {N}x{N} with {2*h+1}x{2*h+1}: median {np.median(times)*1e3:.1f} ms (min {min(times)*1e3:.1f} ms)")
