"""The model beyond the seeds (damping, friction, a moving pivot, a cart) through the integrators:
convergence orders, the energy balance in both forms, the Gauss methods' Newton iteration on
stiff stages, Lyapunov spectra of damped chains against the phase-space contraction rate, the
Kapitza threshold, checkpoints and batches, and the bad input each gets. (The equations
themselves are checked against an independent symbolic derivation in test_model_derivation.py.)"""
import math

import numpy as np
import pytest

import multipendulum as mp

DAMPED = dict(lengths=[1.0, 0.8], masses=[1.0, 1.5], damping=[0.3, 0.1], friction=[0.05, 0.02], friction_velocity=0.5)
SHAKE = mp.Pivot(x=mp.Sinusoid(amplitude=0.05, frequency=7.0), y=mp.Sinusoid(amplitude=0.03, frequency=11.0, phase=0.4))


def _variants():
    return {
        "damped": (mp.Chain(**DAMPED), {}),
        "pivot": (mp.Chain.rods([1.0, 0.7], [1.0, 2.0]), {"pivot": SHAKE}),
        "cart": (mp.Chain.rods([0.6, 0.4], [0.3, 0.2], cart=mp.Cart(1.0, damping=0.2)),
                 {"cart_v0": 0.4, "cart_force": mp.Sinusoid(amplitude=1.0, frequency=3.0)}),
    }


@pytest.mark.parametrize("variant", ["damped", "pivot", "cart"])
@pytest.mark.parametrize("method", ["rk4", "dop853", "gauss4", "gauss6"])
def test_every_method_converges_at_its_order(method, variant):
    chain, kw = _variants()[variant]
    order = mp.METHOD_INFO[method]["order"]
    theta0, omega0, t_end = [0.5, -0.3], [0.0, 0.0], 1.0
    t_eval = np.linspace(0.0, t_end, 11)
    ref = mp.simulate(chain, theta0, omega0, t_end, rtol=1e-14, atol=1e-16, t_eval=t_eval, **kw)
    # Steps halving within the asymptotic range and well above round-off (dop853 with
    # adaptive=False takes steps of dt).
    dts = {"rk4": (0.01, 0.005, 0.0025), "dop853": (0.1, 0.05, 0.025), "gauss4": (0.02, 0.01, 0.005),
           "gauss6": (0.05, 0.025, 0.0125)}[method]
    errs = []
    for dt in dts:
        extra = {"adaptive": False} if method == "dop853" else {}
        s = mp.simulate(chain, theta0, omega0, t_end, method=method, dt=dt, t_eval=t_eval, **extra, **kw)
        errs.append(np.max(np.abs(s.theta - ref.theta)))
    measured = np.polyfit(np.log(dts), np.log(errs), 1)[0]
    # (Errors still shrinking faster than the order, before the asymptotic range, are allowed
    # some slack upwards; a lower order is not.)
    assert order - 0.5 < measured < order + 1.5, f"{method} on {variant}: order {measured:.2f}, errors {errs}"


@pytest.mark.parametrize("form", ["lagrangian", "hamiltonian"])
@pytest.mark.parametrize("variant", ["damped", "pivot", "cart"])
def test_the_energy_balance_closes_to_the_tolerance_in_both_forms(variant, form):
    chain, kw = _variants()[variant]
    torque = mp.Sinusoid(amplitude=[0.4, 0.0], frequency=[2.0, 1.0])
    s = mp.simulate(chain, [1.0, -0.5], [0.3, 0.0], 5.0, rtol=1e-11, atol=1e-13, form=form, torque=torque, **kw)
    w = s.work
    residual = s.energy - s.energy[0] - w.torque - w.pivot - w.cart + w.dissipated
    scale = np.max(np.abs(s.energy)) + np.max(np.abs(w.torque)) + 1.0
    assert np.max(np.abs(residual)) < 1e-8 * scale
    assert s.stats.energy_error < 1e-8
    # The work terms are there, and the dissipation never decreases.
    assert np.max(np.abs(w.torque)) > 1e-3
    if variant == "pivot":
        assert np.max(np.abs(w.pivot)) > 1e-3
    if variant in ("damped", "cart"):
        assert w.dissipated[-1] > 1e-3 and np.all(np.diff(w.dissipated) >= -1e-12)
    # A wrong term would not close it: leaving out the dissipation (or the pivot's work) fails.
    missing = residual - (w.dissipated if variant != "pivot" else -w.pivot)
    assert np.max(np.abs(missing)) > 1e-4


