"""Physics of multipendulum.Chain checked against derivations that share no code with it.

References (all in tests/symbolic.py): a sympy derivation of the Lagrangian from geometry, seed
000's Cramer's rule for point masses, seed 001's closed forms for the double pendulum of rods, and
D'Alembert's principle with COM Jacobians for larger N. The only hard-coded numbers are analytic
results (the normal modes of the double pendulum).

Comparisons are norm-relative: max|a - b| <= rtol * max(1, max|b|).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import symbolic as S  # noqa: E402

import multipendulum as mp  # noqa: E402

RTOL_SYMBOLIC = 1e-12  # package vs independent derivation
RTOL_ALGORITHMS = 1e-11  # package algorithm vs package algorithm
STATES_PER_CASE = 3


def assert_close(actual, expected, rtol, what):
    a = np.asarray(actual, dtype=float)
    b = np.asarray(expected, dtype=float)
    assert a.shape == b.shape, f"{what}: shape {a.shape}, expected {b.shape}"
    assert np.all(np.isfinite(a)), f"{what}: non-finite values {a}"
    err = float(np.max(np.abs(a - b))) if a.size else 0.0
    scale = max(1.0, float(np.max(np.abs(b)))) if b.size else 1.0
    assert err <= rtol * scale, (
        f"{what}: max|diff| = {err:.3e} > {rtol:.0e} * {scale:.3e}\n"
        f"  package:   {a.ravel()}\n  reference: {b.ravel()}"
    )


def rng_for(*key: int) -> np.random.Generator:
    return np.random.default_rng([20240601, *key])


def make_chain(kind, lengths, masses, com, inertia, g):
    """Build through the constructor each kind is meant to use (defaults, rods, explicit)."""
    if kind == "point":
        return mp.Chain(lengths=lengths, masses=masses, g=g)
    if kind == "rod":
        return mp.Chain.rods(lengths=lengths, masses=masses, g=g)
    return mp.Chain(lengths=lengths, masses=masses, com=com, inertia=inertia, g=g)


def random_state(rng, n):
    theta = rng.uniform(-np.pi, np.pi, n)
    omega = rng.normal(0.0, 2.0, n)
    torque = rng.normal(0.0, 3.0, n)
    return theta, omega, torque


@pytest.fixture(params=[(n, kind) for kind in S.KINDS for n in range(1, 6)], ids=lambda p: f"{p[1]}-N{p[0]}")
def case(request):
    """A random chain of the given kind and size, the package's Chain and the symbolic reference."""
    n, kind = request.param
    rng = rng_for(n, S.KINDS.index(kind))
    lengths, masses, com, inertia = S.random_chain(rng, n, kind)
    g = rng.uniform(1.0, 20.0)
    chain = make_chain(kind, lengths, masses, com, inertia, g)
    ref = S.Reference(lengths, masses, com, inertia, g, kind=kind)
    states = [random_state(rng, n) for _ in range(STATES_PER_CASE)]
    return chain, ref, states


# --- the references agree with each other (no package involved) ----------------------------------


def test_references_agree_with_each_other(case):
    """Guards the guards: sympy vs the seeds' closed forms, D'Alembert, and energy balance."""
    _, ref, states = case
    lengths, masses, com, inertia, g = ref.lengths, ref.masses, ref.com, ref.inertia, ref.g
    for theta, omega, torque in states:
        a = ref.mass_matrix(theta)
        acc = ref.accelerations(theta, omega, torque)
        assert_close(ref.el_matrix(theta), a, 1e-14, "Euler-Lagrange coefficient matrix = Hessian of T")
        a_vw, _, acc_vw = S.virtual_work_accelerations(lengths, masses, com, inertia, g, theta, omega, torque)
        assert_close(a_vw, a, 1e-14, "virtual work A")
        assert_close(acc_vw, acc, 1e-13, "virtual work accelerations")
        if ref.kind == "point":
            cramer = S.cramer_point_masses(lengths, masses, g, theta, omega, torque)
            assert_close(cramer, acc, 1e-13, "seed 000 Cramer vs sympy")
        if ref.kind == "rod" and ref.n == 2:
            assert_close(S.seed001_rod_mass_matrix(lengths, masses, theta), a, 1e-14, "seed 001 A vs sympy")
            seed_p_dot = S.seed001_rod_p_dot(lengths, masses, g, theta, omega)
            assert_close(seed_p_dot, ref.p_dot(theta, omega), 1e-14, "seed 001 p_dot vs sympy")
        # Along the motion dE/dt = tau . omega and dp/dt = dL/dtheta (central differences).
        h = 1e-6
        energy = [ref.energy(theta + s * omega, omega + s * acc) for s in (h, -h)]
        assert_close((energy[0] - energy[1]) / (2 * h), torque @ omega, 1e-7, "power balance")
        p = [ref.momenta(theta + s * omega, omega + s * acc) for s in (h, -h)]
        assert_close((p[0] - p[1]) / (2 * h), ref.p_dot(theta, omega, torque), 1e-7, "dp/dt = dL/dtheta")


