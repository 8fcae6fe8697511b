#!/usr/bin/env python3
"""Test inputs and independent expected values for sparkout's metrology
(docs/metrology.md), computed with numpy and scipy only.

    python3 tests/data/metrology/make_oracles.py

writes, beside this script:
  spiky_map.parquet        gridded height map (mm), NaN holes, 4 injected spikes
  profile_uniform.csv      x_mm, z_um: a uniform profile (units by name suffix)
  profile_nonuniform.parquet  x_um (suffix), z with field metadata unit=nm
  expected.json            the figures, from the definitions in docs/metrology.md
and reads the instrument samples in ../surface_samples for their expected
figures. Nothing here calls sparkout.
"""
import json
import math
import os

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from scipy.ndimage import gaussian_filter1d
from scipy.optimize import linprog

HERE = os.path.dirname(os.path.abspath(__file__))
SAMPLES = os.path.join(HERE, "..", "surface_samples")
K = 6.0
ALPHA = math.sqrt(math.log(2) / math.pi)


# ---- areal ----
def form_residuals(x, y, z, degree):
    mx, my, mz = x.mean(), y.mean(), z.mean()
    u, v = x - mx, y - my
    cols = [np.ones_like(u), u, v]
    if degree == 2:
        cols += [u * u, u * v, v * v]
    a = np.column_stack(cols)
    c, *_ = np.linalg.lstsq(a, z - mz, rcond=None)
    return (z - mz) - a @ c


def heights(r):
    sq = math.sqrt(np.mean(r ** 2))
    return {
        "Sq": sq,
        "Sa": float(np.mean(np.abs(r))),
        "Sp": float(r.max()),
        "Sv": float(-r.min()),
        "Sz": float(r.max() - r.min()),
        "Ssk": float(np.mean(r ** 3) / sq ** 3),
        "Sku": float(np.mean(r ** 4) / sq ** 4),
    }


def min_zone_plane(x, y, z):
    """min h_hi - h_lo s.t. h_lo <= z - a x - b y <= h_hi (HiGHS)."""
    n = len(z)
    xs, ys = (x - x.mean()) / np.ptp(x), (y - y.mean()) / np.ptp(y)
    zc = z - z.mean()
    # variables a, b, lo, hi
    c = [0, 0, -1, 1]
    a_ub = np.vstack([
        np.column_stack([-xs, -ys, np.zeros(n), -np.ones(n)]),  # z - ax - by <= hi
        np.column_stack([xs, ys, np.ones(n), np.zeros(n)]),     # lo <= z - ax - by
    ])
    b_ub = np.concatenate([-zc, zc])
    res = linprog(c, A_ub=a_ub, b_ub=b_ub, bounds=[(None, None)] * 4, method="highs")
    return float(res.fun)


def ls_flatness(x, y, z):
    r = form_residuals(x, y, z, 1)
    return float(r.max() - r.min())


def spiky_map():
    rng = np.random.default_rng(11)
    xs = np.arange(40) * 0.5          # mm
    ys = np.arange(30) * 0.4
    gx, gy = np.meshgrid(xs, ys)      # rows = y
    z = (0.05 + 2e-4 * gx - 1e-4 * gy + 2e-6 * (gx - 10) ** 2
         + 2e-4 * np.sin(gx / 2.1) * np.cos(gy / 1.7)
         + rng.normal(0, 2e-5, gx.shape))
    spikes = [(3, 7, 0.004), (12, 25, -0.003), (20, 33, 0.0025), (27, 2, 0.005)]
    for i, j, h in spikes:
        z[i, j] += h
    z[5, 5] = np.nan
    z[17, 0] = np.nan
    z[29, 39] = np.nan
    cols = {f"{v:g}": z[:, k] for k, v in enumerate(xs)}
    table = pa.table({"y": ys, **cols})
    pq.write_table(table, os.path.join(HERE, "spiky_map.parquet"))
    ok = ~np.isnan(z)
    x, y, zz = gx[ok], gy[ok], z[ok]
    r = form_residuals(x, y, zz, 1)
    med = np.median(r)
    mad = np.median(np.abs(r - med))
    out = np.abs(r - med) > K * 1.4826 * mad
    keep = ~out
    rk = form_residuals(x[keep], y[keep], zz[keep], 1)
    return {
        "n_valid": int(ok.sum()),
        "n_not_measured": int((~ok).sum()),
        "plane": heights(r),
        "second_order": heights(form_residuals(x, y, zz, 2)),
        "spike_count": int(out.sum()),
        "spike_positions": sorted([[float(a), float(b)] for a, b in zip(x[out], y[out])]),
        "threshold_mm": float(K * 1.4826 * mad),
        "with": {
            "least_squares_flatness": ls_flatness(x, y, zz),
            "min_zone_flatness": min_zone_plane(x, y, zz),
            "Sz": float(r.max() - r.min()),
        },
        "without": {
            "least_squares_flatness": ls_flatness(x[keep], y[keep], zz[keep]),
            "min_zone_flatness": min_zone_plane(x[keep], y[keep], zz[keep]),
            "Sz": float(rk.max() - rk.min()),
            "n": int(keep.sum()),
        },
    }


