"""The model beyond the seeds (damping, friction, a moving pivot, a cart) through the integrators:
convergence orders, the energy balance in both forms, the Gauss methods' Newton iteration on
stiff stages, Lyapunov spectra of damped chains against the phase-space contraction rate, the
Kapitza threshold, checkpoints and batches, and the bad input each gets. (The equations
themselves are checked against an independent symbolic derivation in test_model_derivation.py.)"""
import importlib.util
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


def _contraction_rate(chain, sol, B):
    """The mean phase-space contraction rate that a Lyapunov spectrum in Lagrangian coordinates
    sums to over [0, T]: in canonical coordinates (q, p) volumes contract at -tr(M^-1 B)
    (Liouville; B the viscous damping matrix, M the mass matrix, both of q = (x, theta) on a
    cart); the exponents are measured in (q, q_dot) = (q, M^-1 p), whose volumes are those
    divided by det M, so the sum is the mean rate minus ln(det M(T) / det M(0)) / T. A moving
    pivot's force depends on time only and keeps volumes. (A chaotic motion's averages differ
    from one approximation of it to another: the run takes the Lyapunov run's rk4 steps, and
    the span keeps lambda T below ~15, so that the last-bit differences of their steps stay
    far below the tolerance.)"""
    M = chain.mass_matrix(sol.theta)
    rate = np.array([-np.trace(np.linalg.solve(a, B)) for a in M])
    trapezoid = getattr(np, "trapezoid", None) or getattr(np, "trapz")
    dets = np.linalg.det(M[[0, -1]])
    t_end = sol.t[-1]
    return float(trapezoid(rate, sol.t) / t_end) - math.log(dets[1] / dets[0]) / t_end


def _joint_damping(b):
    """B = D^T diag(b) D, with w = D omega the joints' relative rates."""
    D = np.eye(len(b)) - np.eye(len(b), k=-1)
    return D.T @ np.diag(b) @ D


def test_damped_lyapunov_spectra_sum_to_the_phase_space_contraction_rate():
    # A single pendulum: d(omega_dot)/d(omega) = -b / (m l^2), constant; the two exponents
    # sum to it exactly.
    m, l, b = 1.0, 0.8, 0.3
    single = mp.Chain([l], [m], damping=b)
    lam = mp.lyapunov(single, [0.5], [0.0], 40.0, dt=0.005, k=2).exponents
    assert abs(lam.sum() - (-b / (m * l * l))) < 1e-6
    double = mp.Chain([1.0, 0.8], [1.0, 1.5], damping=[0.3, 0.1])
    t_end, dt = 40.0, 0.002
    lam = mp.lyapunov(double, [2.0, 2.5], [0.0, 0.0], t_end, dt=dt, k=4).exponents
    s = mp.simulate(double, [2.0, 2.5], [0.0, 0.0], t_end, method="rk4", dt=dt)
    mean = _contraction_rate(double, s, _joint_damping(double.damping))
    assert abs(lam.sum() - mean) < 1e-4 * abs(mean), (lam.sum(), mean)


def _driven(variant, t0=0.0):
    """A chaotic double pendulum on a shaken pivot, or on a damped cart pushed by a sinusoidal
    force, with its drive started at time t0 (a sinusoid's phase moved on: a run restarted at
    t0 sees the drive the first run saw then)."""
    if variant == "pivot":
        chain = mp.Chain.rods([1.0, 0.7], [1.0, 2.0], damping=[0.05, 0.02])
        return chain, {"pivot": mp.Pivot(x=mp.Sinusoid(amplitude=0.05, frequency=7.0, phase=7.0 * t0),
                                         y=mp.Sinusoid(amplitude=0.03, frequency=11.0, phase=0.4 + 11.0 * t0))}
    chain = mp.Chain([1.0, 0.8], [1.0, 1.5], damping=[0.3, 0.1], cart=mp.Cart(2.0, damping=0.5))
    return chain, {"cart_force": mp.Sinusoid(amplitude=1.0, frequency=3.0, phase=3.0 * t0)}