# --- the package against the symbolic Lagrangian, N = 1..5 ------------------------------------------


def test_chain_parameters_follow_the_link_model(case):
    chain, ref, _ = case
    assert chain.n == ref.n
    assert_close(chain.lengths, ref.lengths, 0, "lengths")
    assert_close(chain.masses, ref.masses, 0, "masses")
    assert_close(chain.com, ref.com, 1e-15, "com")  # point: c = l; rods: c = l/2
    assert_close(chain.inertia, ref.inertia, 1e-15, "inertia")  # point: 0; rods: m l^2/12
    assert chain.g == pytest.approx(ref.g, rel=1e-15)


def test_mass_matrix_matches_symbolic(case):
    chain, ref, states = case
    for theta, _, _ in states:
        assert_close(chain.mass_matrix(theta), ref.mass_matrix(theta), RTOL_SYMBOLIC, "mass matrix")


def test_accelerations_match_symbolic(case):
    chain, ref, states = case
    for theta, omega, torque in states:
        assert_close(
            chain.accelerations(theta, omega),
            ref.accelerations(theta, omega),
            RTOL_SYMBOLIC,
            "accelerations, no torque",
        )
        assert_close(
            chain.accelerations(theta, omega, torque=torque),
            ref.accelerations(theta, omega, torque),
            RTOL_SYMBOLIC,
            "accelerations with generalized torque",
        )


def test_energy_matches_symbolic(case):
    chain, ref, states = case
    for theta, omega, _ in states:
        t, u = ref.kinetic_energy(theta, omega), ref.potential_energy(theta)
        assert_close(chain.kinetic_energy(theta, omega), t, RTOL_SYMBOLIC, "kinetic energy")
        assert_close(chain.potential_energy(theta), u, RTOL_SYMBOLIC, "potential energy")
        assert_close(chain.energy(theta, omega), t + u, RTOL_SYMBOLIC, "energy")
    # U is measured from the pivot: hanging at rest is sum m_i g (-c_i - sum_{j<i} l_j) < 0.
    rest = np.zeros(ref.n)
    assert chain.energy(rest, rest) < 0
    assert_close(chain.energy(rest, rest), ref.potential_energy(rest), RTOL_SYMBOLIC, "energy at rest")


def test_momenta_match_symbolic(case):
    chain, ref, states = case
    for theta, omega, _ in states:
        p = chain.momenta(theta, omega)
        assert_close(p, ref.momenta(theta, omega), RTOL_SYMBOLIC, "momenta dL/domega")


def test_hamilton_matches_symbolic(case):
    chain, ref, states = case
    for theta, omega, torque in states:
        p = ref.momenta(theta, omega)
        for tau in (None, torque):
            theta_dot, p_dot = chain.hamilton(theta, p, torque=tau)
            ref_theta_dot, ref_p_dot = ref.hamilton(theta, p, tau)
            label = "no torque" if tau is None else "with torque"
            assert_close(theta_dot, ref_theta_dot, RTOL_SYMBOLIC, f"hamilton theta_dot ({label})")
            assert_close(p_dot, ref_p_dot, RTOL_SYMBOLIC, f"hamilton p_dot = dL/dtheta ({label})")


# --- the seeds' own closed forms ------------------------------------------------------------------


