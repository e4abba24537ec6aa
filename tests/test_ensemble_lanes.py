"""mp.ensemble in SIMD lanes (issue 14): chains (damping, friction and a cart included), undriven
or driven by built-in torques, run by rk4 or dop853 go through the core's lanes; the per-trajectory route (a batch simulate with
a non-terminal Flip event, forced with MULTIPENDULUM_LANES=scalar) is the reference they must
agree with: rk4 to round-off, dop853 (each lane with its own steps) to its tolerance."""
import numpy as np
import pytest

import multipendulum as mp

SWITCH = "MULTIPENDULUM_LANES"
CHAINS = {
    2: mp.Chain([1.0, 1.0], [1.0, 1.0]),
    3: mp.Chain.rods([1.0, 0.5, 0.8], [1.0, 0.3, 2.0]),
    5: mp.Chain([0.4] * 5, [1.0, 0.5, 2.0, 1.0, 0.1], com=[0.2] * 5, inertia=[0.01] * 5, g=3.7),
    # Losses: the energy error is then the balance with the dissipated energy.
    "2, damped with friction": mp.Chain([1.0, 1.0], [1.0, 1.0], damping=[0.1, 0.3], friction=[0.2, 0.0],
                                        friction_velocity=0.05),
    "3, damped": mp.Chain.rods([1.0, 0.5, 0.8], [1.0, 0.3, 2.0], damping=0.2),
    # On a cart (at rest at the start): momenta and energy with the cart's motion.
    "2 on a free cart": mp.Chain([1.0, 1.0], [1.0, 1.0], cart=mp.Cart(2.0)),
    "3 on a damped cart": mp.Chain.rods([1.0, 0.5, 0.8], [1.0, 0.3, 2.0], damping=0.05, cart=mp.Cart(1.0, damping=0.3)),
}


def on_both_routes(monkeypatch, run, *args, **kwargs):
    """``run(*args, **kwargs)`` in the lanes and on the per-trajectory route: (fast, slow)."""
    monkeypatch.setenv(SWITCH, "auto")
    fast = run(*args, **kwargs)
    monkeypatch.setenv(SWITCH, "scalar")
    slow = run(*args, **kwargs)
    return fast, slow


def both_routes(monkeypatch, *args, **kwargs):
    return on_both_routes(monkeypatch, mp.ensemble, *args, **kwargs)


@pytest.mark.parametrize("key", list(CHAINS))
def test_lanes_agree_with_the_per_trajectory_route(monkeypatch, key):
    chain = CHAINS[key]
    n = chain.n
    rng = np.random.default_rng(n)
    th0 = rng.uniform(-3.0, 3.0, (45, n))  # many start near the top: flips within the run
    om0 = rng.uniform(-2, 2, (45, n))
    fast, slow = both_routes(monkeypatch, chain, th0, om0, 0.834, method="rk4", dt=0.01)
    # Round-off only (the lanes' sin/cos, fused operations, the triple pendulum's closed form),
    # grown a little by chaos.
    for name in ("theta", "omega"):
        a, b = getattr(fast, name), getattr(slow, name)
        assert np.all(np.abs(a - b) <= 1e-12 * (1 + np.abs(b))), name
    # The momenta sum terms A_ab omega_b that may cancel (a fast trajectory's p of 0.5 from
    # terms near 50): their round-off is relative to the terms' size.
    a = np.abs(chain.mass_matrix(slow.theta))[..., -n:, -n:]
    terms = np.einsum("bij,bj->bi", a, np.abs(slow.omega))
    assert np.all(np.abs(fast.p - slow.p) <= 1e-12 * (1 + np.abs(slow.p) + terms)), "p"
    np.testing.assert_array_equal(fast.steps, slow.steps)
    assert fast.steps[0] == 84  # the last step shortened to land on t_end
    np.testing.assert_allclose(fast.energy_error, slow.energy_error, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.isfinite(fast.first_flip), np.isfinite(slow.first_flip))
    flipped = np.isfinite(slow.first_flip)
    assert flipped.sum() > 3
    np.testing.assert_allclose(fast.first_flip[flipped], slow.first_flip[flipped], rtol=0, atol=1e-12)


def test_the_energy_error_shrinks_at_rk4s_order():
    # Low energy: regular motion, where the balance residual is rk4's error (order 4 per unit time).
    th0 = np.random.default_rng(1).uniform(-0.6, 0.6, (64, 3))
    errors = {dt: mp.ensemble(CHAINS[3], th0, np.zeros_like(th0), 5.0, method="rk4", dt=dt).energy_error
              for dt in (0.02, 0.01)}
    ratio = np.median(errors[0.02] / errors[0.01])
    assert ratio > 2**3.8, ratio  # order 4 at least: halving dt divides the residual by 16 or more


