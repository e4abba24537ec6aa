"""Integrators: convergence order against the declared order, energy behaviour, forms, batches."""
import numpy as np
import pytest

import multipendulum as mp

DOUBLE = dict(lengths=[1.0, 0.8], masses=[1.0, 1.5])
THETA0, OMEGA0 = [1.2, -0.6], [0.3, 0.9]


def reference_state(chain, theta0, omega0, t_end):
    sol = mp.simulate(chain, theta0, omega0, t_end, rtol=1e-14, atol=1e-15, t_eval=[t_end])
    return np.concatenate([sol.theta[-1], sol.omega[-1]])


# Step sizes inside the asymptotic regime for this problem and well above round-off: measured
# ratios per halving were 3.74, 3.88 (rk4), 4.00 (gauss4), 6.0-7.0 (gauss6), 7.5-10 (dop853:
# high-order methods approach their order irregularly, so four steps are fitted).
STEPS = {
    "rk4": [0.005, 0.0025, 0.00125],
    "gauss4": [0.02, 0.01, 0.005],
    "gauss6": [0.05, 0.025, 0.0125],
    "dop853": [0.1, 0.05, 0.025, 0.0125],
}


@pytest.mark.parametrize("method", mp.METHODS)
def test_convergence_order_matches_declared_order(method):
    # RMS error over the trajectory at times on every step grid, so that one component's error
    # constant passing through zero cannot fake or hide an order.
    chain = mp.Chain(lengths=[1.0, 0.8], masses=[1.0, 1.5])
    theta0, omega0, t_end = [0.5, -0.3], [0.0, 0.0], 2.0
    t_eval = np.linspace(0, t_end, 11)
    ref = mp.simulate(chain, theta0, omega0, t_end, rtol=1e-14, atol=1e-15, t_eval=t_eval)
    errors = []
    for dt in STEPS[method]:
        sol = mp.simulate(chain, theta0, omega0, t_end, method=method, dt=dt, adaptive=False, t_eval=t_eval)
        errors.append(np.sqrt(np.mean((sol.theta - ref.theta) ** 2 + (sol.omega - ref.omega) ** 2)))
    slope = np.polyfit(np.log(STEPS[method]), np.log(errors), 1)[0]
    order = mp.METHOD_INFO[method]["order"]
    # At least the declared order; a broken coefficient typically drops it by two or more.
    assert order - 0.5 < slope < order + 1.0, f"{method}: measured order {slope:.2f}, declared {order}; errors {errors}"


def test_rk4_works_in_both_forms_at_the_same_order():
    chain = mp.Chain(**DOUBLE)
    ref = reference_state(chain, THETA0, OMEGA0, 1.0)
    for form in ("lagrangian", "hamiltonian"):
        errs = []
        for dt in (0.002, 0.001):
            sol = mp.simulate(chain, THETA0, OMEGA0, 1.0, method="rk4", dt=dt, form=form, t_eval=[1.0])
            errs.append(np.max(np.abs(np.concatenate([sol.theta[-1], sol.omega[-1]]) - ref)))
        assert 2**3.5 < errs[0] / errs[1] < 2**4.5, (form, errs)


def test_lagrangian_and_hamiltonian_forms_give_the_same_trajectory():
    chain = mp.Chain(lengths=[1.0, 0.7, 0.5], masses=[1.0, 2.0, 0.5], com=[0.6, 0.3, 0.5], inertia=[0.05, 0.1, 0.0])
    t = np.linspace(0, 3, 31)
    a = mp.simulate(chain, [1.0, 0.2, -0.4], [0.0, 1.0, 0.5], 3.0, rtol=1e-12, atol=1e-14, t_eval=t, form="lagrangian")
    b = mp.simulate(chain, [1.0, 0.2, -0.4], [0.0, 1.0, 0.5], 3.0, rtol=1e-12, atol=1e-14, t_eval=t, form="hamiltonian")
    assert b.form == "hamiltonian" and a.form == "lagrangian"
    np.testing.assert_allclose(a.theta, b.theta, atol=1e-9, rtol=0)
    np.testing.assert_allclose(a.p, b.p, atol=1e-9, rtol=0)


def windows(err, frac=0.1):
    k = max(1, int(len(err) * frac))
    return np.max(err[1:k]), np.max(err[-k:])


