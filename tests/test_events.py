"""Events located by root finding on the dense output; Poincaré sections."""
import numpy as np
import pytest
from scipy.integrate import quad

import multipendulum as mp

DOUBLE = mp.Chain([1.0, 1.0], [1.0, 1.0])


def single_flip_time(w0, g=9.81, l=1.0):
    return quad(lambda th: 1.0 / np.sqrt(w0**2 - 2 * g / l * (1 - np.cos(th))), 0.0, np.pi, epsabs=1e-13)[0]


@pytest.mark.parametrize("method, kw, tol", [("dop853", dict(rtol=1e-12, atol=1e-14), 1e-9), ("rk4", dict(dt=0.01), 1e-6),
                                             ("gauss6", dict(dt=0.01), 1e-8)])
def test_terminal_flip_event_stops_at_the_exact_flip_time(method, kw, tol):
    chain = mp.Chain([1.0], [1.0])
    sol = mp.simulate(chain, [0.0], [7.0], 5.0, method=method, events=[mp.Flip()], **kw)
    exact = single_flip_time(7.0)
    assert abs(sol.stopped_at - exact) < tol
    assert sol.t[-1] == sol.stopped_at and abs(abs(sol.theta[-1, 0]) - np.pi) < 10 * tol
    assert sol.events[0].t.size == 1


def test_crossings_land_on_zero_and_directions_partition_them():
    t_eval = [30.0]
    up = mp.simulate(DOUBLE, [0.5, 0.3], [0, 0], 30.0, t_eval=t_eval, events=[mp.Crossing(theta=[1, 0], direction=1)])
    down = mp.simulate(DOUBLE, [0.5, 0.3], [0, 0], 30.0, t_eval=t_eval, events=[mp.Crossing(theta=[1, 0], direction=-1)])
    both = mp.simulate(DOUBLE, [0.5, 0.3], [0, 0], 30.0, t_eval=t_eval, events=[mp.Crossing(theta=[1, 0], direction=0)])
    u, d, b = up.events[0], down.events[0], both.events[0]
    assert u.t.size > 5 and b.t.size == u.t.size + d.t.size
    np.testing.assert_allclose(np.sort(np.concatenate([u.t, d.t])), b.t, rtol=0, atol=1e-12)
    assert np.max(np.abs(b.theta[:, 0])) < 1e-10  # the root, not the step where the sign changed
    assert np.all(u.omega[:, 0] > 0) and np.all(d.omega[:, 0] < 0)
    # Independent: the same crossings from a fine fixed-step run agree to its accuracy.
    rk = mp.simulate(DOUBLE, [0.5, 0.3], [0, 0], 30.0, method="rk4", dt=0.001, events=[mp.Crossing(theta=[1, 0])])
    np.testing.assert_allclose(rk.events[0].t, u.t, atol=1e-7)


def test_omega_coefficients_and_a_constant_make_other_conditions():
    # omega_1 falling through 0: local maxima of theta_1, where theta_1'' <= 0.
    sol = mp.simulate(DOUBLE, [0.5, 0.3], [0, 0], 10.0, t_eval=[10.0],
                      events=[mp.Crossing(omega=[1, 0], direction=-1), mp.Crossing(theta=[1, 0], constant=-0.25, direction=1)])
    turns = sol.events[0]
    assert turns.t.size > 3 and np.max(np.abs(turns.omega[:, 0])) < 1e-10
    assert np.all(DOUBLE.accelerations(turns.theta, turns.omega)[:, 0] < 0)
    np.testing.assert_allclose(sol.events[1].theta[:, 0], 0.25, atol=1e-10)


def test_batch_events_equal_single_runs():
    th0 = np.array([[0.5, 0.3], [1.0, -0.4], [2.0, 2.5]])
    ev = [mp.Crossing(theta=[1, 0])]
    batch = mp.simulate(DOUBLE, th0, np.zeros_like(th0), 10.0, t_eval=[10.0], events=ev)
    for b in range(3):
        single = mp.simulate(DOUBLE, th0[b], [0, 0], 10.0, t_eval=[10.0], events=ev)
        np.testing.assert_array_equal(batch.events[b][0].t, single.events[0].t)


def occupancy(sec, bins=30):
    h, _, _ = np.histogram2d(sec.theta, sec.p, bins=bins)
    return np.mean(h > 0)


