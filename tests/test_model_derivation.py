"""The extended model (joint damping, regularised Coulomb friction, a prescribed pivot motion, a
cart) against an independent symbolic derivation from Cartesian positions.

Nothing here reads the package's formulas (nor tests/symbolic.py). For every N the sympy side
builds, from geometry alone:

* the centre of mass of link i in the lab frame, ``r_i = base + sum_{j<i} l_j (sin th_j, -cos th_j)
  + c_i (sin th_i, -cos th_i)``, with the base at the origin, at a prescribed ``(X(t), Y(t))``, or
  on a cart ``(x, 0)`` whose position x is a generalized coordinate (the first);
* velocities and accelerations by the chain rule on the coordinates' and the base's jets
  (``d/dt q = v``, ``d/dt v = a``, ``d/dt X = X'``, ...), i.e. sympy differentiates r_i(t);
* ``L = T - U``, ``T = sum m_i |v_i|^2 / 2 + I_i thdot_i^2 / 2 (+ M_c xdot^2 / 2)``,
  ``U = sum m_i g y_i``; the Rayleigh function ``R = sum b_i w_i^2 / 2 (+ c xdot^2 / 2)``;
* the generalized forces of the joint couples (friction ``-f_i tanh(w_i / v_s)`` and motors),
  the generalized torques ``tau`` and the cart force F by virtual work: a couple u on a body
  whose orientation is phi does ``u dphi``; joint i puts ``+u_i`` on link i and ``-u_i`` on
  link i-1 (link 0: the base, which does not rotate); ``tau_i`` does ``tau_i dth_i``, F ``F dx``;
* the Euler-Lagrange equations ``d/dt dL/dqdot - dL/dq + dR/dqdot = Q``, lambdified; the mass
  matrix is their coefficient of the accelerations, and the accelerations are solved for
  numerically. Energy ``T + U`` and momenta ``dL/dqdot`` come from the same Lagrangian.

One derivation per (N, base) keeps every parameter symbolic and serves every chain (cached).
N = 4, 5 are the slow ones (a few seconds each); their test ids end in "heavy", so
``-k "not heavy"`` leaves them out.
"""
from __future__ import annotations

from functools import lru_cache
from typing import Callable, NamedTuple, Optional, Tuple

import numpy as np
import pytest
import sympy as sp
from scipy.integrate import cumulative_simpson
from scipy.interpolate import CubicSpline

import multipendulum as mp

TOL = 1e-12
KINDS = ("point", "rod", "general")
NS = [pytest.param(n, id=f"N{n}" + ("-heavy" if n >= 4 else "")) for n in range(1, 6)]
t_sym = sp.Symbol("t")


# ---------------------------------------------------------------------------------------------
# The symbolic derivation
# ---------------------------------------------------------------------------------------------
class Derivation(NamedTuple):
    """Lambdified functions of ``(q, v, a, l, m, c, I, b, f, v_s, g, tau, u, P, (M_c, c_c, F))``
    with P = (X, X', X'', Y, Y', Y'') the base's jets (zeros unless base == "pivot")."""

    nq: int
    mass: Callable        # (nq, nq): coefficient of a in the Euler-Lagrange equations
    rest: Callable        # (nq, 1): the equations at a = 0, so mass @ a + rest = 0
    kinetic: Callable
    potential: Callable
    momenta: Callable     # (nq, 1): dL/dqdot
    base_force: Callable  # (2, 1): the force the base exerts on the chain, sum m_i a_i - sum m_i g_vec