def test_a_row_has_the_same_bits_alone_and_in_any_batch():
    th0 = np.random.default_rng(2).uniform(-2.5, 2.5, (37, 3))
    om0 = np.zeros_like(th0)
    batch = mp.ensemble(CHAINS[3], th0, om0, 3.0, method="rk4", dt=0.01)
    for i in (0, 8, 36):
        one = mp.ensemble(CHAINS[3], th0[i:i + 1], om0[i:i + 1], 3.0, method="rk4", dt=0.01)
        np.testing.assert_array_equal(one.theta[0], batch.theta[i])
        assert one.first_flip[0] == batch.first_flip[i] or np.isinf(batch.first_flip[i])


@pytest.mark.parametrize("key", [2, 3, "2, damped with friction", "3 on a damped cart"])
def test_dop853_lanes_agree_with_the_per_trajectory_route_to_its_tolerance(monkeypatch, key):
    chain = CHAINS[key]
    n = chain.n
    rng = np.random.default_rng(n + 10)
    th0 = rng.uniform(-3.0, 3.0, (30, n))
    om0 = rng.uniform(-2, 2, (30, n))
    fast, slow = both_routes(monkeypatch, chain, th0, om0, 0.834)
    # The steps' sizes drift apart by round-off that the controller amplifies (its error
    # estimate cancels to round-off): agreement to the tolerance's scale, not to round-off.
    for name in ("theta", "omega", "p"):
        a, b = getattr(fast, name), getattr(slow, name)
        assert np.all(np.abs(a - b) <= 1e-8 * (1 + np.abs(b))), (name, np.max(np.abs(a - b)))
    assert np.all(np.abs(fast.steps - slow.steps) <= max(1, 0.05 * slow.steps.max())), (fast.steps, slow.steps)
    assert abs(int(fast.steps.sum()) - int(slow.steps.sum())) <= 0.02 * slow.steps.sum()
    np.testing.assert_allclose(fast.energy_error, slow.energy_error, rtol=0, atol=1e-10)
    assert fast.energy_error.max() < 1e-8
    np.testing.assert_array_equal(np.isfinite(fast.first_flip), np.isfinite(slow.first_flip))
    flipped = np.isfinite(slow.first_flip)
    assert flipped.sum() > 3
    np.testing.assert_allclose(fast.first_flip[flipped], slow.first_flip[flipped], rtol=0, atol=1e-8)


def test_dop853_lanes_meet_the_tolerance_they_are_given():
    # Regular motion against a run 1000 times tighter: the global error follows the tolerance.
    chain = CHAINS[3]
    th0 = np.random.default_rng(4).uniform(-0.8, 0.8, (24, 3))
    om0 = np.zeros_like(th0)
    exact = mp.ensemble(chain, th0, om0, 5.0, rtol=1e-13, atol=1e-15)
    errors = {rtol: np.max(np.abs(mp.ensemble(chain, th0, om0, 5.0, rtol=rtol, atol=rtol * 1e-2).theta - exact.theta))
              for rtol in (1e-6, 1e-9)}
    assert errors[1e-9] < 1e-7 and errors[1e-6] < 1e-4, errors
    assert errors[1e-6] / errors[1e-9] > 30, errors  # tighter tolerance, smaller error


@pytest.mark.parametrize("key, kwargs", [
    (2, dict(method="rk4", dt=0.01, torque=mp.Sinusoid([1.5, -0.7], [3.0, 5.5]))),
    ("3 on a damped cart", dict(method="rk4", dt=0.01, joint_torque=mp.Table([0.0, 0.3, 0.9], [[0, 1, -2], [1, .5, 0], [2, -1, .3]],
                                                                                 kind="cubic"))),
    ("2, damped with friction", dict(torque=[0.3, -0.2])),
    (3, dict(joint_torque=mp.Sinusoid([2.0, 0.0, 1.0], [4.0, 1.0, 2.0]))),
])
def test_driven_lanes_agree_with_the_per_trajectory_route(monkeypatch, key, kwargs):
    chain = CHAINS[key]
    n = chain.n
    rng = np.random.default_rng(n + 20)
    th0 = rng.uniform(-3.0, 3.0, (30, n))
    om0 = rng.uniform(-2, 2, (30, n))
    fast, slow = both_routes(monkeypatch, chain, th0, om0, 0.834, **kwargs)
    # rk4: round-off grown by chaos (the drive pumps energy in); dop853: its tolerance.
    tol = 1e-11 if kwargs.get("method") == "rk4" else 1e-8
    for name in ("theta", "omega", "p"):
        a, b = getattr(fast, name), getattr(slow, name)
        assert np.all(np.abs(a - b) <= tol * (1 + np.abs(b))), (name, np.max(np.abs(a - b)))
    # The energy error is the balance with the torque's work, on both routes.
    np.testing.assert_allclose(fast.energy_error, slow.energy_error, rtol=0, atol=1e-10)
    if kwargs.get("method") != "rk4":
        assert fast.energy_error.max() < 1e-8
    np.testing.assert_array_equal(np.isfinite(fast.first_flip), np.isfinite(slow.first_flip))


