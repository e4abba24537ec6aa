"""Independent reference physics for the planar N-link pendulum (a test helper, not a test file).

Nothing here reads the package or the mass-matrix formula in DESIGN.md. Three routes:

* ``derive(n, kind)``: sympy builds the Lagrangian from geometry alone. The centre of mass of link
  i sits at ``sum_{j<i} l_j (sin th_j, -cos th_j) + c_i (sin th_i, -cos th_i)``; velocities come
  from sympy's chain rule on ``theta_i(t)``; ``T = sum m_i |v_i|^2 / 2 + I_i w_i^2 / 2``,
  ``U = sum m_i g y_i`` and the driving term ``+ sum tau_i theta_i``. The mass matrix (Hessian of
  T in omega), the Euler-Lagrange equations, momenta dL/domega, Hamilton's p_dot = dL/dtheta and
  the energy follow by differentiation, and are lambdified to plain NumPy float64 code. Every
  derivation keeps l, m, c, I, g, tau symbolic, so one derivation per (n, kind) serves every chain.
* ``cramer_point_masses``: seed 000's own closed form (M*, S, Cramer's rule) for point masses.
* ``seed001_rod_mass_matrix`` / ``seed001_rod_p_dot``: seed 001's closed forms for the double
  pendulum of uniform rods.

``virtual_work_accelerations`` adds a numeric route valid for any N (D'Alembert's principle
with COM Jacobians built from the same geometry), used where sympy would be too slow.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import numpy as np
import sympy as sp
from sympy.polys.domains import QQ
from sympy.polys.rings import ring

KINDS = ("general", "point", "rod")


@dataclass(frozen=True)
class Derivation:
    """Lambdified results of one symbolic derivation.

    Every function takes ``(sin(theta), cos(theta), theta, omega, alpha, l, m, c, I, tau, g)``
    (arrays of length n except the scalar g; arguments a result does not use are accepted and
    ignored) and returns float64.
    """

    n: int
    kind: str
    mass_matrix: Callable  # (n, n): Hessian of T in omega
    el_matrix: Callable  # (n, n): coefficient of theta_ddot in the Euler-Lagrange equations
    el_rhs: Callable  # (n,): M theta_ddot = el_rhs
    kinetic: Callable
    potential: Callable
    momenta: Callable  # (n,): dL/domega
    dl_dtheta: Callable  # (n,): dL/dtheta, including tau
    com: Callable  # (n, 2): centre-of-mass positions
    tips: Callable  # (n, 2): end of each link


@lru_cache(maxsize=None)
def derive(n: int, kind: str = "general") -> Derivation:
    """Derive the dynamics of an n-link chain symbolically (cached per (n, kind)).

    ``kind`` fixes the link model before differentiating: "point" puts c = l, I = 0 (seed 000),
    "rod" puts c = l/2, I = m l^2 / 12 (seed 001), "general" leaves c and I free.

    The algebra runs in a sympy polynomial ring over QQ whose generators are the parameters,
    ``s_k = sin(theta_k)``, ``k_k = cos(theta_k)``, ``theta_k`` (for the ``tau.theta`` term),
    ``omega_k`` and ``alpha_k`` (theta''). d/dtheta_k acts by the chain rule through
    ``ds_k/dtheta_k = k_k`` and ``dk_k/dtheta_k = -s_k``; d/dt is the chain rule on theta(t):
    ``sum_k d/dtheta_k * omega_k + d/domega_k * alpha_k``. Exact rational arithmetic, no
    simplification step, and about a hundred times faster than generic sympy expressions.
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    groups = ("s", "k", "theta", "omega", "alpha", "l", "m", "c", "I", "tau")
    names = [f"{grp}{i}" for grp in groups for i in range(n)] + ["g"]
    _, *gens = ring(",".join(names), QQ)
    sym = dict(zip(names, gens))
    s, k, th, om, al, l, m, c, inertia, tau = (
        [sym[f"{grp}{i}"] for i in range(n)] for grp in groups
    )
    g = sym["g"]
    zero = g * 0
    half = QQ(1, 2)

    if kind == "point":
        c_eff, i_eff = list(l), [zero] * n
    elif kind == "rod":
        c_eff = [li * half for li in l]
        i_eff = [mi * li**2 * QQ(1, 12) for mi, li in zip(m, l)]
    else:
        c_eff, i_eff = list(c), list(inertia)

    def d_dtheta(expr, j):
        return expr.diff(s[j]) * k[j] - expr.diff(k[j]) * s[j] + expr.diff(th[j])

    def d_dt(expr):
        """Total time derivative along theta(t), omega = theta', alpha = omega'."""
        return sum((d_dtheta(expr, j) * om[j] + expr.diff(om[j]) * al[j] for j in range(n)), zero)

    # Geometry: link i starts at the previous joint and points along (sin th_i, -cos th_i).
    tips, coms = [], []
    jx, jy = zero, zero
    for i in range(n):
        coms.append((jx + c_eff[i] * s[i], jy - c_eff[i] * k[i]))
        jx, jy = jx + l[i] * s[i], jy - l[i] * k[i]
        tips.append((jx, jy))

    kin, pot = zero, zero
    for i in range(n):
        vx, vy = d_dt(coms[i][0]), d_dt(coms[i][1])
        kin += m[i] * (vx**2 + vy**2) * half + i_eff[i] * d_dt(th[i]) ** 2 * half
        pot += m[i] * g * coms[i][1]
    lag = kin - pot + sum((tau[i] * th[i] for i in range(n)), zero)

    # Euler-Lagrange: d/dt dL/d(omega_i) - dL/d(theta_i) = 0, linear in alpha.
    el = [d_dt(lag.diff(om[i])) - d_dtheta(lag, i) for i in range(n)]
    no_acc = [e.subs([(a, 0) for a in al]) for e in el]

    exprs = {
        "mass_matrix": [[kin.diff(om[a]).diff(om[b]) for b in range(n)] for a in range(n)],
        "el_matrix": [[el[a].diff(al[b]) for b in range(n)] for a in range(n)],
        "el_rhs": [-e for e in no_acc],
        "kinetic": kin,
        "potential": pot,
        "momenta": [lag.diff(om[i]) for i in range(n)],
        "dl_dtheta": [d_dtheta(lag, i) for i in range(n)],
        "com": [list(p) for p in coms],
        "tips": [list(p) for p in tips],
    }

    symbols = {nm: sp.Symbol(nm) for nm in names}
    args = [[symbols[f"{grp}{i}"] for i in range(n)] for grp in groups] + [symbols["g"]]

    gens_as_symbols = [symbols[nm] for nm in names]

    def to_sympy(x):
        """Ring element -> expression; list -> column, list of lists -> matrix."""
        if not isinstance(x, list):
            return x.as_expr(*gens_as_symbols)
        rows = [row if isinstance(row, list) else [row] for row in x]
        return sp.Matrix([[y.as_expr(*gens_as_symbols) for y in row] for row in rows])

    def fn(x):
        return sp.lambdify(args, to_sympy(x), modules="numpy", cse=True)

    return Derivation(n=n, kind=kind, **{key: fn(x) for key, x in exprs.items()})