@lru_cache(maxsize=None)
def derive(n: int, base: str) -> Derivation:
    """base: "fixed" (at the origin), "pivot" (prescribed X(t), Y(t)) or "cart" (x a coordinate)."""
    assert base in ("fixed", "pivot", "cart")
    l, m, c, inertia = (sp.symbols(f"{s}0:{n}") for s in ("l", "m", "c", "I"))
    b, fr, tau, mot = (sp.symbols(f"{s}0:{n}") for s in ("b", "f", "tau", "u"))
    g, vs, Mc, cc, F = sp.symbols("g v_s M_c c_c F")
    P = sp.symbols("X Xd Xdd Y Yd Ydd")
    nq = n + (base == "cart")
    q, v, a = (sp.symbols(f"{s}0:{nq}") for s in ("q", "v", "a"))
    th = q[nq - n:]
    # The jets: each symbol and its time derivative (the chain rule is d/dt).
    jets = list(zip(q, v)) + list(zip(v, a))
    if base == "pivot":
        jets += [(P[0], P[1]), (P[1], P[2]), (P[3], P[4]), (P[4], P[5])]

    def ddt(e: sp.Expr) -> sp.Expr:
        return sum((sp.diff(e, s) * ds for s, ds in jets), sp.Integer(0))

    xb, yb = {"fixed": (sp.Integer(0), sp.Integer(0)), "pivot": (P[0], P[3]), "cart": (q[0], sp.Integer(0))}[base]
    com = []
    jx, jy = xb, yb
    for i in range(n):
        com.append((jx + c[i] * sp.sin(th[i]), jy - c[i] * sp.cos(th[i])))
        jx, jy = jx + l[i] * sp.sin(th[i]), jy - l[i] * sp.cos(th[i])
    vel = [(ddt(x), ddt(y)) for x, y in com]
    half = sp.Rational(1, 2)
    T = sum(half * m[i] * (vel[i][0] ** 2 + vel[i][1] ** 2) + half * inertia[i] * ddt(th[i]) ** 2 for i in range(n))
    if base == "cart":
        T += half * Mc * ddt(q[0]) ** 2
    U = sum(m[i] * g * com[i][1] for i in range(n))
    L = T - U
    # Bodies' orientations: the base (or cart) does not rotate, link i is at th_i.
    orient = [sp.Integer(0)] + list(th)
    w = [ddt(orient[i + 1] - orient[i]) for i in range(n)]
    R = sum(half * b[i] * w[i] ** 2 for i in range(n))
    if base == "cart":
        R += half * cc * ddt(q[0]) ** 2
    # Virtual work: joint i's couple u_i acts +u_i on link i and -u_i on link i-1.
    u = [-fr[i] * sp.tanh(w[i] / vs) + mot[i] for i in range(n)]
    dq = sp.symbols(f"dq0:{nq}")

    def variation(e: sp.Expr) -> sp.Expr:
        return sum((sp.diff(e, qk) * dk for qk, dk in zip(q, dq)), sp.Integer(0))

    dW = sum(u[i] * variation(orient[i + 1]) - u[i] * variation(orient[i]) for i in range(n))
    dW += sum(tau[i] * variation(th[i]) for i in range(n))
    if base == "cart":
        dW += F * variation(q[0])
    dW = sp.expand(dW)
    Q = [dW.coeff(d) for d in dq]
    EL = [ddt(sp.diff(L, v[k])) - sp.diff(L, q[k]) + sp.diff(R, v[k]) - Q[k] for k in range(nq)]
    mass = sp.Matrix([[sp.diff(e, ak) for ak in a] for e in EL])
    rest = sp.Matrix([e.subs({ak: 0 for ak in a}) for e in EL])
    momenta = sp.Matrix([sp.diff(L, vk) for vk in v])
    base_force = sp.Matrix([sum(m[i] * ddt(vel[i][0]) for i in range(n)),
                            sum(m[i] * (ddt(vel[i][1]) + g) for i in range(n))])
    args = (q, v, a, l, m, c, inertia, b, fr, vs, g, tau, mot, P, (Mc, cc, F))

    def lam(e: sp.Expr) -> Callable:
        return sp.lambdify(args, e, modules="numpy", cse=True)

    return Derivation(nq, lam(mass), lam(rest), lam(T), lam(U), lam(momenta), lam(base_force))


def sympy_jets(expr: sp.Expr) -> Callable[[float], np.ndarray]:
    """(x, x', x'') of a sympy expression in t."""
    f = sp.lambdify(t_sym, [expr, sp.diff(expr, t_sym), sp.diff(expr, t_sym, 2)], "numpy")
    return lambda tt: np.array(f(tt), dtype=float)


def sinusoid_expr(amplitude: float, frequency: float, phase: float = 0.0, offset: float = 0.0) -> sp.Expr:
    return offset + amplitude * sp.sin(frequency * t_sym + phase)


class Reference:
    """Numbers from a derivation for one chain's parameters."""

    def __init__(self, n: int, base: str, l, m, c, inertia, g, b, f, vs, cart_mass=0.0, cart_damping=0.0,
                 derivation: Optional[str] = None):
        self.n, self.base = n, base
        # The fixed pivot is the prescribed pivot at rest at the origin (test_the_reference_reduces
        # checks the two derivations agree); a separate "fixed" derivation only where asked.
        self.d = derive(n, derivation or ("cart" if base == "cart" else "pivot"))
        self.p = tuple(np.asarray(x, float) for x in (l, m, c, inertia, b, f))
        self.vs, self.g, self.cart = float(vs), float(g), (float(cart_mass), float(cart_damping))

    def _args(self, theta, omega, acc=None, tau=None, mot=None, jets=None, cart_x=0.0, cart_v=0.0, force=0.0):
        n, nq = self.n, self.d.nq
        theta, omega = np.asarray(theta, float), np.asarray(omega, float)
        if nq > n:
            q, v = np.r_[cart_x, theta], np.r_[cart_v, omega]
        else:
            q, v = theta, omega
        a = np.zeros(nq) if acc is None else np.asarray(acc, float)
        tau = np.zeros(n) if tau is None else np.asarray(tau, float)
        mot = np.zeros(n) if mot is None else np.asarray(mot, float)
        P = np.zeros(6) if jets is None else np.asarray(jets, float)
        return (q, v, a) + self.p + (self.vs, self.g, tau, mot, P, self.cart + (float(force),))

    def mass(self, theta) -> np.ndarray:
        return np.array(self.d.mass(*self._args(theta, np.zeros(self.n))), float)

    def accelerations(self, theta, omega, **kw) -> np.ndarray:
        args = self._args(theta, omega, **kw)
        M = np.array(self.d.mass(*args), float)
        rest = np.array(self.d.rest(*args), float).ravel()
        return np.linalg.solve(M, -rest)

    def kinetic(self, theta, omega, **kw) -> float:
        return float(self.d.kinetic(*self._args(theta, omega, **kw)))

    def potential(self, theta, **kw) -> float:
        return float(self.d.potential(*self._args(theta, np.zeros(self.n), **kw)))

    def energy(self, theta, omega, **kw) -> float:
        return self.kinetic(theta, omega, **kw) + self.potential(theta, **{k: v for k, v in kw.items()
                                                                            if k in ("jets", "cart_x")})

    def momenta(self, theta, omega, **kw) -> np.ndarray:
        return np.array(self.d.momenta(*self._args(theta, omega, **kw)), float).ravel()

    def base_force(self, theta, omega, acc, **kw) -> np.ndarray:
        return np.array(self.d.base_force(*self._args(theta, omega, acc=acc, **kw)), float).ravel()