@pytest.mark.parametrize("kwargs", [
    dict(method="gauss4", dt=0.01),                                  # another method
    dict(method="rk4", dt=0.01, torque=lambda t: [0.3 * np.sin(t), 0.0]),  # a Python function
])
def test_what_the_lanes_do_not_cover_takes_the_per_trajectory_route(monkeypatch, kwargs):
    th0 = np.random.default_rng(3).uniform(-1, 1, (6, 2))
    fast, slow = both_routes(monkeypatch, CHAINS[2], th0, np.zeros_like(th0), 2.0, **kwargs)
    for name in ("theta", "omega", "energy_error", "first_flip"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name))




def test_a_damped_ensembles_energy_balance_closes_at_rk4s_order():
    # The lanes integrate the dissipated energy with the state: the residual of E(t) - E(0) + D
    # is rk4's error, order 4, while the energy itself falls by far more.
    chain = CHAINS["3, damped"]
    th0 = np.random.default_rng(5).uniform(-0.6, 0.6, (64, 3))
    runs = {dt: mp.ensemble(chain, th0, np.zeros_like(th0), 5.0, method="rk4", dt=dt) for dt in (0.01, 0.005)}
    ratio = np.median(runs[0.01].energy_error / runs[0.005].energy_error)
    assert ratio > 2**3.5, ratio  # about 14 (order 4, not yet asymptotic); an order-3 residual would give 8
    lost = chain.energy(th0, np.zeros_like(th0)) - chain.energy(runs[0.005].theta, runs[0.005].omega)
    assert lost.min() > 1e3 * runs[0.005].energy_error.max()  # (a relative error: lost is in J)


@pytest.mark.parametrize("kwargs, message", [
    (dict(dt=-0.01), "dt must be > 0 and finite, got -0.01"),
    (dict(dt=0.01, t_end=-1.0), "t_end must be > 0 and finite, got -1"),
    (dict(dt=None), "method rk4 takes a fixed step: give dt"),
    (dict(dt=1e-12, t_end=1e6), "max_steps"),
    (dict(method="dop853", rtol=1e-17), "rtol"),
    (dict(method="dop853", atol=-1.0), "atol"),
    (dict(method="dop853", dt=-0.5), "dt must be > 0 and finite, got -0.5"),
])
def test_bad_input_gives_the_same_error_on_both_routes(monkeypatch, kwargs, message):
    kwargs = {"t_end": 1.0, "method": "rk4", **kwargs}
    th0 = np.full((3, 2), 0.1)
    errors = []
    for route in ("auto", "scalar"):
        monkeypatch.setenv(SWITCH, route)
        with pytest.raises(mp.InputError) as e:
            mp.ensemble(CHAINS[2], th0, np.zeros_like(th0), **kwargs)
        assert message in str(e.value), (route, str(e.value))
        errors.append(str(e.value))
    assert errors[0] == errors[1]


def test_a_blow_up_names_its_trajectory_on_both_routes(monkeypatch):
    th0 = np.full((3, 2), 0.1)
    om0 = np.zeros((3, 2))
    om0[2, 0] = 1e200
    for route in ("auto", "scalar"):
        monkeypatch.setenv(SWITCH, route)
        for kwargs in (dict(method="rk4", dt=0.01), dict(method="dop853", dt=0.01, rtol=1e-6)):
            with pytest.raises(mp.IntegrationError) as e:
                mp.ensemble(CHAINS[2], th0, om0, 1.0, **kwargs)
            assert "trajectory 2:" in str(e.value), (route, kwargs, str(e.value))
            if kwargs["method"] == "rk4":  # a blow-up, as the scalar route names it, on both routes
                assert "the state became non-finite" in str(e.value), (route, str(e.value))



