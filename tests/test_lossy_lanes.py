"""Damping, friction and a cart in the SIMD lanes (issue 14): flip times, ensembles and chaos
indicators of lossy chains (flip times of chains on a cart too) run in lanes and agree with the
per-trajectory routes they replace (forced with MULTIPENDULUM_FLIP_KERNEL=scalar /
MULTIPENDULUM_LANES=scalar)."""
import numpy as np
import pytest

import multipendulum as mp

LOSSY = {
    "double, damped with friction": mp.Chain([1.0, 1.0], [1.0, 1.0], damping=[0.1, 0.3], friction=[0.2, 0.0],
                                             friction_velocity=0.05),
    "triple rods, damped": mp.Chain.rods([1.0, 0.5, 0.8], [1.0, 0.3, 2.0], damping=0.15),
    # (a friction_velocity that rk4 at these steps resolves: a stiff one amplifies round-off)
    "five links, friction": mp.Chain([0.4] * 5, [1.0, 0.5, 2.0, 1.0, 0.1], friction=0.05, friction_velocity=0.5),
}


def _both(monkeypatch, switch, fn):
    monkeypatch.setenv(switch, "auto")
    fast = fn()
    monkeypatch.setenv(switch, "scalar")
    return fast, fn()


ON_CART = {
    "double on a free cart": mp.Chain([1.0, 1.0], [1.0, 1.0], cart=mp.Cart(2.0)),
    "triple rods on a damped cart": mp.Chain.rods([1.0, 0.5, 0.8], [1.0, 0.3, 2.0], damping=0.05,
                                                  cart=mp.Cart(1.0, damping=0.3)),
}


@pytest.mark.parametrize("key", list(LOSSY) + list(ON_CART))
def test_flip_times_of_lossy_chains_agree_with_the_per_trajectory_path(monkeypatch, key):
    chain = {**LOSSY, **ON_CART}[key]
    th0 = np.random.default_rng(7).uniform(-3.0, 3.0, (300, chain.n))
    fast, slow = _both(monkeypatch, "MULTIPENDULUM_FLIP_KERNEL", lambda: mp.flip_times(chain, th0, t_max=3.0, dt=0.01))
    np.testing.assert_array_equal(np.isfinite(fast), np.isfinite(slow))
    early = np.isfinite(slow) & (slow < 1.5)  # before chaos amplifies round-off
    assert early.sum() > 20
    np.testing.assert_allclose(fast[early], slow[early], rtol=0, atol=1e-9)


@pytest.mark.parametrize("key", list(LOSSY))
@pytest.mark.parametrize("indicator", ["megno", "fli", "sali"])
def test_indicators_of_lossy_chains_agree_with_the_per_state_route(monkeypatch, key, indicator):
    chain = LOSSY[key]
    th0 = np.random.default_rng(8).uniform(-2.0, 2.0, (19, chain.n))
    fast, slow = _both(monkeypatch, "MULTIPENDULUM_LANES",
                       lambda: mp.indicator(chain, th0, np.zeros_like(th0), 1.0, indicator, dt=0.005))
    np.testing.assert_allclose(fast, slow, rtol=1e-11, atol=1e-12)


def test_damping_makes_megno_negative_in_lanes_too():
    # A damped pendulum contracts phase space: nearby orbits converge, MEGNO turns negative.
    chain = mp.Chain([1.0, 1.0], [1.0, 1.0], damping=0.5)
    th0 = np.array([[2.0, 2.5], [0.3, 0.2], [1.0, -0.5]])
    assert np.all(mp.megno(chain, th0, np.zeros_like(th0), t_end=100.0) < 0)


@pytest.mark.parametrize("key", ["double, damped with friction", "triple rods, damped"])
@pytest.mark.parametrize("indicator", ["megno", "fli", "sali"])
def test_indicators_of_driven_chains_agree_with_the_per_state_route(monkeypatch, key, indicator):
    # A built-in torque of time rides along in the lanes too (it has no tangent of its own).
    chain = LOSSY[key]
    torque = mp.Sinusoid(np.full(chain.n, 3.0), 2.0 + np.arange(chain.n), offset=0.5)
    th0 = np.random.default_rng(9).uniform(-2.0, 2.0, (19, chain.n))
    run = lambda torque: mp.indicator(chain, th0, np.zeros_like(th0), 1.0, indicator, dt=0.005, torque=torque)
    fast, slow = _both(monkeypatch, "MULTIPENDULUM_LANES", lambda: run(torque))
    np.testing.assert_allclose(fast, slow, rtol=1e-11, atol=1e-12)
    assert np.max(np.abs(fast - run(None))) > 1e-3  # the torque matters