def make(n: int, kind: str, seed: int, cart: bool = False, losses: bool = True,
         base: Optional[str] = None) -> Tuple[mp.Chain, Reference]:
    """A random chain of the given kind and its reference (same parameters)."""
    rng = np.random.default_rng(seed)
    l = rng.uniform(0.4, 1.5, n)
    m = rng.uniform(0.3, 2.0, n)
    g = rng.uniform(5.0, 15.0)
    b = rng.uniform(0.0, 0.6, n) if losses else np.zeros(n)
    f = rng.uniform(0.0, 0.4, n) if losses else np.zeros(n)
    vs = rng.uniform(0.05, 2.0)
    Mc, cc = rng.uniform(0.3, 3.0), (rng.uniform(0.0, 1.0) if losses else 0.0)
    kw = dict(g=g, damping=b, friction=f, friction_velocity=vs, cart=mp.Cart(Mc, cc) if cart else None)
    if kind == "point":
        c, inertia = l.copy(), np.zeros(n)
        chain = mp.Chain(l, m, **kw)
    elif kind == "rod":
        c, inertia = l / 2, m * l**2 / 12
        chain = mp.Chain.rods(l, m, **kw)
    else:
        c, inertia = l * (1.0 - rng.random(n)), rng.uniform(0.01, 0.3, n)  # c in (0, l]
        chain = mp.Chain(l, m, com=c, inertia=inertia, **kw)
    ref = Reference(n, base or ("cart" if cart else "fixed"), l, m, c, inertia, g, b, f, vs,
                    Mc if cart else 0.0, cc if cart else 0.0)
    return chain, ref


def states(n: int, seed: int, k: int = 4):
    rng = np.random.default_rng(seed)
    for _ in range(k):
        yield rng.uniform(-np.pi, np.pi, n), rng.normal(0.0, 1.5, n)


def seed_of(n: int, kind: str, extra: int = 0) -> int:
    return 1000 * n + 100 * KINDS.index(kind) + extra


def check(got, want, what: str, scale: Optional[float] = None, tol: float = TOL) -> None:
    got, want = np.asarray(got, float), np.asarray(want, float)
    assert got.shape == want.shape, f"{what}: shape {got.shape}, expected {want.shape}"
    s = max(1.0, float(np.max(np.abs(want))) if scale is None else scale)
    err = float(np.max(np.abs(got - want)))
    assert err <= tol * s, f"{what}: max |difference| {err:.3e} > {tol:.0e} * {s:.3g}\n got  {got}\n want {want}"


def acceleration_scale(ref: Reference, theta, omega, **kw) -> float:
    """The size of the terms the accelerations are made of: |A^-1| |rest| and the result."""
    args = ref._args(theta, omega, **kw)
    M = np.array(ref.d.mass(*args), float)
    rest = np.array(ref.d.rest(*args), float).ravel()
    return max(1.0, float(np.max(np.abs(np.linalg.solve(M, -rest)))),
               float(np.max(np.abs(np.linalg.inv(M)))) * float(np.max(np.abs(rest))))


# ---------------------------------------------------------------------------------------------
# The reference itself (these hold with the plain chain, before the extension)
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("n", NS)
def test_the_reference_matches_the_plain_chain(n, kind):
    """No losses, fixed pivot, no cart: the seeds' model the package had before the extension."""
    chain, ref = make(n, kind, seed_of(n, kind, 1), losses=False)
    rng = np.random.default_rng(seed_of(n, kind, 2))
    for theta, omega in states(n, seed_of(n, kind, 3)):
        tau = rng.normal(0.0, 2.0, n)
        check(chain.mass_matrix(theta), ref.mass(theta), f"plain mass matrix N={n} {kind}")
        check(chain.accelerations(theta, omega, torque=tau), ref.accelerations(theta, omega, tau=tau),
              f"plain accelerations N={n} {kind}", acceleration_scale(ref, theta, omega, tau=tau))
        check(chain.energy(theta, omega), ref.energy(theta, omega), f"plain energy N={n} {kind}",
              ref.kinetic(theta, omega) + abs(ref.potential(theta)))