def test_both_forms_give_the_same_motion():
    for chain, kw in _variants().values():
        a = mp.simulate(chain, [1.0, -0.5], [0.3, 0.0], 2.0, rtol=1e-12, atol=1e-14, t_eval=[2.0], **kw)
        b = mp.simulate(chain, [1.0, -0.5], [0.3, 0.0], 2.0, rtol=1e-12, atol=1e-14, t_eval=[2.0], form="hamiltonian", **kw)
        assert np.allclose(a.theta, b.theta, atol=1e-9) and np.allclose(a.omega, b.omega, atol=1e-8)
        if chain.cart is not None:
            assert abs(a.cart_x[-1] - b.cart_x[-1]) < 1e-9 and abs(a.cart_v[-1] - b.cart_v[-1]) < 1e-8


def test_a_free_cart_conserves_horizontal_momentum_and_energy():
    chain = mp.Chain.rods([0.6, 0.4], [0.3, 0.2], cart=mp.Cart(1.0))
    s = mp.simulate(chain, [2.0, -1.0], [1.0, 0.0], 10.0, cart_v0=0.5, rtol=1e-12, atol=1e-14)
    px = chain.momenta(s.theta, s.omega, cart_v=s.cart_v)[:, 0]
    assert np.max(np.abs(px - px[0])) < 1e-10 * max(1.0, abs(px[0]))
    assert s.stats.energy_error < 1e-10
    # The cart does move (the momentum is shared with the links).
    assert np.ptp(s.cart_v) > 0.1


def test_gauss_solves_stiff_stages_by_newton_where_fixed_point_iteration_diverges():
    # h b / I = 0.01 * 500 / 1 = 5: fixed-point iteration cannot contract; Newton can.
    chain = mp.Chain([1.0], [1.0], damping=500.0)
    ref = mp.simulate(chain, [1.0], [0.0], 1.0, rtol=1e-12, atol=1e-14, t_eval=[1.0])
    for method in ("gauss4", "gauss6"):
        s = mp.simulate(chain, [1.0], [0.0], 1.0, method=method, dt=0.01)
        assert abs(s.theta[-1, 0] - ref.theta[-1, 0]) < 1e-6, method
        assert s.stats.energy_error < 1e-9
    # An ill-scaled chain (a light, short last rod: fast, stiff stages) runs too.
    light = mp.Chain.rods([1.0, 0.01], [1.0, 1e-4])
    s = mp.simulate(light, [1.0, 0.5], [0.0, 0.0], 1.0, method="gauss6", dt=0.01)
    assert s.stats.energy_error < 1e-8


def test_damped_lyapunov_spectra_sum_to_the_phase_space_contraction_rate():
    # A single pendulum: d(omega_dot)/d(omega) = -b / (m l^2), constant; the two exponents
    # sum to it exactly.
    m, l, b = 1.0, 0.8, 0.3
    single = mp.Chain([l], [m], damping=b)
    lam = mp.lyapunov(single, [0.5], [0.0], 40.0, dt=0.005, k=2).exponents
    assert abs(lam.sum() - (-b / (m * l * l))) < 1e-6
    # A double pendulum: in canonical coordinates (theta, p) phase space contracts at the rate
    # -tr(A^-1 B) (B = D^T diag(b) D, w = D omega; Liouville); the exponents are measured in
    # (theta, omega) = (theta, A^-1 p), whose volumes are those divided by det A: their sum over
    # [0, T] is the mean rate minus ln(det A(T) / det A(0)) / T.
    # (The same rk4 steps as the Lyapunov run's own trajectory: a chaotic motion's averages
    # differ from one approximation of it to another.)
    double = mp.Chain([1.0, 0.8], [1.0, 1.5], damping=[0.3, 0.1])
    t_end, dt = 40.0, 0.002
    lam = mp.lyapunov(double, [2.0, 2.5], [0.0, 0.0], t_end, dt=dt, k=4).exponents
    s = mp.simulate(double, [2.0, 2.5], [0.0, 0.0], t_end, method="rk4", dt=dt)
    D = np.array([[1.0, 0.0], [-1.0, 1.0]])
    B = D.T @ np.diag(double.damping) @ D
    rate = np.array([-np.trace(np.linalg.solve(A, B)) for A in double.mass_matrix(s.theta)])
    trapezoid = getattr(np, "trapezoid", None) or getattr(np, "trapz")
    dets = np.linalg.det(double.mass_matrix(s.theta[[0, -1]]))
    mean = float(trapezoid(rate, s.t) / t_end) - math.log(dets[1] / dets[0]) / t_end
    assert abs(lam.sum() - mean) < 1e-4 * abs(mean), (lam.sum(), mean)


