"""The Gymnasium environments (multipendulum.envs), checked with gymnasium itself: its env
checker on every id, its own Acrobot-v1 and CartPole-v1 as the references for the drop-in and the
cart-pole's equations, its SyncVectorEnv as the reference for the vector environment."""
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
import multipendulum as mp  # noqa: E402
import multipendulum.envs as envs  # noqa: E402
from gymnasium.utils.env_checker import check_env  # noqa: E402
from gymnasium.vector import AutoresetMode  # noqa: E402

IDS = ["multipendulum/Acrobot-v0", "multipendulum/CartPole-v0", "multipendulum/AcrobotCompat-v0"]
# Expected: unbounded rates (as MuJoCo's envs have), and check_env's try of render_mode="human"
# saying that this headless test run has no window.
EXPECTED = ("minimum value is -infinity", "maximum value is infinity", "needs a window")


@pytest.mark.parametrize("env_id,kwargs", [
    (IDS[0], {}), (IDS[0], {"action_type": "discrete", "n": 3}), (IDS[0], {"actuated": "all", "n": 3}),
    (IDS[0], {"actuated": "first", "action_type": "discrete", "damping": 0.05}),
    (IDS[1], {}), (IDS[1], {"n": 2, "task": "swingup", "friction": 0.01}), (IDS[2], {}),
])
def test_gymnasium_check_env_passes_on_every_id(env_id, kwargs):
    env = gym.make(env_id, render_mode="rgb_array", **kwargs)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    other = [str(w.message) for w in caught if not any(s in str(w.message) for s in EXPECTED)]
    assert other == [], other


def test_the_ids_make_this_package_s_vector_env():
    for env_id in IDS:
        v = gym.make_vec(env_id, num_envs=3)
        assert type(v).__module__.startswith("multipendulum.envs"), type(v)
        assert isinstance(v.unwrapped, gym.vector.VectorEnv)
        assert v.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
        assert v.observation_space.shape[0] == 3
        v.close()


@pytest.mark.parametrize("env_id,kwargs", [(IDS[0], {"n": 3}), (IDS[1], {"n": 2, "task": "swingup"})])
def test_observations_are_the_documented_functions_of_the_state(env_id, kwargs):
    """The core computes the observation from each copy's state (the lanes' sin/cos): it is the
    documented layout of cos, sin, rates (and the cart's x, v), to the last bit or two."""
    v = gym.make_vec(env_id, num_envs=11, **kwargs)
    v.reset(seed=3)
    rng = np.random.default_rng(3)
    for _ in range(5):
        obs = v.step(rng.uniform(-1, 1, v.action_space.shape))[0]
    s, n = v.unwrapped.state, kwargs["n"]
    if env_id == IDS[0]:
        theta, omega = s[:, :n], s[:, n:]
        want = np.concatenate([np.cos(theta), np.sin(theta), omega], axis=1)
    else:  # (x, theta, v, omega) -> (x, cos, sin, v, omega)
        theta = s[:, 1:n + 1]
        want = np.concatenate([s[:, :1], np.cos(theta), np.sin(theta), s[:, n + 1:n + 2], s[:, n + 2:]], axis=1)
    assert np.abs(theta).max() > 0.05  # the angles moved: a nontrivial check
    np.testing.assert_allclose(obs, want, rtol=0, atol=4.5e-16)


