"""What each environment asks of its chain: the action space and how actions become joint
torques or a cart force, the observation, the reward and the end of an episode, and the start.
The task's keywords are checked here and made into the core's ``Task`` (:attr:`Task.core`),
which turns a batch of actions into inputs and computes the observations, rewards and ends in
the same call as the step, so one environment and a vector of them share the same arithmetic.
Angles are the package's: absolute, from the downward vertical,
counter-clockwise positive (upright is ``theta = pi``)."""
from __future__ import annotations

import math
from typing import Any, Dict, Optional, Sequence, Tuple

import numpy as np
import numpy.typing as npt
from gymnasium import spaces
from gymnasium.envs.classic_control import utils

import multipendulum._core as _core

from .._chain import Cart, Chain
from ..errors import InputError
from ._engine import Array, build_chain, count, per_link, positive, refuse_unknown, stepping

#: Kinds of observation column (``Task.columns``): a state row's value, its cosine, its sine.
VALUE, COS, SIN = 0, 1, 2


def _columns(*groups: Sequence[Tuple[int, int]]) -> npt.NDArray[np.int64]:
    return np.array([c for g in groups for c in g], dtype=np.int64).ravel()


def _numbers(action: object, what: str) -> np.ndarray:
    try:
        a = np.asarray(action)
    except (TypeError, ValueError) as e:
        raise InputError(f"{what} must be an array of numbers, got {action!r}: {e}") from None
    if a.dtype.kind not in "biuf":
        raise InputError(f"{what} must be numbers, got dtype {a.dtype} ({action!r})")
    return a


def action_space(core: _core.Task) -> spaces.Space[Any]:
    """One copy's action space, of the shape and values the core's task takes: ``Discrete`` for
    one discrete component, ``MultiDiscrete`` for more, else a ``Box`` of the clipping range."""
    shape, levels = tuple(core.action_shape), core.action_levels
    if levels is not None:
        return spaces.Discrete(levels) if shape == () else spaces.MultiDiscrete([levels] * shape[0])
    low, high = core.action_bounds
    return spaces.Box(low, high, shape, dtype=np.float64)


class Task:
    """The common part: a chain, its stepping, and the batched action check."""

    name = ""
    chain: Chain
    dt: float
    substeps: int
    method: str
    single_action_space: spaces.Space[Any]
    single_observation_space: spaces.Box
    low: float
    high: float

    def __init__(self) -> None:
        self.n = 0
        self.discrete = False
        self.scale: Array = np.zeros(0)

    @property
    def cart(self) -> bool:
        return self.chain.cart is not None

    def actions(self, actions: object, batch: Tuple[int, ...]) -> Array:
        """Actions of the action space's shape (``batch`` + one action's) as the flat float64
        array the core's :attr:`core` takes; their values are the core's to check (continuous:
        clipped to [-1, 1], as gymnasium's Pendulum and MountainCarContinuous do, NaN and inf
        refused; discrete: 0, 1 or 2)."""
        shape = batch + tuple(self.single_action_space.shape or ())
        a = actions if type(actions) is np.ndarray else _numbers(actions, "action")
        if a.dtype.kind not in "biuf":
            raise InputError(f"action must be numbers, got dtype {a.dtype} ({actions!r})")
        if a.shape != shape:
            if not self.discrete and a.size == int(np.prod(shape)) and batch == () and a.ndim <= 1:
                a = a.reshape(shape)  # a bare number for a one-value action
            else:
                raise InputError(f"action must have shape {shape}, got {a.shape}")
        return np.ascontiguousarray(a, dtype=np.float64).reshape(-1)

    def reset_bounds(self, options: Optional[Dict[str, Any]]) -> Tuple[float, float]:
        """``options={"low": .., "high": ..}`` as gymnasium's classic-control environments take."""
        low, high = utils.maybe_parse_reset_bounds(options, self.low, self.high)
        return float(low), float(high)

    # -- each task's own --------------------------------------------------------------------
    #: The actions' inputs, the observation, the reward and the end, as the core applies them
    #: around each step (``Steppers.act``): made by each task from its keywords.
    core: _core.Task

    def initial(self, rng: np.random.Generator, low: float, high: float) -> Array:
        """One start, a core state row ``(theta, omega, [x, v])``."""
        raise NotImplementedError

    #: The observation's columns, computed by the core from a state row (``Engine.observe``):
    #: flat pairs ``(kind, index)``, kind :data:`VALUE`, :data:`COS` or :data:`SIN` of the row's
    #: entry ``index``.
    columns: npt.NDArray[np.int64]

    def public_state(self, states: Array) -> Array:
        """The state as the environment shows it (``env.state``)."""
        return states.copy()

    def core_state(self, state: object) -> Tuple[Array, Array, Tuple[float, float]]:
        """``env.state``'s form -> (theta, omega, (x, v)), checked."""
        n = self.n
        s = _numbers(state, "state").astype(np.float64).ravel()
        want = 2 * n + 2 * self.cart
        if s.size != want or not np.all(np.isfinite(s)):
            raise InputError(f"state must be {want} finite numbers, got {state!r}")
        return s[:n], s[n:2 * n], (0.0, 0.0)