@pytest.mark.parametrize("n", [1, 2, 3])
def test_the_reference_reduces(n):
    """The derivations agree among themselves: a pivot at rest at the origin is the fixed
    derivation; a pivot prescribed to move as the cart does gives the cart's angular
    accelerations; the cart's equations do not depend on its position x."""
    _, ref = make(n, "general", seed_of(n, "general", 4), cart=True)
    fixed = Reference(n, "fixed", *ref.p[:4], ref.g, *ref.p[4:], ref.vs, derivation="fixed")
    pivot = Reference(n, "pivot", *ref.p[:4], ref.g, *ref.p[4:], ref.vs)
    rng = np.random.default_rng(n)
    for theta, omega in states(n, 10 + n):
        tau, mot = rng.normal(0.0, 1.0, n), rng.normal(0.0, 1.0, n)
        check(pivot.mass(theta), fixed.mass(theta), "pivot at rest: mass matrix")
        check(pivot.accelerations(theta, omega, tau=tau, mot=mot), fixed.accelerations(theta, omega, tau=tau, mot=mot),
              "pivot at rest: accelerations")
        check(pivot.energy(theta, omega), fixed.energy(theta, omega), "pivot at rest: energy")
        v, F = rng.normal(), rng.normal()
        acc = ref.accelerations(theta, omega, tau=tau, mot=mot, cart_v=v, force=F)
        check(ref.accelerations(theta, omega, tau=tau, mot=mot, cart_v=v, force=F, cart_x=rng.normal()), acc,
              "cart: x does not enter")
        X = rng.normal()
        jets = [X, v, acc[0], 0.0, 0.0, 0.0]
        check(pivot.accelerations(theta, omega, tau=tau, mot=mot, jets=jets), acc[1:], "pivot moved as the cart")
        # The cart's kinetic energy is the pivot-driven chain's plus M_c v^2 / 2.
        check(ref.kinetic(theta, omega, cart_v=v), pivot.kinetic(theta, omega, jets=jets) + ref.cart[0] * v**2 / 2,
              "cart kinetic energy")


# ---------------------------------------------------------------------------------------------
# The package against the derivation
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("n", NS)
def test_fixed_pivot_with_damping_friction_and_torques(n, kind):
    chain, ref = make(n, kind, seed_of(n, kind, 5))
    assert np.array_equal(chain.damping, ref.p[4]) and np.array_equal(chain.friction, ref.p[5])
    rng = np.random.default_rng(seed_of(n, kind, 6))
    for theta, omega in states(n, seed_of(n, kind, 7)):
        tau, mot = rng.normal(0.0, 2.0, n), rng.normal(0.0, 2.0, n)
        what = f"N={n} {kind} theta={theta} omega={omega}"
        check(chain.mass_matrix(theta), ref.mass(theta), f"mass matrix {what}")
        for label, kw, rkw in (("no torque", {}, {}), ("torque", dict(torque=tau), dict(tau=tau)),
                               ("joint_torque", dict(joint_torque=mot), dict(mot=mot))):
            want = ref.accelerations(theta, omega, **rkw)
            check(chain.accelerations(theta, omega, **kw), want, f"accelerations ({label}) {what}",
                  acceleration_scale(ref, theta, omega, **rkw))
        e_scale = ref.kinetic(theta, omega) + abs(ref.potential(theta))
        check(chain.energy(theta, omega), ref.energy(theta, omega), f"energy {what}", e_scale)
        check(chain.momenta(theta, omega), ref.momenta(theta, omega), f"momenta {what}")


@pytest.mark.parametrize("n", [1, 3])
def test_friction_inside_its_default_regularisation(n):
    """friction_velocity left at its default (1e-3 rad/s) and joint rates of that size, where
    tanh(w / v_s) is neither linear nor saturated."""
    rng = np.random.default_rng(600 + n)
    l, m, f = rng.uniform(0.5, 1.2, n), rng.uniform(0.5, 1.5, n), rng.uniform(0.05, 0.5, n)
    chain = mp.Chain(l, m, friction=f)
    assert chain.friction_velocity == 1e-3
    ref = Reference(n, "fixed", l, m, l, np.zeros(n), 9.81, np.zeros(n), f, 1e-3)
    for _ in range(4):
        theta = rng.uniform(-np.pi, np.pi, n)
        omega = np.cumsum(rng.uniform(-2e-3, 2e-3, n))  # joint rates w_i within +-2 v_s
        check(chain.accelerations(theta, omega), ref.accelerations(theta, omega), f"N={n} friction near w = 0",
              acceleration_scale(ref, theta, omega))


