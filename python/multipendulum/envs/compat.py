"""``multipendulum/AcrobotCompat-v0``: a drop-in for gymnasium's ``Acrobot-v1`` whose transitions
are gymnasium's own: its parameters (two links of 1 kg and 1 m, centres of mass at 0.5 m,
moments of inertia 1 about them, g = 9.8), its state ``(theta1, theta2 relative to link 1,
dtheta1, dtheta2)``, one RK4 step of ``dt = 0.2`` s per action, its velocity bounds (4 pi,
9 pi) and angle wrapping, its settable ``unwrapped.state``, observation and reward. The step is
the core's rk4 on the same chain (in absolute angles, which RK4 maps exactly onto gymnasium's
relative ones); the result equals gymnasium's to round-off (tests/test_envs.py: 1e-9).

Like gymnasium's, the class attributes (``dt``, ``LINK_*``, ``MAX_VEL_*``, ``AVAIL_TORQUE``,
``torque_noise_max``) may be changed on ``env.unwrapped``; only the book's dynamics
(``book_or_nips = "book"``, gymnasium's default and the correct equations) are offered."""
from __future__ import annotations

from math import pi
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces
from gymnasium.envs.classic_control import utils
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .._chain import Chain
from ..errors import InputError
from ._engine import Array, Engine, count, refuse_unknown
from ._env import _seeds
from ._render import Renderer

G = 9.8  # gymnasium's Acrobot


class _Acrobot:
    """The parameters and transition shared by the single and the vector drop-in."""

    dt = 0.2
    LINK_LENGTH_1 = 1.0
    LINK_LENGTH_2 = 1.0
    LINK_MASS_1 = 1.0
    LINK_MASS_2 = 1.0
    LINK_COM_POS_1 = 0.5
    LINK_COM_POS_2 = 0.5
    LINK_MOI = 1.0
    MAX_VEL_1 = 4 * pi
    MAX_VEL_2 = 9 * pi
    AVAIL_TORQUE = [-1.0, 0.0, +1]
    torque_noise_max = 0.0
    book_or_nips = "book"
    actions_num = 3
    name = "multipendulum/AcrobotCompat-v0"

    def _setup(self, num: int) -> None:
        self._num = num
        self._key: Optional[Tuple[float, ...]] = None
        self._engine: Optional[Engine] = None
        high = np.array([1.0, 1.0, 1.0, 1.0, self.MAX_VEL_1, self.MAX_VEL_2], dtype=np.float32)
        self._single_obs_space = spaces.Box(low=-high, high=high, dtype=np.float32)

    def _chain_engine(self) -> Engine:
        key = (self.dt, self.LINK_LENGTH_1, self.LINK_LENGTH_2, self.LINK_MASS_1, self.LINK_MASS_2,
               self.LINK_COM_POS_1, self.LINK_COM_POS_2, self.LINK_MOI)
        if key != self._key or self._engine is None:
            if self.book_or_nips != "book":
                raise InputError("AcrobotCompat-v0 offers the book's dynamics only (book_or_nips='book', "
                                 f"gymnasium's default), got {self.book_or_nips!r}")
            chain = Chain([self.LINK_LENGTH_1, self.LINK_LENGTH_2], [self.LINK_MASS_1, self.LINK_MASS_2],
                          com=[self.LINK_COM_POS_1, self.LINK_COM_POS_2], inertia=[self.LINK_MOI, self.LINK_MOI], g=G)
            self._engine = Engine(chain, self._num, float(self.dt), 1, "rk4")
            self._key = key
        if self.book_or_nips != "book":
            raise InputError("AcrobotCompat-v0 offers the book's dynamics only (book_or_nips='book'), "
                             f"got {self.book_or_nips!r}")
        return self._engine

    def _transition(self, states: Array, torques: Array) -> Tuple[Array, Array]:
        """(B, 4) gymnasium states and (B,) torques -> the next states and the steps' residuals."""
        engine = self._chain_engine()
        s = np.asarray(states, dtype=np.float64)
        engine.reset_all(np.stack([s[:, 0], s[:, 0] + s[:, 1]], axis=1), np.stack([s[:, 2], s[:, 2] + s[:, 3]], axis=1))
        joint = np.zeros((len(s), 2))
        joint[:, 1] = torques
        engine.step(joint, None)
        y = engine.states()
        ns = np.stack([y[:, 0], y[:, 1] - y[:, 0], y[:, 2], y[:, 3] - y[:, 2]], axis=1)
        ns[:, 0], ns[:, 1] = _wrap(ns[:, 0]), _wrap(ns[:, 1])
        ns[:, 2] = np.minimum(np.maximum(ns[:, 2], -self.MAX_VEL_1), self.MAX_VEL_1)
        ns[:, 3] = np.minimum(np.maximum(ns[:, 3], -self.MAX_VEL_2), self.MAX_VEL_2)
        return ns, engine.balance()[:, 2]

    def _torque(self, a: Any, rng: np.random.Generator) -> float:
        if isinstance(a, (bool, np.bool_)) or not isinstance(a, (int, np.integer)) \
                and not (isinstance(a, np.ndarray) and a.shape == () and a.dtype.kind in "iu"):
            raise InputError(f"action must be an integer 0, 1 or 2 (Discrete(3)), got {a!r}")
        if not 0 <= int(a) < self.actions_num:
            raise InputError(f"action must be 0, 1 or 2 (Discrete(3)), got {a!r}")
        torque = float(self.AVAIL_TORQUE[int(a)])
        if self.torque_noise_max > 0:
            torque += rng.uniform(-self.torque_noise_max, self.torque_noise_max)
        return torque

    @staticmethod
    def _observe(s: Array) -> npt.NDArray[np.float32]:
        """gymnasium's observations of the states ``s`` (B, 4), float32."""
        return np.stack([np.cos(s[:, 0]), np.sin(s[:, 0]), np.cos(s[:, 1]), np.sin(s[:, 1]), s[:, 2], s[:, 3]],
                        axis=1).astype(np.float32)

    @staticmethod
    def _terminal(s: Array) -> npt.NDArray[np.bool_]:
        """gymnasium's goal of the states ``s`` (B, 4): the tip above one link's length."""
        return -np.cos(s[:, 0]) - np.cos(s[:, 1] + s[:, 0]) > 1.0


