"""Reference for benches/guideway_predictor.rs: the same
10^6-sample ARIMA(4,2,0) series, differenced twice, AR order by FPE over
p = 1..20 with statsmodels AutoReg per order (trend="n", hold_back=20, so
every order is fitted on the same samples, as the Rust code does).

    pip install numpy statsmodels
    python3 benches/reference/ar_fpe.py

Prints the chosen order, the FPE values and the wall time of the search.
"""
import time

import numpy as np

N = 1_000_000
AR = [0.5, -0.3, 0.25, -0.3]
MASK = (1 << 64) - 1


def series():
    # xorshift64 + Irwin-Hall(4), identical to the Rust bench.
    s = 0x2545F4914F6CDD1D
    e = np.empty(N)
    for t in range(N):
        acc = 0.0
        for _ in range(4):
            s ^= (s << 13) & MASK
            s ^= s >> 7
            s ^= (s << 17) & MASK
            acc += (s >> 11) / float(1 << 53)
        e[t] = (acc - 2.0) * np.sqrt(3.0) * 1e-3
    y = np.zeros(N)
    for t in range(N):
        v = e[t]
        for i, a in enumerate(AR):
            if t > i:
                v += a * y[t - 1 - i]
        y[t] = v
    return np.cumsum(np.cumsum(y))


def main():
    # Imported here so ar_fpe_numpy.py can reuse series() without statsmodels.
    from statsmodels.tsa.ar_model import AutoReg

    dz = series()
    t0, c0 = time.perf_counter(), time.process_time()
    y = np.diff(dz, n=2)
    pmax = 20
    fpe = []
    for p in range(1, pmax + 1):
        r = AutoReg(y, lags=p, trend="n", hold_back=pmax).fit()
        n = r.nobs
        fpe.append(r.sigma2 * (n + p + 1) / (n - p - 1))
    order = int(np.argmin(fpe)) + 1
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    print(f"order {order}; FPE(1..5) {[f'{v:.4e}' for v in fpe[:5]]}")
    print(
        f"statsmodels AutoReg FPE search p<=20 over {N} samples: "
        f"{dt:.3f} s wall, {dc:.3f} s CPU (all threads)"
    )


if __name__ == "__main__":
    main()