@pytest.mark.parametrize("variant", ["pivot", "cart"])
def test_driven_lyapunov_spectra_sum_to_the_contraction_rate(variant):
    chain, drive = _driven(variant)
    start = dict(cart_v0=0.4) if variant == "cart" else {}
    t_end, dt = 15.0, 0.002
    lam = mp.lyapunov(chain, [2.0, 2.5], [0.0, 0.0], t_end, dt=dt, **drive, **start).exponents
    assert lam.size == (6 if variant == "cart" else 4)  # (theta, omega), and the cart's (x, v)
    s = mp.simulate(chain, [2.0, 2.5], [0.0, 0.0], t_end, method="rk4", dt=dt, **drive, **start)
    B = _joint_damping(chain.damping)
    if variant == "cart":
        B = np.block([[np.full((1, 1), chain.cart.damping), np.zeros((1, 2))], [np.zeros((2, 1)), B]])
    mean = _contraction_rate(chain, s, B)
    assert abs(lam.sum() - mean) < 1e-4 * abs(mean), (lam.sum(), mean)
    if variant == "cart":  # the cart's damping is in the sum: without it the rate would differ
        assert abs(mean - _contraction_rate(chain, s, np.pad(B[1:, 1:], ((1, 0), (1, 0))))) > 0.05


@pytest.mark.parametrize("variant", ["pivot", "cart"])
def test_the_largest_driven_exponent_is_the_divergence_rate_of_two_nearby_runs(variant):
    # Benettin's two-trajectory estimate, independent of the tangent equations: a copy started
    # d0 away, each interval's separation's growth logged and the copy pulled back to d0 along
    # it, both runs by mp.simulate's rk4 on the same steps (restarted at each interval, the
    # drive's phase moved on). The tangent vector follows the derivative of the same rk4 map.
    t_end, dt, every, d0 = 20.0, 0.005, 20, 1e-8
    chain, drive = _driven(variant)
    cart = variant == "cart"
    lam = mp.lyapunov(chain, [2.0, 2.5], [0.0, 0.0], t_end, dt=dt, k=1, renorm_every=every, **drive).largest
    tau = every * dt
    m = 2 * chain.n + 2 * cart

    def advance(state, t0):
        _, drive_now = _driven(variant, t0)
        base = dict(cart_x0=state[4], cart_v0=state[5]) if cart else {}
        s = mp.simulate(chain, state[:2], state[2:4], tau, method="rk4", dt=dt, t_eval=[tau], **drive_now, **base)
        out = np.concatenate([s.theta[-1], s.omega[-1]])
        return np.concatenate([out, [s.cart_x[-1], s.cart_v[-1]]]) if cart else out

    # (theta, omega, x, v): the Lyapunov run's first tangent vector is the unit vector along theta_1.
    a = np.array([2.0, 2.5, 0.0, 0.0] + [0.0] * (m - 4))
    b = a + d0 * np.eye(m)[0]
    logs = 0.0
    for i in range(round(t_end / tau)):
        a, b = advance(a, i * tau), advance(b, i * tau)
        d = np.linalg.norm(b - a)
        logs += math.log(d / d0)
        b = a + (b - a) * (d0 / d)
    assert abs(lam - logs / t_end) < 1e-3 * abs(lam), (lam, logs / t_end)
    assert lam > 0.1  # chaotic: the test compares a growth, not two zeros


def test_driven_runs_say_how_long_they_are_trustworthy():
    # The estimate's Lyapunov run takes the run's own drive, at a twentieth of the fastest time
    # scale: the chain's linearisation's, or a fast pivot's (200 rad/s: steps of 0.05 / 200 s).
    kapitza = mp.Pivot(y=mp.Sinusoid(amplitude=0.02, frequency=200.0))
    cart, push = _driven("cart")
    # (On the cart from its own initial state, which the outputs need not hold: t_eval from 1 s.)
    push = dict(push, cart_x0=0.3, cart_v0=-0.7)
    for chain, drive in [(mp.Chain([1.0, 0.7], [1.0, 2.0]), {"pivot": kapitza}), (cart, push)]:
        sol = mp.simulate(chain, [2.0, 2.5], [0.0, 0.0], 5.0, t_eval=np.linspace(1.0, 5.0, 5), **drive)
        until, why = sol.trustworthy(horizon=5.0)
        rho = max(np.max(np.abs(np.linalg.eigvals(chain.jacobian([2.0, 2.5], [0.0, 0.0])))), 200.0 if "pivot" in drive else 0.0)
        lam = mp.lyapunov(chain, [2.0, 2.5], [0.0, 0.0], 5.0, dt=min(0.005, 0.05 / rho), k=1, **drive).largest
        assert why == f"largest Lyapunov exponent {lam:.3g}/s", why
        assert until == pytest.approx(mp.trustworthy_until(lam if lam > 0.05 else 0.0, eps=1e-10))
    pushed = mp.simulate(cart, [2.0, 2.5], [0.0, 0.0], 1.0, cart_force=lambda t, s: -s[0])
    assert pushed.trustworthy() == (None, "not estimated under a cart force given as a Python function")