def _vec(x, n) -> np.ndarray:
    x = np.zeros(n) if x is None else np.asarray(x, dtype=float)
    if x.shape != (n,):
        raise ValueError(f"expected shape ({n},), got {x.shape}")
    return x


class Reference:
    """Numeric evaluation of the symbolic derivation for one concrete chain."""

    def __init__(self, lengths, masses, com=None, inertia=None, g=9.81, kind="general"):
        self.lengths = np.asarray(lengths, dtype=float)
        self.n = n = self.lengths.size
        self.masses = _vec(masses, n)
        self.com = self.lengths.copy() if com is None else _vec(com, n)
        self.inertia = _vec(inertia, n)
        self.g = float(g)
        self.kind = kind
        self._d = derive(n, kind)

    def _call(self, f, theta, omega=None, torque=None):
        n = self.n
        theta = _vec(theta, n)
        out = f(
            list(np.sin(theta)),
            list(np.cos(theta)),
            list(theta),
            list(_vec(omega, n)),
            [0.0] * n,  # alpha: every result used here is evaluated at theta_ddot = 0
            list(self.lengths),
            list(self.masses),
            list(self.com),
            list(self.inertia),
            list(_vec(torque, n)),
            self.g,
        )
        return np.array(out, dtype=float)

    def mass_matrix(self, theta) -> np.ndarray:
        return self._call(self._d.mass_matrix, theta)

    def el_matrix(self, theta, omega=None) -> np.ndarray:
        return self._call(self._d.el_matrix, theta, omega)

    def accelerations(self, theta, omega, torque=None) -> np.ndarray:
        a = self._call(self._d.el_matrix, theta, omega, torque)
        b = self._call(self._d.el_rhs, theta, omega, torque).reshape(self.n)
        return np.linalg.solve(a, b)

    def kinetic_energy(self, theta, omega) -> float:
        return float(self._call(self._d.kinetic, theta, omega))

    def potential_energy(self, theta) -> float:
        return float(self._call(self._d.potential, theta))

    def energy(self, theta, omega) -> float:
        return self.kinetic_energy(theta, omega) + self.potential_energy(theta)

    def momenta(self, theta, omega) -> np.ndarray:
        return self._call(self._d.momenta, theta, omega).reshape(self.n)

    def p_dot(self, theta, omega, torque=None) -> np.ndarray:
        """Hamilton's p_dot = dL/dtheta at the velocity omega (the Lagrangian includes tau.theta)."""
        return self._call(self._d.dl_dtheta, theta, omega, torque).reshape(self.n)

    def hamilton(self, theta, p, torque=None):
        """(theta_dot, p_dot) from the canonical state: omega = A^-1 p, then dL/dtheta."""
        omega = np.linalg.solve(self.mass_matrix(theta), _vec(p, self.n))
        return omega, self.p_dot(theta, omega, torque)

    def com_positions(self, theta) -> np.ndarray:
        return self._call(self._d.com, theta).reshape(self.n, 2)

    def tip_positions(self, theta) -> np.ndarray:
        return self._call(self._d.tips, theta).reshape(self.n, 2)


