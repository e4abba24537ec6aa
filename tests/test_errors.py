"""Every kind of bad input raises its documented class with a message naming field, index and value."""
import re

import numpy as np
import pytest

import multipendulum as mp

CHAIN = dict(lengths=[1.0, 1.0], masses=[1.0, 1.0])


@pytest.mark.parametrize("kwargs, message", [
    (dict(lengths=[1, 1, 0], masses=[1, 1, 1]), "lengths[2] must be > 0 and finite, got 0"),
    (dict(lengths=[1, -2], masses=[1, 1]), "lengths[1] must be > 0 and finite, got -2"),
    (dict(lengths=[np.inf, 1], masses=[1, 1]), "lengths[0] must be > 0 and finite, got inf"),
    (dict(lengths=[np.nan], masses=[1]), "lengths[0] must be > 0 and finite, got NaN"),
    (dict(lengths=[1, 1], masses=[1, -1]), "masses[1] must be >= 0 and finite, got -1"),
    (dict(lengths=[1, 1], masses=[1, 1], inertia=[0, -0.5]), "inertia[1] must be >= 0 and finite, got -0.5"),
    (dict(lengths=[1, 1], masses=[1]), "masses must have 2 entries (one per link), got 1"),
    (dict(lengths=[1, 1], masses=[1, 1], com=[0.5]), "com must have 2 entries (one per link), got 1"),
    (dict(lengths=[], masses=[]), "lengths must have at least one entry, got 0"),
    (dict(lengths=[1, 1], masses=[1, 1], g=np.nan), "g must be finite, got NaN"),
])
def test_invalid_chains_are_refused_with_the_field_named(kwargs, message):
    with pytest.raises(mp.InputError) as e:
        mp.Chain(**kwargs)
    assert str(e.value) == message
    assert isinstance(e.value, ValueError)


def test_a_massless_last_point_mass_leaves_the_mass_matrix_singular():
    with pytest.raises(mp.InputError, match=r"^link 1 leaves the mass matrix singular: masses\[1\] = 0"):
        mp.Chain(lengths=[1, 1], masses=[1, 0])
    with pytest.raises(mp.InputError, match=r"^link 0 leaves the mass matrix singular"):
        mp.Chain(lengths=[1, 1], masses=[0, 1])  # massless link carrying a point mass
    mp.Chain(lengths=[1, 1], masses=[0, 1], com=[1, 0.5], inertia=[0, 0.1])  # but a rod holds it


def test_rods_with_mismatched_sizes():
    with pytest.raises(mp.InputError, match=r"masses must have 2 entries \(one per link\), got 3"):
        mp.Chain.rods(lengths=[1, 1], masses=[1, 1, 1])


@pytest.mark.parametrize("theta0, omega0, message", [
    ([0.1, np.nan], [0, 0], "theta0[1] must be finite, got nan"),
    ([0.1, 0.2], [np.inf, 0], "omega0[0] must be finite, got inf"),
    ([0.1, -1e300], [0, 0], "theta0[1] must be within +-1e+15 rad, got -1e+300"),
    # A batch names the entry as NumPy indexes it.
    ([[0.1, 0.2], [np.nan, 0.3]], [[0, 0], [0, 0]], "theta0[1, 0] must be finite, got nan"),
    ([[0.1, 0.2], [0.1, 0.3]], [[0, 0], [0, -np.inf]], "omega0[1, 1] must be finite, got -inf"),
    ([0.1, 0.2, 0.3], [0, 0, 0], "theta0 must have shape (2,) or (..., 2) (one entry per link), got shape (3,)"),
    ([0.1, 0.2], [0, 0, 0], "omega0 must have shape (2,) or (..., 2) (one entry per link), got shape (3,)"),
    ([[0.1, 0.2]], [0, 0], "theta0 and omega0 must have the same shape, got (1, 2) and (2,)"),
    ("ab", [0, 0], "theta0 must be an array of numbers"),
])
def test_bad_initial_states(theta0, omega0, message):
    with pytest.raises(mp.InputError) as e:
        mp.simulate(mp.Chain(**CHAIN), theta0, omega0, 1.0)
    assert str(e.value).startswith(message)


