"""One environment (``gymnasium.Env``) and a vector of them (``gymnasium.vector.VectorEnv``)
over a :mod:`~multipendulum.envs.tasks` task. Both step their chains through the core's
``Steppers`` (one copy, or B copies in one call), so a vector's sub-environment is, bit for bit,
the single environment with the same seed."""
from __future__ import annotations

from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..errors import InputError
from ._engine import Array, Engine, count
from ._render import Renderer
from .tasks import Task

Info = Dict[str, Any]


def _info(balance: Array) -> Info:
    """What each step and reset reports of the integration: the time, the energy and the relative
    residual of the energy balance ``E - E0 - W`` (work of the inputs, dissipation)."""
    return {"t": float(balance[0]), "energy": float(balance[1]), "energy_error": float(balance[2])}


class PendulumEnv(gym.Env[Any, Any]):
    """A single environment over ``task``. See :mod:`multipendulum.envs` for the ids."""

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 30}

    def __init__(self, task: Task, render_mode: Optional[str] = None) -> None:
        self.task = task
        self.action_space = task.single_action_space
        self.observation_space = task.single_observation_space
        self.metadata = {**self.metadata, "render_fps": max(1, round(1 / task.dt))}
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise InputError(f"render_mode must be one of {', '.join(self.metadata['render_modes'])} or None, got {render_mode!r}")
        self.render_mode = render_mode
        self._engine = Engine(task.chain, 1, task.dt, task.substeps, task.method)
        self._states: Optional[Array] = None
        self._terminated = False
        self._warned = False
        self._steps = np.zeros(1, dtype=np.uint64)  # (the TimeLimit wrapper truncates a single environment)
        self._renderer: Optional[Renderer] = None

    @property
    def state(self) -> Array:
        """The current state, ``(theta (N), omega (N))``; with a cart ``(x, theta, v, omega)``."""
        if self._states is None:
            raise gym.error.ResetNeeded("call reset() before reading the state")
        return self.task.public_state(self._states)[0]

    def reset(self, *, seed: Optional[int] = None, options: Optional[Dict[str, Any]] = None) -> Tuple[Array, Info]:
        """``options``: ``{"low": .., "high": ..}`` (the uniform start's bounds), or
        ``{"state": s}``, an exact start in :attr:`state`'s form."""
        super().reset(seed=seed)
        if options is not None and "state" in options:
            theta, omega, cart = self.task.core_state(options["state"])
        else:
            low, high = self.task.reset_bounds(options)
            row = self.task.initial(self.np_random, low, high)
            theta, omega, cart = self._split(row)
        self._engine.reset(0, theta, omega, cart)
        self._states = self._engine.states()
        self._terminated, self._warned = False, False
        obs = self._engine.observe(self.task.columns)[0]
        if self.render_mode == "human":
            self.render()
        return obs, _info(self._engine.balance()[0])

    def _split(self, row: Array) -> Tuple[Array, Array, Tuple[float, float]]:
        n = self.task.n
        cart = (float(row[2 * n]), float(row[2 * n + 1])) if self.task.cart else (0.0, 0.0)
        return row[:n], row[n:2 * n], cart

    def step(self, action: Any) -> Tuple[Array, float, bool, bool, Info]:
        if self._states is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        obs, reward, terminated, _, _ = self._engine.act(self.task.core, self.task.actions(action, ()), False, self._steps)
        self._states = self._engine.states()
        r = float(reward[0])
        if self._terminated:
            # As gymnasium's CartPole: stepping on after the end says so, once, and earns nothing.
            if not self._warned:
                gym.logger.warn("step() called after the episode terminated; call reset() first "
                                "(further steps earn reward 0)")
                self._warned = True
            r = 0.0
        self._terminated = self._terminated or bool(terminated[0])
        if self.render_mode == "human":
            self.render()
        return obs[0], r, bool(terminated[0]), False, _info(self._engine.balance()[0])

    def render(self) -> Optional[npt.NDArray[np.uint8]]:
        if self.render_mode is None:
            gym.logger.warn("render() without a render_mode: give gym.make(..., render_mode='rgb_array')")
            return None
        if self._states is None:
            raise gym.error.ResetNeeded("call reset() before render()")
        if self._renderer is None:
            self._renderer = Renderer(self.task, self.metadata["render_fps"])
        balance = self._engine.balance()[0]
        frame = self._renderer.frame(self._states[0], balance[0], balance[2])
        if self.render_mode == "human":
            self._renderer.show(frame)
            return None
        return frame

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def _seeds(seed: Union[None, int, Sequence[Optional[int]]], num: int) -> List[Optional[int]]:
    """As gymnasium's SyncVectorEnv: None for all, ``seed + i``, or one per environment."""
    if seed is None:
        return [None] * num
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
        return [int(seed) + i for i in range(num)]
    seeds: List[Optional[int]] = list(seed)  # type: ignore[arg-type]
    if len(seeds) != num:
        raise InputError(f"seed must be None, an int or {num} seeds (one per environment), got {len(seeds)}")
    return seeds