def test_gauss6_energy_error_is_bounded_without_drift_over_1e5_steps():
    chain = mp.Chain(lengths=[1, 1], masses=[1, 1])
    errors = {}
    for dt in (0.01, 0.02):  # the same 1000 s at two steps: 10^5 and 5 10^4 steps
        sol = mp.simulate(chain, [2.0, 2.5], [0, 0], 1000.0, method="gauss6", dt=dt)
        assert sol.stats.steps == round(1000.0 / dt)
        errors[dt] = np.abs(sol.energy - sol.energy[0]) / abs(sol.energy[0])
    err = errors[0.01]
    # The bound from the order: a symplectic method of order 6 keeps the energy within
    # C h^6 for the whole run (backward error analysis), so halving the step must divide the
    # largest error by 2^6 = 64; at least 2^5 is asked (one order of slack for a
    # pre-asymptotic step). An order-4 error (as from a broken coefficient) divides by 16 only.
    assert np.max(err) <= np.max(errors[0.02]) / 2**5, (np.max(err), np.max(errors[0.02]))
    # No secular drift: the late window's error is of the same size as the early one's.
    early, late = windows(err)
    assert late < 2 * early, (early, late)


def test_rk4_energy_drifts_secularly_where_gauss6_does_not():
    # Not a target but a documented property: rk4 is not symplectic, its energy error grows.
    chain = mp.Chain(lengths=[1, 1], masses=[1, 1])
    sol = mp.simulate(chain, [0.5, 0.5], [0, 0], 1000.0, method="rk4", dt=0.01)
    early, late = windows(np.abs(sol.energy - sol.energy[0]))
    assert late > 5 * early, (early, late)


def test_fixed_step_output_on_the_step_grid_is_exact_and_between_is_hermite():
    chain = mp.Chain(**DOUBLE)
    full = mp.simulate(chain, THETA0, OMEGA0, 1.0, method="rk4", dt=0.01)
    assert full.t.size == 101
    on_grid = mp.simulate(chain, THETA0, OMEGA0, 1.0, method="rk4", dt=0.01, t_eval=np.linspace(0, 1, 11))
    np.testing.assert_array_equal(on_grid.theta, full.theta[::10])
    between = mp.simulate(chain, THETA0, OMEGA0, 1.0, method="rk4", dt=0.01, t_eval=[0.005, 0.505])
    exact = mp.simulate(chain, THETA0, OMEGA0, 1.0, rtol=1e-13, atol=1e-14, t_eval=[0.005, 0.505])
    linear_error = np.max(np.abs(0.5 * (full.theta[[0, 50]] + full.theta[[1, 51]]) - exact.theta))
    h = 0.01
    for k, i in enumerate((0, 50)):  # the step [t_i, t_i + h] around each output
        hermite_error = np.max(np.abs(between.theta[k] - exact.theta[k]))
        # The cubic Hermite interpolant's bound: the error of its data (rk4's angles at both
        # ends, and its rates weighted by the derivative basis functions, |h10|, |h11| <= 4h/27)
        # plus the interpolation error of exact data, h^4 / 384 max |d^4 theta / dt^4| over the step.
        ends = full.t[[i, i + 1]]
        ref = mp.simulate(chain, THETA0, OMEGA0, 1.0, rtol=1e-13, atol=1e-14, t_eval=ends)
        data = np.max(np.abs(full.theta[[i, i + 1]] - ref.theta))
        rates = np.max(np.abs(full.omega[[i, i + 1]] - ref.omega))
        fine = np.linspace(max(0.0, ends[0] - 0.002), ends[1] + 0.002, 61)
        dense = mp.simulate(chain, THETA0, OMEGA0, 1.0, rtol=1e-13, atol=1e-14, t_eval=fine)
        acc = chain.accelerations(dense.theta, dense.omega)
        fourth = np.max(np.abs(np.diff(acc, 2, axis=0))) / (fine[1] - fine[0]) ** 2  # second derivative of theta''
        # 1.25: the largest sampled value of a smooth function may fall a little short of its maximum
        bound = data + 8 / 27 * h * rates + 1.25 * h**4 / 384 * fourth
        assert hermite_error <= bound, (k, hermite_error, data, rates, fourth)
        assert hermite_error < 1e-2 * linear_error, (hermite_error, linear_error)


