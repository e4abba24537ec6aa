"""A batch mp.simulate in SIMD lanes (issue 14): rk4 and dop853 batches of a chain on a fixed
or shaken pivot or on a cart (damping and friction included), undriven or under a built-in
torque, without events, run eight trajectories at a time in the core. The per-trajectory route (forced with
MULTIPENDULUM_LANES=scalar) is the reference: every output agrees to round-off over short runs
(dop853, each lane with its own steps: to the tolerance)."""
import numpy as np
import pytest

import multipendulum as mp
from test_ensemble_lanes import SWITCH, on_both_routes

CASES = {
    "double, sinusoid": (mp.Chain([1.0, 1.0], [1.0, 1.0]),
                         dict(torque=mp.Sinusoid([1.5, -0.7], [3.0, 5.5], [0.1, 0.0], [0.2, 0.0]))),
    "general links": (mp.Chain([0.4] * 5, [1.0, 0.5, 2.0, 1.0, 0.1], com=[0.2] * 5, inertia=[0.01] * 5, g=3.7), {}),
    "damped with friction, joint table": (
        mp.Chain.rods([1.0, 0.5, 0.8], [1.0, 0.3, 2.0], damping=[0.0, 0.2, 0.1], friction=[0.1, 0.1, 0.0]),
        dict(joint_torque=mp.Table([0.0, 0.3, 0.9], [[0.0, 1.0, -2.0], [1.0, 0.5, 0.0], [2.0, -1.0, 0.3]], kind="cubic"))),
    "shaken pivot, damped": (
        mp.Chain([1.0, 1.0], [1.0, 1.0], damping=0.1),
        dict(pivot=mp.Pivot(x=mp.Sinusoid(0.05, 20.0, 0.3), y=mp.Table([0.0, 0.2, 0.5, 1.0], [0.0, 0.03, -0.02, 0.01], kind="cubic")),
             torque=mp.Sinusoid([0.5, 0.0], [2.0, 0.0]))),
    "damped cart, moving at the start": (
        mp.Chain.rods([1.0, 0.5, 0.8], [1.0, 0.3, 2.0], damping=0.05, cart=mp.Cart(1.0, damping=0.3)),
        dict(torque=[0.3, -0.2, 0.1], cart_x0=0.3, cart_v0=-0.2)),
}


def both_routes(monkeypatch, *args, **kwargs):
    return on_both_routes(monkeypatch, mp.simulate, *args, **kwargs)


