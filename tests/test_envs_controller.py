"""A controller through the cart-pole environment (examples/cartpole_swingup.py): the energy
pump swings the pole up from the environment's hanging start and the LQR (gain from the
package's own linearisation) catches and holds it, on the track, without a termination; the
LQR alone holds one and two poles from starts near upright (``reset(options={"state": ...})``)."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("scipy")
import multipendulum.envs  # noqa: E402,F401
from multipendulum.modes import linearize  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ENV_ID = "multipendulum/CartPole-v0"
TOL = 0.05      # rad: "upright"
TAIL = 200      # steps that must stay upright at the end of the episode
X_LIMIT = 2.4   # the environment's default track


def _example(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


ex = _example("cartpole_swingup")


def lean(states, n):
    """(T,) largest |theta_i - pi| (wrapped) of the environment's states (x, theta, v, omega)."""
    th = np.asarray(states)[:, 1:1 + n]
    return np.max(np.abs((th - np.pi + np.pi) % (2 * np.pi) - np.pi), axis=1)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_swingup_from_the_hanging_start_reaches_upright_and_holds_it(seed):
    steps = 500  # the environment's registered episode length (10 s)
    r = ex.run(seed, steps)
    S = r["states"]
    assert S.shape == (steps + 1, 4) and r["steps"] == steps
    # the environment's own swing-up start: hanging, every value within +-0.05
    assert np.all(np.abs(S[0]) <= 0.05)
    assert r["truncated"] and not r["terminated"]
    assert np.all(np.abs(S[:, 0]) < X_LIMIT), f"cart left the track: max |x| = {np.abs(S[:, 0]).max():.2f} m"
    up = lean(S, 1)
    reached = np.flatnonzero((up < TOL) & (np.abs(S[:, 3]) < 0.5))
    assert reached.size, f"never upright: closest {up.min():.3f} rad"
    assert reached[0] <= steps - TAIL, f"upright only at step {reached[0]}"
    assert up[reached[0]:].max() < TOL, "fell after reaching upright"
    assert up[-TAIL:].max() < TOL and np.abs(S[-TAIL:, 3]).max() < 0.5
    assert up[-1] < 1e-3 and abs(S[-1, 0]) < 0.2  # settled, the cart back near the centre
    assert r["modes"][0] == "swing" and r["modes"][-1] == "balance" and r["switches"] == 1
    assert np.all(np.abs(r["actions"]) <= 1.0)
    assert r["energy_error"] < 1e-6  # the environment's integration stayed sound under the inputs


def test_without_the_controller_the_pole_stays_down():
    """The reference that makes the test above mean something: no force, no swing-up."""
    env = gym.make(ENV_ID, task="swingup")
    env.reset(seed=0)
    worst = np.pi
    for _ in range(500):
        env.step(np.zeros(1))
        worst = min(worst, float(lean(env.unwrapped.state[None], 1)[0]))
    env.close()
    assert worst > np.pi - 0.2


@pytest.mark.parametrize("n", [1, 2])
def test_the_lqr_gain_is_from_the_package_linearisation_and_stabilises_it(n):
    env = gym.make(ENV_ID, n=n)
    K = ex.lqr_gain(env)
    A, B = linearize(env.unwrapped.task.chain, np.full(n, np.pi), inputs="cart")
    env.close()
    assert K.shape == (1, 2 * n + 2) and A.shape == (2 * n + 2, 2 * n + 2)
    assert np.linalg.eigvals(A).real.max() > 1.0  # upright is unstable by itself ...
    assert np.linalg.eigvals(A - B @ K).real.max() < -0.1  # ... and stable under F = -K s


@pytest.mark.parametrize("n, start", [
    (1, [0.1]), (1, [-0.15]), (2, [0.05, 0.05]), (2, [0.1, 0.0]), (2, [0.05, -0.05]),
])
def test_lqr_catch_alone_from_near_upright(n, start):
    """task="balance" (terminated beyond 12 degrees or off the track), started with
    ``reset(options={"state": ...})`` at rest, the poles leaning by ``start`` rad."""
    state = [0.0] + list(np.pi + np.asarray(start)) + [0.0] * (n + 1)
    r = ex.run(0, 500, task="balance", state=state, env_kwargs={"n": n})
    S = r["states"]
    np.testing.assert_allclose(S[0], state)  # the environment started where it was told
    assert r["modes"] == ["balance"] * 500
    assert not r["terminated"] and r["steps"] == 500
    assert np.all(np.abs(S[:, 0]) < X_LIMIT)
    assert lean(S, n)[-TAIL:].max() < TOL and lean(S, n)[-1] < 1e-3
    assert np.abs(S[-1, 1 + n:]).max() < 1e-2 and abs(S[-1, 0]) < 0.05  # at rest, centred


@pytest.mark.parametrize("n", [1, 2])
def test_lqr_holds_the_balance_task_from_its_own_random_starts(n):
    for seed in range(5):
        r = ex.run(seed, 300, task="balance", env_kwargs={"n": n})
        assert not r["terminated"] and r["steps"] == 300, f"n={n} seed {seed} fell"
        assert lean(r["states"], n)[-TAIL:].max() < TOL


def test_main_runs_and_reports_success(capsys):
    assert ex.main(["1", "500"]) == 0
    out = capsys.readouterr().out
    assert "seed 0: upright at t =" in out and "all ok" in out and "FAILED" not in out


def test_the_controller_refuses_an_environment_without_a_cart():
    env = gym.make("multipendulum/Acrobot-v0")
    with pytest.raises(ValueError, match="CartPole"):
        ex.controller(env)
    env.close()