def test_seed001_rod_double_pendulum_closed_form():
    rng = rng_for(1001)
    for _ in range(10):
        lengths = rng.uniform(0.2, 3.0, 2)
        masses = rng.uniform(0.1, 5.0, 2)
        g = rng.uniform(1.0, 20.0)
        theta, omega, _ = random_state(rng, 2)
        chain = mp.Chain.rods(lengths=lengths, masses=masses, g=g)
        a = S.seed001_rod_mass_matrix(lengths, masses, theta)
        assert_close(chain.mass_matrix(theta), a, RTOL_SYMBOLIC, "seed 001 A")
        assert_close(chain.momenta(theta, omega), a @ omega, RTOL_SYMBOLIC, "seed 001 p = A theta_dot")
        theta_dot, p_dot = chain.hamilton(theta, a @ omega)
        assert_close(theta_dot, omega, RTOL_SYMBOLIC, "seed 001 theta_dot = A^-1 p")
        expected_p_dot = S.seed001_rod_p_dot(lengths, masses, g, theta, omega)
        assert_close(p_dot, expected_p_dot, RTOL_SYMBOLIC, "seed 001 p_dot, Eq. (2)")


@pytest.mark.parametrize("n", range(1, 7))
def test_seed000_cramer_point_masses(n):
    rng = rng_for(1000, n)
    for _ in range(STATES_PER_CASE):
        lengths, masses, _, _ = S.random_chain(rng, n, "point")
        g = rng.uniform(1.0, 20.0)
        theta, omega, torque = random_state(rng, n)
        chain = mp.Chain(lengths=lengths, masses=masses, g=g)
        expected = S.cramer_point_masses(lengths, masses, g, theta, omega, torque)
        for algorithm in ("recursive", "cholesky", "cramer"):
            assert_close(
                chain.accelerations(theta, omega, torque=torque, algorithm=algorithm),
                expected,
                RTOL_SYMBOLIC,
                f"seed 000 Cramer vs algorithm={algorithm}",
            )


@pytest.mark.parametrize("n", [10, 50])
def test_virtual_work_reference_for_larger_chains(n):
    """D'Alembert with COM Jacobians (same geometry, no Lagrangian) beyond the sympy range."""
    rng = rng_for(2000, n)
    lengths, masses, com, inertia = S.random_chain(rng, n, "general")
    chain = mp.Chain(lengths=lengths, masses=masses, com=com, inertia=inertia, g=9.81)
    theta, omega, torque = random_state(rng, n)
    a, _, expected = S.virtual_work_accelerations(lengths, masses, com, inertia, 9.81, theta, omega, torque)
    assert_close(chain.mass_matrix(theta), a, RTOL_SYMBOLIC, f"mass matrix N={n}")
    # 1e-11, not 1e-12: cond(A) ~ 1e4 at N = 50 and both sides solve in float64.
    got = chain.accelerations(theta, omega, torque=torque)
    assert_close(got, expected, RTOL_ALGORITHMS, f"accelerations N={n}")


# --- the package's algorithms against each other ----------------------------------------------------

EPS = np.finfo(float).eps
RTOL_BACKWARD = 2e-15  # |A (x1 - x2)| / (|A| |x|): both routes solve the same system to rounding


def random_general_chain(rng, n):
    """Masses over three decades, general links, and a random state with torque."""
    lengths, masses, com, inertia = S.random_chain(rng, n, "general", mass_decades=3.0)
    chain = mp.Chain(lengths=lengths, masses=masses, com=com, inertia=inertia, g=rng.uniform(1.0, 20.0))
    return chain, random_state(rng, n)


def assert_same_solution(chain, theta, got, want, what, backward_stable=True):
    """Two solvers of A(theta) x = b agree.

    Backward (for backward-stable solvers; Cramer's rule is not one, Higham 2002 section 1.10):
    the residual of their difference is at rounding level whatever the conditioning.
    Forward: to RTOL_ALGORITHMS, or to the float64 limit eps * cond(A) when that is larger. With
    masses over three decades, cond(A) reaches 1e7 at N = 300; there every float64 solver
    (recursive, Cholesky, NumPy's LU) lands about 1e-11 from an extended-precision solution, so
    no two of them can promise 1e-11 to each other.
    """
    a = np.asarray(chain.mass_matrix(theta))
    got, want = np.asarray(got), np.asarray(want)
    scale = np.abs(a).sum(axis=1).max() * max(np.abs(want).max(), np.finfo(float).tiny)
    backward = np.abs(a @ (got - want)).max() / scale
    if backward_stable:
        assert backward <= RTOL_BACKWARD, f"{what}: backward error {backward:.2e} > {RTOL_BACKWARD:.0e}"
    assert_close(got, want, max(RTOL_ALGORITHMS, EPS * np.linalg.cond(a)), what)


