"""Chaos indicators (MEGNO, FLI/OFLI, SALI, GALI_k) against what the theory says they do, with the
Lyapunov exponents of the same orbits (mp.lyapunov, an independent integration) as the rates:
MEGNO -> 2 on regular non-isochronous orbits, ~ lambda t / 2 on chaotic ones; FLI ~ lambda t on
chaotic orbits, ~ ln t on regular ones, OFLI bounded on periodic ones; SALI -> 0 at
lambda_1 - lambda_2 on chaotic orbits, positive on regular ones; GALI_k constant for k <= N and
~ t^(-2(k - N)) beyond on regular orbits, ~ exp(-sum_i (lambda_1 - lambda_i) t) on chaotic ones."""
import doctest

import numpy as np
import pytest

import multipendulum as mp

DOUBLE = mp.Chain([1.0, 1.0], [1.0, 1.0])
REGULAR, CHAOTIC = [0.3, 0.2], [2.0, 2.5]
ZERO = [0.0, 0.0]


def _slope(x, y):
    return float(np.polyfit(x, y, 1)[0])


def test_megno_tends_to_2_on_a_regular_orbit_and_to_0_on_a_nearly_isochronous_one():
    r = mp.megno(DOUBLE, REGULAR, ZERO, t_end=2000.0, dt=0.01)
    assert 1.8 < r.value < 2.2, r.value
    late = r.values[r.times > 1000]
    assert 1.7 < late.min() and late.max() < 2.3
    # One pendulum: every orbit is regular. Swinging wide it is non-isochronous (-> 2); at 1e-3
    # rad its period hardly depends on the amplitude (-> 0 over this time).
    single = mp.Chain([1.0], [1.0])
    assert 1.8 < mp.megno(single, [2.0], [0.0], t_end=2000.0, dt=0.01).value < 2.2
    assert abs(mp.megno(single, [1e-3], [0.0], t_end=2000.0, dt=0.01).value) < 0.05


def test_megno_and_fli_grow_at_the_lyapunov_exponent_on_a_chaotic_orbit():
    lam = mp.lyapunov(DOUBLE, CHAOTIC, ZERO, t_end=200.0, dt=0.005).largest
    m = mp.megno(DOUBLE, CHAOTIC, ZERO, t_end=200.0, record_every=100)
    late = m.times > 100
    assert _slope(m.times[late], m.values[late]) == pytest.approx(lam / 2, rel=0.15)
    assert m.value == pytest.approx(lam * 200.0 / 2, rel=0.15)
    f = mp.fli(DOUBLE, CHAOTIC, ZERO, t_end=200.0)
    assert f.value == pytest.approx(lam * 200.0, rel=0.1)


def test_fli_grows_like_ln_t_on_regular_orbits_and_ofli_stays_bounded_on_periodic_ones():
    f = mp.fli(DOUBLE, REGULAR, ZERO, t_end=2000.0, dt=0.01)
    late = f.times > 20
    assert _slope(np.log(f.times[late]), f.values[late]) == pytest.approx(1.0, abs=0.25)
    # One pendulum swinging wide: periodic, its deviation grows along the flow (the phase), not
    # across it.
    single = mp.Chain([1.0], [1.0])
    full = mp.fli(single, [2.0], [0.0], t_end=1000.0, dt=0.01)
    ortho = mp.fli(single, [2.0], [0.0], t_end=1000.0, dt=0.01, orthogonal=True)
    at = lambda r, t: r.values[np.searchsorted(r.times, t)]  # noqa: E731
    assert at(full, 1000.0) - at(full, 100.0) == pytest.approx(np.log(10.0), abs=0.3)
    assert at(ortho, 1000.0) - at(ortho, 100.0) < 0.3


def test_sali_vanishes_at_lambda1_minus_lambda2_on_chaotic_orbits_and_stays_positive_on_regular_ones():
    spec = _window_exponents(2.0, 14.0)
    s = mp.sali(DOUBLE, CHAOTIC, ZERO, t_end=14.0, record_every=10)
    ok = (s.times >= 2.0) & (s.values > 1e-13)
    assert _slope(s.times[ok], np.log(s.values[ok])) == pytest.approx(-(spec[0] - spec[1]), rel=0.3)
    assert mp.sali(DOUBLE, CHAOTIC, ZERO, t_end=60.0).value < 1e-12
    r = mp.sali(DOUBLE, REGULAR, ZERO, t_end=1000.0, dt=0.01)
    assert r.values[r.times > 10].min() > 1e-3