# ---- profiles ----
def ls_line_residual(x, z):
    b, a = np.polyfit(x, z, 1)
    return z - (b * x + a)


def pl_moments(x, z):
    """Piecewise-linear integrals, as docs/metrology.md states them."""
    d = np.diff(x)
    length = x[-1] - x[0]
    z0, z1 = z[:-1], z[1:]
    m = np.sum(d * (z0 + z1) / 2) / length
    i2 = np.sum(d * (z0 * z0 + z0 * z1 + z1 * z1) / 3) / length
    q = math.sqrt(i2 - m * m)
    a, b = z0 - m, z1 - m
    with np.errstate(invalid="ignore", divide="ignore"):
        ia = np.where(a * b >= 0, d * (np.abs(a) + np.abs(b)) / 2,
                      d * (a * a + b * b) / (2 * (np.abs(a) + np.abs(b))))
    i3 = np.sum(d * (a ** 3 + a * a * b + a * b * b + b ** 3) / 4) / length
    i4 = np.sum(d * (a ** 4 + a ** 3 * b + a * a * b * b + a * b ** 3 + b ** 4) / 5) / length
    return {"q": q, "a": float(ia.sum() / length), "sk": i3 / q ** 3, "ku": i4 / q ** 4,
            "t": float(z.max() - z.min()), "mean": m}


def mean_line(x, z, lc):
    """Δx-weighted Gaussian, normalised, truncated at ±λc."""
    al = ALPHA * lc
    d = np.empty_like(x)
    d[1:-1] = (x[2:] - x[:-2]) / 2
    d[0] = (x[1] - x[0]) / 2
    d[-1] = (x[-1] - x[-2]) / 2
    out = np.empty_like(z)
    for i in range(len(x)):
        lo = max(np.searchsorted(x, x[i] - lc) - 2, 0)
        hi = min(np.searchsorted(x, x[i] + lc) + 2, len(x))
        xj = x[lo:hi]
        sel = ((x[i] - xj) <= lc) & ((xj - x[i]) <= lc)
        t = (xj[sel] - x[i]) / al
        w = np.exp(-np.pi * t * t) / al * d[lo:hi][sel]
        out[i] = np.sum(w * z[lo:hi][sel]) / np.sum(w)
    return out


def min_zone_line(x, z):
    """Exact: the best slope is that of a pair of convex-hull vertices."""
    pts = sorted(zip(x, z))

    def half(points):
        h = []
        for p in points:
            while len(h) >= 2 and ((h[-1][0] - h[-2][0]) * (p[1] - h[-2][1])
                                   - (h[-1][1] - h[-2][1]) * (p[0] - h[-2][0])) <= 0:
                h.pop()
            h.append(p)
        return h
    hull = half(pts) + half(pts[::-1])
    hull = np.array(sorted(set(hull)))
    best = math.inf
    hx, hz = hull[:, 0], hull[:, 1]
    for i in range(len(hull)):
        for j in range(i + 1, len(hull)):
            if hx[i] != hx[j]:
                s = (hz[j] - hz[i]) / (hx[j] - hx[i])
                r = hz - s * hx
                best = min(best, r.max() - r.min())
    return float(best)


def profile_figures(x, z, lc, n_sampling=5):
    p = ls_line_residual(x, z)
    pm = pl_moments(x, p)
    out = {
        "straightness_ls": float(p.max() - p.min()),
        "straightness_mz": min_zone_line(x, z),
        "Pt": pm["t"], "Pq": pm["q"], "Pa": pm["a"], "Psk": pm["sk"], "Pku": pm["ku"],
    }
    if lc is None:
        return out, p
    total = x[-1] - x[0]
    k = min(n_sampling, int(math.floor((total - lc) / lc + 1e-9)))
    r = p - mean_line(x, p, lc)
    ln = k * lc
    start = x[0] + (total - ln) / 2
    end = start + ln
    eps = 1e-9 * lc
    sel = (x >= start - eps) & (x <= end + eps)
    ex, er = x[sel], r[sel]
    rm = pl_moments(ex, er)
    zs = []
    for s in range(k):
        a, b = start + s * lc, start + (s + 1) * lc
        last = s + 1 == k
        w = (ex >= a - eps) & ((ex < b - eps) | (last & (ex <= b + eps)))
        zs.append(er[w].max() - er[w].min())
    out.update({"Rq": rm["q"], "Ra": rm["a"], "Rz": float(np.mean(zs)), "Rt": rm["t"],
                "Rsk": rm["sk"], "Rku": rm["ku"], "sampling_lengths": k,
                "evaluation_start": start})
    return out, p