def _pivot_case(case: str, rng: np.random.Generator):
    """(mp.Pivot, function t -> the six jets)."""
    def sinusoid():
        A, w, ph, off = rng.uniform(0.02, 0.3), rng.uniform(1.0, 15.0), rng.uniform(-3, 3), rng.uniform(-1, 1)
        return mp.Sinusoid(amplitude=A, frequency=w, phase=ph, offset=off), sympy_jets(sinusoid_expr(A, w, ph, off))

    if case == "sinusoid":
        (px, jx), (py, jy) = sinusoid(), sinusoid()
    elif case == "table":
        tk = np.linspace(0.0, 2.0, 9)
        vals = rng.uniform(-0.3, 0.3, tk.size)
        spline = CubicSpline(tk, vals, bc_type="natural")
        px = mp.Table(tk, vals, kind="cubic")
        jx = lambda tt: np.array([spline(tt), spline(tt, 1), spline(tt, 2)], float)  # noqa: E731
        py, jy = sinusoid()
    else:  # a callable x(t) and a fixed y
        expr = 0.1 * sp.cos(2.3 * t_sym) + 0.05 * t_sym**2 - 0.2 * t_sym
        jx = sympy_jets(expr)
        px = lambda tt: tuple(float(x) for x in jx(tt))  # noqa: E731
        y0 = rng.uniform(-0.5, 0.5)
        py, jy = y0, (lambda tt: np.array([y0, 0.0, 0.0]))
    return mp.Pivot(x=px, y=py), (lambda tt: np.r_[jx(tt), jy(tt)])


@pytest.mark.parametrize("case", ["sinusoid", "table", "callable"])
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("n", NS)
def test_prescribed_pivot(n, kind, case):
    chain, ref = make(n, kind, seed_of(n, kind, 8), base="pivot")
    rng = np.random.default_rng(seed_of(n, kind, 9 + ["sinusoid", "table", "callable"].index(case)))
    pivot, jets_of = _pivot_case(case, rng)
    for theta, omega in states(n, seed_of(n, kind, 12)):
        tt = rng.uniform(0.1, 1.9)
        jets = jets_of(tt)
        tau = rng.normal(0.0, 2.0, n)
        what = f"N={n} {kind} pivot {case} t={tt:.4f} jets={jets} theta={theta} omega={omega}"
        want = ref.accelerations(theta, omega, tau=tau, jets=jets)
        check(chain.accelerations(theta, omega, t=tt, torque=tau, pivot=pivot), want, f"accelerations {what}",
              acceleration_scale(ref, theta, omega, tau=tau, jets=jets))
        kin, pot = ref.kinetic(theta, omega, jets=jets), ref.potential(theta, jets=jets)
        e_scale = kin + abs(pot)
        check(chain.energy(theta, omega, t=tt, pivot=pivot), kin + pot, f"lab energy {what}", e_scale)
        check(chain.kinetic_energy(theta, omega, t=tt, pivot=pivot), kin, f"lab kinetic energy {what}", e_scale)
        check(chain.potential_energy(theta, t=tt, pivot=pivot), pot, f"lab potential energy {what}", e_scale)
        if case != "callable":
            check(pivot.position(tt), jets[[0, 3]], f"pivot position {what}")


def _force_case(case: str, n: int, rng: np.random.Generator):
    """(cart_force for the package, function (t, theta, v, omega) -> F)."""
    if case == "none":
        return None, lambda tt, th, v, om: 0.0
    if case == "constant":
        F = rng.normal(0.0, 3.0)
        return F, lambda tt, th, v, om: F
    if case == "sinusoid":
        A, w, ph, off = rng.uniform(0.5, 3.0), rng.uniform(1.0, 10.0), rng.uniform(-3, 3), rng.uniform(-1, 1)
        f = sp.lambdify(t_sym, sinusoid_expr(A, w, ph, off))
        return mp.Sinusoid(amplitude=A, frequency=w, phase=ph, offset=off), lambda tt, th, v, om: float(f(tt))
    # feedback on the state (x, theta_1..N, v, omega_1..N); the cart's x is 0 here
    k = rng.normal(0.0, 1.0, 2 * n + 2)

    def force(tt, state):
        state = np.asarray(state, float)
        assert state.shape == (2 * n + 2,)
        return float(k @ state + 0.3 * tt)

    return force, lambda tt, th, v, om: float(k @ np.r_[0.0, th, v, om] + 0.3 * tt)