def test_gali_follows_the_power_laws_on_a_regular_orbit():
    """N = 2: GALI_2 constant, GALI_3 ~ t^-2, GALI_4 ~ t^-4; N = 3: GALI_4 ~ t^-2, GALI_6 ~ t^-6."""
    for chain, state, laws, tol in [(DOUBLE, (REGULAR, ZERO), {2: 0, 3: -2, 4: -4}, 0.3),
                                    (mp.Chain([1.0] * 3, [1.0] * 3), ([0.5, 0.3, 0.1], [0.0] * 3), {3: 0, 4: -2, 6: -6}, 0.5)]:
        for k, power in laws.items():
            g = mp.gali(chain, *state, t_end=1000.0, k=k, dt=0.01, record_every=10)
            late = g.times >= 20
            assert _slope(np.log(g.times[late]), np.log(g.values[late])) == pytest.approx(power, abs=tol), (chain.n, k)


def _window_exponents(a, b):
    """The Lyapunov spectrum of the chaotic orbit over [a, b]: the growth of mp.lyapunov's
    running sums between the two times (its initial transient left out, as the fits leave it)."""
    ly = mp.lyapunov(DOUBLE, CHAOTIC, ZERO, t_end=b, dt=0.005, renorm_every=10)
    sums = ly.history * ly.times[:, None]
    ia, ib = np.searchsorted(ly.times, a), np.searchsorted(ly.times, b)
    return (sums[ib] - sums[ia]) / (ly.times[ib] - ly.times[ia])


def test_gali_decays_with_the_sums_of_exponent_differences_on_a_chaotic_orbit():
    # Each over a window before it reaches round-off (GALI_4 gets there first).
    for k, (a, b) in {2: (2.0, 14.0), 3: (1.0, 7.0), 4: (0.5, 3.5)}.items():
        spec = _window_exponents(a, b)
        g = mp.gali(DOUBLE, CHAOTIC, ZERO, t_end=b, k=k, record_every=10)
        ok = (g.times >= a) & (g.values > 1e-13)
        rate = -_slope(g.times[ok], np.log(g.values[ok]))
        assert rate == pytest.approx(sum(spec[0] - spec[i] for i in range(1, k)), rel=0.3), (k, rate, spec)


def test_the_lyapunov_indicator_is_the_largest_exponent():
    """One renormalised vector (a generic start) against mp.lyapunov's k = 1 (unit start)."""
    lam = mp.lyapunov(DOUBLE, CHAOTIC, ZERO, t_end=300.0, k=1, renorm_every=1).largest
    assert mp.indicator(DOUBLE, CHAOTIC, ZERO, 300.0, "lyapunov").value == pytest.approx(lam, rel=0.05)
    assert abs(mp.indicator(DOUBLE, REGULAR, ZERO, 1000.0, "lyapunov", dt=0.01).value) < 0.02


def test_a_batch_is_its_rows_and_a_map_is_its_cells():
    theta = np.array([REGULAR, CHAOTIC, [1.0, -0.5]])
    batch = mp.indicator(DOUBLE, theta, np.zeros_like(theta), 20.0, "megno")
    for i, row in enumerate(theta):
        assert batch[i] == mp.megno(DOUBLE, row, ZERO, t_end=20.0).value  # bit for bit
    m = mp.indicator_map(DOUBLE, [0.3, 2.0], [0.2, 2.5], t_end=20.0, indicator="gali", k=3)
    assert m.values.shape == (2, 2) and m.indicator == "gali"
    assert m.values[0, 0] == mp.gali(DOUBLE, [0.3, 0.2], ZERO, t_end=20.0, k=3).value
    assert m.values[1, 1] < 1e-10 < m.values[0, 0]   # chaotic high up, regular near rest


def test_damping_is_in_the_variational_equations():
    """A damped double pendulum settles: its deviations shrink, so the FLI's supremum stops at
    its early transient and MEGNO turns negative (contraction), as Lyapunov exponents < 0 say."""
    damped = mp.Chain([1.0, 1.0], [1.0, 1.0], damping=0.5)
    lam = mp.lyapunov(damped, CHAOTIC, ZERO, t_end=100.0).largest
    assert lam < 0
    assert mp.megno(damped, CHAOTIC, ZERO, t_end=100.0).value < 0


SHAKE = mp.Pivot(x=mp.Sinusoid(amplitude=0.05, frequency=7.0), y=mp.Sinusoid(amplitude=0.03, frequency=11.0, phase=0.4))