def test_lyapunov_refuses_what_it_cannot_differentiate_and_bad_base_inputs():
    cart = mp.Chain([1.0, 0.8], [1.0, 1.5], cart=mp.Cart(2.0))
    run = lambda chain, **kw: mp.lyapunov(chain, [0.5, 0.2], [0.0, 0.0], 1.0, dt=0.01, **kw)  # noqa: E731
    with pytest.raises(mp.InputError, match=r"Lyapunov exponents take a cart force of time alone \(a number, Sinusoid or Table\), not a function of the state"):
        run(cart, cart_force=lambda t, s: -s[0])
    with pytest.raises(mp.InputError, match=r"k must be between 1 and 2N \+ 2 = 6 \(the angles, their rates and the cart's\), got 7"):
        run(cart, k=7)
    with pytest.raises(mp.InputError, match="a chain on a cart has no prescribed pivot motion"):
        run(cart, pivot=SHAKE)
    fixed = mp.Chain([1.0, 0.8], [1.0, 1.5])
    with pytest.raises(mp.InputError, match="need a chain with a cart"):
        run(fixed, cart_v0=1.0)
    with pytest.raises(mp.InputError, match="need a chain with a cart"):
        run(fixed, cart_force=1.0)
    with pytest.raises(mp.InputError, match="cart_x0 must be finite"):
        run(cart, cart_x0=float("nan"))
    with pytest.raises(mp.InputError, match="pivot must be a multipendulum.Pivot, got float"):
        run(fixed, pivot=0.5)

    def boom(t):
        raise ZeroDivisionError("my pivot failed")

    # A pivot function's own exception, as simulate reports it.
    with pytest.raises(mp.InputError, match=r"the pivot y function raised ZeroDivisionError\('my pivot failed'\) at t = 0") as info:
        run(fixed, pivot=mp.Pivot(y=boom))
    assert isinstance(info.value.__cause__, ZeroDivisionError)
    # A pivot function of time is differentiable along the state (it does not depend on it).
    kapitza = lambda t: (0.02 * math.sin(200 * t), 4.0 * math.cos(200 * t), -800.0 * math.sin(200 * t))  # noqa: E731
    a = mp.lyapunov(fixed, [0.5, 0.2], [0.0, 0.0], 1.0, dt=0.001, pivot=mp.Pivot(y=kapitza)).exponents
    b = mp.lyapunov(fixed, [0.5, 0.2], [0.0, 0.0], 1.0, dt=0.001, pivot=mp.Pivot(y=mp.Sinusoid(amplitude=0.02, frequency=200.0))).exponents
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("a", [3.0, -2.0])
def test_flip_times_on_an_accelerating_pivot_converge_to_the_closed_form(a):
    # A point mass on a pivot accelerating at a along x feels the gravity (-a, -g): from
    # (1/2) m l^2 w^2 + m l (a sin th - g cos th) = const, the time to reach pi is the integral of
    # d(th) / w(th), by quadrature. The pivot is a function of time (the Python route).
    scipy_integrate = pytest.importorskip("scipy.integrate")
    l, g, th0, w0 = 0.8, 9.81, 0.3, 8.0
    potential = lambda th: (a * math.sin(th) - g * math.cos(th)) / l  # noqa: E731
    rate = lambda th: math.sqrt(w0 * w0 + 2.0 * (potential(th0) - potential(th)))  # noqa: E731
    assert min(rate(th) for th in np.linspace(th0, math.pi, 1001)) > 0.5  # it goes over, never turning
    exact = scipy_integrate.quad(lambda th: 1.0 / rate(th), th0, math.pi, epsabs=1e-14, epsrel=1e-13)[0]
    pivot = mp.Pivot(x=lambda t: (0.5 * a * t * t, a * t, a))
    chain = mp.Chain([l], [1.0], g=g)
    err = [abs(float(mp.flip_times(chain, [th0], [w0], t_max=5.0, dt=dt, pivot=pivot)) - exact) for dt in (0.02, 0.01)]
    assert err[1] < 1e-7 and err[0] / err[1] > 8.0, (err, exact)  # rk4 and the cubic interpolant: order 4
    # The pivot is what moves it: on a fixed pivot the same start takes another time.
    assert abs(float(mp.flip_times(chain, [th0], [w0], t_max=5.0, dt=0.01)) - exact) > 1e-2