def test_dop853_dense_output_matches_a_run_ending_there():
    chain = mp.Chain(**DOUBLE)
    t_eval = np.array([0.37, 1.91, 3.3])
    dense = mp.simulate(chain, THETA0, OMEGA0, 4.0, rtol=1e-12, atol=1e-14, t_eval=t_eval)
    for k, t in enumerate(t_eval):
        end = mp.simulate(chain, THETA0, OMEGA0, t, rtol=1e-12, atol=1e-14, t_eval=[t])
        np.testing.assert_allclose(dense.theta[k], end.theta[0], atol=1e-9)


def test_batch_runs_equal_single_runs_bit_for_bit(monkeypatch):
    """Trajectory by trajectory, a batch's rows are its single runs, bit for bit. An rk4 or
    dop853 batch runs in SIMD lanes (issue 14): its rows agree with the single runs (rk4 to
    round-off, dop853 to its tolerance), and each keeps its bits in any batch (here: alone, as a
    batch of one)."""
    chain = mp.Chain(**DOUBLE)
    rng = np.random.default_rng(1)
    th0, om0 = rng.uniform(-2, 2, (6, 2)), rng.uniform(-1, 1, (6, 2))
    for route in ("scalar", "auto"):
        monkeypatch.setenv("MULTIPENDULUM_LANES", route)
        for method, kw in (("rk4", dict(dt=0.01)), ("dop853", dict(t_eval=np.linspace(0, 2, 21))), ("gauss6", dict(dt=0.02))):
            batch = mp.simulate(chain, th0, om0, 2.0, method=method, **kw)
            assert batch.theta.shape[0] == 6 and batch.energy.shape[0] == 6
            lanes = route == "auto" and method in ("rk4", "dop853")
            for b in range(6):
                single = mp.simulate(chain, th0[b], om0[b], 2.0, method=method, **kw)
                if lanes:
                    tol = 1e-12 if method == "rk4" else 1e-8
                    np.testing.assert_allclose(batch.theta[b], single.theta, rtol=0, atol=tol)
                    np.testing.assert_allclose(batch.omega[b], single.omega, rtol=0, atol=tol)
                    single = mp.simulate(chain, th0[b:b + 1], om0[b:b + 1], 2.0, method=method, **kw)
                    single.theta, single.omega = single.theta[0], single.omega[0]
                np.testing.assert_array_equal(batch.theta[b], single.theta)
                np.testing.assert_array_equal(batch.omega[b], single.omega)


def test_driven_run_work_equals_energy_change():
    chain = mp.Chain.rods(lengths=[1.0, 0.7], masses=[1.0, 2.0])
    torque = mp.Sinusoid(amplitude=[2.0, -1.0], frequency=[3.0, 5.0], phase=[0.0, 1.0])
    sol = mp.simulate(chain, [0.1, 0.2], [0, 0], 10.0, torque=torque, rtol=1e-12, atol=1e-14, t_eval=np.linspace(0, 10, 2001))
    change = sol.energy - sol.energy[0]
    assert np.ptp(change) > 1.0  # the torque really pumps energy in and out
    np.testing.assert_allclose(change, sol.work, atol=1e-9 * np.max(np.abs(change)))
    # The work integral itself, recomputed from the outputs: W = int tau . omega dt (Simpson).
    t = sol.t
    tau = 2.0 * np.sin(3 * t)[:, None] * [1, 0] + (-1.0 * np.sin(5 * t + 1.0))[:, None] * [0, 1]
    power = np.sum(tau * sol.omega, axis=1)
    from scipy.integrate import simpson
    assert abs(simpson(power, x=t) - sol.work[-1]) < 1e-6


def test_joint_motor_power_is_the_work_done_by_joint_torques():
    chain = mp.Chain(lengths=[1.0, 1.0, 1.0], masses=[1.0, 1.0, 1.0])
    u = np.array([1.5, -0.7, 0.4])  # constant joint-motor torques
    sol = mp.simulate(chain, [0.2, 0.1, 0.0], [0, 0, 0], 5.0, joint_torque=u, rtol=1e-12, atol=1e-14,
                      t_eval=np.linspace(0, 5, 4001))
    rel = np.diff(np.concatenate([np.zeros((sol.t.size, 1)), sol.omega], axis=1), axis=1)  # joint rates
    power = rel @ u  # each motor's power is u_i times the relative rate of its joint
    from scipy.integrate import simpson
    assert abs(simpson(power, x=sol.t) - sol.work[-1]) < 1e-6 * max(1, abs(sol.work[-1]))
    np.testing.assert_allclose(sol.energy - sol.energy[0], sol.work, atol=1e-8)