SHAKEN = mp.Pivot(x=mp.Sinusoid(0.05, 20.0, 0.3), y=mp.Table([0.0, 0.2, 0.5, 1.0], [0.0, 0.03, -0.02, 0.01], kind="cubic"))


@pytest.mark.parametrize("key", [2, 5, "2, damped with friction"])
def test_lanes_on_a_moving_pivot_agree_with_the_per_trajectory_route(monkeypatch, key):
    """The pivot's forces ride in the lanes, and its work in the energy balance, as the
    per-trajectory route's: rk4 to round-off, dop853 to its tolerance."""
    chain = CHAINS[key]
    rng = np.random.default_rng(7)
    th0, om0 = rng.uniform(-3.0, 3.0, (21, chain.n)), rng.uniform(-2, 2, (21, chain.n))
    fast, slow = both_routes(monkeypatch, chain, th0, om0, 0.834, pivot=SHAKEN, method="rk4", dt=0.01)
    for name in ("theta", "omega", "p"):  # rk4: round-off
        a, b = getattr(fast, name), getattr(slow, name)
        assert np.all(np.abs(a - b) <= 1e-12 * (1 + np.abs(b))), name
    np.testing.assert_allclose(fast.energy_error, slow.energy_error, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(np.isfinite(fast.first_flip), np.isfinite(slow.first_flip))
    # dop853, each route with its own steps: as near the exact motion as the other where the
    # motion is regular (released at low energy; in this violent chaos either route's error
    # swings tenfold with its steps), and at a tight tolerance on the violent rows too.
    gentle = 0.4 * th0
    monkeypatch.setenv(SWITCH, "scalar")
    exact = mp.ensemble(chain, gentle, np.zeros_like(gentle), 0.834, pivot=SHAKEN, rtol=1e-13, atol=1e-15)
    fast, slow = both_routes(monkeypatch, chain, gentle, np.zeros_like(gentle), 0.834, pivot=SHAKEN)
    for name in ("theta", "omega", "p"):
        a, b, e = getattr(fast, name), getattr(slow, name), getattr(exact, name)
        assert np.abs(a - e).max() <= 10 * np.abs(b - e).max() + 1e-10, name
    np.testing.assert_allclose(fast.energy_error, slow.energy_error, rtol=0, atol=1e-10)
    monkeypatch.setenv(SWITCH, "scalar")
    exact = mp.ensemble(chain, th0, om0, 0.834, pivot=SHAKEN, rtol=1e-13, atol=1e-15)
    monkeypatch.setenv(SWITCH, "auto")
    tight = mp.ensemble(chain, th0, om0, 0.834, pivot=SHAKEN, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(tight.theta, exact.theta, rtol=0, atol=1e-9)
    # The pivot's work is in the balance: without it the error would be the work itself, joules.
    sol = mp.simulate(chain, th0, om0, 0.834, pivot=SHAKEN, t_eval=[0.834])
    assert np.abs(sol.work.pivot[:, -1]).max() > 0.1
    assert fast.energy_error.max() < 1e-8


def test_a_pivot_function_takes_the_per_trajectory_route_and_a_pivot_on_a_cart_is_refused(monkeypatch):
    chain = CHAINS[2]
    th0 = np.random.default_rng(3).uniform(-2, 2, (9, 2))
    # x = 0.05 sin(20 t + 0.3), as a function: the same motion as SHAKEN's x axis.
    function = mp.Pivot(x=lambda t: (0.05 * np.sin(20 * t + 0.3), np.cos(20 * t + 0.3), -20 * np.sin(20 * t + 0.3)))
    by_function = mp.ensemble(chain, th0, np.zeros_like(th0), 0.5, method="rk4", dt=0.01, pivot=function)
    built_in = mp.ensemble(chain, th0, np.zeros_like(th0), 0.5, method="rk4", dt=0.01, pivot=mp.Pivot(x=mp.Sinusoid(0.05, 20.0, 0.3)))
    np.testing.assert_allclose(by_function.theta, built_in.theta, rtol=0, atol=1e-12)
    with pytest.raises(mp.InputError, match="a chain on a cart has no prescribed pivot motion"):
        mp.ensemble(CHAINS["2 on a free cart"], th0, np.zeros_like(th0), 0.5, method="rk4", dt=0.01, pivot=SHAKEN)
