"""High-precision reference solutions for the work-precision diagrams (bench/bench.py).

Written independently of the Rust core: the equations of motion are derived here from the
Lagrangian of a chain of rigid links (seed formulas), solved as a dense linear system in
mpmath at ``DPS`` decimal digits, and integrated with Gragg-Bulirsch-Stoer extrapolation
(modified midpoint rule, step sequence 2, 4, ..., 2k, Aitken-Neville extrapolation in h^2:
order 2k) on a fixed macro-step H. Its accuracy is shown by halving: the reported
``halving_diff`` is the largest difference between the final states at 2H and H, a bound on the
error of the run at 2H (the run at H, the one returned, is 2^(2k) times more accurate).

With absolute angles theta (from the downward vertical), K_aa = I_a + m_a c_a^2 +
l_a^2 sum_{k>a} m_k, K_ab = l_min(a,b) h_max(a,b) (a != b), h_b = m_b c_b + l_b sum_{k>b} m_k,
the Euler-Lagrange equations of T = 1/2 sum K_ab cos(theta_a - theta_b) w_a w_b and
U = -g sum m_i y_com_i are

    sum_b K_ab cos(theta_a - theta_b) theta_b'' = -sum_b K_ab sin(theta_a - theta_b) w_b^2
                                                  - g h_a sin(theta_a).

Results are cached in bench/build/ as JSON keyed by the problem (a hash of its parameters).
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import mpmath

DPS = 40
CACHE = Path(__file__).resolve().parent / "build"


def _coefficients(lengths, masses, com, inertia):
    mp = mpmath.mp
    n = len(lengths)
    l = [mp.mpf(x) for x in lengths]
    m = [mp.mpf(x) for x in masses]
    c = [mp.mpf(x) for x in com]
    inn = [mp.mpf(x) for x in inertia]
    below = [sum(m[a + 1:], mp.mpf(0)) for a in range(n)]  # mass hanging below link a
    h = [m[b] * c[b] + l[b] * below[b] for b in range(n)]
    K = [[None] * n for _ in range(n)]
    for a in range(n):
        for b in range(n):
            if a == b:
                K[a][a] = inn[a] + m[a] * c[a] ** 2 + l[a] ** 2 * below[a]
            else:
                lo, hi = min(a, b), max(a, b)
                K[a][b] = l[lo] * h[hi]
    return K, h


def _rhs_factory(lengths, masses, com, inertia, g):
    n = len(lengths)
    K, h = _coefficients(lengths, masses, com, inertia)
    gh = [mpmath.mpf(g) * x for x in h]
    sin, cos = mpmath.sin, mpmath.cos

    def rhs(y):
        th, w = y[:n], y[n:]
        s = [sin(x) for x in th]
        co = [cos(x) for x in th]
        w2 = [x * x for x in w]
        A = [[None] * n for _ in range(n)]
        r = [None] * n
        for a in range(n):
            acc = -gh[a] * s[a]
            row = A[a]
            for b in range(n):
                if a == b:
                    row[b] = K[a][a]
                else:
                    row[b] = K[a][b] * (co[a] * co[b] + s[a] * s[b])
                    acc -= K[a][b] * (s[a] * co[b] - co[a] * s[b]) * w2[b]
            r[a] = acc
        # Gaussian elimination without pivoting: A is symmetric positive definite.
        for k in range(n):
            piv = A[k][k]
            for i in range(k + 1, n):
                f = A[i][k] / piv
                if f:
                    Ai, Ak = A[i], A[k]
                    for j in range(k + 1, n):
                        Ai[j] -= f * Ak[j]
                    r[i] -= f * r[k]
        x = [None] * n
        for i in range(n - 1, -1, -1):
            acc = r[i]
            for j in range(i + 1, n):
                acc -= A[i][j] * x[j]
            x[i] = acc / A[i][i]
        return list(w) + x

    return rhs


def _gbs_step(rhs, y, H, k):
    """One Gragg-Bulirsch-Stoer macro-step of size H, order 2k."""
    f0 = rhs(y)
    table = []
    for j in range(1, k + 1):
        nj = 2 * j
        hj = H / nj
        z0 = list(y)
        z1 = [a + hj * b for a, b in zip(y, f0)]
        for _ in range(1, nj):
            f = rhs(z1)
            z0, z1 = z1, [a + 2 * hj * b for a, b in zip(z0, f)]
        row = [z1]
        for i in range(1, j):  # Aitken-Neville in h^2 with n_j = 2j
            ratio = mpmath.mpf(j * j) / ((j - i) * (j - i)) - 1
            prev, prev_up = row[i - 1], table[-1][i - 1]
            row.append([a + (a - b) / ratio for a, b in zip(prev, prev_up)])
        table.append(row)
    return table[-1][-1]


def integrate(lengths, masses, com, inertia, g, theta0, omega0, t_end, macro_steps, k):
    with mpmath.workdps(DPS):
        rhs = _rhs_factory(lengths, masses, com, inertia, g)
        y = [mpmath.mpf(x) for x in list(theta0) + list(omega0)]
        H = mpmath.mpf(t_end) / macro_steps
        for _ in range(macro_steps):
            y = _gbs_step(rhs, y, H, k)
        return y


def reference(name, lengths, masses, com, inertia, g, theta0, omega0, t_end, macro_steps, k,
              log=print):
    """Final state (floats) of the problem at t_end, with its accuracy; cached in bench/build."""
    problem = {"lengths": list(map(float, lengths)), "masses": list(map(float, masses)),
               "com": list(map(float, com)), "inertia": list(map(float, inertia)),
               "g": float(g), "theta0": list(map(float, theta0)),
               "omega0": list(map(float, omega0)), "t_end": float(t_end),
               "macro_steps": int(macro_steps), "k": int(k), "dps": DPS, "version": 2}
    key = hashlib.sha256(json.dumps(problem, sort_keys=True).encode()).hexdigest()[:16]
    path = CACHE / f"reference_{name}_{key}.json"
    if path.exists():
        out = json.loads(path.read_text())
        out["cached"] = True
        return out
    log(f"computing the {name} reference in mpmath ({DPS} digits, GBS order {2 * k}, "
        f"H = {t_end / macro_steps:g} and 2H; cached afterwards) ...")
    t0 = time.perf_counter()
    args = (problem["lengths"], problem["masses"], problem["com"], problem["inertia"], g,
            problem["theta0"], problem["omega0"], t_end)
    fine = integrate(*args, macro_steps, k)
    coarse = integrate(*args, macro_steps // 2, k)
    diff = max(abs(a - b) for a, b in zip(coarse, fine))
    out = {"problem": problem, "final": [float(x) for x in fine],
           "final_str": [mpmath.nstr(x, 30) for x in fine],
           "halving_diff": float(diff), "seconds": time.perf_counter() - t0, "cached": False}
    CACHE.mkdir(exist_ok=True)
    path.write_text(json.dumps(out, indent=1))
    return out