@pytest.mark.parametrize("case", ["none", "constant", "sinusoid", "feedback"])
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("n", NS)
def test_cart(n, kind, case):
    chain, ref = make(n, kind, seed_of(n, kind, 13), cart=True)
    assert chain.cart == mp.Cart(*ref.cart) and chain.dof == n + 1
    rng = np.random.default_rng(seed_of(n, kind, 14 + ["none", "constant", "sinusoid", "feedback"].index(case)))
    cart_force, F_of = _force_case(case, n, rng)
    for theta, omega in states(n, seed_of(n, kind, 18)):
        v, tt = rng.normal(0.0, 1.5), rng.uniform(0.0, 3.0)
        tau = rng.normal(0.0, 2.0, n)
        F = F_of(tt, theta, v, omega)
        what = f"N={n} {kind} cart force {case} F={F:.6g} t={tt:.4f} v={v:.6g} theta={theta} omega={omega}"
        check(chain.mass_matrix(theta), ref.mass(theta), f"cart mass matrix {what}")
        want = ref.accelerations(theta, omega, tau=tau, cart_v=v, force=F)
        check(chain.accelerations(theta, omega, t=tt, torque=tau, cart_v=v, cart_force=cart_force), want,
              f"accelerations [x_ddot, theta_ddot] {what}", acceleration_scale(ref, theta, omega, tau=tau, cart_v=v, force=F))
        kin, pot = ref.kinetic(theta, omega, cart_v=v), ref.potential(theta)
        check(chain.energy(theta, omega, cart_v=v), kin + pot, f"cart energy {what}", kin + abs(pot))
        check(chain.kinetic_energy(theta, omega, cart_v=v), kin, f"cart kinetic energy {what}", kin + abs(pot))
        check(chain.momenta(theta, omega, cart_v=v), ref.momenta(theta, omega, cart_v=v), f"cart momenta {what}")


def test_a_wrong_parameter_does_not_match():
    """The comparisons above can fail: each parameter, changed a little, is seen."""
    n = 3
    theta, omega = np.array([0.7, -1.2, 2.0]), np.array([0.9, -0.4, 1.3])
    tau = np.array([0.3, -0.2, 0.5])

    def moved(ref: Reference, i: int, by: float, **kw) -> Reference:
        p = list(ref.p)
        p[i] = p[i] + by
        return Reference(ref.n, ref.base, *p[:4], ref.g, *p[4:], kw.get("vs", ref.vs), *kw.get("cart", ref.cart))

    chain, ref = make(n, "general", 77)
    got = chain.accelerations(theta, omega, torque=tau)
    scale = acceleration_scale(ref, theta, omega, tau=tau)
    check(got, ref.accelerations(theta, omega, tau=tau), "the right parameters", scale)
    wrong = {
        "another damping": moved(ref, 4, np.array([0.0, 0.01, 0.0])).accelerations(theta, omega, tau=tau),
        "another friction": moved(ref, 5, np.array([0.01, 0.0, 0.0])).accelerations(theta, omega, tau=tau),
        "another friction velocity": moved(ref, 5, 0.0, vs=ref.vs * 1.5).accelerations(theta, omega, tau=tau),
        "torques as joint torques": ref.accelerations(theta, omega, mot=tau),
    }
    chain_c, ref_c = make(n, "general", 78, cart=True)
    v, F = 0.6, 1.1
    got_c = chain_c.accelerations(theta, omega, cart_v=v, cart_force=F)
    check(got_c, ref_c.accelerations(theta, omega, cart_v=v, force=F), "the right cart")
    Mc, cc = ref_c.cart
    wrong_c = {
        "another cart damping": moved(ref_c, 4, 0.0, cart=(Mc, cc + 0.01)).accelerations(theta, omega, cart_v=v, force=F),
        "another cart mass": moved(ref_c, 4, 0.0, cart=(Mc + 0.01, cc)).accelerations(theta, omega, cart_v=v, force=F),
        "another force": ref_c.accelerations(theta, omega, cart_v=v, force=F + 0.01),
    }
    for label, want in wrong.items():
        with pytest.raises(AssertionError):
            check(got, want, label, scale)
        assert np.max(np.abs(got - want)) > 1e6 * TOL * scale, label
    for label, want in wrong_c.items():
        with pytest.raises(AssertionError):
            check(got_c, want, label)
        assert np.max(np.abs(got_c - want)) > 1e-6, label
    # and the pivot's phase
    _, ref_p = make(n, "general", 77, base="pivot")
    A, w, ph = 0.1, 5.0, 0.3
    pivot = mp.Pivot(x=mp.Sinusoid(amplitude=A, frequency=w, phase=ph))
    got_p = chain.accelerations(theta, omega, t=0.4, pivot=pivot)
    check(got_p, ref_p.accelerations(theta, omega, jets=np.r_[sympy_jets(sinusoid_expr(A, w, ph))(0.4), 0, 0, 0]),
          "the right pivot")
    other = ref_p.accelerations(theta, omega, jets=np.r_[sympy_jets(sinusoid_expr(A, w, ph + 0.01))(0.4), 0, 0, 0])
    assert np.max(np.abs(got_p - other)) > 1e-6


