"""Chaos tools: Lyapunov spectra from the variational equations, flip times, the flip-map energy bound."""
import numpy as np
import pytest
from scipy.integrate import quad

import multipendulum as mp

DOUBLE = mp.Chain(lengths=[1.0, 1.0], masses=[1.0, 1.0])


def test_full_spectrum_of_the_chaotic_double_pendulum_pairs_up_and_sums_to_zero():
    res = mp.lyapunov(DOUBLE, [2.0, 2.5], [0.0, 0.0], t_end=200.0, dt=0.005)
    lam = res.exponents
    assert lam.shape == (4,) and np.all(np.diff(lam) <= 0)
    assert lam[0] > 0.5  # chaotic
    assert abs(lam.sum()) < 0.02 * lam[0]  # Hamiltonian: phase-space volume is conserved
    assert abs(lam[0] + lam[3]) < 0.05 * lam[0] and abs(lam[1] + lam[2]) < 0.05 * lam[0]  # +/- pairs
    assert res.history.shape == (res.times.size, 4)


def test_small_oscillations_have_exponents_near_zero():
    res = mp.lyapunov(DOUBLE, [0.05, 0.0], [0.0, 0.0], t_end=200.0)
    assert np.max(np.abs(res.exponents)) < 0.03


def test_rods_and_longer_chains_are_chaotic_too_with_zero_sum():
    chain = mp.Chain.rods(lengths=[1.0, 0.8, 0.6], masses=[1.0, 0.8, 0.6])
    res = mp.lyapunov(chain, [1.5, 2.0, 2.5], [0, 0, 0], t_end=100.0, dt=0.002)
    assert res.largest > 0.3
    assert abs(res.exponents.sum()) < 0.03 * res.largest


def test_trustworthy_until_uses_the_largest_exponent():
    assert mp.trustworthy_until(1.0, tolerance=1e-2, eps=1e-16) == pytest.approx(np.log(1e14))
    assert mp.trustworthy_until(0.0) == np.inf


def test_flip_time_of_a_single_pendulum_matches_the_quadrature():
    g, l, w0 = 9.81, 1.0, 7.0  # enough energy to go over the top: w0^2 > 4 g / l
    chain = mp.Chain(lengths=[l], masses=[1.0], g=g)
    exact, _ = quad(lambda th: 1.0 / np.sqrt(w0**2 - 2 * g / l * (1 - np.cos(th))), 0.0, np.pi, epsabs=1e-13)
    err = {dt: abs(float(mp.flip_times(chain, [0.0], [w0], t_max=5.0, dt=dt)) - exact) for dt in (0.02, 0.01)}
    # rk4 is of order 4 and the root is found on the step's cubic Hermite interpolant (order 4
    # too): halving the step must divide the error by 2^4 = 16; at least 2^3 is asked. The
    # quadrature is good to 1e-13, far below either error.
    assert 1e-12 < err[0.01] <= err[0.02] / 2**3, err
    assert mp.flip_times(chain, [0.0], [5.0], t_max=5.0, dt=0.01) == np.inf  # not enough energy


@pytest.mark.parametrize("make, bound", [
    (lambda: mp.Chain([1, 1], [1, 1]), lambda t1, t2: 2 * np.cos(t1) + np.cos(t2) > 1),
    (lambda: mp.Chain.rods([1, 1], [1, 1]), lambda t1, t2: 3 * np.cos(t1) + np.cos(t2) > 2),
])
def test_flip_map_respects_the_energy_bound(make, bound):
    chain = make()
    x = np.linspace(-np.pi, np.pi, 61)
    fm = mp.flip_map(chain, x, x, t_max=8.0)
    T1, T2 = np.meshgrid(x, x)
    forbidden = bound(T1, T2)
    # The derived threshold reproduces the known closed-form regions (up to the boundary itself).
    interior = np.abs(fm.allowed.astype(int) - (~forbidden).astype(int)) == 0
    assert interior.mean() > 0.99
    assert not np.any(np.isfinite(fm.times) & forbidden)  # nothing flips where energy forbids it
    assert np.isfinite(fm.times[~forbidden]).mean() > 0.3  # and much of the rest does


def test_flip_times_are_thread_count_independent_and_match_single_runs():
    rng = np.random.default_rng(3)
    th0 = rng.uniform(-3, 3, (40, 2))
    batch = mp.flip_times(DOUBLE, th0, t_max=5.0)
    singles = np.array([mp.flip_times(DOUBLE, th0[i], t_max=5.0) for i in range(40)])
    np.testing.assert_array_equal(batch, singles)


def test_bad_chaos_input():
    with pytest.raises(mp.InputError, match=r"k must be between 1 and 2N = 4, got 5"):
        mp.lyapunov(DOUBLE, [1, 1], [0, 0], 10.0, k=5)
    with pytest.raises(mp.InputError, match=r"link must be an integer in \[0, 2\) or None"):
        mp.flip_times(DOUBLE, [1, 1], link=2)
    with pytest.raises(mp.InputError, match="t_max must be > 0 and finite, got -1"):
        mp.flip_times(DOUBLE, [1, 1], t_max=-1.0)
    with pytest.raises(mp.InputError, match="lyapunov takes built-in torques only"):
        mp.lyapunov(DOUBLE, [1, 1], [0, 0], 10.0, torque=lambda t: [0, 0])