def test_a_shaken_pivot_is_in_the_variational_equations():
    # Two derivations of the pivot's part of the tangent on the same orbits: in lanes (the
    # pivot's forces and their derivative added to the lanes' tangent: a built-in pivot) and per
    # state (the general model's exact tangent, as mp.lyapunov's, whose exponents the two-run
    # divergence test holds: a pivot given as a function). Over 10 s of the chaotic orbit the two
    # integrations stay on one orbit (round-off times e^(lambda t)).
    w = lambda a, f, p: lambda t: (a * np.sin(f * t + p), a * f * np.cos(f * t + p), -a * f * f * np.sin(f * t + p))  # noqa: E731
    called = mp.Pivot(x=w(0.05, 7.0, 0.0), y=w(0.03, 11.0, 0.4))
    theta = np.array([REGULAR, CHAOTIC, [1.0, -0.5]])
    for name in ("lyapunov", "megno", "sali"):
        lanes = mp.indicator(DOUBLE, theta, np.zeros_like(theta), 10.0, name, pivot=SHAKE)
        per_state = mp.indicator(DOUBLE, theta, np.zeros_like(theta), 10.0, name, pivot=called)
        np.testing.assert_allclose(per_state, lanes, rtol=1e-6, atol=1e-12)
        still = mp.indicator(DOUBLE, theta, np.zeros_like(theta), 10.0, name)
        assert np.max(np.abs(still - lanes) / (1e-12 + np.abs(still))) > 0.05, name  # the pivot matters
    # A map's cells are the states' own values.
    m = mp.indicator_map(DOUBLE, [0.3, 2.0], [0.2, 2.5], t_end=10.0, indicator="fli", pivot=SHAKE)
    assert m.values[0, 0] == mp.fli(DOUBLE, [0.3, 0.2], ZERO, t_end=10.0, pivot=SHAKE).value
    # A pivot held anywhere is the fixed one, bit for bit.
    held = mp.megno(DOUBLE, theta, np.zeros_like(theta), t_end=5.0, pivot=mp.Pivot(x=0.4))
    np.testing.assert_array_equal(held, mp.megno(DOUBLE, theta, np.zeros_like(theta), t_end=5.0))

    def boom(t):
        raise ZeroDivisionError("my pivot failed")

    with pytest.raises(mp.InputError, match=r"the pivot y function raised ZeroDivisionError\('my pivot failed'\) at t = 0") as info:
        mp.sali(DOUBLE, theta, np.zeros_like(theta), t_end=1.0, pivot=mp.Pivot(y=boom))
    assert isinstance(info.value.__cause__, ZeroDivisionError)


def test_bad_requests_are_refused_by_name():
    with pytest.raises(mp.InputError, match="indicator must be one of megno, fli, ofli, sali, gali, lyapunov, got 'lyap'"):
        mp.indicator(DOUBLE, REGULAR, ZERO, 1.0, "lyap")
    with pytest.raises(mp.InputError, match=r"GALI's order k must be between 2 and 2N = 4, got 5"):
        mp.gali(DOUBLE, REGULAR, ZERO, 1.0, k=5)
    with pytest.raises(mp.InputError, match=r"gali needs its order k"):
        mp.indicator(DOUBLE, REGULAR, ZERO, 1.0, "gali")
    with pytest.raises(mp.InputError, match="k is GALI's order; megno takes none"):
        mp.indicator(DOUBLE, REGULAR, ZERO, 1.0, "megno", k=2)
    with pytest.raises(mp.InputError, match=r"on a pivot \(fixed or moving\), not on a cart .*mp.lyapunov takes a cart"):
        mp.megno(mp.Chain.rods([1.0], [1.0], cart=mp.Cart(1.0)), [0.1], [0.0], 1.0)
    with pytest.raises(mp.InputError, match=r"deviations must have shape \(2, 2N = 4\)"):
        mp.indicator(DOUBLE, REGULAR, ZERO, 1.0, "sali", deviations=[1, 0, 0, 0])
    with pytest.raises(mp.InputError, match="linearly independent"):
        mp.indicator(DOUBLE, REGULAR, ZERO, 1.0, "sali", deviations=[[1, 0, 0, 0], [2, 0, 0, 0]])
    with pytest.raises(mp.InputError, match="x must be a non-empty array of finite numbers"):
        mp.indicator_map(DOUBLE, [0.1, np.nan], [0.2], t_end=1.0)
    with pytest.raises(mp.InputError, match="dt must be > 0"):
        mp.megno(DOUBLE, REGULAR, ZERO, 1.0, dt=-0.1)


def test_the_docstring_examples_run():
    import multipendulum._indicators as ind
    import multipendulum.chaos as chaos

    for module in (ind, chaos):
        failed, tried = doctest.testmod(module)
        assert tried >= 1 and failed == 0, module.__name__