@pytest.mark.parametrize("n", range(1, 7))
def test_cramer_algorithm_equals_recursive(n):
    rng = rng_for(3000, n)
    for _ in range(STATES_PER_CASE):
        chain, (theta, omega, torque) = random_general_chain(rng, n)
        expected = chain.accelerations(theta, omega, torque=torque)
        recursive = chain.accelerations(theta, omega, torque=torque, algorithm="recursive")
        assert_close(recursive, expected, 0, "default is recursive")
        assert_same_solution(
            chain,
            theta,
            chain.accelerations(theta, omega, torque=torque, algorithm="cramer"),
            expected,
            "cramer vs recursive",
            backward_stable=False,
        )


@pytest.mark.parametrize("n", [2, 10, 50, 300])
def test_cholesky_algorithm_equals_recursive(n):
    rng = rng_for(4000, n)
    for _ in range(STATES_PER_CASE):
        chain, (theta, omega, torque) = random_general_chain(rng, n)
        assert_same_solution(
            chain,
            theta,
            chain.accelerations(theta, omega, torque=torque, algorithm="cholesky"),
            chain.accelerations(theta, omega, torque=torque, algorithm="recursive"),
            "cholesky vs recursive",
        )


# --- invariants -----------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8])
def test_velocities_invert_momenta(n):
    rng = rng_for(5000, n)
    for kind in S.KINDS:
        lengths, masses, com, inertia = S.random_chain(rng, n, kind)
        chain = make_chain(kind, lengths, masses, com, inertia, 9.81)
        theta, omega, _ = random_state(rng, n)
        p = chain.momenta(theta, omega)
        assert_close(chain.velocities(theta, p), omega, RTOL_ALGORITHMS, f"velocities(momenta) ({kind})")
        assert_close(p, chain.mass_matrix(theta) @ omega, RTOL_SYMBOLIC, f"p = A omega ({kind})")


@pytest.mark.parametrize("n", [1, 2, 5, 20, 100])
def test_mass_matrix_symmetric_positive_definite(n):
    rng = rng_for(6000, n)
    for kind in S.KINDS:
        lengths, masses, com, inertia = S.random_chain(rng, n, kind, mass_decades=2.0)
        chain = make_chain(kind, lengths, masses, com, inertia, 9.81)
        theta, omega, _ = random_state(rng, n)
        a = np.asarray(chain.mass_matrix(theta))
        assert a.shape == (n, n)
        assert_close(a, a.T, 1e-15, f"symmetry ({kind})")
        np.linalg.cholesky(a)  # raises LinAlgError unless positive definite
        assert np.linalg.eigvalsh(a).min() > 0
        t = chain.kinetic_energy(theta, omega)
        assert_close(t, 0.5 * omega @ a @ omega, RTOL_SYMBOLIC, f"T = w.A.w/2 ({kind})")


@pytest.mark.parametrize("kind", S.KINDS)
@pytest.mark.parametrize("n", [1, 2, 5])
def test_positions_geometry(n, kind):
    rng = rng_for(7000, n, S.KINDS.index(kind))
    lengths, masses, com, inertia = S.random_chain(rng, n, kind)
    chain = make_chain(kind, lengths, masses, com, inertia, 9.81)
    theta, _, _ = random_state(rng, n)
    pos = np.asarray(chain.positions(theta))
    assert pos.shape == (n, 2)
    assert np.hypot(*pos[0]) == pytest.approx(lengths[0], rel=1e-14)
    links = np.diff(np.vstack([np.zeros((1, 2)), pos]), axis=0)
    assert_close(np.hypot(links[:, 0], links[:, 1]), lengths, 1e-14, "link lengths")
    # Orientation: from the downward vertical, counter-clockwise (the symbolic geometry).
    expected = S.Reference(lengths, masses, com, inertia, kind=kind).tip_positions(theta)
    assert_close(pos, expected, 1e-14, "positions")
    hanging = np.asarray(chain.positions(np.zeros(n)))
    assert_close(hanging, np.column_stack([np.zeros(n), -np.cumsum(lengths)]), 1e-15, "hanging chain")
    if kind == "point":  # the bobs are the masses: U = g sum m_i y_i
        u = 9.81 * masses @ pos[:, 1]
        assert_close(chain.potential_energy(theta), u, RTOL_SYMBOLIC, "U from positions")


