"""Recover the parameters of a damped double pendulum from noisy angle measurements.

The "measurements" are a run of the true chain with Gaussian noise of 0.01 rad added; the fit
starts 30% off in every parameter, moves the lengths, the second mass (the first sets the mass
scale, which angles alone cannot tell), the damping and the initial angles, and reports each
value with its 95% confidence interval.

    python examples/fit_damped_double.py
"""
import numpy as np

import multipendulum as mp

SIGMA = 0.01  # rad, the measurement noise
TRUTH = dict(lengths=[1.0, 0.8], masses=[1.0, 0.6], damping=[0.05, 0.03])
THETA0 = [1.2, -0.5]


def measure(seed=0, t_end=10.0, samples=501):
    """Noisy angles of the true chain released from rest."""
    truth = mp.Chain(TRUTH["lengths"], TRUTH["masses"], damping=TRUTH["damping"])
    t = np.linspace(0.0, t_end, samples)
    clean = mp.simulate(truth, THETA0, [0.0, 0.0], t_end, t_eval=t).theta
    return t, clean + np.random.default_rng(seed).normal(0.0, SIGMA, clean.shape)


def main(seed=0):
    t, measured = measure(seed)
    off = 1.3  # every parameter 30% off (the first mass, the scale, stays)
    guess = mp.Chain(np.array(TRUTH["lengths"]) * [off, 1 / off], [1.0, 0.6 * off],
                     damping=np.array(TRUTH["damping"]) * [off, 1 / off])
    result = mp.fit(guess, t, measured, params={"lengths": None, "masses": [1], "damping": None, "theta0": None},
                    theta0=measured[0], sigma=SIGMA)
    interval = result.interval(0.95)
    truth = dict(TRUTH, theta0=THETA0)
    for name, values in result.values.items():
        for j, v, (lo, hi) in zip(result.indices[name], values, interval[name]):
            true = truth[name][j]
            flag = "inside" if lo <= true <= hi else "OUTSIDE"
            print(f"{name}[{j}]: {v:.5f}  95% CI [{lo:.5f}, {hi:.5f}]  true {true}  ({flag})")
    print(f"rms misfit {result.rms:.4f} rad (noise {SIGMA}), {result.nfev} runs")
    return result, truth


if __name__ == "__main__":
    main()