def _joint_set(actuated: object, n: int) -> Tuple[int, ...]:
    if isinstance(actuated, str):
        named = {"last": (n - 1,), "first": (0,), "all": tuple(range(n))}
        if actuated not in named:
            raise InputError(f"actuated must be 'last', 'first', 'all' or joint indices (0 to {n - 1}), got {actuated!r}")
        return named[actuated]
    try:
        joints = tuple(int(j) for j in actuated)  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        raise InputError(f"actuated must be 'last', 'first', 'all' or joint indices (0 to {n - 1}), got {actuated!r}") from None
    if not joints or len(set(joints)) != len(joints) or any(not 0 <= j < n for j in joints):
        raise InputError(f"actuated must name distinct joints 0 to {n - 1}, got {actuated!r}")
    return tuple(sorted(joints))


class Acrobot(Task):
    """An N-link chain hanging from a fixed pivot, motors on some joints, swung up.

    Observation: ``(cos theta_1..N, sin theta_1..N, omega_1..N)``. Reward -1 per step, 0 on the
    step that ends the episode (gymnasium's Acrobot): terminated when the tip rises above the
    pivot by ``goal`` times the chain's length (0.5: Acrobot's "one link above the pivot")."""

    name = "multipendulum/Acrobot-v0"
    KEYWORDS = ("n", "lengths", "masses", "links", "com", "inertia", "g", "damping", "friction", "friction_velocity",
                "actuated",
                "action_type", "max_torque", "dt", "substeps", "method", "goal", "low", "high")

    def __init__(self, n: int = 2, lengths: object = 1.0, masses: object = 1.0, links: str = "rods",
                 com: object = None, inertia: object = None, g: Optional[float] = None, damping: object = None, friction: object = None,
                 friction_velocity: Optional[float] = None, actuated: object = "last",
                 action_type: str = "continuous", max_torque: object = 1.0, dt: float = 0.2,
                 substeps: Optional[int] = None, method: str = "rk4", goal: float = 0.5,
                 low: float = -0.1, high: float = 0.1, **unknown: Any) -> None:
        super().__init__()
        refuse_unknown(self.name, unknown, self.KEYWORDS + ("render_mode", "max_episode_steps"))
        self.n = count(n, "n")
        self.chain = build_chain(self.n, lengths, masses, links, g, damping, friction, friction_velocity,
                                 com=com, inertia=inertia)
        self.dt, self.substeps, self.method = stepping(dt, substeps, method, self.n, upright=False)
        self.joints = _joint_set(actuated, self.n)
        k = len(self.joints)
        self.scale = per_link(max_torque, "max_torque", k)
        if np.any(self.scale <= 0) or not np.all(np.isfinite(self.scale)):
            raise InputError(f"max_torque must be > 0 and finite, got {max_torque!r}")
        if action_type not in ("continuous", "discrete"):
            raise InputError(f"action_type must be 'continuous' or 'discrete', got {action_type!r}")
        self.discrete = action_type == "discrete"
        self.goal = as_fraction(goal)
        self.low, self.high = float(low), float(high)
        self.reach = float(np.sum(self.chain.lengths))
        n_ = self.n
        hi = np.concatenate([np.ones(2 * n_), np.full(n_, np.inf)])
        self.single_observation_space = spaces.Box(-hi, hi, dtype=np.float64)
        a = range(n_)
        self.columns = _columns([(COS, i) for i in a], [(SIN, i) for i in a], [(VALUE, n_ + i) for i in a])
        self.core = _core.Task(self.chain._c, discrete=self.discrete, targets=list(self.joints), scale=self.scale.tolist(),
                               columns=self.columns, goal="height", above=self.goal * self.reach)
        self.single_action_space = action_space(self.core)

    def initial(self, rng: np.random.Generator, low: float, high: float) -> Array:
        return rng.uniform(low=low, high=high, size=(2 * self.n,))


def as_fraction(goal: object) -> float:
    v = positive(goal, "goal")
    if v > 1:
        raise InputError(f"goal must be in (0, 1] (a fraction of the chain's length), got {v:g}")
    return v