def uniform_profile():
    step = 0.002
    x = np.arange(4001) * step                      # 8 mm
    rng = np.random.default_rng(5)
    z = (1e-3 * x + 4e-4 * np.sin(2 * np.pi * x / 6.0)      # form and waviness, mm
         + 2e-4 * np.sin(2 * np.pi * x / 0.11) + 8e-5 * np.sin(2 * np.pi * x / 0.037 + 1)
         + rng.normal(0, 3e-5, x.size))
    with open(os.path.join(HERE, "profile_uniform.csv"), "w") as f:
        f.write("x_mm,z_um\n")
        for a, b in zip(x, z * 1e3):
            f.write(f"{a:.6f},{b:.17g}\n")
    # Re-read what was written (the CSV rounds x to 1 nm).
    data = np.loadtxt(os.path.join(HERE, "profile_uniform.csv"), delimiter=",", skiprows=1)
    x, z = data[:, 0], data[:, 1] / 1e3
    lc = 0.8
    out, p = profile_figures(x, z, lc)
    # Cross-check with scipy's uniform-grid Gaussian (a different
    # discretisation: a kernel of 4σ... set to ±λc here, reflect at the ends).
    sigma = ALPHA * lc / math.sqrt(2 * math.pi) / step
    w = gaussian_filter1d(p, sigma, mode="reflect", truncate=lc / step / sigma)
    r = p - w
    total = x[-1] - x[0]
    start = x[0] + (total - 5 * lc) / 2
    sel = (x >= start - 1e-9) & (x <= start + 5 * lc + 1e-9)
    out["Rq_scipy_gaussian_filter1d"] = float(np.sqrt(np.mean((r[sel] - r[sel].mean()) ** 2)))
    out["lambda_c"] = lc
    return out


def nonuniform_profile():
    rng = np.random.default_rng(8)
    steps = rng.uniform(0.5, 3.0, 2999)             # µm
    x_um = np.concatenate([[0.0], np.cumsum(steps)])
    z_nm = 50 * np.sin(x_um / 400) + 20 * np.sin(x_um / 13) + rng.normal(0, 4, x_um.size)
    z_nm[[100, 1700]] = np.nan                       # not measured
    field = pa.field("height", pa.float64(), metadata={"unit": "nm"})
    t = pa.table({"x_um": x_um, "height": pa.array(z_nm)},
                 schema=pa.schema([pa.field("x_um", pa.float64()), field]))
    pq.write_table(t, os.path.join(HERE, "profile_nonuniform.parquet"))
    ok = ~np.isnan(z_nm)
    x, z = x_um[ok] / 1e3, z_nm[ok] / 1e6
    lc = 0.8
    out, _ = profile_figures(x, z, lc)
    out["n_points"] = int(ok.sum())
    out["n_not_measured"] = int((~ok).sum())
    out["lambda_c"] = lc
    return out


def samples():
    s = {}
    d = np.loadtxt(os.path.join(SAMPLES, "opdx-3.txt"))
    x, z = d[:, 0] * 1e3, d[:, 1] * 1e3             # m -> mm
    p = ls_line_residual(d[:, 0], d[:, 1])
    s["opdx-3"] = {"Pt": float((p.max() - p.min()) * 1e3), "n": len(x),
                   "Pq": pl_moments(x, ls_line_residual(x, z))["q"]}
    d = np.loadtxt(os.path.join(SAMPLES, "nonuniform.asc"))
    x, z = d[:, 0] / 1e3, d[:, 1] / 1e3             # µm -> mm
    f, _ = profile_figures(x, z, None)
    s["nonuniform"] = {"Pq": f["Pq"], "Pt": f["Pt"], "n": len(x)}
    d = np.loadtxt(os.path.join(SAMPLES, "xy-2.txt"), delimiter=",", skiprows=2)
    x, z = d[:, 0] / 1e3, d[:, 1] / 1e3
    f, _ = profile_figures(x, z, None)
    s["xy-2"] = {"Pt": f["Pt"], "Pq": f["Pq"], "straightness_mz": f["straightness_mz"], "n": len(x)}
    d = np.loadtxt(os.path.join(SAMPLES, "csv-1.csv"), delimiter=",", skiprows=1)
    x, z = d[:, 0] / 1e3, d[:, 1] / 1e3
    f, _ = profile_figures(x, z, None)
    s["csv-1"] = {"Pt": f["Pt"], "Pq": f["Pq"], "n": len(x)}
    m = np.loadtxt(os.path.join(SAMPLES, "matrix-6.txt"), comments="#") * 1e3   # m -> mm
    rows, cols = m.shape
    gx, gy = np.meshgrid(np.arange(cols) * 10e-3 / cols, np.arange(rows) * 10e-3 / rows)
    s["matrix-6"] = {"n": int(m.size), "rows": rows, "cols": cols,
                     "pixel_x_mm": 10e-3 / cols, "pixel_y_mm": 10e-3 / rows,
                     "least_squares_flatness": ls_flatness(gx.ravel(), gy.ravel(), m.ravel()),
                     "z_max_mm": float(m.max())}
    return s


def main():
    expected = {
        "spiky_map": spiky_map(),
        "profile_uniform": uniform_profile(),
        "profile_nonuniform": nonuniform_profile(),
        "samples": samples(),
    }
    with open(os.path.join(HERE, "expected.json"), "w") as f:
        json.dump(expected, f, indent=1, sort_keys=True)
        f.write("\n")


if __name__ == "__main__":
    main()