# --- seed 000: point masses, Cramer's rule on the symmetric M* ------------------------------------


def cramer_point_masses(lengths, masses, g, theta, omega, torque=None) -> np.ndarray:
    """Seed 000, section 3, verbatim (0-based indices here).

    M*_ab = cos(th_a - th_b) sum_{i >= max(a,b)} m_i
    S_a   = tau_a / l_a - sum_{i >= a} m_i [g sin th_a + sum_{j <= i} l_j w_j^2 sin(th_a - th_j)]
    thdd_n = det(M*_n) / (l_n det M*),  M*_n = M* with column n replaced by S.
    """
    l = np.asarray(lengths, dtype=float)
    m = np.asarray(masses, dtype=float)
    th = np.asarray(theta, dtype=float)
    w = np.asarray(omega, dtype=float)
    n = l.size
    tau = np.zeros(n) if torque is None else np.asarray(torque, dtype=float)
    mstar = np.empty((n, n))
    for a in range(n):
        for b in range(n):
            mstar[a, b] = np.cos(th[a] - th[b]) * m[max(a, b):].sum()
    s = np.empty(n)
    for a in range(n):
        acc = 0.0
        for i in range(a, n):
            inner = sum(l[j] * w[j] ** 2 * np.sin(th[a] - th[j]) for j in range(i + 1))
            acc += m[i] * (g * np.sin(th[a]) + inner)
        s[a] = tau[a] / l[a] - acc
    det = np.linalg.det(mstar)
    out = np.empty(n)
    for k in range(n):
        mk = mstar.copy()
        mk[:, k] = s
        out[k] = np.linalg.det(mk) / (l[k] * det)
    return out


# --- seed 001: double pendulum of uniform rods -----------------------------------------------------


def seed001_rod_mass_matrix(lengths, masses, theta) -> np.ndarray:
    """Seed 001's A for two uniform rods: COM at mid-arm, L_i = m_i l_i^2 / 12 about the COM."""
    l1, l2 = map(float, lengths)
    m1, m2 = map(float, masses)
    th1, th2 = map(float, theta)
    big_l1, big_l2 = m1 * l1**2 / 12, m2 * l2**2 / 12
    off = 0.5 * m2 * l1 * l2 * np.cos(th1 - th2)
    return np.array(
        [
            [m1 * (0.5 * l1) ** 2 + big_l1 + m2 * l1**2, off],
            [off, m2 * (0.5 * l2) ** 2 + big_l2],
        ]
    )