def test_jacobian_matches_central_differences_of_the_right_hand_side():
    chain = mp.Chain(lengths=[1.0, 0.7, 0.5], masses=[1.0, 2.0, 0.5], com=[0.6, 0.3, 0.5], inertia=[0.05, 0.1, 0.0])
    x0 = np.array([0.3, -1.2, 2.0, 0.5, 2.0, -1.0])
    f = lambda x: np.concatenate([x[3:], chain.accelerations(x[:3], x[3:])])  # noqa: E731
    e = 1e-6
    fd = np.stack([(f(x0 + e * d) - f(x0 - e * d)) / (2 * e) for d in np.eye(6)], axis=1)
    np.testing.assert_allclose(chain.jacobian(x0[:3], x0[3:]), fd, atol=1e-7 * np.abs(fd).max())


@pytest.mark.parametrize("top", [False, True])
def test_linearisation_gives_the_equal_double_pendulum_modes(top):
    # Hanging: omega^2 = (g/l)(2 -+ sqrt 2). Inverted: the same magnitudes, as growth rates.
    g = 9.81
    chain = mp.Chain([1.0, 1.0], [1.0, 1.0], g=g)
    theta = [np.pi, np.pi] if top else [0.0, 0.0]
    ev = np.linalg.eigvals(chain.jacobian(theta, [0, 0]))
    squares = np.sort(np.unique(np.round((ev**2).real / g, 10)))
    expected = np.array([2 - np.sqrt(2), 2 + np.sqrt(2)]) * (1 if top else -1)
    np.testing.assert_allclose(np.sort(squares), np.sort(expected), rtol=1e-10)


def test_ensemble_keeps_final_states_and_reductions_equal_to_single_runs(monkeypatch):
    rng = np.random.default_rng(7)
    th0 = rng.uniform(-2.5, 2.5, (12, 2))
    om0 = rng.uniform(-1, 1, (12, 2))
    # dop853 in lanes agrees with the per-trajectory route to the tolerance (its steps are
    # steered by an error estimate that cancels to round-off), and that route with single runs
    # bit for bit.
    ens = mp.ensemble(DOUBLE, th0, om0, t_end=8.0)
    monkeypatch.setenv("MULTIPENDULUM_LANES", "scalar")
    alone = mp.ensemble(DOUBLE, th0, om0, t_end=8.0)
    np.testing.assert_allclose(ens.theta, alone.theta, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(ens.energy_error, alone.energy_error, rtol=0, atol=1e-11)
    assert np.all(np.abs(ens.steps - alone.steps) <= 1), (ens.steps, alone.steps)
    ens = alone
    assert ens.theta.shape == (12, 2) and ens.first_flip.shape == (12,)
    # The energy error from the states themselves: the change in energy since t = 0 (no torque:
    # no work), by the chain's energy, over the core's scale S = g sum |h_i| + max T. Energy is
    # conserved, so T <= E0 - U_min = E0 + g sum |h_i| and S lies between g sum |h_i| and
    # 2 g sum |h_i| + E0; the reported error must lie between the two quotients (and is not 0:
    # dop853 at rtol 1e-10 over 8 s of chaos does not conserve energy to the last bit).
    m, c, length = DOUBLE.masses, DOUBLE.com, DOUBLE.lengths
    below = np.concatenate([np.cumsum(m[::-1])[::-1][1:], [0.0]])  # mass hanging below each link
    depth = DOUBLE.g * np.sum(np.abs(m * c + length * below))
    for b in (0, 5, 11):
        single = mp.simulate(DOUBLE, th0[b], om0[b], 8.0, t_eval=[8.0])
        np.testing.assert_array_equal(ens.theta[b], single.theta[-1])
        assert ens.energy_error[b] == single.stats.energy_error
        e0 = DOUBLE.energy(th0[b], om0[b])
        change = abs(DOUBLE.energy(ens.theta[b], ens.omega[b]) - e0)
        assert change > 0
        lo, hi = change / (2 * depth + e0), change / depth
        roundoff = 16 * np.finfo(float).eps * (abs(e0) + 2 * depth) / depth  # of the two energies, relative
        assert lo - roundoff <= ens.energy_error[b] <= hi + roundoff, (b, ens.energy_error[b], lo, hi)
    # First flips agree with the dedicated flip kernel to the accuracy of its rk4 steps.
    flips = mp.flip_times(DOUBLE, th0, om0, t_max=8.0, dt=0.001)
    np.testing.assert_array_equal(np.isfinite(ens.first_flip), np.isfinite(flips))
    both = np.isfinite(flips)
    assert both.any() and np.max(np.abs(ens.first_flip[both] - flips[both])) < 1e-6


def test_every_run_can_say_how_long_it_is_trustworthy():
    chaotic = mp.simulate(DOUBLE, [2.0, 2.5], [0, 0], 60.0, t_eval=np.linspace(0, 60, 601))
    until = chaotic.trustworthy_until()
    # lambda ~ 1.5/s, eps = rtol 1e-10: ln(1e8)/1.5 ~ 12 s, well before the end of the run.
    assert 5.0 < until < 30.0
    regular = mp.simulate(DOUBLE, [0.1, 0.05], [0, 0], 60.0, t_eval=np.linspace(0, 60, 601))
    assert regular.trustworthy_until() == np.inf
    assert mp.simulate(DOUBLE, [2.0, 2.5], [0, 0], 5.0, torque=lambda t: [0, 0]).trustworthy_until() is None
