"""The SIMD flip-map kernels (crates/core/src/chaos/flipkernel.rs) behind mp.flip_times for the
undriven double pendulum and for undriven ideal chains of any other N (in lanes), against the
per-trajectory rk4 path they replace (MULTIPENDULUM_FLIP_KERNEL=scalar)."""
import os

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


def cpu_flags():
    """The CPU's feature flags from /proc/cpuinfo (empty where there is none: not Linux x86)."""
    try:
        text = open("/proc/cpuinfo").read()
    except OSError:
        return set()
    line = next((l for l in text.splitlines() if l.startswith("flags")), "")
    return set(line.split(":", 1)[1].split()) if ":" in line else set()


def expected_simd_paths(flags):
    """The kernel's SIMD paths this CPU can run (the kernel's own test: AVX2 or AVX-512F, and FMA)."""
    paths = []
    if {"avx2", "fma"} <= flags:
        paths.append("avx2")
    if {"avx512f", "fma"} <= flags:
        paths.append("avx512")
    return paths


def test_every_kernel_path_gives_the_same_bits(monkeypatch, record_property):
    th0 = grid(40)
    om0 = np.random.default_rng(2).uniform(-2, 2, th0.shape)
    ref = flips(monkeypatch, "portable", CHAINS["rods"], th0, om0, t_max=8.0)
    assert np.isfinite(ref).any() and np.isinf(ref).any()
    expected = expected_simd_paths(cpu_flags())
    ran, refused = [], {}
    for path in ("avx2", "avx512"):
        try:
            got = flips(monkeypatch, path, CHAINS["rods"], th0, om0, t_max=8.0)
        except mp.InputError as e:
            assert "not supported by this CPU" in str(e)
            refused[path] = str(e)
            continue
        ran.append(path)
        assert got.tobytes() == ref.tobytes(), path
    # "auto" takes the best path there is: the same bits again.
    assert flips(monkeypatch, "auto", CHAINS["rods"], th0, om0, t_max=8.0).tobytes() == ref.tobytes()
    record_property("kernel_paths_compared", ",".join(["portable"] + ran))
    print(f"flip kernel: compared portable with {', '.join(ran) or 'no SIMD path'}; "
          f"the CPU offers {', '.join(expected) or 'none'}")
    # A path the CPU offers must run: a kernel that refuses it would leave it untested.
    missing = [p for p in expected if p not in ran]
    assert not missing, f"the CPU supports {missing} but the kernel refused them: {refused}"
    if not ran:
        message = ("no SIMD path ran on this CPU (no AVX2+FMA): the portable path was compared with "
                   "itself only")
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(message + "; CI must run on a machine with AVX2 to check the promise")
        pytest.skip(message)


@pytest.mark.parametrize("name", list(CHAINS))
def test_no_flip_where_the_energy_forbids_it(monkeypatch, name):
    chain = CHAINS[name]
    monkeypatch.setenv(SWITCH, "auto")
    fm = mp.flip_map(chain, np.linspace(-np.pi, np.pi, 71), np.linspace(-np.pi, np.pi, 71), t_max=8.0)
    assert not np.any(np.isfinite(fm.times) & ~fm.allowed)
    assert np.isfinite(fm.times[fm.allowed]).mean() > 0.2


@pytest.mark.parametrize("route", ["auto", "generic", "scalar"])
def test_a_blow_up_raises_integration_error_naming_its_row(monkeypatch, route):
    monkeypatch.setenv(SWITCH, route)
    omega = np.zeros((1500, 2))
    omega[1234, 0] = 1e200
    with pytest.raises(mp.IntegrationError, match="trajectory 1234: .*non-finite"):
        mp.flip_times(CHAINS["point"], np.full((1500, 2), 0.1), omega, t_max=1.0)


def test_an_unknown_route_is_refused(monkeypatch):
    monkeypatch.setenv(SWITCH, "gpu")
    with pytest.raises(mp.InputError,
                       match=f"{SWITCH} must be one of auto, scalar, portable, avx2, avx512, generic, got \"gpu\""):
        mp.flip_times(CHAINS["point"], [1.0, 2.0])


def test_the_generic_lanes_time_the_double_pendulum_as_its_own_kernel(monkeypatch):
    # MULTIPENDULUM_FLIP_KERNEL=generic: the lanes of any chain (the O(N) route's closed form for
    # two links) instead of the double pendulum's kernel; the same times to round-off.
    th0 = np.random.default_rng(3).uniform(-3.0, 3.0, (500, 2))
    monkeypatch.setenv(SWITCH, "auto")
    own = mp.flip_times(CHAINS["point"], th0, t_max=2.0)
    monkeypatch.setenv(SWITCH, "generic")
    generic = mp.flip_times(CHAINS["point"], th0, t_max=2.0)
    np.testing.assert_array_equal(np.isfinite(own), np.isfinite(generic))
    early = np.isfinite(own) & (own < 1.5)
    assert early.sum() > 30
    np.testing.assert_allclose(generic[early], own[early], rtol=0, atol=1e-9)


