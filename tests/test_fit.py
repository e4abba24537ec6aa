"""mp.fit: parameter identification from measured angles with the sensitivities' exact Jacobian."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp
from multipendulum.errors import InputError

ROOT = Path(__file__).resolve().parents[1]


def example():
    spec = importlib.util.spec_from_file_location("fit_damped_double", ROOT / "examples" / "fit_damped_double.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_example_recovers_the_damped_double_pendulum_within_its_intervals(capsys):
    ex = example()
    result, truth = ex.main(seed=0)
    inside = 0
    for name, values in result.values.items():
        for j, v, (lo, hi), err in zip(result.indices[name], values, result.interval(0.95)[name], result.stderr[name]):
            # Each value within 3 standard errors of the truth (the 99.7% interval), and the
            # interval a real one: positive width, small against the value.
            assert abs(v - truth[name][j]) < 3 * err, (name, j, v, err)
            assert 0 < hi - lo < 0.2 * abs(truth[name][j])
            inside += lo <= truth[name][j] <= hi
    assert inside >= len(result.names) - 1  # 95% intervals: at most one of seven may miss
    assert abs(result.rms - ex.SIGMA) < 0.1 * ex.SIGMA  # the misfit is the noise
    assert "95% CI" in capsys.readouterr().out


def test_the_reported_errors_match_the_scatter_over_noise_realisations():
    ex = example()
    fits = []
    for seed in range(8):
        t, measured = ex.measure(seed, t_end=6.0, samples=301)
        guess = mp.Chain([1.1, 0.75], [1.0, 0.65], damping=[0.06, 0.025])
        fits.append(mp.fit(guess, t, measured, params={"lengths": None, "masses": [1], "damping": None},
                           theta0=ex.THETA0, sigma=ex.SIGMA))
    for name in ("lengths", "damping"):
        spread = np.std([f.values[name] for f in fits], axis=0, ddof=1)
        reported = np.mean([f.stderr[name] for f in fits], axis=0)
        assert np.all((spread > 0.4 * reported) & (spread < 2.5 * reported)), (name, spread, reported)


@pytest.mark.parametrize("kind", ["points", "rods"])
def test_a_length_carries_what_the_chain_kind_ties_to_it(kind):
    # Exact data of a point-mass or rod chain: the fit moves com (and a rod's inertia) with the
    # lengths and lands on the truth; a fit that moved the lengths alone would not.
    build = (lambda l, m: mp.Chain(l, m)) if kind == "points" else (lambda l, m: mp.Chain.rods(l, m))
    truth = build([1.0, 0.7], [1.0, 0.5])
    t = np.linspace(0, 4, 201)
    measured = mp.simulate(truth, [1.0, 0.4], [0, 0], 4.0, t_eval=t).theta
    result = mp.fit(build([1.1, 0.63], [1.0, 0.55]), t, measured, params={"lengths": None, "masses": [1]})
    assert np.allclose(result.chain.lengths, truth.lengths, rtol=1e-7)
    assert np.allclose(result.chain.com, truth.com, rtol=1e-7)
    assert np.allclose(result.chain.inertia, truth.inertia, rtol=1e-7, atol=1e-12)
    assert result.rms < 1e-8


def test_g_and_the_initial_rates_of_a_chain_on_a_cart():
    def chain(g):
        return mp.Chain([1.0], [0.5], com=[0.6], inertia=[0.02], g=g, cart=mp.Cart(2.0, damping=0.3))
    t = np.linspace(0, 3, 151)
    drive = dict(cart_v0=0.4, cart_force=mp.Sinusoid([0.5], [3.0]))
    measured = mp.simulate(chain(9.81), [0.8], [0.3], 3.0, t_eval=t, **drive).theta
    result = mp.fit(chain(8.0), t, measured, params=["g", "omega0"], theta0=[0.8], **drive)
    assert abs(result.values["g"][0] - 9.81) < 1e-7 and abs(result.values["omega0"][0] - 0.3) < 1e-7
    assert result.chain.cart == mp.Cart(2.0, damping=0.3)


def test_bad_fits_are_refused():
    chain = mp.Chain([1.0, 0.8], [1.0, 0.6])
    t = np.linspace(0, 1, 3)
    theta = mp.simulate(chain, [1.0, 0.2], [0, 0], 1.0, t_eval=t).theta
    with pytest.raises(InputError, match=r"^a fit of 7 values needs at least as many measurements, got 6 "
                                         r"\(3 times x 2 angles\)$"):
        mp.fit(chain, t, theta, params=["lengths", "masses", "damping", "g"])
    with pytest.raises(InputError, match=r"^cannot fit 'length': the parameters are theta0, omega0, lengths"):
        mp.fit(chain, t, theta, params=["length"])
    with pytest.raises(InputError, match=r"^theta_measured must have shape \(len\(t\), N\) = \(3, 2\), got \(3, 1\)$"):
        mp.fit(chain, t, theta[:, :1])
    with pytest.raises(InputError, match=r"^t must hold at least two ascending times"):
        mp.fit(chain, t[::-1], theta)
    with pytest.raises(InputError, match=r"^give theta0: the measurements start at t = 0.5"):
        mp.fit(chain, t + 0.5, theta)
    with pytest.raises(InputError, match=r"^params\['masses'\] must be distinct indices in \[0, 2\), got \[2\]$"):
        mp.fit(chain, t, theta, params={"masses": [2]})
    # Every mass and the damping together: the motion cannot tell them apart.
    t = np.linspace(0, 3, 61)
    damped = mp.Chain([1.0, 0.8], [1.0, 0.6], damping=[0.1, 0.1])
    theta = mp.simulate(damped, [1.0, 0.2], [0, 0], 3.0, t_eval=t).theta
    with pytest.raises(InputError, match=r"^the parameters cannot be told apart from these measurements: the "
                                         r"Jacobian has rank 3 for 4 values"):
        mp.fit(mp.Chain([1.0, 0.8], [1.2, 0.5], damping=[0.12, 0.09]), t, theta,
               params=["masses", "damping"], theta0=[1.0, 0.2])


def test_more_bad_input_is_refused():
    chain = mp.Chain([1.0, 0.8], [1.0, 0.6])
    t = np.linspace(0, 1, 11)
    theta = mp.simulate(chain, [1.0, 0.2], [0, 0], 1.0, t_eval=t).theta
    with pytest.raises(InputError, match=r"^t must hold at least two ascending times"):
        mp.fit(chain, np.r_[t[:-1], np.nan], theta)
    with pytest.raises(InputError, match=r"^params\['masses'\] must be None or a list of integer indices, got 'a'$"):
        mp.fit(chain, t, theta, params={"masses": "a"})
    with pytest.raises(InputError, match=r"^params\['masses'\] must be None or a list of integer indices, got \[1.7\]$"):
        mp.fit(chain, t, theta, params={"masses": [1.7]})
    with pytest.raises(InputError, match=r"^fit sets bounds, x_scale of least_squares itself"):
        mp.fit(chain, t, theta, params=["lengths"], bounds=(0, 1), x_scale=1.0)
    with pytest.raises(InputError, match=r"^cart_x0, cart_v0 and cart_force need a chain with a cart"):
        mp.fit(chain, t, theta, params=["lengths"], cart_v0=1.0)