@pytest.mark.parametrize("frequency, upright", [(300.0, True), (100.0, False)])
def test_kapitza_stands_upside_down_above_the_threshold_only(frequency, upright):
    # A point mass on a massless rod: I_pivot = m l^2, m c = m l, threshold a^2 W^2 > 2 g l.
    l, a, g = 0.5, 0.02, 9.81
    assert ((a * frequency) ** 2 > 2 * g * l) == upright
    chain = mp.Chain([l], [1.0], g=g)
    pivot = mp.Pivot(y=mp.Sinusoid(amplitude=a, frequency=frequency))
    s = mp.simulate(chain, [math.pi - 0.1], [0.0], 5.0, pivot=pivot, rtol=1e-10, t_eval=np.linspace(0, 5, 2001))
    off = np.abs(np.angle(np.exp(1j * (s.theta[:, 0] - math.pi))))
    if upright:
        assert off.max() < 0.3, off.max()
    else:
        assert off.max() > 1.0, off.max()
    assert s.stats.energy_error < 1e-7


def test_a_lightly_damped_pendulum_decays_at_the_linear_rate():
    m, l, b, g = 1.0, 1.0, 0.05, 9.81
    chain = mp.Chain([l], [m], damping=b, g=g)
    gamma = b / (2 * m * l * l)
    w = math.sqrt(g / l - gamma**2)
    t = np.linspace(0, 20, 4001)
    s = mp.simulate(chain, [1e-4], [0.0], 20.0, rtol=1e-12, atol=1e-16, t_eval=t)
    exact = 1e-4 * np.exp(-gamma * t) * (np.cos(w * t) + gamma / w * np.sin(w * t))
    assert np.max(np.abs(s.theta[:, 0] - exact)) < 1e-4 * 1e-4


def test_checkpoints_resume_the_general_model_bit_for_bit(tmp_path):
    for name, (chain, kw) in _variants().items():
        path = tmp_path / f"{name}.ckpt"
        full = mp.simulate(chain, [1.0, -0.5], [0.3, 0.0], 1.0, method="rk4", dt=0.01, checkpoint=path,
                           checkpoint_every=37, **kw)
        again = mp.resume(path)
        assert np.array_equal(again.theta, full.theta) and np.array_equal(again.work.net, full.work.net), name
        if chain.cart is not None:
            assert np.array_equal(again.cart_x, full.cart_x)


@pytest.mark.parametrize("variant", ["damped", "pivot", "cart"])
def test_events_land_on_their_roots_on_every_variant(variant):
    """Crossings located on the dense output of a damped, a pivot-driven and a cart run land on
    their roots, a terminal one stops the run there, and a fine fixed-step run (no events,
    crossings interpolated linearly between its samples) crosses at the same times."""
    chain, kw = _variants()[variant]
    th0, om0, t_end = [1.0, -0.5], [0.3, 0.0], 4.0
    sol = mp.simulate(chain, th0, om0, t_end, rtol=1e-12, atol=1e-14, t_eval=[t_end],
                      events=[mp.Crossing(theta=[1, 0], direction=0)], **kw)
    crossings = sol.events[0]
    assert crossings.t.size >= 4 and np.max(np.abs(crossings.theta[:, 0])) < 1e-10
    stopped = mp.simulate(chain, th0, om0, t_end, rtol=1e-12, atol=1e-14,
                          events=[mp.Crossing(omega=[0, 1], constant=-0.5, direction=1, terminal=True)], **kw)
    stop = stopped.events[0]
    assert stop.t.size == 1 and abs(stop.omega[0, 1] - 0.5) < 1e-10
    assert stopped.stopped_at == stop.t[0] == stopped.t[-1] < t_end
    fine = mp.simulate(chain, th0, om0, t_end, method="rk4", dt=1e-4, t_eval=np.arange(0, 40001) * 1e-4, **kw)
    th1 = fine.theta[:, 0]
    sign = np.flatnonzero(np.sign(th1[1:]) != np.sign(th1[:-1]))
    # Linear interpolation between the fine samples: good to ~1e-8 here.
    roots = fine.t[sign] - th1[sign] * (fine.t[sign + 1] - fine.t[sign]) / (th1[sign + 1] - th1[sign])
    np.testing.assert_allclose(crossings.t, roots, atol=1e-6)


def test_batches_equal_their_single_runs():
    for chain, kw in _variants().values():
        th = np.array([[1.0, -0.5], [0.2, 0.3], [2.0, 2.5]])
        batch = mp.simulate(chain, th, np.zeros_like(th), 1.0, method="rk4", dt=0.01, **kw)
        for i in range(3):
            one = mp.simulate(chain, th[i], np.zeros(2), 1.0, method="rk4", dt=0.01, **kw)
            assert np.array_equal(batch.theta[i], one.theta)
            assert np.array_equal(batch.work.dissipated[i], one.work.dissipated)