@pytest.mark.parametrize("key", list(CASES))
@pytest.mark.parametrize("t_eval", [None, "grid", "between"])
def test_a_batch_in_lanes_agrees_with_the_per_trajectory_route(monkeypatch, key, t_eval):
    chain, inputs = CASES[key]
    rng = np.random.default_rng(chain.n)
    th0, om0 = rng.uniform(-3.0, 3.0, (19, chain.n)), rng.uniform(-2.0, 2.0, (19, chain.n))
    times = {None: None, "grid": np.linspace(0.0, 0.8, 9), "between": [0.0, 0.013, 0.0171, 0.3333, 0.75, 0.834]}[t_eval]
    fast, slow = both_routes(monkeypatch, chain, th0, om0, 0.834, method="rk4", dt=0.01, t_eval=times, **inputs)
    np.testing.assert_array_equal(fast.t, slow.t)
    for name in ("theta", "omega", "p", "energy", "energy_error", "positions"):
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), rtol=1e-12, atol=1e-12, err_msg=name)
    for part in ("torque", "pivot", "cart", "dissipated"):
        np.testing.assert_allclose(getattr(fast.work, part), getattr(slow.work, part), rtol=1e-12, atol=1e-12, err_msg=part)
    if chain.cart is not None:
        np.testing.assert_allclose(fast.cart_x, slow.cart_x, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(fast.cart_v, slow.cart_v, rtol=1e-12, atol=1e-12)
        assert np.all(fast.cart_x[:, 0] == 0.3) and np.all(fast.cart_v[:, 0] == -0.2)
    for counter in ("steps", "evaluations", "rejected"):
        np.testing.assert_array_equal(getattr(fast.stats, counter), getattr(slow.stats, counter), err_msg=counter)
    np.testing.assert_allclose(fast.pivot, slow.pivot, rtol=1e-12, atol=1e-12)  # a cart: (cart_x, 0)
    # The inputs did work (which the energy errors compared above balance).
    if inputs.keys() & {"torque", "joint_torque"}:
        assert np.abs(fast.work.torque[:, -1]).max() > 1e-2
    if "pivot" in inputs:
        assert np.abs(fast.work.pivot[:, -1]).max() > 1e-2


@pytest.mark.parametrize("key", list(CASES))
def test_a_dop853_batch_in_lanes_agrees_with_the_per_trajectory_route_to_its_tolerance(monkeypatch, key):
    """Each lane takes its own steps (the driver's first step and controller, rejected trials
    masked, a finished lane refilled): as near the exact motion as the per-trajectory run, with
    the outputs between steps from the lane's own 7th-order interpolant. Row by row, not at the
    worst row: where the inputs are not smooth (the cubic table's kinks, friction's steep tanh)
    the error a step controller leaves is a heavy-tailed function of round-off (over 21
    tolerances within 5% of 1e-10 the worst of these 70 rows ranged from 1e-8 to 1e-5 on
    either route, with equal medians), so the typical row and the tenth-worst are compared."""
    chain, inputs = CASES[key]
    rng = np.random.default_rng(chain.n)
    th0, om0 = rng.uniform(-1.2, 1.2, (70, chain.n)), rng.uniform(-0.5, 0.5, (70, chain.n))
    times = [0.0, 0.013, 0.0171, 0.3333, 0.75, 2.0]
    fast, slow = both_routes(monkeypatch, chain, th0, om0, 2.0, t_eval=times, **inputs)
    exact = mp.simulate(chain, th0, om0, 2.0, t_eval=times, rtol=1e-13, atol=1e-15, **inputs)
    np.testing.assert_array_equal(fast.t, slow.t)
    for name in ("theta", "omega", "energy"):
        a, b, e = getattr(fast, name), getattr(slow, name), getattr(exact, name)
        rows = tuple(range(1, a.ndim))
        ra, rb = np.abs(a - e).max(axis=rows), np.abs(b - e).max(axis=rows)
        assert np.median(ra) <= 3 * np.median(rb) + 1e-12, name
        assert np.quantile(ra, 0.9) <= 10 * np.quantile(rb, 0.9) + 1e-10, name
    np.testing.assert_allclose(fast.energy_error, slow.energy_error, rtol=0, atol=1e-9)
    assert np.abs(fast.stats.steps - slow.stats.steps).max() <= 1 + slow.stats.steps.max() // 20


def test_a_trajectory_of_a_batch_in_lanes_keeps_its_bits_whatever_its_neighbours(monkeypatch):
    """A row's bits depend neither on its neighbours nor on the threads: run with other
    neighbours (a batch of two, in lanes, six lanes idle) it gives the bits it gave in the batch."""
    monkeypatch.setenv(SWITCH, "auto")
    chain, inputs = CASES["damped with friction, joint table"]
    rng = np.random.default_rng(5)
    th0, om0 = rng.uniform(-3.0, 3.0, (21, 3)), rng.uniform(-2.0, 2.0, (21, 3))
    batch = mp.simulate(chain, th0, om0, 1.0, method="rk4", dt=0.01, t_eval=[0.05, 0.5, 1.0], **inputs)
    alone = mp.simulate(chain, th0[[13, 2]], om0[[13, 2]], 1.0, method="rk4", dt=0.01, t_eval=[0.05, 0.5, 1.0], **inputs)
    np.testing.assert_array_equal(alone.theta[0], batch.theta[13])
    np.testing.assert_array_equal(alone.energy[0], batch.energy[13])


def test_bad_rows_and_blow_ups_are_named_alike_on_both_routes(monkeypatch):
    chain = mp.Chain([1.0, 1.0], [1.0, 1.0])
    om0 = np.zeros((12, 2))
    om0[9, 0] = 1e200
    th0 = np.full((12, 2), 0.1)
    messages = []
    for route in ("auto", "scalar"):
        monkeypatch.setenv(SWITCH, route)
        with pytest.raises(mp.IntegrationError) as e:
            mp.simulate(chain, th0, om0, 1.0, method="rk4", dt=0.01)
        messages.append(str(e.value))
    assert messages[0] == messages[1]
    assert messages[0].startswith("integration failed at t = 0.01: trajectory 9: the state became non-finite")