# ---------------------------------------------------------------------------------------------
# Closed forms and conservation laws along runs
# ---------------------------------------------------------------------------------------------
def test_a_lightly_damped_pendulum_decays_and_rings_at_the_linear_rates():
    """m l^2 th'' + b th' + m g l th = 0: decay rate b / (2 m l^2), frequency
    sqrt(g/l - (b / (2 m l^2))^2). For the linear oscillator the zeros of theta, and the extrema
    (zeros of omega), are spaced by pi / omega_d, and |theta| at the extrema decays as exp(-gamma t)."""
    l, m, g, b = 0.9, 1.3, 9.81, 0.05
    gamma = b / (2 * m * l**2)
    omega_d = np.sqrt(g / l - gamma**2)
    chain = mp.Chain([l], [m], g=g, damping=b)
    sol = mp.simulate(chain, [0.01], [0.0], 40.0, method="dop853", rtol=1e-12, atol=1e-16,
                      events=[mp.Crossing(theta=[1.0], direction=0), mp.Crossing(omega=[1.0], direction=0)])
    zeros, extrema = sol.events
    assert zeros.t.size > 20 and extrema.t.size > 20
    k = np.arange(zeros.t.size)
    freq = np.pi / np.polyfit(k, zeros.t, 1)[0]
    rate = -np.polyfit(extrema.t, np.log(np.abs(extrema.theta[:, 0])), 1)[0]
    freq_x = np.pi / np.polyfit(np.arange(extrema.t.size), extrema.t, 1)[0]
    assert abs(freq / omega_d - 1) < 1e-4, (freq, omega_d)
    assert abs(freq_x / omega_d - 1) < 1e-4, (freq_x, omega_d)
    assert abs(rate / gamma - 1) < 1e-4, (rate, gamma)
    # and an undamped one does not decay (the fit sees the damping, not the integrator)
    sol0 = mp.simulate(mp.Chain([l], [m], g=g), [0.01], [0.0], 40.0, method="dop853", rtol=1e-12, atol=1e-16,
                       events=[mp.Crossing(omega=[1.0], direction=0)])
    rate0 = -np.polyfit(sol0.events[0].t, np.log(np.abs(sol0.events[0].theta[:, 0])), 1)[0]
    assert abs(rate0) < 1e-4 * gamma


@pytest.mark.parametrize("n", [1, 2, 3])
def test_a_free_cart_conserves_horizontal_momentum(n):
    """p_x = dL/dxdot (from the derivation) is constant without cart damping, force or friction;
    the energy too."""
    chain, ref = make(n, "general", 300 + n, cart=True, losses=False)
    rng = np.random.default_rng(400 + n)
    theta0, omega0 = rng.uniform(-2.0, 2.0, n), rng.normal(0.0, 1.0, n)
    sol = mp.simulate(chain, theta0, omega0, 5.0, method="dop853", rtol=1e-12, atol=1e-14, cart_x0=0.3, cart_v0=0.7,
                      t_eval=np.linspace(0.0, 5.0, 501))
    assert sol.cart_x is not None and sol.cart_v is not None
    assert abs(sol.cart_x[0] - 0.3) < 1e-15 and abs(sol.cart_v[0] - 0.7) < 1e-15
    px = np.array([ref.momenta(th, om, cart_x=x, cart_v=v)[0]
                   for th, om, x, v in zip(sol.theta, sol.omega, sol.cart_x, sol.cart_v)])
    row = np.array([ref.mass(th)[0] for th in sol.theta])  # dp_x/d(v, omega)
    rates = np.c_[sol.cart_v, sol.omega]
    scale = float(np.max(np.sum(np.abs(row * rates), axis=1)))
    drift = float(np.max(np.abs(px - px[0])))
    assert drift < 1e-9 * scale, f"p_x drifts by {drift:.3e} (scale {scale:.3g}): {px[[0, -1]]}"
    energy = np.array([ref.energy(th, om, cart_v=v) for th, om, v in zip(sol.theta, sol.omega, sol.cart_v)])
    e_scale = ref.g * float(np.sum(ref.p[1] * np.abs(ref.p[2]) + ref.p[0] * (np.cumsum(ref.p[1][::-1])[::-1] - ref.p[1])))
    e_scale += float(np.max([ref.kinetic(th, om, cart_v=v) for th, om, v in zip(sol.theta, sol.omega, sol.cart_v)]))
    assert float(np.max(np.abs(energy - energy[0]))) < 1e-9 * e_scale
    check(sol.energy, energy, "sol.energy on a cart", e_scale)