def seed001_rod_p_dot(lengths, masses, g, theta, omega) -> np.ndarray:
    """Seed 001, Eq. (2): p_dot = dL/dtheta for two uniform rods, no driving torque."""
    l1, l2 = map(float, lengths)
    m1, m2 = map(float, masses)
    th1, th2 = map(float, theta)
    w1, w2 = map(float, omega)
    cross = 0.5 * m2 * l1 * l2 * np.sin(th1 - th2) * w1 * w2
    return np.array(
        [
            -cross - m1 * g * 0.5 * l1 * np.sin(th1) - m2 * g * l1 * np.sin(th1),
            +cross - m2 * g * 0.5 * l2 * np.sin(th2),
        ]
    )


# --- numeric geometry route for any N (D'Alembert / virtual work) ----------------------------------


def com_jacobians(lengths, com, theta) -> np.ndarray:
    """J[i] (2 x N): d(COM_i)/d(theta) from the same geometry as ``derive``."""
    l = np.asarray(lengths, dtype=float)
    c = np.asarray(com, dtype=float)
    th = np.asarray(theta, dtype=float)
    n = l.size
    jac = np.zeros((n, 2, n))
    for i in range(n):
        for j in range(i):
            jac[i, :, j] = l[j] * np.cos(th[j]), l[j] * np.sin(th[j])
        jac[i, :, i] = c[i] * np.cos(th[i]), c[i] * np.sin(th[i])
    return jac


def virtual_work_accelerations(lengths, masses, com, inertia, g, theta, omega, torque=None):
    """Accelerations from D'Alembert's principle, O(N^3) in NumPy; returns (A, rhs, theta_ddot).

    sum_i J_i^T m_i (J_i thdd + a_c,i) + diag(I) thdd = tau + sum_i J_i^T m_i (0, -g), where the
    centripetal part of the COM acceleration is a_c,i = sum_{j<i} l_j w_j^2 (-sin th_j, cos th_j)
    + c_i w_i^2 (-sin th_i, cos th_i).
    """
    l = np.asarray(lengths, dtype=float)
    m = np.asarray(masses, dtype=float)
    c = np.asarray(com, dtype=float)
    inertia = np.asarray(inertia, dtype=float)
    th = np.asarray(theta, dtype=float)
    w = np.asarray(omega, dtype=float)
    n = l.size
    tau = np.zeros(n) if torque is None else np.asarray(torque, dtype=float)
    jac = com_jacobians(l, c, th)
    a = np.einsum("i,ikj,ikl->jl", m, jac, jac) + np.diag(inertia)
    radial = np.stack([-np.sin(th), np.cos(th)], axis=1)  # unit vector towards the joint, (n, 2)
    joint_part = np.cumsum(l[:, None] * w[:, None] ** 2 * radial, axis=0)
    joint_part = np.vstack([np.zeros((1, 2)), joint_part[:-1]])
    centripetal = joint_part + c[:, None] * w[:, None] ** 2 * radial
    force = m[:, None] * (np.array([0.0, -g])[None, :] - centripetal)
    rhs = tau + np.einsum("ikj,ik->j", jac, force)
    return a, rhs, np.linalg.solve(a, rhs)


def random_chain(rng: np.random.Generator, n: int, kind: str = "general", mass_decades: float = 0.0):
    """Random valid chain parameters (lengths, masses, com, inertia) for tests.

    ``mass_decades`` spreads the masses log-uniformly over that many decades around 1.
    """
    lengths = rng.uniform(0.5, 1.5, n)
    if mass_decades > 0:
        masses = 10.0 ** rng.uniform(-mass_decades / 2, mass_decades / 2, n)
    else:
        masses = rng.uniform(0.5, 2.0, n)
    if kind == "point":
        com, inertia = lengths.copy(), np.zeros(n)
    elif kind == "rod":
        com, inertia = lengths / 2, masses * lengths**2 / 12
    else:
        com = lengths * rng.uniform(0.1, 1.0, n)
        inertia = masses * lengths**2 * rng.uniform(0.0, 0.2, n)
    return lengths, masses, com, inertia