class PendulumVectorEnv(VectorEnv[Any, Any, Any]):
    """``num_envs`` environments over one task, stepped in one call into the core (parallel across
    cores, the GIL released). Sub-environment i is seeded as gymnasium's SyncVectorEnv seeds it
    (``seed + i``) and has its own random generator, so it follows the single environment with
    that seed exactly. ``autoreset_mode``: gymnasium's (default next-step)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, task: Task, num_envs: int = 1, max_episode_steps: Optional[int] = None,
                 render_mode: Optional[str] = None,
                 autoreset_mode: Union[str, AutoresetMode] = AutoresetMode.NEXT_STEP) -> None:
        self.task = task
        self.num_envs = count(num_envs, "num_envs")
        # First: the core refuses a batch that would not fit before anything is allocated.
        self._engine = Engine(task.chain, self.num_envs, task.dt, task.substeps, task.method)
        self.max_episode_steps = None if max_episode_steps is None else count(max_episode_steps, "max_episode_steps")
        try:
            mode = AutoresetMode(autoreset_mode)
        except ValueError:
            raise InputError(f"autoreset_mode must be one of {', '.join(m.value for m in AutoresetMode)}, "
                             f"got {autoreset_mode!r}") from None
        self.autoreset_mode = mode
        self.metadata = {**self.metadata, "autoreset_mode": mode, "render_fps": max(1, round(1 / task.dt))}
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise InputError(f"render_mode must be one of {', '.join(self.metadata['render_modes'])} or None, got {render_mode!r}")
        self.render_mode = render_mode
        self.single_action_space = task.single_action_space
        self.single_observation_space = task.single_observation_space
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._rngs: List[np.random.Generator] = [seeding.np_random(None)[0] for _ in range(self.num_envs)]
        self._states: Optional[Array] = None
        self._steps = np.zeros(self.num_envs, dtype=np.uint64)
        self._done = np.zeros(self.num_envs, dtype=np.bool_)
        self._ended = False  # any of _done
        self._none_done = np.zeros(self.num_envs, dtype=np.bool_)
        self._none_done.flags.writeable = False
        self._every = np.ones(self.num_envs, dtype=np.bool_)  # the info keys' masks after a step
        self._every.flags.writeable = False
        self._renderer: Optional[Renderer] = None

    @property
    def state(self) -> Array:
        """(num_envs, ...): each environment's state in the single environment's form."""
        if self._states is None:
            raise gym.error.ResetNeeded("call reset() before reading the state")
        return self.task.public_state(self._states)

    def _start_each(self, which: npt.NDArray[np.intp], options: Optional[Dict[str, Any]]) -> None:
        """Environments ``which`` start anew: from ``options["state"]``'s rows, else each drawn
        by its own generator."""
        task = self.task
        if options is not None and "state" in options:
            states = np.asarray(options["state"])
            for i in which:
                self._engine.reset(int(i), *task.core_state(states[i]))
        elif len(which):
            low, high = task.reset_bounds(options)
            rngs = self._rngs
            self._engine.reset_rows(which, np.stack([task.initial(rngs[i], low, high) for i in which]))
        self._steps[which] = 0

    def reset(self, *, seed: Union[None, int, Sequence[Optional[int]]] = None,
              options: Optional[Dict[str, Any]] = None) -> Tuple[Array, Info]:
        """``options``: as the single environment's, plus gymnasium's ``reset_mask`` (reset only
        these environments, for ``autoreset_mode="Disabled"``); ``"state"`` then has one row per
        environment."""
        seeds = _seeds(seed, self.num_envs)
        options = dict(options) if options is not None else None
        mask = np.ones(self.num_envs, dtype=np.bool_)
        if options is not None and "reset_mask" in options:
            mask = np.asarray(options.pop("reset_mask"))
            if mask.shape != (self.num_envs,) or mask.dtype != np.bool_ or not mask.any():
                raise InputError(f"options['reset_mask'] must be a bool array of shape ({self.num_envs},) "
                                 f"with at least one True, got {mask!r}")
        which = np.flatnonzero(mask)
        for i in which:
            if seeds[i] is not None or self._states is None:
                self._rngs[i] = seeding.np_random(seeds[i])[0]
        self._start_each(which, options)
        self._done = self._done & ~mask
        self._ended = bool(self._done.any())
        self._states = self._engine.states()
        return self._engine.observe(self.task.columns), self._infos(self._engine.balance(), mask)

    def _infos(self, balance: Array, mask: Optional[npt.NDArray[np.bool_]]) -> Info:
        """Each environment's time, energy and residual, where ``mask`` (None: everywhere)."""
        if mask is None:
            columns, mask = balance.T, self._every  # read-only views of the engine's array
            columns.flags.writeable = False
            return {"t": columns[0], "_t": mask, "energy": columns[1], "_energy": mask,
                    "energy_error": columns[2], "_energy_error": mask}
        columns = np.where(mask, balance.T, 0.0)
        return {"t": columns[0], "_t": mask.copy(), "energy": columns[1], "_energy": mask.copy(),
                "energy_error": columns[2], "_energy_error": mask.copy()}

    def step(self, actions: Any) -> Tuple[Array, Array, npt.NDArray[np.bool_], npt.NDArray[np.bool_], Info]:
        if self._states is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = self.task.actions(actions, (self.num_envs,))
        mode = self.autoreset_mode
        if mode == AutoresetMode.DISABLED and self._ended:
            raise InputError("autoreset_mode='Disabled': reset the environments that ended "
                             f"(indices {np.flatnonzero(self._done).tolist()}) with reset(options={{'reset_mask': ...}})")
        # The environments that ended last step start anew instead of stepping (NEXT_STEP); the
        # core gives them reward 0 and no end.
        restart = None
        if mode == AutoresetMode.NEXT_STEP and self._ended:
            restart = self._done
            self._start_each(np.flatnonzero(restart), None)
        obs, reward, terminated, truncated, ended = self._engine.act(
            self.task.core, a, True, self._steps, self.max_episode_steps, None if restart is None else ~restart)
        self._states, balance = self._engine.states(), self._engine.balance()
        info = self._infos(balance, None)
        done = terminated | truncated if ended else self._none_done
        if mode == AutoresetMode.SAME_STEP and ended:
            final_obs = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(done):
                final_obs[i] = obs[i].copy()
            info["final_obs"], info["_final_obs"] = final_obs, done.copy()
            info["final_info"], info["_final_info"] = self._infos(balance, done), done.copy()
            self._start_each(np.flatnonzero(done), None)
            self._states = self._engine.states()
            obs = self._engine.observe(self.task.columns)
            info.update(self._infos(self._engine.balance(), None))
            done, ended = self._none_done, 0
        self._done, self._ended = done, ended > 0
        return obs, reward, terminated, truncated, info

    def render(self) -> Optional[Tuple[npt.NDArray[np.uint8], ...]]:
        if self.render_mode is None:
            gym.logger.warn("render() without a render_mode: give gym.make_vec(..., render_mode='rgb_array')")
            return None
        if self._states is None:
            raise gym.error.ResetNeeded("call reset() before render()")
        if self._renderer is None:
            self._renderer = Renderer(self.task, self.metadata["render_fps"])
        balance = self._engine.balance()
        return tuple(self._renderer.frame(s, b[0], b[2]) for s, b in zip(self._states, balance))

    def close_extras(self, **kwargs: Any) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