@pytest.mark.parametrize("n", [1, 2, 3, 5, 12])
def test_joint_torque_is_relative_generalized_torque(n):
    """Motor u_i between links i-1 and i acts +u_i on link i and -u_i on link i-1."""
    rng = rng_for(8000, n)
    for kind in S.KINDS:
        lengths, masses, com, inertia = S.random_chain(rng, n, kind)
        chain = make_chain(kind, lengths, masses, com, inertia, 9.81)
        theta, omega, u = random_state(rng, n)
        tau = u - np.append(u[1:], 0.0)
        assert_close(
            chain.accelerations(theta, omega, joint_torque=u),
            chain.accelerations(theta, omega, torque=tau),
            RTOL_SYMBOLIC,
            f"accelerations, joint_torque vs torque ({kind})",
        )
        p = chain.momenta(theta, omega)
        by_motor = chain.hamilton(theta, p, joint_torque=u)
        by_tau = chain.hamilton(theta, p, torque=tau)
        for got, want, name in zip(by_motor, by_tau, ("theta_dot", "p_dot")):
            assert_close(got, want, RTOL_SYMBOLIC, f"hamilton {name}, joint_torque vs torque ({kind})")
        if n <= 5:
            assert_close(
                chain.accelerations(theta, omega, joint_torque=u),
                S.Reference(lengths, masses, com, inertia, kind=kind).accelerations(theta, omega, tau),
                RTOL_SYMBOLIC,
                f"joint_torque vs symbolic ({kind})",
            )


def test_small_angle_normal_modes_equal_double_pendulum():
    """Equal point masses, l = m = 1: omega^2 = (g/l)(2 -+ sqrt 2), mode shapes theta2/theta1 = +-sqrt 2."""
    g, length = 9.81, 1.0
    chain = mp.Chain(lengths=[length, length], masses=[1.0, 1.0], g=g)
    rest = np.zeros(2)
    h = 1e-6
    # Linearisation theta_ddot = -D theta; D = M(0)^-1 K, taken from accelerations by central differences.
    d = np.empty((2, 2))
    for j in range(2):
        step = np.zeros(2)
        step[j] = h
        d[:, j] = -(chain.accelerations(rest + step, rest) - chain.accelerations(rest - step, rest)) / (2 * h)
    expected = (g / length) * np.array([2 - np.sqrt(2), 2 + np.sqrt(2)])
    eigvals, eigvecs = np.linalg.eig(d)
    order = np.argsort(eigvals.real)
    eigvals, eigvecs = eigvals.real[order], eigvecs.real[:, order]
    assert_close(eigvals, expected, 1e-6, "omega^2 from accelerations")
    ratios = eigvecs[1] / eigvecs[0]
    assert_close(ratios, [np.sqrt(2), -np.sqrt(2)], 1e-6, "mode shapes theta2/theta1")

    # The same frequencies from the energy: K = Hessian of U at rest, M(0) from mass_matrix.
    hu = 1e-4
    k = np.empty((2, 2))
    for i in range(2):
        for j in range(2):
            ei, ej = np.eye(2)[i] * hu, np.eye(2)[j] * hu
            k[i, j] = (
                chain.potential_energy(ei + ej)
                - chain.potential_energy(ei - ej)
                - chain.potential_energy(-ei + ej)
                + chain.potential_energy(-ei - ej)
            ) / (4 * hu * hu)
    from_energy = np.sort(np.linalg.eigvals(np.linalg.solve(chain.mass_matrix(rest), k)).real)
    assert_close(from_energy, expected, 1e-6, "omega^2 from M(0)^-1 K")