def test_bad_observation_columns_are_input_errors():
    import multipendulum._core as core
    st = core.Steppers(mp.Chain.rods([1, 1], [1, 1])._c, 3, method="rk4", rtol=1e-10, atol=1e-12, max_steps=10, dt=0.01)
    states = np.zeros(3 * 4)
    for columns, message in [([3, 0], "kind 0, 1 or 2"), ([1, -1], "index >= 0"), ([1, 4], "outside a state row of 4"),
                             ([1], "(kind, index) pairs")]:
        with pytest.raises(mp.InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
            st.observe(states, np.array(columns, dtype=np.int64))
    with pytest.raises(mp.InputError, match="states must have count x 4 = 12 values, got 8"):
        st.observe(np.zeros(8), np.array([1, 0], dtype=np.int64))


# --- AcrobotCompat-v0 against gymnasium's Acrobot-v1 -------------------------------------------

def test_compat_transitions_equal_gymnasium_acrobot_from_the_same_states():
    ours = gym.make("multipendulum/AcrobotCompat-v0").unwrapped
    ref = gym.make("Acrobot-v1").unwrapped
    ours.reset(seed=0)
    ref.reset(seed=0)
    rng = np.random.default_rng(5)
    worst = 0.0
    for _ in range(400):
        s = rng.uniform([-np.pi, -np.pi, -4 * np.pi, -9 * np.pi], [np.pi, np.pi, 4 * np.pi, 9 * np.pi])
        a = int(rng.integers(3))
        ours.state, ref.state = s.copy(), s.copy()  # settable, as in gymnasium's AcrobotEnv
        o1, r1, t1, _, info = ours.step(a)
        o2, r2, t2, _, _ = ref.step(a)
        d = np.abs(ours.state - ref.state)
        d[:2] = np.minimum(d[:2], 2 * np.pi - d[:2])  # the same angle either side of the wrap
        worst = max(worst, float(d.max()))
        assert (r1, t1) == (r2, t2)
        np.testing.assert_allclose(o1, o2, atol=1e-6)  # float32 observations
    assert worst < 1e-9, worst


def test_compat_episodes_equal_gymnasium_from_the_same_seed():
    ours, ref = gym.make("multipendulum/AcrobotCompat-v0"), gym.make("Acrobot-v1")
    for seed in (0, 7):
        o1, _ = ours.reset(seed=seed)
        o2, _ = ref.reset(seed=seed)
        np.testing.assert_array_equal(o1, o2)
        rng = np.random.default_rng(seed)
        for _ in range(60):  # chaos amplifies round-off later: compare while it is small
            a = int(rng.integers(3))
            s1, s2 = ours.step(a), ref.step(a)
            np.testing.assert_allclose(ours.unwrapped.state, ref.unwrapped.state, atol=1e-9)
            assert s1[1:4] == s2[1:4]


def test_compat_vector_env_equals_gymnasium_sync_vector_of_acrobot():
    ours = gym.make_vec("multipendulum/AcrobotCompat-v0", num_envs=4, max_episode_steps=7)
    ref = gym.make_vec("Acrobot-v1", num_envs=4, vectorization_mode="sync", max_episode_steps=7)
    o1, _ = ours.reset(seed=3)
    o2, _ = ref.reset(seed=3)
    np.testing.assert_array_equal(o1, o2)
    rng = np.random.default_rng(0)
    for _ in range(20):  # past two truncations and their next-step resets
        a = rng.integers(3, size=4)
        r1, r2 = ours.step(a), ref.step(a)
        np.testing.assert_allclose(r1[0], r2[0], atol=1e-6)
        for k in (1, 2, 3):
            np.testing.assert_array_equal(r1[k], r2[k])


def test_compat_refuses_the_nips_dynamics_and_bad_actions():
    env = gym.make("multipendulum/AcrobotCompat-v0").unwrapped
    env.reset(seed=0)
    for bad in (3, -1, 1.5, "1"):
        with pytest.raises(mp.InputError, match="action must be"):
            env.step(bad)
    env.book_or_nips = "nips"
    with pytest.raises(mp.InputError, match="book's dynamics only"):
        env.step(1)


# --- CartPole-v0 against gymnasium's CartPole-v1 -----------------------------------------------

def test_cartpole_accelerations_equal_gymnasium_cartpole_equations_for_a_rod():
    """gymnasium's CartPole-v1 (a uniform rod of length 2 * 0.5, masses 0.1 and 1, g = 9.8; its
    angle from upright, positive clockwise: ours is pi - its), its accelerations recovered from
    one Euler step of its own code."""
    task = envs.CartPole(g=9.8)  # the env's defaults otherwise: gymnasium's parameters
    ref = gym.make("CartPole-v1").unwrapped
    ref.reset(seed=0)
    ref.kinematics_integrator = "euler"
    rng = np.random.default_rng(1)
    for _ in range(300):
        x, v, th, w = rng.uniform(-1, 1, 4) * [2, 3, 3, 6]
        a = int(rng.integers(2))
        ref.state = np.array([x, v, th, w])
        ref.steps_beyond_terminated = None
        ref.step(a)
        xacc, thacc = (ref.state[1] - v) / ref.tau, (ref.state[3] - w) / ref.tau
        force = (1.0 if a == 1 else -1.0) * task.scale[0]  # max_force 10 N = gymnasium's force_mag
        ours = task.chain.accelerations([np.pi - th], [-w], cart_v=v, cart_force=force)
        np.testing.assert_allclose([ours[0], -ours[1]], [xacc, thacc], rtol=1e-12, atol=1e-11)


# --- honest integration ----------------------------------------------------------------------

@pytest.mark.parametrize("env_id,kwargs", [
    (IDS[0], {}), (IDS[0], {"n": 1}), (IDS[0], {"n": 3}), (IDS[0], {"n": 4}), (IDS[0], {"links": "points"}),
    (IDS[1], {}), (IDS[1], {"n": 2}), (IDS[1], {"n": 3}), (IDS[1], {"n": 4}), (IDS[1], {"task": "swingup", "n": 3}),
])
def test_a_1000_step_undriven_episode_keeps_the_energy_balance_to_1e6(env_id, kwargs):
    """The default step (envs.MAX_STEP's rule), from the default start, several seeds."""
    worst = 0.0
    for seed in range(3):
        env = gym.make(env_id, max_episode_steps=None, **kwargs).unwrapped
        env.reset(seed=seed)
        zero = np.zeros(env.action_space.shape)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a balance task falls and ends; it is stepped on
            for _ in range(1000):
                info = env.step(zero)[-1]
                worst = max(worst, info["energy_error"])
    assert worst < 1e-6, worst
    assert info["t"] == pytest.approx(1000 * env.task.dt)


def test_driven_and_damped_episodes_keep_their_energy_balance():
    """The work of the actions and the dissipation are in the balance: a random policy on a
    damped, rubbing chain still closes it, over 300 steps of one episode (the cart-pole's swing-up
    task: balancing, a random policy drops the poles within 20 steps)."""
    for env_id, kwargs in [(IDS[0], {"n": 3, "actuated": "all", "damping": 0.1, "friction": 0.05, "substeps": 40}),
                           (IDS[1], {"n": 2, "damping": 0.02, "cart_damping": 0.3, "task": "swingup"})]:
        env = gym.make(env_id, **kwargs).unwrapped
        env.reset(seed=1)
        env.action_space.seed(1)
        for steps in range(1, 301):
            _, _, terminated, _, info = env.step(env.action_space.sample())
            if terminated:  # (stepping on would only warn: the episode is over)
                break
        assert steps == 300 and info["energy_error"] < 1e-6, (env_id, steps, info)


def test_the_step_is_substeps_of_the_chosen_method():
    """dt and substeps as given: one env step of rk4 equals mp.simulate's rk4 over dt in
    dt / substeps steps."""
    env = gym.make(IDS[0], n=2, dt=0.1, substeps=4, max_torque=0.5).unwrapped
    env.reset(options={"state": [0.3, -0.2, 0.1, 0.4]})
    env.step(np.array([0.6]))
    sol = mp.simulate(env.task.chain, [0.3, -0.2], [0.1, 0.4], t_end=0.1, method="rk4", dt=0.025,
                      joint_torque=[0.0, 0.3])
    # The env's ideal chain steps in SIMD lanes (their own sin/cos): the same steps to round-off.
    assert env.unwrapped._engine._st.route.startswith("lanes:")
    np.testing.assert_allclose(env.state, np.concatenate([sol.theta[-1], sol.omega[-1]]), rtol=0, atol=1e-12)
    gauss = gym.make(IDS[0], method="gauss6").unwrapped
    gauss.reset(seed=0)
    for _ in range(50):
        info = gauss.step(np.zeros(1))[-1]
    assert info["energy_error"] < 1e-10


# --- determinism, the vector env ---------------------------------------------------------------

def test_reset_with_a_seed_is_deterministic():
    env = gym.make(IDS[1], n=2)
    a, _ = env.reset(seed=11)
    b, _ = env.reset(seed=11)
    c, _ = env.reset(seed=12)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def _sync(env_id, num, **kwargs):
    return gym.make_vec(env_id, num_envs=num, vectorization_mode="sync", **kwargs)


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
@pytest.mark.parametrize("env_id,kwargs", [(IDS[0], {"n": 2, "goal": 0.05}), (IDS[1], {"n": 2})])
def test_the_vector_env_equals_gymnasium_sync_vector_env_of_the_single_env(env_id, kwargs, mode):
    """Bit for bit, through terminations, truncations and autoresets of gymnasium's kind."""
    num = 5
    ours = gym.make_vec(env_id, num_envs=num, max_episode_steps=9, autoreset_mode=mode, **kwargs)
    ref = _sync(env_id, num, max_episode_steps=9, vector_kwargs={"autoreset_mode": mode}, **kwargs)
    o1, i1 = ours.reset(seed=2)
    o2, i2 = ref.reset(seed=2)
    np.testing.assert_array_equal(o1, o2)
    np.testing.assert_array_equal(i1["energy_error"], i2["energy_error"])
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(40):
        a = rng.uniform(-1, 1, (num,) + ours.single_action_space.shape)
        r1, r2 = ours.step(a), ref.step(a)
        for k in range(4):
            np.testing.assert_array_equal(r1[k], r2[k])
        np.testing.assert_array_equal(r1[4]["energy_error"], r2[4]["energy_error"])
        if mode == AutoresetMode.SAME_STEP and "final_obs" in r2[4]:
            np.testing.assert_array_equal(r1[4]["_final_obs"], r2[4]["_final_obs"])
            for f1, f2 in zip(r1[4]["final_obs"], r2[4]["final_obs"]):
                assert (f1 is None and f2 is None) or np.array_equal(f1, f2)
        ends += int(np.sum(r1[2] | r1[3]))
    assert ends >= num * 3  # the comparison went through several autoresets


def test_the_vector_env_s_infos_are_read_only_and_keep_their_values():
    """A step's infos are the engine's numbers, shared without copies: writing into one is refused
    (it would change what the renderer draws), and a later step does not change them."""
    envs_ = gym.make_vec(IDS[0], num_envs=4)
    envs_.reset(seed=1)
    info = envs_.step(np.zeros((4, 1)))[4]
    kept = {k: np.array(v) for k, v in info.items()}
    for key in ("t", "_t", "energy", "energy_error"):
        with pytest.raises(ValueError, match="read-only"):
            info[key][0] = 1.0
    later = envs_.step(np.ones((4, 1)))[4]
    assert np.all(later["t"] > info["t"])
    for k, v in kept.items():
        np.testing.assert_array_equal(info[k], v)


def test_the_vector_env_is_the_same_on_any_number_of_threads():
    code = ("import numpy as np, gymnasium as gym, multipendulum.envs\n"
            "v = gym.make_vec('multipendulum/Acrobot-v0', num_envs=64, n=3)\n"
            "v.reset(seed=0); rng = np.random.default_rng(0)\n"
            "for _ in range(30): o = v.step(rng.uniform(-1, 1, (64, 1)))[0]\n"
            "print(o.tobytes().hex())\n")
    outs = {subprocess.run([sys.executable, "-c", code], env={**os.environ, "RAYON_NUM_THREADS": str(t)},
                           capture_output=True, text=True, check=True).stdout for t in (1, 2)}
    assert len(outs) == 1


@pytest.mark.parametrize("env", [
    "'multipendulum/Acrobot-v0', n=3",
    "'multipendulum/Acrobot-v0', n=3, damping=0.1, friction=[0.05, 0.0, 0.1], friction_velocity=0.5",
    "'multipendulum/CartPole-v0', n=2",
    "'multipendulum/CartPole-v0', n=1, cart_damping=0.2, damping=0.05",
], ids=["acrobot", "acrobot with damping and friction", "cart-pole of two", "cart-pole with damping"])
def test_the_lanes_and_the_per_copy_route_agree_to_round_off(env):
    """A chain's copies step in SIMD lanes (every path the same bits), on a fixed pivot or a
    cart, damping and friction included; forced through a stepper per copy
    (MULTIPENDULUM_LANES=scalar) they agree to round-off, and so does the energy balance info
    reports."""
    code = ("import numpy as np, gymnasium as gym, multipendulum.envs\n"
            f"v = gym.make_vec({env}, num_envs=20, max_episode_steps=None)\n"
            "v.reset(seed=0); rng = np.random.default_rng(0)\n"
            "for _ in range(10): o, _, _, _, info = v.step(rng.uniform(-1, 1, (20, 1)))\n"
            "o = np.concatenate([o.ravel(), info['energy_error']])\n"
            "print(v.unwrapped._engine._st.route); print(' '.join(map(repr, o.ravel().tolist())))\n")
    runs = {}
    for route in ("auto", "portable", "scalar"):
        out = subprocess.run([sys.executable, "-c", code], env={**os.environ, "MULTIPENDULUM_LANES": route},
                             capture_output=True, text=True, check=True).stdout.splitlines()
        runs[route] = (out[0], np.array([float(x) for x in out[1].split()]))
    assert runs["scalar"][0] == "each" and runs["portable"][0] == "lanes:portable"
    np.testing.assert_array_equal(runs["auto"][1], runs["portable"][1])  # the same bits on every path
    np.testing.assert_allclose(runs["auto"][1], runs["scalar"][1], rtol=0, atol=1e-11)


def test_disabled_autoreset_needs_a_masked_reset():
    v = gym.make_vec(IDS[0], num_envs=3, max_episode_steps=2, autoreset_mode="Disabled")
    v.reset(seed=0)
    v.step(np.zeros((3, 1)))
    _, _, _, trunc, _ = v.step(np.zeros((3, 1)))
    assert trunc.all()
    with pytest.raises(mp.InputError, match="reset_mask"):
        v.step(np.zeros((3, 1)))
    mask = np.array([True, False, True])
    v.reset(options={"reset_mask": mask})
    with pytest.raises(mp.InputError, match=r"indices \[1\]"):
        v.step(np.zeros((3, 1)))


# --- bad input ---------------------------------------------------------------------------------

def test_unknown_make_keywords_are_input_errors_naming_them():
    with pytest.raises(mp.InputError, match="unknown keyword.*lenghts.*valid keywords: n, lengths"):
        gym.make(IDS[0], lenghts=2.0)
    with pytest.raises(mp.InputError, match="unknown keyword.*masss"):
        gym.make_vec(IDS[1], num_envs=2, masss=1.0)
    with pytest.raises(mp.InputError, match="method must be one of"):
        gym.make(IDS[0], method="euler")
    with pytest.raises(mp.InputError, match="dt must be > 0"):
        gym.make(IDS[1], dt=-0.1)
    with pytest.raises(mp.InputError, match="actuated must name distinct joints 0 to 1"):
        gym.make(IDS[0], actuated=[2])
    with pytest.raises(mp.InputError, match="masses"):
        gym.make(IDS[0], masses=[1.0, -1.0])
    # Limits checked when the environment is made, not in the middle of a step or an allocation.
    with pytest.raises(mp.InputError, match=r"dt = 1e\+09 s would take 7e\+10 integrator steps, more than 1e\+06"):
        gym.make(IDS[0], dt=1e9)
    with pytest.raises(mp.InputError, match="integrator steps, more than"):
        gym.make(IDS[0], substeps=10**7)
    for env_id in IDS:
        with pytest.raises(mp.InputError, match="1000000000 copies of the chain.*use fewer copies"):
            gym.make_vec(env_id, num_envs=10**9)
    with pytest.raises(mp.InputError, match="com and inertia need links='general'"):
        gym.make(IDS[0], com=0.5)
    with pytest.raises(mp.InputError, match="needs com"):
        gym.make(IDS[0], links="general", com=0.5)


def test_general_links_make_gymnasium_s_acrobot_chain():
    """links='general' with Acrobot-v1's parameters (and g = 9.8): the same step as the drop-in."""
    ours = gym.make(IDS[0], links="general", com=0.5, inertia=1.0, g=9.8, dt=0.2, substeps=1,
                    action_type="discrete").unwrapped
    compat = gym.make(IDS[2]).unwrapped
    ours.reset(options={"state": [0.3, 0.1, -1.0, 2.0]})
    compat.reset(seed=0)
    compat.state = np.array([0.3, 0.1 - 0.3, -1.0, 2.0 + 1.0])  # relative angle and rate
    ours.step(2)
    compat.step(2)
    th, om = ours.state[:2], ours.state[2:]
    np.testing.assert_allclose(compat.state, [th[0], th[1] - th[0], om[0], om[1] - om[0]], atol=1e-12)


def test_actions_of_the_wrong_shape_or_nan_are_refused_and_out_of_range_clipped():
    env = gym.make(IDS[0], n=3, actuated="all").unwrapped
    env.reset(seed=0)
    with pytest.raises(mp.InputError, match=r"action must have shape \(3,\), got \(2,\)"):
        env.step(np.zeros(2))
    with pytest.raises(mp.InputError, match="action must be finite, got nan at index \\(1,\\)"):
        env.step(np.array([0.0, np.nan, 0.0]))
    with pytest.raises(mp.InputError, match="numbers"):
        env.step(np.array(["a", "b", "c"]))
    assert np.all(np.isfinite(env.state))  # the refused steps did not move it
    start = {"state": env.state}
    a = env.step(np.array([5.0, -7.0, 0.5]))[0]
    env.reset(options=start)
    b = env.step(np.array([1.0, -1.0, 0.5]))[0]
    np.testing.assert_array_equal(a, b)
    d = gym.make(IDS[0], action_type="discrete").unwrapped
    d.reset(seed=0)
    for bad, shown in ((3, "3"), (-1, "-1"), (0.5, "0.5"), (np.nan, "nan")):
        with pytest.raises(mp.InputError, match=rf"^a discrete action must be 0, 1 or 2, got {shown}$"):
            d.step(bad)  # one number, Discrete(3): no index
    v = gym.make_vec(IDS[1], num_envs=4)
    v.reset(seed=0)
    with pytest.raises(mp.InputError, match=r"action must have shape \(4, 1\)"):
        v.step(np.zeros(3))
    with pytest.raises(mp.InputError, match=r"^action must be finite, got inf at index \(0, 0\)$"):
        v.step(np.full((4, 1), np.inf))
    with pytest.raises(mp.InputError, match=r"^action must be finite, got -inf at index \(2, 0\)$"):
        v.step(np.array([[0.0], [1.0], [-np.inf], [0.0]]))
    vd = gym.make_vec(IDS[0], num_envs=3, action_type="discrete")
    vd.reset(seed=0)
    with pytest.raises(mp.InputError, match=r"^a discrete action must be 0, 1 or 2, got 3 at index \(2,\)$"):
        vd.step(np.array([0, 1, 3]))  # the actions' shape is (3,): copy 2's
    md = gym.make_vec(IDS[0], num_envs=3, n=3, actuated=[0, 2], action_type="discrete")
    md.reset(seed=0)
    with pytest.raises(mp.InputError, match=r"^a discrete action must be 0, 1 or 2, got 7 at index \(1, 1\)$"):
        md.step(np.array([[0, 1], [2, 7], [1, 1]]))


def _outcome_by_hand(task, states):
    """Reward and end of each state row (theta, omega, [x, v]) from the task's documented rules,
    written here with the tip's height from the links' Cartesian ends."""
    n = task.n
    theta = states[:, :n]
    if isinstance(task, envs.tasks.Acrobot):
        ends_y = -np.cumsum(task.chain.lengths * np.cos(theta), axis=1)
        ended = ends_y[:, -1] > task.goal * np.sum(task.chain.lengths)
        return np.where(ended, 0.0, -1.0), ended
    off_track = np.abs(states[:, 2 * n]) > task.x_limit
    if task.task == "balance":
        lean = np.abs(np.angle(np.exp(1j * (theta - np.pi))))
        return np.ones(len(states)), off_track | np.any(lean > task.angle_limit, axis=1)
    return np.mean((1 - np.cos(theta)) / 2, axis=1), off_track


def test_action_spaces_are_the_actions_the_core_takes():
    """Each environment's action space is what its core task takes: one discrete component is
    gymnasium's Discrete(3) (one number a step), more a MultiDiscrete, continuous ones a Box of the
    clipping range; every sample of a space steps, the first value past it is refused."""
    from gymnasium import spaces

    one = gym.make(IDS[0], action_type="discrete").unwrapped
    many = gym.make(IDS[0], n=3, actuated=[0, 2], action_type="discrete").unwrapped
    box = gym.make(IDS[0], n=3, actuated="all").unwrapped
    cart = gym.make(IDS[1], n=2).unwrapped
    assert one.action_space == spaces.Discrete(3)
    assert many.action_space == spaces.MultiDiscrete([3, 3])
    assert box.action_space == spaces.Box(-1.0, 1.0, (3,), dtype=np.float64)
    assert cart.action_space == spaces.Box(-1.0, 1.0, (1,), dtype=np.float64)
    for env in (one, many, box, cart):
        env.reset(seed=0)
        env.action_space.seed(0)
        for _ in range(5):
            env.step(env.action_space.sample())
    with pytest.raises(mp.InputError, match=r"^a discrete action must be 0, 1 or 2, got 3$"):
        one.step(one.action_space.n)
    with pytest.raises(mp.InputError, match=r"^a discrete action must be 0, 1 or 2, got 3 at index \(1,\)$"):
        many.step(many.action_space.nvec - [1, 0])
    v = gym.make_vec(IDS[0], num_envs=4, action_type="discrete")
    assert v.single_action_space == spaces.Discrete(3) and v.action_space == spaces.MultiDiscrete([3] * 4)
    v.close()


@pytest.mark.parametrize("env_id,kwargs", [
    (IDS[0], {"max_torque": 6.0, "goal": 0.2}),
    (IDS[0], {"n": 3, "actuated": [0, 2], "action_type": "discrete", "max_torque": 8.0, "goal": 0.2}),
    (IDS[0], {"actuated": "first", "max_torque": 8.0, "goal": 0.2}),
    (IDS[1], {}), (IDS[1], {"n": 2, "angle_limit": 0.3}), (IDS[1], {"n": 2, "task": "swingup", "x_limit": 0.5}),
])
def test_rewards_and_ends_follow_the_documented_rules_and_actions_their_joints(env_id, kwargs):
    """The vector env's rewards and ends against the rules written out here from its states, and
    each step against the core stepped with the action's inputs written out by hand (clipped,
    scaled, on the actuated joints or the cart), over random actions with episodes ending."""
    num = 16
    v = gym.make_vec(env_id, num_envs=num, max_episode_steps=40, **kwargs)
    task = v.task
    v.reset(seed=3)
    v.action_space.seed(4)
    seen = set()
    for step in range(120):
        before = v._engine.states().copy()
        done_before = v._done.copy()
        a = v.action_space.sample()
        if step % 7 == 0 and not task.discrete:
            a = a * 3.0  # beyond the space: clipped
        obs, reward, terminated, truncated, _ = v.step(a)
        states = v._engine.states()
        want_reward, want_ended = _outcome_by_hand(task, states)
        moved = ~done_before
        np.testing.assert_allclose(reward[moved], want_reward[moved], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(terminated[moved], want_ended[moved])
        assert not reward[done_before].any() and not terminated[done_before].any()  # started anew
        seen.update(bool(x) for x in terminated[moved])
        # The inputs: the same step through Steppers.step with torques and forces by hand.
        rows = before[moved]
        n = task.n
        u = np.asarray(a, dtype=float).reshape(num, -1)[moved]
        level = u - 1.0 if task.discrete else np.clip(u, -1.0, 1.0)
        torques = np.zeros((len(rows), n))
        forces = np.zeros(len(rows) if task.cart else 0)
        if task.cart:
            forces[:] = level[:, 0] * task.max_force
        else:
            torques[:, list(task.joints)] = level * task.scale
        idx = np.flatnonzero(moved)
        ref = mp._core.Steppers(task.chain._c, len(rows), method="rk4", rtol=1e-10, atol=1e-12, max_steps=10**8,
                                    dt=task.dt / task.substeps)
        for r, row in enumerate(rows):
            ref.reset(r, row[:n], row[n:2 * n], (row[2 * n], row[2 * n + 1]) if task.cart else (0.0, 0.0))
        got, _ = ref.step(torques.ravel(), forces, task.dt)
        np.testing.assert_array_equal(got.reshape(len(rows), -1), states[idx])
    assert seen == {True, False}, seen  # episodes ended and went on


def test_stepping_after_termination_warns_once_and_earns_nothing():
    env = gym.make(IDS[1]).unwrapped
    env.reset(seed=0)
    terminated = False
    while not terminated:
        _, _, terminated, _, _ = env.step(np.ones(1))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r1 = env.step(np.ones(1))[1]
        r2 = env.step(np.ones(1))[1]
    assert (r1, r2) == (0.0, 0.0)
    assert sum("after the episode terminated" in str(w.message) for w in caught) == 1
    with pytest.raises(gym.error.ResetNeeded):
        gym.make(IDS[0]).unwrapped.step(np.zeros(1))


def test_rgb_array_frames_show_the_state():
    env = gym.make(IDS[1], n=2, render_mode="rgb_array")
    env.reset(seed=0)
    a = env.render()
    assert a.ndim == 3 and a.shape[2] == 3 and a.shape[0] >= 400 and a.dtype == np.uint8
    env.unwrapped.reset(options={"state": [1.0, 0.5, 2.0, 0.0, 0.0, 0.0]})
    b = env.render()
    assert a.shape == b.shape and np.mean(a != b) > 0.001
    frames = gym.make_vec(IDS[0], num_envs=2, render_mode="rgb_array")
    frames.reset(seed=0)
    assert [f.shape for f in frames.render()] == [a.shape] * 2