# ---- chains of any N, in lanes

def chains(n):
    lengths = 1.0 - 0.05 * np.arange(n)
    masses = 1.0 + 0.3 * (np.arange(n) % 3)
    return {
        "point": mp.Chain(lengths, masses),
        "rods": mp.Chain.rods(lengths, masses),
        "links": mp.Chain(lengths, masses, com=0.4 * lengths, inertia=0.02 * lengths, g=3.7),
    }


def released(n, side=31):
    """A grid of theta_1 and theta_N from rest, the links between at 0.3 rad."""
    x = np.linspace(-np.pi, np.pi, side)
    X, Y = np.meshgrid(x, x)
    th = np.full(X.shape + (n,), 0.3)
    th[..., 0], th[..., -1] = X, Y
    return th.reshape(-1, n)


@pytest.mark.parametrize("n", [1, 3, 6])
@pytest.mark.parametrize("kind", ["point", "rods", "links"])
def test_chains_of_any_n_flip_in_lanes_as_on_the_per_trajectory_path(monkeypatch, n, kind):
    chain = chains(n)[kind]
    th0 = released(n)
    # A single pendulum flips only from a fast start (omega^2 > 4 g / l from the bottom).
    om0 = np.random.default_rng(n).uniform(-1, 1, th0.shape) * (8.0 if n == 1 else 1.0)
    monkeypatch.setenv(SWITCH, "auto")
    fast = mp.flip_times(chain, th0, om0, t_max=4.0)
    monkeypatch.setenv(SWITCH, "scalar")
    slow = mp.flip_times(chain, th0, om0, t_max=4.0)
    # Chaos amplifies the last-bit differences of the lanes' sin/cos: late flips may differ.
    assert np.mean(np.isfinite(fast) == np.isfinite(slow)) > 0.98
    early = (fast < 1.0) & (slow < 1.0) & (slow > 0)
    assert early.sum() > 30
    np.testing.assert_allclose(fast[early], slow[early], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(fast == 0, slow == 0)


@pytest.mark.parametrize("n, torque", [
    (2, mp.Sinusoid([4.0, 0.0], [2.0, 1.0], phase=[0.3, 0.0], offset=[0.5, 0.0])),   # the double pendulum's
    (3, mp.Sinusoid([3.0, 1.0, 2.0], [2.0, 3.0, 5.0])),                            # own kernel is undriven
    (3, mp.Table([0.0, 1.0, 2.0], [[0, 1, 2], [2, -1, 0], [1, 1, 1]], kind="cubic")),
])
def test_driven_chains_flip_in_lanes_as_on_the_per_trajectory_path(monkeypatch, n, torque):
    chain = chains(n)["rods"]
    th0 = released(n)
    monkeypatch.setenv(SWITCH, "auto")
    fast = mp.flip_times(chain, th0, t_max=4.0, torque=torque)
    undriven = mp.flip_times(chain, th0, t_max=4.0)
    monkeypatch.setenv(SWITCH, "scalar")
    slow = mp.flip_times(chain, th0, t_max=4.0, torque=torque)
    assert np.mean(fast != undriven) > 0.2  # the torque matters
    assert np.mean(np.isfinite(fast) == np.isfinite(slow)) > 0.98
    early = (fast < 1.0) & (slow < 1.0) & (slow > 0)
    assert early.sum() > 30
    np.testing.assert_allclose(fast[early], slow[early], rtol=0, atol=1e-9)


@pytest.mark.parametrize("n", [3, 4])
def test_lanes_give_the_same_bits_on_every_path_and_alone(monkeypatch, n):
    # Rows alone take one group of lanes; many, two groups side by side (for N = 3 in
    # fixed-size arrays, for N = 4 one after the other): the same bits either way.
    chain = chains(n)["rods"]
    th0 = released(n, 25)
    monkeypatch.setenv(SWITCH, "portable")
    ref = mp.flip_times(chain, th0, t_max=6.0)
    assert np.isfinite(ref).any() and np.isinf(ref).any()
    ran = []
    for path in ("avx2", "avx512"):
        monkeypatch.setenv(SWITCH, path)
        try:
            got = mp.flip_times(chain, th0, t_max=6.0)
        except mp.InputError as e:
            assert "not supported by this CPU" in str(e)
            continue
        ran.append(path)
        np.testing.assert_array_equal(got, ref)
    assert ran == expected_simd_paths(cpu_flags())
    monkeypatch.setenv(SWITCH, "auto")
    singles = np.array([mp.flip_times(chain, th0[i], t_max=6.0) for i in range(0, len(th0), 37)])
    np.testing.assert_array_equal(singles, ref[::37])