def test_poincare_sections_show_the_regular_to_chaotic_transition():
    th = np.array([[0.3, 0.0], [2.2, 0.0]])
    low, high = mp.poincare(DOUBLE, th, np.zeros_like(th), 1000.0)
    assert high.energy > low.energy
    assert min(low.t.size, high.t.size) > 300
    # A regular orbit's points lie on a closed curve; a chaotic one's fill an area.
    assert occupancy(low) < 0.15 < 0.3 < occupancy(high), (occupancy(low), occupancy(high))
    assert mp.lyapunov(DOUBLE, th[0], [0, 0], 200.0).largest < 0.05 < 0.5 < mp.lyapunov(DOUBLE, th[1], [0, 0], 200.0).largest


def test_bad_events():
    with pytest.raises(mp.InputError, match=r"Crossing.theta must have 2 coefficients \(one per link\), got shape \(3,\)"):
        mp.simulate(DOUBLE, [0.5, 0.3], [0, 0], 1.0, events=[mp.Crossing(theta=[1, 0, 0])])
    with pytest.raises(mp.InputError, match="direction must be -1, 0 or \\+1, got 2"):
        mp.simulate(DOUBLE, [0.5, 0.3], [0, 0], 1.0, events=[mp.Crossing(theta=[1, 0], direction=2)])
    with pytest.raises(mp.InputError, match=r"Flip.link must be an integer in \[0, 2\) or None, got 5"):
        mp.simulate(DOUBLE, [0.5, 0.3], [0, 0], 1.0, events=[mp.Flip(link=5)])
    with pytest.raises(mp.InputError, match="events must be mp.Flip, mp.Crossing or mp.Event objects, got function"):
        mp.simulate(DOUBLE, [0.5, 0.3], [0, 0], 1.0, events=[lambda t, y: 0])


def test_a_python_condition_is_root_found_like_the_built_ins():
    # The tip's height crossing y = -1.5 downward: a nonlinear condition of the state.
    def below(t, theta, omega):
        return -1.5 - DOUBLE.positions(theta)[-1, 1]

    sol = mp.simulate(DOUBLE, [1.2, 1.5], [0, 0], 6.0, t_eval=[6.0], events=[mp.Event(below, direction=1)])
    hits = sol.events[0]
    assert hits.t.size >= 2
    np.testing.assert_allclose(DOUBLE.positions(hits.theta)[:, -1, 1], -1.5, atol=1e-10)
    # Terminal, on the time axis: stops at t = 1.234 exactly (to the root finder's precision).
    stop = mp.simulate(DOUBLE, [1.2, 1.5], [0, 0], 6.0, events=[mp.Event(lambda t, th, om: t - 1.234, terminal=True)])
    assert abs(stop.stopped_at - 1.234) < 1e-12


def test_a_python_condition_that_raises_or_returns_junk():
    class Oops(Exception):
        pass

    def bad(t, theta, omega):
        if t > 0.3:
            raise Oops("condition failed")
        return 1.0

    with pytest.raises(Oops, match="condition failed"):
        mp.simulate(DOUBLE, [1.0, 0.5], [0, 0], 1.0, events=[mp.Event(bad)])
    with pytest.raises(mp.InputError, match="the event function must return a number, got 'x'"):
        mp.simulate(DOUBLE, [1.0, 0.5], [0, 0], 1.0, events=[mp.Event(lambda t, th, om: "x")])
    with pytest.raises(mp.InputError, match="runs in single runs only"):
        mp.simulate(DOUBLE, [[1.0, 0.5]], [[0, 0]], 1.0, t_eval=[1.0], events=[mp.Event(lambda t, th, om: t)])


def test_a_batch_refuses_a_terminal_event_and_records_a_non_terminal_one():
    # Each trajectory would stop at its own time: the batch's (B, T, N) arrays cannot hold that.
    chain = mp.Chain([1.0, 1.0], [1.0, 1.0])
    th0 = np.array([[2.5, 2.0], [0.1, 0.1]])
    with pytest.raises(mp.InputError, match=r"^a terminal event \(Flip\(terminal=True\), mp.Flip's default\) "
                                            r"would stop each trajectory of a batch at its own time"):
        mp.simulate(chain, th0, np.zeros_like(th0), 10.0, method="rk4", dt=0.01, t_eval=np.linspace(0, 10, 11),
                    events=[mp.Flip()])
    sol = mp.simulate(chain, th0, np.zeros_like(th0), 10.0, method="rk4", dt=0.01, t_eval=np.linspace(0, 10, 11),
                      events=[mp.Flip(terminal=False)])
    one = mp.simulate(chain, th0[0], [0.0, 0.0], 10.0, method="rk4", dt=0.01, t_eval=np.linspace(0, 10, 11),
                      events=[mp.Flip(terminal=False)])
    assert sol.theta.shape == (2, 11, 2) and len(sol.events[0][0].t) == len(one.events[0].t) > 0
