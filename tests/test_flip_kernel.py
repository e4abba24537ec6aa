"""The SIMD flip-map kernel (crates/core/src/flipkernel.rs) behind mp.flip_times for the undriven
double pendulum, against the per-trajectory rk4 path it replaces (MULTIPENDULUM_FLIP_KERNEL=scalar)."""
import numpy as np
import pytest

import multipendulum as mp

SWITCH = "MULTIPENDULUM_FLIP_KERNEL"
CHAINS = {
    "point": mp.Chain([1.0, 1.0], [1.0, 1.0]),
    "rods": mp.Chain.rods([1.0, 0.7], [1.0, 2.0]),
    "links": mp.Chain([1.0, 0.7], [1.0, 2.0], com=[0.6, 0.3], inertia=[0.05, 0.1], g=3.7),
}


def grid(n):
    x = np.linspace(-np.pi, np.pi, n)
    X, Y = np.meshgrid(x, x)
    return np.stack([X, Y], -1).reshape(-1, 2)


def flips(monkeypatch, route, chain, theta0, omega0=None, **kw):
    monkeypatch.setenv(SWITCH, route)
    return mp.flip_times(chain, theta0, omega0, **kw)


@pytest.mark.parametrize("name", list(CHAINS))
@pytest.mark.parametrize("link", [None, 0, 1])
def test_kernel_flip_times_equal_the_scalar_paths_where_the_motion_is_regular(monkeypatch, name, link):
    chain = CHAINS[name]
    th0 = grid(45)
    om0 = np.random.default_rng(1).uniform(-1, 1, th0.shape)
    fast = flips(monkeypatch, "auto", chain, th0, om0, t_max=5.0, link=link)
    slow = flips(monkeypatch, "scalar", chain, th0, om0, t_max=5.0, link=link)
    # Chaos amplifies the last-bit differences of sin/cos, so late flips may differ; early ones not.
    assert np.mean(np.isfinite(fast) == np.isfinite(slow)) > 0.99
    early = (fast < 1.5) & (slow < 1.5) & (slow > 0)
    assert early.sum() > 30
    np.testing.assert_allclose(fast[early], slow[early], rtol=0, atol=1e-9)
    # Rows that start beyond pi give 0 on both routes.
    np.testing.assert_array_equal(fast == 0, slow == 0)
    assert (fast == 0).any()


def test_every_kernel_path_gives_the_same_bits(monkeypatch):
    th0 = grid(40)
    om0 = np.random.default_rng(2).uniform(-2, 2, th0.shape)
    ref = flips(monkeypatch, "portable", CHAINS["rods"], th0, om0, t_max=8.0)
    ran = 0
    for path in ("avx2", "avx512", "auto"):
        try:
            got = flips(monkeypatch, path, CHAINS["rods"], th0, om0, t_max=8.0)
        except mp.InputError as e:
            assert "not supported by this CPU" in str(e)
            continue
        ran += 1
        assert got.tobytes() == ref.tobytes(), path
    assert ran >= 1  # "auto" always runs


@pytest.mark.parametrize("name", list(CHAINS))
def test_no_flip_where_the_energy_forbids_it(monkeypatch, name):
    chain = CHAINS[name]
    monkeypatch.setenv(SWITCH, "auto")
    fm = mp.flip_map(chain, np.linspace(-np.pi, np.pi, 71), np.linspace(-np.pi, np.pi, 71), t_max=8.0)
    assert not np.any(np.isfinite(fm.times) & ~fm.allowed)
    assert np.isfinite(fm.times[fm.allowed]).mean() > 0.2


def test_a_blow_up_raises_integration_error(monkeypatch):
    monkeypatch.setenv(SWITCH, "auto")
    with pytest.raises(mp.IntegrationError, match="non-finite"):
        mp.flip_times(CHAINS["point"], [[0.1, 0.2], [0.1, 0.2]], [[0.0, 0.0], [1e200, 0.0]], t_max=1.0)


def test_an_unknown_route_is_refused(monkeypatch):
    monkeypatch.setenv(SWITCH, "gpu")
    with pytest.raises(mp.InputError, match=f"{SWITCH} must be one of auto, scalar, portable, avx2, avx512, got \"gpu\""):
        mp.flip_times(CHAINS["point"], [1.0, 2.0])