@pytest.mark.parametrize("kwargs, message", [
    (dict(t_end=0.0), "t_end must be > 0 and finite, got 0"),
    (dict(t_end=-1.0), "t_end must be > 0 and finite, got -1"),
    (dict(t_end=np.nan), "t_end must be > 0 and finite, got NaN"),
    (dict(t_end=-1e300), "t_end must be > 0 and finite, got -1e+300"),
    (dict(method="rk4", dt=-1e-300), "dt must be > 0 and finite, got -1e-300"),
    (dict(method="rk4", dt=0.0), "dt must be > 0 and finite, got 0"),
    (dict(method="rk4", dt=-0.1), "dt must be > 0 and finite, got -0.1"),
    (dict(method="rk4"), "method rk4 takes a fixed step: give dt"),
    (dict(method="gauss6"), "method gauss6 takes a fixed step: give dt"),
    (dict(method="euler"), 'method must be one of rk4, dop853, gauss4, gauss6, got "euler"'),
    (dict(rtol=0.0), "rtol must be >= 1e-15 and finite, got 0"),
    (dict(atol=-1.0), "atol must be >= 0 and finite, got -1"),
    (dict(t_eval=[0.5, 2.0]), "t_eval[1] must lie in [0, t_end = 1], got 2"),
    (dict(t_eval=[0.5, 0.2]), "t_eval must be ascending: t_eval[1] = 0.2 < t_eval[0] = 0.5"),
    (dict(method="gauss6", dt=0.1, form="lagrangian"),
     'method gauss6 integrates Hamilton\'s equations; form must be "hamiltonian", got "lagrangian"'),
    (dict(form="euler"), 'form must be "lagrangian" or "hamiltonian", got "euler"'),
    (dict(torque=[1.0]), "torque must have 2 entries (one per link), got shape (1,)"),
    (dict(torque=[1.0, np.nan]), "torque[1] must be finite, got nan"),
    (dict(torque=[1, 1], joint_torque=[1, 1]), "give torque (generalized, on absolute angles) or joint_torque"),
    (dict(torque=mp.Sinusoid([1, 2, 3], 1.0)), "amplitude must be a number or have 2 entries (one per link), got shape (3,)"),
    (dict(torque=mp.Table([0, 1, 1], [[0, 0]] * 3)), "t[2] must be > t[1] (strictly increasing), got 1 after 1"),
    (dict(torque=mp.Table([0, 1], [[0, 0]] * 3)), "values must have shape (2, 2) for t of shape (2,), got (3, 2)"),
    (dict(torque=mp.Table([0, 1], [[0, 0]] * 2, kind="quintic")), 'kind must be "linear" or "cubic", got "quintic"'),
    (dict(torque=lambda a, b: 0), "a torque function must take (t) or (t, theta, omega), got 2 required arguments"),
])
def test_bad_run_settings(kwargs, message):
    args = dict(t_end=1.0)
    args.update(kwargs)
    with pytest.raises(mp.InputError) as e:
        mp.simulate(mp.Chain(**CHAIN), [0.1, 0.2], [0, 0], **args)
    assert str(e.value).startswith(message), str(e.value)


def test_a_torque_function_that_raises_passes_its_exception_through():
    class Broken(Exception):
        pass

    def torque(t):
        if t > 0.5:
            raise Broken("motor controller failed")
        return [0.0, 0.0]

    with pytest.raises(Broken, match="motor controller failed"):
        mp.simulate(mp.Chain(**CHAIN), [0.1, 0.2], [0, 0], 1.0, torque=torque)


@pytest.mark.parametrize("result, message", [
    ([1.0, 2.0, 3.0], "the torque function must return 2 numbers (one per link), got 3"),
    ("oops", "the torque function must return 2 numbers (one per link), got 'oops'"),
    ([1.0, np.nan], "the torque function returned torque[1] = NaN"),
])
def test_a_torque_function_returning_the_wrong_thing(result, message):
    with pytest.raises(mp.InputError) as e:
        mp.simulate(mp.Chain(**CHAIN), [0.1, 0.2], [0, 0], 1.0, torque=lambda t, th, om: result)
    assert str(e.value).startswith(message), str(e.value)


def test_a_blow_up_raises_integration_error_naming_the_time():
    # rk4 far beyond its stability limit: the state grows without bound and turns non-finite.
    with pytest.raises(mp.IntegrationError, match=r"^integration failed at t = [0-9.e+]+: the state became non-finite") as e:
        mp.simulate(mp.Chain(**CHAIN), [3.0, -3.0], [30.0, -30.0], 1e4, method="rk4", dt=2.0)
    assert 0 < e.value.t <= 1e4
    assert isinstance(e.value, RuntimeError)


def test_gauss_stage_equations_that_cannot_converge_are_reported():
    # Neither fixed-point iteration nor the simplified Newton iteration that takes over solves
    # the stages of a step this large for so fast a chain (at the first step or soon after).
    with pytest.raises(mp.IntegrationError, match="did not converge; reduce dt") as e:
        mp.simulate(mp.Chain(**CHAIN), [3.0, -3.0], [30.0, -30.0], 10.0, method="gauss6", dt=1.0)
    assert e.value.t in (0.0, 1.0, 2.0)


def test_accelerations_refuse_bad_shapes_and_unknown_algorithms():
    chain = mp.Chain(**CHAIN)
    with pytest.raises(mp.InputError, match=re.escape("theta must have shape (2,) or (..., 2)")):
        chain.accelerations([0.1], [0, 0])
    with pytest.raises(mp.InputError, match="algorithm must be one of recursive, cholesky, cramer, got 'lu'"):
        chain.accelerations([0.1, 0.2], [0, 0], algorithm="lu")


def test_max_steps_stops_a_run_that_would_not_finish():
    with pytest.raises(mp.IntegrationError, match="reached max_steps = 10 before t_end"):
        mp.simulate(mp.Chain(**CHAIN), [2.0, 2.0], [0, 0], 100.0, max_steps=10)


def test_a_run_that_would_not_fit_in_memory_is_refused_with_advice():
    with pytest.raises(mp.InputError, match=r"needs [0-9.]+ GiB .* ask for fewer with t_eval"):
        mp.simulate(mp.Chain(lengths=[1.0] * 100, masses=[1.0] * 100), [0.0] * 100, [0.0] * 100, 1e9, method="rk4", dt=1.0)


def test_reference_routes_refuse_sizes_that_would_hang():
    chain = mp.Chain([1.0] * 13, [1.0] * 13)
    with pytest.raises(mp.InputError, match=r"algorithm 'cramer' is a reference route for N <= 12, got N = 13"):
        chain.accelerations([0.0] * 13, [0.0] * 13, algorithm="cramer")