class CartPole(Task):
    """N poles in a chain on a cart; a horizontal force on the cart.

    Observation: ``(x, cos theta_1..N, sin theta_1..N, v, omega_1..N)``; the state
    (``env.state``) is ``(x, theta_1..N, v, omega_1..N)``, the order of
    :meth:`multipendulum.Chain.jacobian` and :func:`multipendulum.modes.linearize`.

    ``task="balance"``: start within ``+-0.05`` of upright (every value), reward +1 per step
    (gymnasium's CartPole-v1), terminated when a pole leans more than ``angle_limit`` from
    upright or the cart leaves ``|x| <= x_limit``. ``task="swingup"``: start hanging
    (``+-0.05``), reward ``mean_i (1 - cos theta_i) / 2`` per step (1 upright, 0 hanging),
    terminated only when the cart leaves the track."""

    name = "multipendulum/CartPole-v0"
    KEYWORDS = ("n", "lengths", "masses", "links", "com", "inertia", "cart_mass", "cart_damping", "g", "damping", "friction",
                "friction_velocity", "max_force", "dt", "substeps", "method", "task", "x_limit", "angle_limit",
                "low", "high")

    def __init__(self, n: int = 1, lengths: object = 1.0, masses: object = 0.1, links: str = "rods",
                 com: object = None, inertia: object = None, cart_mass: float = 1.0, cart_damping: float = 0.0, g: Optional[float] = None,
                 damping: object = None, friction: object = None, friction_velocity: Optional[float] = None,
                 max_force: float = 10.0, dt: float = 0.02, substeps: Optional[int] = None, method: str = "rk4",
                 task: str = "balance", x_limit: float = 2.4, angle_limit: float = 12 * math.pi / 180,
                 low: float = -0.05, high: float = 0.05, **unknown: Any) -> None:
        super().__init__()
        refuse_unknown(self.name, unknown, self.KEYWORDS + ("render_mode", "max_episode_steps"))
        self.n = count(n, "n")
        cart = Cart(cart_mass, damping=cart_damping)
        self.chain = build_chain(self.n, lengths, masses, links, g, damping, friction, friction_velocity, cart,
                                 com=com, inertia=inertia)
        if task not in ("balance", "swingup"):
            raise InputError(f"task must be 'balance' or 'swingup', got {task!r}")
        self.task = task
        self.dt, self.substeps, self.method = stepping(dt, substeps, method, self.n, upright=task == "balance")
        self.max_force = positive(max_force, "max_force")
        self.scale = np.array([self.max_force])
        self.x_limit = positive(x_limit, "x_limit")
        self.angle_limit = positive(angle_limit, "angle_limit")
        self.low, self.high = float(low), float(high)
        n_ = self.n
        hi = np.concatenate([[np.inf], np.ones(2 * n_), np.full(n_ + 1, np.inf)])
        self.single_observation_space = spaces.Box(-hi, hi, dtype=np.float64)
        a = range(n_)
        self.columns = _columns([(VALUE, 2 * n_)], [(COS, i) for i in a], [(SIN, i) for i in a],
                                [(VALUE, 2 * n_ + 1)], [(VALUE, n_ + i) for i in a])
        limits = {"x_limit": self.x_limit} if task == "swingup" else {"x_limit": self.x_limit, "angle_limit": self.angle_limit}
        self.core = _core.Task(self.chain._c, discrete=False, targets=[None], scale=[self.max_force], columns=self.columns,
                               goal="balance" if task == "balance" else "swingup", **limits)
        self.single_action_space = action_space(self.core)

    def initial(self, rng: np.random.Generator, low: float, high: float) -> Array:
        n = self.n
        s = rng.uniform(low=low, high=high, size=(2 * n + 2,))  # (x, theta, v, omega)
        if self.task == "balance":
            s[1:n + 1] += np.pi
        return np.concatenate([s[1:n + 1], s[n + 2:], [s[0], s[n + 1]]])

    def public_state(self, states: Array) -> Array:
        n = self.n
        return np.concatenate([states[:, 2 * n:2 * n + 1], states[:, :n], states[:, 2 * n + 1:], states[:, n:2 * n]], axis=1)

    def core_state(self, state: object) -> Tuple[Array, Array, Tuple[float, float]]:
        n = self.n
        s = _numbers(state, "state").astype(np.float64).ravel()
        if s.size != 2 * n + 2 or not np.all(np.isfinite(s)):
            raise InputError(f"state must be {2 * n + 2} finite numbers (x, theta (N), v, omega (N)), got {state!r}")
        return s[1:n + 1], s[n + 2:], (float(s[0]), float(s[n + 1]))


TASKS: Dict[str, Any] = {"acrobot": Acrobot, "cartpole": CartPole}
__all__: Sequence[str] = ["Task", "Acrobot", "CartPole", "TASKS"]