def _wrap(x: Array) -> Array:
    """gymnasium's wrap(x, -pi, pi), its loops and its rounding, on an array."""
    x = x.copy()
    diff = 2 * pi
    while np.any(x > pi):
        x = np.where(x > pi, x - diff, x)
    while np.any(x < -pi):
        x = np.where(x < -pi, x + diff, x)
    return x


class AcrobotCompatEnv(_Acrobot, gym.Env[Any, Any]):
    """gymnasium's ``Acrobot-v1``, stepped by the core (see the module)."""

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 15}

    def __init__(self, render_mode: Optional[str] = None, **unknown: Any) -> None:
        refuse_unknown(self.name, unknown, ("render_mode", "max_episode_steps"))
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise InputError(f"render_mode must be one of human, rgb_array or None, got {render_mode!r}")
        self.render_mode = render_mode
        self._setup(1)
        self.observation_space = self._single_obs_space
        self.action_space = spaces.Discrete(3)
        self.state: Optional[Array] = None
        self._residual = 0.0
        self._renderer: Optional[Renderer] = None

    def reset(self, *, seed: Optional[int] = None, options: Optional[Dict[str, Any]] = None) -> Tuple[npt.NDArray[np.float32], Dict[str, Any]]:
        super().reset(seed=seed)
        low, high = utils.maybe_parse_reset_bounds(options, -0.1, 0.1)
        self.state = self.np_random.uniform(low=low, high=high, size=(4,)).astype(np.float32)
        self._residual = 0.0
        if self.render_mode == "human":
            self.render()
        return self._observe(self.state[None])[0], {"energy_error": 0.0}

    def step(self, a: Any) -> Tuple[npt.NDArray[np.float32], float, bool, bool, Dict[str, Any]]:
        if self.state is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        torque = self._torque(a, self.np_random)
        s = np.asarray(self.state, dtype=np.float64).reshape(1, 4)
        if not np.all(np.isfinite(s)):
            raise InputError(f"state must be finite, got {self.state!r}")
        ns, residual = self._transition(s, np.array([torque]))
        self.state = ns[0]
        self._residual = float(residual[0])
        terminated = bool(self._terminal(self.state[None])[0])
        if self.render_mode == "human":
            self.render()
        return self._observe(self.state[None])[0], -1.0 if not terminated else 0.0, terminated, False, {"energy_error": self._residual}

    def render(self) -> Optional[npt.NDArray[np.uint8]]:
        if self.render_mode is None:
            gym.logger.warn("render() without a render_mode: give gym.make(..., render_mode='rgb_array')")
            return None
        if self.state is None:
            raise gym.error.ResetNeeded("call reset() before render()")
        frame = _draw(self, [self.state], [self._residual])[0]
        if self.render_mode == "human":
            assert self._renderer is not None
            self._renderer.show(frame)
            return None
        return frame

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def _draw(env: Any, states: Sequence[Array], residuals: Sequence[float]) -> List[npt.NDArray[np.uint8]]:
    if env._renderer is None:
        task = type("View", (), {"chain": env._chain_engine().chain, "n": 2, "cart": False, "name": env.name})
        env._renderer = Renderer(task, env.metadata["render_fps"])
    frames = []
    for s, r in zip(states, residuals):
        row = np.array([s[0], s[0] + s[1], s[2], s[2] + s[3]], dtype=np.float64)
        frames.append(env._renderer.frame(row, 0.0, r))
    return frames


