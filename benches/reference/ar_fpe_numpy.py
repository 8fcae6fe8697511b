"""Reference for `guideway_predictor/fpe_search_p20_1e6`:
the FPE order search p = 1..20 over the same twice-differenced 10^6-sample
series as benches/guideway_predictor.rs, by numpy normal equations — one
lagged design matrix, its Gram matrix X'X and X'y once, then each order's
leading p x p block solved (the fastest plain-numpy way; statsmodels'
AutoReg per order, benches/reference/ar_fpe.py, is far slower). Then RLS
of the chosen order over the same samples in a numpy loop (the per-sample
recursion cannot be vectorised), for `rls_chosen_order_1e6`.

    pip install numpy
    python3 benches/reference/ar_fpe_numpy.py

Prints the chosen order, the FPE values and the best wall time of 5 runs.
"""
import time

import numpy as np

from ar_fpe import N, series


def fpe_search(y, pmax=20):
    n = len(y) - pmax
    # Column i = y lagged by i+1, rows t = pmax..len-1 (hold_back = pmax).
    X = np.lib.stride_tricks.sliding_window_view(y[:-1], pmax)[:, ::-1]
    X = np.ascontiguousarray(X[: n])
    t = y[pmax:]
    G = X.T @ X
    b = X.T @ t
    tt = t @ t
    fpe = []
    for p in range(1, pmax + 1):
        a = np.linalg.solve(G[:p, :p], b[:p])
        rss = tt - a @ b[:p]
        s2 = rss / n
        fpe.append(s2 * (n + p) / (n - p))
    return int(np.argmin(fpe)) + 1, fpe


def rls(y, p, lam=1.0, p0=1e6):
    a = np.zeros(p)
    P = np.eye(p) * p0
    for t in range(p, len(y)):
        x = y[t - p : t][::-1]
        Px = P @ x
        k = Px / (lam + x @ Px)
        a += k * (y[t] - x @ a)
        P = (P - np.outer(k, Px)) / lam
    return a


def main():
    dz = series()
    y = np.diff(dz, n=2)
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        order, fpe = fpe_search(y)
        best = min(best, time.perf_counter() - t0)
    print(f"order {order}; FPE(1..5) {[f'{v:.4e}' for v in fpe[:5]]}")
    print(f"numpy normal-equations FPE search p<=20 over {N} samples: {best:.3f} s (best of 5)")
    t0 = time.perf_counter()
    rls(y, order)
    print(f"numpy RLS order {order} over {N} samples: {time.perf_counter() - t0:.2f} s")


if __name__ == "__main__":
    main()