def test_feedback_torque_callable_damps_energy_monotonically():
    chain = mp.Chain(lengths=[1, 1], masses=[1, 1])
    calls = []

    def damping(t, theta, omega):
        calls.append(t)
        return -0.5 * omega

    sol = mp.simulate(chain, [1.0, 1.5], [0, 0], 5.0, torque=damping, t_eval=np.linspace(0, 5, 101))
    assert len(calls) == sol.stats.evaluations
    assert np.all(np.diff(sol.energy) < 0)
    np.testing.assert_allclose(sol.energy - sol.energy[0], sol.work, atol=1e-8)


def test_time_callable_equals_builtin_sinusoid():
    chain = mp.Chain(lengths=[1, 1], masses=[1, 1])
    builtin = mp.simulate(chain, [0.3, 0], [0, 0], 3.0, method="rk4", dt=0.01, torque=mp.Sinusoid([1, 0], 2.0))
    python = mp.simulate(chain, [0.3, 0], [0, 0], 3.0, method="rk4", dt=0.01, torque=lambda t: [np.sin(2 * t), 0.0])
    np.testing.assert_allclose(builtin.theta, python.theta, rtol=0, atol=1e-14)


def test_tabulated_torque_linear_equals_constant_when_flat_and_cubic_is_the_natural_spline():
    from scipy.interpolate import CubicSpline

    chain = mp.Chain(lengths=[1, 1], masses=[1, 1])
    flat = mp.Table(t=[0, 1, 2, 10], values=[[0.5, -0.2]] * 4, kind="linear")
    a = mp.simulate(chain, [0.3, 0], [0, 0], 3.0, method="rk4", dt=0.01, torque=flat)
    b = mp.simulate(chain, [0.3, 0], [0, 0], 3.0, method="rk4", dt=0.01, torque=[0.5, -0.2])
    np.testing.assert_array_equal(a.theta, b.theta)
    # "cubic" is the natural cubic spline through the samples (zero second derivative at both
    # ends): the same run with SciPy's natural spline as a Python torque function must agree to
    # round-off, since rk4 evaluates both at the same times. The two evaluate the same cubic
    # pieces by different formulas (a few ulps of |u| apart); over 300 steps of a regular motion
    # that moves the angles by far less than 1e-12 rad. Uneven knots, so no symmetry hides a slip.
    ts = np.sort(np.concatenate([[0.0, 4.0], np.random.default_rng(4).uniform(0, 4, 60)]))
    values = np.stack([np.sin(2 * ts) + 0.3 * ts**2, np.cos(3 * ts)], axis=1)
    spline = CubicSpline(ts, values, bc_type="natural")
    c = mp.simulate(chain, [0.3, 0], [0, 0], 3.0, method="rk4", dt=0.01,
                    torque=mp.Table(t=ts, values=values, kind="cubic"))
    d = mp.simulate(chain, [0.3, 0], [0, 0], 3.0, method="rk4", dt=0.01, torque=lambda t: spline(t))
    np.testing.assert_allclose(c.theta, d.theta, rtol=0, atol=1e-12)
    # and a straight line is reproduced to round-off by the cubic kind too (its spline is the line)
    line = mp.Table(t=ts, values=np.stack([0.5 - 0.2 * ts, 0.1 * ts], axis=1), kind="cubic")
    e = mp.simulate(chain, [0.3, 0], [0, 0], 3.0, method="rk4", dt=0.01, torque=line)
    f = mp.simulate(chain, [0.3, 0], [0, 0], 3.0, method="rk4", dt=0.01, torque=lambda t: [0.5 - 0.2 * t, 0.1 * t])
    np.testing.assert_allclose(e.theta, f.theta, rtol=0, atol=1e-12)


def test_stats_count_steps_and_evaluations():
    chain = mp.Chain(lengths=[1, 1], masses=[1, 1])
    sol = mp.simulate(chain, [1, 1], [0, 0], 1.0, method="rk4", dt=0.1)
    assert sol.stats.steps == 10 and sol.stats.evaluations == 40
    sol = mp.simulate(chain, [1, 1], [0, 0], 1.0)
    # 12 per attempt (the last stage is reused as the next first), +2 for the first step's guess
    assert sol.stats.evaluations == 12 * (sol.stats.steps + sol.stats.rejected) + 2