def test_flip_maps_of_a_shaken_chain_have_no_energy_bound_and_follow_single_runs():
    chain = mp.Chain.rods([1.0, 0.7], [1.0, 2.0])
    x = np.linspace(-3.0, 3.0, 9)
    fm = mp.flip_map(chain, x, x, t_max=4.0, dt=0.01, pivot=SHAKE)
    # A shaken pivot pumps energy in: no cell is marked impossible.
    assert fm.threshold == -np.inf and fm.allowed.all()
    # Each cell is its state's flip in a single run (simulate's rk4 on the same steps and its Flip
    # event, to the step's round-off), and the map differs from the fixed pivot's.
    th = np.stack(np.meshgrid(x, x), axis=-1)
    for i, j in [(0, 3), (2, 5), (4, 1), (6, 6), (8, 2)]:
        s = mp.simulate(chain, th[i, j], [0.0, 0.0], 4.0, method="rk4", dt=0.01, pivot=SHAKE, events=[mp.Flip()])
        flip = s.events[0].t[0] if s.events[0].t.size else np.inf
        assert fm.times[i, j] == pytest.approx(flip, abs=1e-9), (i, j)
    fixed = mp.flip_map(chain, x, x, t_max=4.0, dt=0.01)
    assert np.isfinite(fixed.threshold) and (fm.times != fixed.times).any()
    # A pivot held away from the origin moves nothing: the fixed pivot's map and bound, bit for bit.
    held = mp.flip_map(chain, x, x, t_max=4.0, dt=0.01, pivot=mp.Pivot(x=0.3, y=-0.2))
    np.testing.assert_array_equal(held.times, fixed.times)
    assert held.threshold == fixed.threshold
    # Certified and swept maps take the pivot too.
    certified = mp.flip_map(chain, x, x, t_max=4.0, dt=0.01, pivot=SHAKE, certify=True)
    np.testing.assert_array_equal(certified.times, fm.times)
    vary3 = ("theta", 0, "theta", 1, "omega", 0)
    volume = mp.flip_volume(chain, x, x, [0.0, 0.5], t_max=4.0, dt=0.01, vary=vary3, pivot=SHAKE)
    np.testing.assert_array_equal(volume.slice(0).times, fm.times)
    assert volume.threshold == -np.inf
    if importlib.util.find_spec("dask") is not None:
        np.testing.assert_array_equal(mp.sweep_flip_map(chain, x, x, t_max=4.0, dt=0.01, pivot=SHAKE, chunks=4).times, fm.times)
        np.testing.assert_array_equal(mp.sweep(chain, th, t_max=4.0, dt=0.01, pivot=SHAKE, chunks=3), fm.times)
        swept = mp.sweep_flip_volume(chain, x, x, [0.0, 0.5], t_max=4.0, dt=0.01, vary=vary3, pivot=SHAKE, chunks=1)
        np.testing.assert_array_equal(swept.times, volume.times)


def test_flip_times_refuse_a_bad_pivot_and_keep_its_functions_exception():
    chain = mp.Chain([1.0, 0.8], [1.0, 1.5])
    with pytest.raises(mp.InputError, match="pivot must be a multipendulum.Pivot, got str"):
        mp.flip_times(chain, [[0.5, 0.2]], t_max=1.0, pivot="shaken")
    with pytest.raises(mp.InputError, match="a chain on a cart has no prescribed pivot motion"):
        mp.flip_times(mp.Chain([1.0], [1.0], cart=mp.Cart(1.0)), [[0.5]], t_max=1.0, pivot=SHAKE)

    def boom(t):
        raise ZeroDivisionError("my pivot failed")

    with pytest.raises(mp.InputError, match=r"the pivot x function raised ZeroDivisionError\('my pivot failed'\) at t = 0") as info:
        mp.flip_times(chain, np.zeros((20, 2)) + 0.5, t_max=1.0, pivot=mp.Pivot(x=boom))
    assert isinstance(info.value.__cause__, ZeroDivisionError)


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
    """A row of a batch is its own run: bit for bit in any batch (here a batch of one; rk4
    batches run in SIMD lanes where the variant fits them), and to round-off as a single run."""
    for chain, kw in _variants().values():
        th = np.array([[1.0, -0.5], [0.2, 0.3], [2.0, 2.5]])
        batch = mp.simulate(chain, th, np.zeros_like(th), 1.0, method="rk4", dt=0.01, **kw)
        for i in range(3):
            alone = mp.simulate(chain, th[i:i + 1], np.zeros((1, 2)), 1.0, method="rk4", dt=0.01, **kw)
            assert np.array_equal(batch.theta[i], alone.theta[0])
            assert np.array_equal(batch.work.dissipated[i], alone.work.dissipated[0])
            one = mp.simulate(chain, th[i], np.zeros(2), 1.0, method="rk4", dt=0.01, **kw)
            np.testing.assert_allclose(batch.theta[i], one.theta, rtol=0, atol=1e-12)
            np.testing.assert_allclose(batch.work.dissipated[i], one.work.dissipated, rtol=0, atol=1e-12)


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