def _balance_run(case: str):
    """A run with every work term of its kind, on an even grid (for the quadratures)."""
    n = 2
    t_eval = np.linspace(0.0, 5.0, 2001)
    if case == "damped":
        chain, ref = make(n, "general", 501)
        A, w, ph = np.array([0.8, -0.5]), np.array([2.0, 3.3]), np.array([0.1, 0.7])
        torque = mp.Sinusoid(amplitude=A, frequency=w, phase=ph)
        tau_of = lambda tt: A * np.sin(w * tt + ph)  # noqa: E731
        sol = mp.simulate(chain, [1.0, -0.5], [0.3, 0.0], 5.0, method="dop853", rtol=1e-10, atol=1e-12,
                          torque=torque, t_eval=t_eval)
        return chain, ref, sol, dict(tau_of=tau_of)
    if case == "pivot":
        chain, ref = make(n, "rod", 502, base="pivot")
        sx, sy = (0.05, 7.0, 0.0, 0.0), (0.03, 11.0, 0.4, 0.2)
        pivot = mp.Pivot(x=mp.Sinusoid(*sx), y=mp.Sinusoid(*sy))
        jx, jy = sympy_jets(sinusoid_expr(*sx)), sympy_jets(sinusoid_expr(*sy))
        sol = mp.simulate(chain, [1.0, -0.5], [0.3, 0.0], 5.0, method="dop853", rtol=1e-10, atol=1e-12,
                          pivot=pivot, t_eval=t_eval)
        return chain, ref, sol, dict(jets_of=lambda tt: np.r_[jx(tt), jy(tt)])
    chain, ref = make(n, "rod", 503, cart=True)
    fs = (1.0, 3.0, 0.2, 0.1)
    f = sp.lambdify(t_sym, sinusoid_expr(*fs))
    sol = mp.simulate(chain, [1.0, -0.5], [0.3, 0.0], 5.0, method="dop853", rtol=1e-10, atol=1e-12,
                      cart_v0=0.4, cart_force=mp.Sinusoid(*fs), t_eval=t_eval)
    return chain, ref, sol, dict(F_of=lambda tt: float(f(tt)))


@pytest.mark.parametrize("case", ["damped", "pivot", "cart"])
def test_the_energy_balance_of_a_run(case):
    """E - E0 = W_torque + W_pivot + W_cart - D along the run; every term against the derivation:
    sol.energy is the lab energy of the state, and each work is the time integral of its power
    (Simpson on the output grid): torque . omega, the base's force on the chain . the pivot's
    velocity, F v, and the dissipation sum b w^2 + f w tanh(w / v_s) + c v^2."""
    chain, ref, sol, drive = _balance_run(case)
    n, t = chain.n, sol.t
    l, m, c, inertia, b, f = ref.p
    cart_v = sol.cart_v if sol.cart_v is not None else np.zeros_like(t)
    cart_x = sol.cart_x if sol.cart_x is not None else np.zeros_like(t)
    jets = np.array([drive["jets_of"](tt) if "jets_of" in drive else np.zeros(6) for tt in t])
    tau = np.array([drive["tau_of"](tt) if "tau_of" in drive else np.zeros(n) for tt in t])
    F = np.array([drive["F_of"](tt) if "F_of" in drive else 0.0 for tt in t])
    kw = [dict(jets=jets[k], cart_x=cart_x[k], cart_v=cart_v[k]) for k in range(t.size)]
    kinetic = np.array([ref.kinetic(sol.theta[k], sol.omega[k], **kw[k]) for k in range(t.size)])
    energy = kinetic + np.array([ref.potential(sol.theta[k], jets=jets[k]) for k in range(t.size)])
    h = m * c + l * (np.cumsum(m[::-1])[::-1] - m)  # first moments about each link's pivot
    scale = ref.g * float(np.sum(np.abs(h))) + float(np.max(kinetic))
    check(sol.energy, energy, f"{case}: sol.energy against the lab energy of the state", scale)

    w = sol.work
    residual = sol.energy - sol.energy[0] - w.torque - w.pivot - w.cart + w.dissipated
    assert float(np.max(np.abs(residual))) < 1e-7 * scale, f"{case}: balance residual {np.max(np.abs(residual)):.3e}"
    assert np.all(np.diff(w.dissipated) >= 0.0), f"{case}: dissipated decreases by {np.min(np.diff(w.dissipated)):.3e}"
    assert w.dissipated[0] == 0.0 and w.torque[0] == 0.0 and w.pivot[0] == 0.0 and w.cart[0] == 0.0
    assert float(np.max(sol.energy_error)) < 1e-7, f"{case}: sol.energy_error {np.max(sol.energy_error):.3e}"

    rel = np.c_[sol.omega[:, :1], np.diff(sol.omega, axis=1)]  # joint rates w_i
    dissipation = np.sum(b * rel**2 + f * rel * np.tanh(rel / ref.vs), axis=1) + ref.cart[1] * cart_v**2
    p_torque = np.sum(tau * sol.omega, axis=1)
    p_cart = F * cart_v
    p_pivot = np.zeros_like(t)
    if case == "pivot":
        for k in range(t.size):
            acc = ref.accelerations(sol.theta[k], sol.omega[k], jets=jets[k])
            p_pivot[k] = ref.base_force(sol.theta[k], sol.omega[k], acc, jets=jets[k]) @ jets[k][[1, 4]]
    for label, got, power in (("torque", w.torque, p_torque), ("pivot", w.pivot, p_pivot), ("cart", w.cart, p_cart),
                              ("dissipated", w.dissipated, dissipation)):
        want = cumulative_simpson(power, x=t, initial=0.0)
        check(got, want, f"{case}: work.{label} against the integral of its power", scale, tol=1e-6)
    expected = {"damped": ("torque", "dissipated"), "pivot": ("pivot",), "cart": ("cart", "dissipated")}[case]
    for label in expected:
        assert float(np.max(np.abs(getattr(w, label)))) > 1e-2 * scale, f"{case}: work.{label} is there"
