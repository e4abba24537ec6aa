"""The 0-1 test for chaos (multipendulum._zero_one) against independent facts: maps and flows whose
dynamics are known to be chaotic, periodic or quasi-periodic, the double pendulum at low and high
energy, noise (which the test reads as chaotic), the oversampling pitfall, and every bad input's
message."""
import math
import time

import numpy as np
import pytest

import multipendulum as mp
from multipendulum._zero_one import MAX_WORK, ZeroOneResult, zero_one_test
from multipendulum.errors import InputError


def logistic(r, n, x=0.3, transient=1000):
    for _ in range(transient):
        x = r * x * (1 - x)
    out = np.empty(n)
    for i in range(n):
        x = r * x * (1 - x)
        out[i] = x
    return out


def double_pendulum(theta0, dt, n=3000):
    """sin(theta_2) of the point-mass double pendulum (1 m, 1 kg links) every dt seconds."""
    sol = mp.simulate(mp.Chain([1, 1], [1, 1]), theta0, [0, 0], dt * n, t_eval=dt * np.arange(1, n + 1))
    return np.sin(sol.theta[:, 1])


# --- maps -----------------------------------------------------------------------------------

def test_logistic_map_chaotic_at_r_3_97():
    assert zero_one_test(logistic(3.97, 3000)).k > 0.9


def test_logistic_map_period_8_at_r_3_55():
    x = logistic(3.55, 3000)
    assert np.allclose(x[8:], x[:-8], atol=1e-9) and not np.allclose(x[4:], x[:-4], atol=1e-3)  # period 8 indeed
    assert zero_one_test(x).k < 0.1


def test_logistic_map_period_3_window_at_r_3_83():
    x = logistic(3.83, 3000)
    assert np.allclose(x[3:], x[:-3], atol=1e-9) and not np.allclose(x[1:], x[:-1], atol=1e-3)  # period 3 indeed
    assert zero_one_test(x).k < 0.1


def test_a_frequency_resonant_with_a_periodic_series_reads_as_chaotic_and_the_median_discards_it():
    # A period-3 series at c = 2 pi / 3 makes (p, q) drift linearly (K_c ~ 1): G&M's resonances,
    # the reason K is a median over many c.
    x = logistic(3.83, 3000)
    res = zero_one_test(x, c=[2 * np.pi / 3, 1.0, 1.3, 1.7, 2.3])
    assert res.k_c[0] > 0.9
    assert np.all(np.abs(res.k_c[1:]) < 0.1)
    assert res.k < 0.1


# --- flows and noise ------------------------------------------------------------------------

def test_quasi_periodic_series_is_regular():
    t = 0.5 * np.arange(3000)
    assert zero_one_test(np.sin(t) + np.sin(np.sqrt(2) * t)).k < 0.1


def test_iid_noise_reads_as_chaotic():
    # A known property of the test: it tells bounded from diffusive paths, and noise diffuses.
    assert zero_one_test(np.random.default_rng(7).standard_normal(3000)).k > 0.9
    assert zero_one_test(np.random.default_rng(8).uniform(0, 1, 3000)).k > 0.9


def test_double_pendulum_low_energy_is_regular():
    start = time.perf_counter()
    x = double_pendulum([0.1, 0.1], dt=1.0)
    assert zero_one_test(x).k < 0.15
    assert time.perf_counter() - start < 5


def test_double_pendulum_high_energy_is_chaotic():
    start = time.perf_counter()
    x = double_pendulum([2.0, 2.5], dt=1.0)
    assert zero_one_test(x).k > 0.8
    assert time.perf_counter() - start < 5


def test_an_oversampled_chaotic_series_gives_a_spurious_value():
    # The pitfall the docstring warns of (G&M 2009): every 0.01 s, 30 s of the chaotic double
    # pendulum look smooth and the test misreads them.
    assert zero_one_test(double_pendulum([2.0, 2.5], dt=0.01)).k < 0.5


# --- properties -----------------------------------------------------------------------------

def test_same_seed_same_result_and_another_seed_other_frequencies():
    x = logistic(3.97, 2000)
    a, b = zero_one_test(x, seed=3), zero_one_test(x, seed=3)
    assert isinstance(a, ZeroOneResult)
    assert a.k == b.k and np.array_equal(a.k_c, b.k_c) and np.array_equal(a.c, b.c)
    other = zero_one_test(x, seed=4)
    assert not np.array_equal(a.c, other.c)
    assert other.k > 0.9