class AcrobotCompatVectorEnv(_Acrobot, VectorEnv[Any, Any, Any]):
    """``num_envs`` drop-ins in one call into the core, autoreset next-step as gymnasium's
    SyncVectorEnv (sub-environment i seeded ``seed + i``: the same starts as a SyncVectorEnv of
    gymnasium's own Acrobot-v1)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 15, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, max_episode_steps: Optional[int] = 500, render_mode: Optional[str] = None,
                 **unknown: Any) -> None:
        refuse_unknown(self.name, unknown, ("num_envs", "render_mode", "max_episode_steps"))
        self.num_envs = count(num_envs, "num_envs")
        self.max_episode_steps = None if max_episode_steps is None else count(max_episode_steps, "max_episode_steps")
        if render_mode is not None and render_mode != "rgb_array":
            raise InputError(f"render_mode must be rgb_array or None for the vector environment, got {render_mode!r}")
        self.render_mode = render_mode
        self._setup(self.num_envs)
        self._chain_engine()  # first: the core refuses a batch that would not fit before anything is allocated
        self.single_observation_space = self._single_obs_space
        self.single_action_space = spaces.Discrete(3)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._rngs = [seeding.np_random(None)[0] for _ in range(self.num_envs)]
        self.state: Optional[Array] = None
        self._steps = np.zeros(self.num_envs, dtype=np.int64)
        self._done = np.zeros(self.num_envs, dtype=np.bool_)
        self._residual = np.zeros(self.num_envs)
        self._renderer: Optional[Renderer] = None

    def _start(self, i: int, low: float = -0.1, high: float = 0.1) -> None:
        assert self.state is not None
        self.state[i] = self._rngs[i].uniform(low=low, high=high, size=(4,)).astype(np.float32)
        self._steps[i] = 0
        self._residual[i] = 0.0

    def reset(self, *, seed: Union[None, int, Sequence[Optional[int]]] = None,
              options: Optional[Dict[str, Any]] = None) -> Tuple[npt.NDArray[np.float32], Dict[str, Any]]:
        seeds = _seeds(seed, self.num_envs)
        low, high = utils.maybe_parse_reset_bounds(options, -0.1, 0.1)
        first = self.state is None
        if first:
            self.state = np.zeros((self.num_envs, 4))
        for i in range(self.num_envs):
            if seeds[i] is not None or first:
                self._rngs[i] = seeding.np_random(seeds[i])[0]
            self._start(i, low, high)
        self._done[:] = False
        return self._obs(), self._info()

    def _obs(self) -> npt.NDArray[np.float32]:
        assert self.state is not None
        return self._observe(self.state)

    def _info(self) -> Dict[str, Any]:
        return {"energy_error": self._residual.copy(), "_energy_error": np.ones(self.num_envs, dtype=np.bool_)}

    def step(self, actions: Any) -> Tuple[npt.NDArray[np.float32], Array, npt.NDArray[np.bool_], npt.NDArray[np.bool_], Dict[str, Any]]:
        if self.state is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = np.asarray(actions)
        if a.shape != (self.num_envs,):
            raise InputError(f"actions must have shape ({self.num_envs},), got {a.shape}")
        if a.dtype.kind not in "iu" or np.any((a < 0) | (a >= self.actions_num)):
            raise InputError(f"actions must be integers 0, 1 or 2 (Discrete(3)), got {actions!r}")
        restart = self._done.copy()
        torques = np.where(restart, 0.0, np.asarray(self.AVAIL_TORQUE, dtype=float)[a])
        if self.torque_noise_max > 0:  # drawn as gymnasium's env draws it, from each env's generator
            for i in np.flatnonzero(~restart):
                torques[i] += self._rngs[i].uniform(-self.torque_noise_max, self.torque_noise_max)
        ns, residual = self._transition(self.state, torques)
        self.state[~restart] = ns[~restart]
        self._residual[~restart] = residual[~restart]
        for i in np.flatnonzero(restart):
            self._start(int(i))
        self._steps[~restart] += 1
        terminated = ~restart & self._terminal(self.state)
        truncated = (self._steps >= self.max_episode_steps) & ~restart if self.max_episode_steps is not None \
            else np.zeros(self.num_envs, dtype=np.bool_)
        reward = np.where(terminated | restart, 0.0, -1.0)
        self._done = terminated | truncated
        return self._obs(), reward, terminated, truncated, self._info()

    def render(self) -> Optional[Tuple[npt.NDArray[np.uint8], ...]]:
        if self.render_mode is None:
            gym.logger.warn("render() without a render_mode: give gym.make_vec(..., render_mode='rgb_array')")
            return None
        if self.state is None:
            raise gym.error.ResetNeeded("call reset() before render()")
        return tuple(_draw(self, list(self.state), list(self._residual)))
