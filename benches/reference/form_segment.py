"""Python (numpy/scipy) reference for benches/form_segment.rs: the same
2000-point tangent cam, curvature by a local cubic (Savitzky-Golay, wrap)
and the segment sweep N = 1..10 with 11 radii per segment (docs/models.md §4).
Prints the timings and the sweep's maximum errors for comparison with
`sparkout stage segment`. Run: python3 benches/reference/form_segment.py"""
import time
import numpy as np
from scipy.signal import savgol_filter

BASE, NOSE, D = 40.0, 14.0, 36.0


def cam_r(phi):
    c, s = np.cos(phi), np.sin(phi)
    best = np.full_like(phi, BASE)
    disc = (D * c) ** 2 - (D * D - NOSE * NOSE)
    ok = disc >= 0
    best[ok] = np.maximum(best[ok], D * c[ok] + np.sqrt(disc[ok]))
    th = np.arccos((BASE - NOSE) / D)
    q = [(BASE * np.cos(th), BASE * np.sin(th)), (D + NOSE * np.cos(th), NOSE * np.sin(th)),
         (D + NOSE * np.cos(th), -NOSE * np.sin(th)), (BASE * np.cos(th), -BASE * np.sin(th))]
    for k in range(4):
        p, r = q[k], q[(k + 1) % 4]
        e = (r[0] - p[0], r[1] - p[1])
        den = c * e[1] - s * e[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (p[0] * e[1] - p[1] * e[0]) / den
            u = (p[0] * s - p[1] * c) / den
        hit = (np.abs(den) > 1e-15) & (t > 0) & (u >= -1e-12) & (u <= 1 + 1e-12)
        best[hit] = np.maximum(best[hit], t[hit])
    return best


def geometry(phi, r, window=9):
    h = phi[1] - phi[0]
    d1 = savgol_filter(r, window, 3, deriv=1, delta=h, mode="wrap")
    d2 = savgol_filter(r, window, 3, deriv=2, delta=h, mode="wrap")
    kappa = (r * r + 2 * d1 * d1 - r * d2) / (r * r + d1 * d1) ** 1.5
    c, s = np.cos(phi), np.sin(phi)
    tx, ty = d1 * c - r * s, d1 * s + r * c
    tn = np.hypot(tx, ty)
    return kappa, np.stack([ty / tn, -tx / tn]), np.stack([r * c, r * s])


def gamma(pts, nrm, rkn):
    cx, cy = pts + rkn * nrm
    re = np.hypot(cx, cy)
    ux, uy = cx / re, cy / re
    return np.arctan2(ux * nrm[1] - uy * nrm[0], ux * nrm[0] + uy * nrm[1])


def delta(kappa, g, rkn, rk):
    d = rkn - rk
    den = 1 + rk * kappa
    sin_e = d * np.sin(g) * kappa / den
    cos_e = np.sqrt(1 - sin_e ** 2)
    return d * (1 - np.cos(g)) - (1 - rk * kappa) * (d * np.sin(g)) ** 2 * kappa / (den * den * (1 + cos_e))


def sweep(kappa, nrm, pts, rmax=175.0, rng=50.0, nmax=10, samples=11):
    out = []
    for n in range(1, nmax + 1):
        w = rng / n
        worst = 0.0
        for k in range(n):
            hi = rmax - k * w
            lo = hi - w
            nom = 0.5 * (lo + hi)
            g = gamma(pts, nrm, nom)
            rk = np.linspace(lo, hi, samples)[:, None]
            worst = max(worst, np.abs(delta(kappa[None, :], g[None, :], nom, rk)).max())
        out.append(worst)
    return out


if __name__ == "__main__":
    phi = 2 * np.pi * np.arange(2000) / 2000
    r = cam_r(phi)
    reps = 50
    t0 = time.perf_counter()
    for _ in range(reps):
        kappa, nrm, pts = geometry(phi, r)
    t1 = time.perf_counter()
    for _ in range(reps):
        sw = sweep(kappa, nrm, pts)
    t2 = time.perf_counter()
    print(f"curvature_2000: {(t1 - t0) / reps * 1e3:.3f} ms")
    print(f"sweep_1_to_10_segments_2000_points: {(t2 - t1) / reps * 1e3:.3f} ms")
    print("max error (mm) for N=1..10:", " ".join(f"{e:.4f}" for e in sw))