def test_default_frequencies_lie_in_g_and_m_interval():
    res = zero_one_test(logistic(3.97, 500), n_c=1000)
    assert res.c.shape == (1000,) and res.k_c.shape == (1000,)
    assert res.c.min() > np.pi / 5 and res.c.max() < 4 * np.pi / 5
    assert res.k == np.median(res.k_c)


def test_given_frequencies_are_used():
    res = zero_one_test(logistic(3.97, 500), c=1.1)
    assert res.c.tolist() == [1.1] and res.k == res.k_c[0]


def test_a_large_mean_masks_chaos_unless_the_oscillatory_term_is_subtracted():
    # G&M 2009: the term mean(phi)^2 (1 - cos nc) / (1 - cos c) of M_c(n) dominates its linear
    # growth when the mean is large; the modified test (detrend=True) removes it.
    x = logistic(3.97, 2000) + 10.0
    assert zero_one_test(x).k > 0.9
    assert zero_one_test(x, detrend=False).k < 0.5


def test_k_is_invariant_under_scaling_the_series():
    x = logistic(3.97, 1000)
    assert zero_one_test(x).k == pytest.approx(zero_one_test(1e3 * x).k, abs=1e-12)


def test_result_is_frozen():
    res = zero_one_test(logistic(3.97, 500))
    with pytest.raises(AttributeError):
        res.k = 0.0


# --- bad input ------------------------------------------------------------------------------

GOOD = np.sin(0.5 * np.arange(1000))


@pytest.mark.parametrize("kwargs, message", [
    (dict(series=np.zeros((10, 20))), "series must be 1-D (one scalar observable per sample), got shape (10, 20)"),
    (dict(series=np.arange(99.0)), "series needs at least 100 samples (a few thousand are better), got 99"),
    (dict(series=np.r_[GOOD[:5], np.nan, GOOD[6:]]), "series must be finite, got series[5] = nan"),
    (dict(series=np.r_[GOOD[:7], -np.inf, GOOD[8:]]), "series must be finite, got series[7] = -inf"),
    (dict(series=np.full(500, 2.5)), "series is constant (2.5): K is undefined for it"),
    (dict(series="abc"), "series must be an array of numbers, got str 'abc'"),
    (dict(n_c=0), "n_c must be at least 1, got 0"),
    (dict(n_c=2.5), "n_c must be an integer, got float 2.5"),
    (dict(n_cut=501), "n_cut must be in [10, 500] (at most half the series' 1000 samples; G&M take N // 10), got 501"),
    (dict(n_cut=9), "n_cut must be in [10, 500] (at most half the series' 1000 samples; G&M take N // 10), got 9"),
    (dict(c=[1.0, math.pi]), "c must lie in (0, pi) (rad per sample; G&M draw it from (pi/5, 4 pi/5)), got c[1] = 3.141592653589793"),
    (dict(c=[0.0]), "c must lie in (0, pi) (rad per sample; G&M draw it from (pi/5, 4 pi/5)), got c[0] = 0.0"),
    (dict(c=[1.0, np.nan]), "c must lie in (0, pi) (rad per sample; G&M draw it from (pi/5, 4 pi/5)), got c[1] = nan"),
    (dict(c=[]), "c must be a number or a 1-D array of at least one number, got shape (0,)"),
    (dict(seed=-1), "seed must be a non-negative integer or None, got -1"),
    (dict(detrend="yes"), "detrend must be True or False, got str 'yes'"),
])
def test_bad_input_messages(kwargs, message):
    kwargs = {"series": GOOD, **kwargs}
    with pytest.raises(InputError) as e:
        zero_one_test(kwargs.pop("series"), **kwargs)
    assert str(e.value) == message
    assert isinstance(e.value, ValueError)


def test_too_much_work_is_refused_with_advice():
    n = 20_000          # n_c * n_cut * N = 100 * 2000 * 20000 = 4e9 > MAX_WORK
    assert 100 * (n // 10) * n > MAX_WORK
    with pytest.raises(InputError) as e:
        zero_one_test(np.sin(0.5 * np.arange(n)))
    assert str(e.value) == ("the test would take n_c * n_cut * N = 100 * 2000 * 20000 = 4e+09 operations "
                            "(at most 2e+09): subsample the series (it needs only a few samples per "
                            "oscillation and a few thousand samples), or pass a smaller n_cut or n_c")
    # the same series subsampled, as advised, passes
    assert zero_one_test(np.sin(0.5 * np.arange(n))[::4]).k < 0.1
