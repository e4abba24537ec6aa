"""The benchmark's independent pieces (bench/reference.py, bench/peers.py) against the core.

The work-precision diagrams measure our errors against bench/reference.py's mpmath solution and
time SciPy on bench/peers.py's NumPy right-hand side; both are written independently of the Rust
core, so they must agree with it here or the benchmark's errors would mean nothing.
"""
import sys
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp

mpmath = pytest.importorskip("mpmath")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import peers  # noqa: E402
import reference  # noqa: E402

CHAINS = {
    "point masses": mp.Chain(lengths=[1.0, 1.0], masses=[1.0, 1.0]),
    "seed 001 rods": mp.Chain.rods([1.0, 0.7], [1.0, 2.0]),
    "general, N = 5": mp.Chain(lengths=[0.5, 1.2, 0.8, 1.0, 0.3], masses=[1.0, 0.4, 2.0, 0.7, 1.5],
                               com=[0.2, 0.9, 0.4, 0.6, 0.3], inertia=[0.01, 0.2, 0.05, 0.0, 0.1],
                               g=3.7),
}


@pytest.mark.parametrize("name", CHAINS)
def test_reference_and_numpy_rhs_match_core_accelerations(name):
    chain = CHAINS[name]
    rng = np.random.default_rng(7)
    theta, omega = rng.uniform(-3, 3, chain.n), rng.uniform(-2, 2, chain.n)
    want = np.asarray(chain.accelerations(theta, omega))
    with mpmath.workdps(30):
        rhs = reference._rhs_factory(chain.lengths, chain.masses, chain.com, chain.inertia, chain.g)
        got = np.array([float(x) for x in rhs([*theta, *omega])])
    np.testing.assert_allclose(got[:chain.n], omega, rtol=0, atol=0)
    np.testing.assert_allclose(got[chain.n:], want, rtol=1e-12, atol=1e-12)
    y = peers.numpy_rhs(chain)(0.0, np.concatenate([theta, omega]))
    np.testing.assert_allclose(y[chain.n:], want, rtol=1e-12, atol=1e-12)


def test_reference_integrator_converges_at_its_order_and_matches_dop853():
    chain = CHAINS["seed 001 rods"]
    args = (chain.lengths, chain.masses, chain.com, chain.inertia, chain.g, [2.0, 2.5], [0.0, 0.0], 0.5)
    with mpmath.workdps(reference.DPS):
        k = 3  # order 6: errors large enough to measure the order at 40 digits
        ys = [reference.integrate(*args, steps, k) for steps in (10, 20, 40)]
        e1 = max(abs(a - b) for a, b in zip(ys[0], ys[2]))
        e2 = max(abs(a - b) for a, b in zip(ys[1], ys[2]))
        order = float(mpmath.log(e1 / e2, 2))
        fine = reference.integrate(*args, 20, 10)
    assert 5.0 < order < 7.5, order
    sol = mp.simulate(chain, [2.0, 2.5], [0, 0], 0.5, rtol=1e-13, atol=1e-13, t_eval=[0.5])
    got = np.concatenate([sol.theta[-1], sol.omega[-1]])
    np.testing.assert_allclose(got, [float(x) for x in fine], rtol=0, atol=1e-10)