@pytest.mark.parametrize("kwargs, message", [
    (dict(damping=-0.1), "damping[0] must be >= 0 and finite, got -0.1"),
    (dict(damping=[0.1, float("nan")]), "damping[1] must be >= 0 and finite, got NaN"),
    (dict(friction=-1.0), "friction[0] must be >= 0 and finite, got -1"),
    (dict(friction=float("inf")), "friction[0] must be >= 0 and finite, got inf"),
    (dict(friction_velocity=0.0), "friction_velocity must be > 0 and finite, got 0"),
    (dict(friction_velocity=-1e-3), "friction_velocity must be > 0 and finite, got -0.001"),
    (dict(cart=mp.Cart(0.0)), "cart mass must be > 0 and finite, got 0"),
    (dict(cart=mp.Cart(-1.0)), "cart mass must be > 0 and finite, got -1"),
    (dict(cart=mp.Cart(float("nan"))), "cart mass must be > 0 and finite, got NaN"),
    (dict(cart=mp.Cart(1.0, damping=-2.0)), "cart damping must be >= 0 and finite, got -2"),
    (dict(damping=[0.1, 0.2, 0.3]), "damping must be a number or have 2 entries (one per joint), got shape (3,)"),
])
def test_bad_model_parameters_are_input_errors(kwargs, message):
    with pytest.raises(mp.InputError) as e:
        mp.Chain([1.0, 1.0], [1.0, 1.0], **kwargs)
    assert str(e.value) == message


def test_bad_pivots_and_cart_inputs_are_input_errors():
    chain = mp.Chain([1.0], [1.0])
    run = lambda **kw: mp.simulate(chain, [0.5], [0.0], 0.1, method="rk4", dt=0.01, **kw)  # noqa: E731
    with pytest.raises(mp.InputError, match="pivot y: a cubic table needs at least 2 samples, got 1"):
        run(pivot=mp.Pivot(y=mp.Table([0.0], [1.0], kind="cubic")))
    with pytest.raises(mp.InputError, match='a pivot Table must be kind="cubic"'):
        run(pivot=mp.Pivot(x=mp.Table([0.0, 1.0], [0.0, 1.0])))
    with pytest.raises(mp.InputError, match=r"pivot x function must return \(position, velocity, acceleration\), 3 finite numbers, got \(1.0, 2.0\)"):
        run(pivot=mp.Pivot(x=lambda t: (1.0, 2.0)))
    with pytest.raises(mp.InputError, match="3 finite numbers, got"):
        run(pivot=mp.Pivot(y=lambda t: (0.0, float("nan"), 0.0)))

    class Broken(Exception):
        pass

    def boom(t):
        raise Broken("my pivot failed")

    with pytest.raises(mp.InputError, match=r"the pivot x function raised Broken\('my pivot failed'\) at t = 0") as info:
        run(pivot=mp.Pivot(x=boom))
    assert isinstance(info.value.__cause__, Broken)  # the function's own exception, kept
    with pytest.raises(mp.InputError, match="need a chain with a cart"):
        run(cart_v0=1.0)
    with pytest.raises(mp.InputError, match="need a chain with a cart"):
        run(cart_force=1.0)
    cart = mp.Chain([1.0], [1.0], cart=mp.Cart(1.0))
    with pytest.raises(mp.InputError, match="a chain on a cart has no prescribed pivot motion"):
        mp.simulate(cart, [0.5], [0.0], 0.1, method="rk4", dt=0.01, pivot=SHAKE)
    with pytest.raises(mp.InputError, match="the cart force function must return one finite number"):
        mp.simulate(cart, [0.5], [0.0], 0.1, method="rk4", dt=0.01, cart_force=lambda t, s: float("nan"))
    with pytest.raises(mp.InputError, match="cart_x0 must be finite"):
        mp.simulate(cart, [0.5], [0.0], 0.1, method="rk4", dt=0.01, cart_x0=float("inf"))


def test_a_run_driven_to_blow_up_is_an_integration_error_with_its_time():
    chain = mp.Chain([1.0], [1.0], cart=mp.Cart(1.0))
    with pytest.raises(mp.IntegrationError) as e:
        mp.simulate(chain, [0.5], [0.0], 100.0, method="rk4", dt=0.01, cart_force=lambda t, s: 1e3 * s[2])
    assert 0 < e.value.t < 100.0


def test_symplectic_methods_say_they_are_symplectic_for_conservative_chains_only():
    for name, info in mp.METHOD_INFO.items():
        if info["symplectic"]:
            assert "conservative" in info["symplectic_when"], name
