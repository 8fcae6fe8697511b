"""Python reference for benches/mill_identification.rs.

The same XFYZ 21-error model (plugins/src/mill/chain.rs: Legendre degree 3
in the identification gauge, 3 squareness terms, tracker frame by Rodrigues
rotation + translation), 2000 tracker points with three tool offsets and
2 um noise, identified with scipy.optimize.least_squares (Levenberg-Marquardt,
finite-difference Jacobian of a vectorised residual: what a numpy user would
write) plus the covariance from J'J. Prints the median wall time of the
identification and the recovery check.

    pip install numpy scipy
    python3 benches/reference/mill_identification.py
"""

import time

import numpy as np
from numpy.polynomial import legendre
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

DEG = 3
TRAVELS = np.array([[0.0, 600.0], [0.0, 400.0], [0.0, 300.0]])
TOOLS = np.array([[0.0, 0.0, -120.0], [100.0, 0.0, -120.0], [0.0, 100.0, -120.0]])
N = 2000


def min_order(f):
    axis, kind = divmod(f, 6)
    if kind < 3:
        return 1 if kind == axis else 2
    return 0 if axis == 2 else 1


COEF = [(f, m) for f in range(18) for m in range(min_order(f), DEG + 1)]
NC = len(COEF)
NP = NC + 9


def skew(v):
    """[v]x for an (n, 3) array -> (n, 3, 3)."""
    z = np.zeros(len(v))
    return np.stack(
        [
            np.stack([z, -v[:, 2], v[:, 1]], -1),
            np.stack([v[:, 2], z, -v[:, 0]], -1),
            np.stack([-v[:, 1], v[:, 0], z], -1),
        ],
        1,
    )


def basis(q):
    """Legendre values per axis: (3, n, DEG+1)."""
    xi = 2 * (q - TRAVELS[:, 0]) / (TRAVELS[:, 1] - TRAVELS[:, 0]) - 1
    return np.stack([legendre.legvander(xi[:, a], DEG) for a in range(3)])


def tracker_points(params, q, tool, leg):
    errs = np.zeros((len(q), 18))
    for j, (f, m) in enumerate(COEF):
        errs[:, f] += params[j] * leg[f // 6][:, m]
    sxy, sxz, syz = params[NC : NC + 3]
    w, t = params[NC + 3 : NC + 6], params[NC + 6 : NC + 9]
    eye = np.eye(3)
    r = [eye + skew(errs[:, 6 * a + 3 : 6 * a + 6]) for a in range(3)]
    d = [errs[:, 6 * a : 6 * a + 3] for a in range(3)]
    x, y, z = q[:, 0:1], q[:, 1:2], q[:, 2:3]
    u_y = np.array([sxy, 1.0, 0.0])
    u_z = np.array([sxz, syz, 1.0])
    wv = z * u_z + d[2] + np.einsum("nij,nj->ni", r[2], tool)
    v = y * u_y + d[1] + np.einsum("nij,nj->ni", r[1], wv) + x * np.array([1.0, 0, 0]) - d[0]
    p = np.linalg.solve(r[0], v[..., None])[..., 0]
    return Rotation.from_rotvec(w).apply(p) + t


def kabsch(p, m):
    pc, mc = p.mean(0), m.mean(0)
    h = (p - pc).T @ (m - mc)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1, 1, d]) @ u.T
    return Rotation.from_matrix(r).as_rotvec(), mc - r @ pc


def identify(q, tool, m):
    leg = basis(q)
    x0 = np.zeros(NP)
    x0[NC + 3 : NC + 6], x0[NC + 6 :] = kabsch(q + tool, m)
    res = least_squares(
        lambda x: (tracker_points(x, q, tool, leg) - m).ravel(),
        x0,
        method="lm",
        x_scale="jac",
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
    )
    j = res.jac
    dof = j.shape[0] - NP
    s2 = (res.fun @ res.fun) / dof
    cov = np.linalg.pinv(j.T @ j) * s2
    return res.x, cov, np.sqrt(s2)


def main():
    rng = np.random.default_rng(1)
    truth = np.zeros(NP)
    for j, (f, m) in enumerate(COEF):
        scale = 25e-6 if f % 6 >= 3 else (0.010 if f % 6 == f // 6 else 0.006)
        truth[j] = scale / max(m, 1) * rng.standard_normal()
    truth[NC : NC + 3] = 30e-6 * rng.standard_normal(3)
    truth[NC + 3 : NC + 6] = [0.3, -0.9, 1.7]
    truth[NC + 6 :] = [1600.0, -500.0, 250.0]
    q = TRAVELS[:, 0] + (TRAVELS[:, 1] - TRAVELS[:, 0]) * rng.random((N, 3))
    tool = TOOLS[np.arange(N) % 3]
    m = tracker_points(truth, q, tool, basis(q)) + 0.002 * rng.standard_normal((N, 3))
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        est, cov, s = identify(q, tool, m)
        times.append(time.perf_counter() - t0)
    z = np.abs(est - truth) / np.sqrt(np.diag(cov))
    print(f"params {NP}, points {N}, sigma {s*1e3:.3f} um, max |est-true|/sigma {z.max():.2f}")
    print(f"identification: median {np.median(times)*1e3:.1f} ms over {len(times)} runs")


if __name__ == "__main__":
    main()
