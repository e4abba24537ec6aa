"""The environments' engine: B copies of one chain in the core (``_core.Steppers``), stepped in
one call with the actions held over each step (parallel across cores, the GIL released), and
the checks of the keywords every environment shares. No physics here: the chain, its
integration and its energy balance are the core's."""
from __future__ import annotations

import math
from typing import Any, Dict, Mapping, Optional, Sequence, Tuple

import numpy as np
import numpy.typing as npt

import multipendulum._core as _core
from .._chain import Cart, Chain
from .._convert import as_float, as_floats
from .._simulate import DEFAULTS, METHOD_INFO
from ..errors import InputError

#: The largest integrator step of an environment unless ``substeps`` is given (1/70 s): each env
#: step of ``dt`` takes ``ceil(dt / h)`` steps of the method, ``h = min(MAX_STEP, 0.01 (k /
#: N)**2.5)`` for N links, ``k = 3`` for a start hanging down and ``k = 1`` for a start upright (a
#: chain that falls from the top moves fastest); chains of fewer than ``k`` links take
#: ``MAX_STEP``. With rk4 this keeps the relative energy-balance residual of a 1000-step undriven
#: episode from the default start below 1e-6 (measured in tests/test_envs.py for every
#: environment, N = 1 to 4; the closest, 4e-7, is the three-link acrobot's).
MAX_STEP = 1 / 70

#: The most integrator steps one env step may take: beyond it a single call into the core would
#: run for minutes without a way to stop it (an env step of ``dt`` far beyond the chain's time
#: scale is a mistake).
MAX_SUBSTEPS = 10**6

Array = npt.NDArray[np.float64]


def refuse_unknown(env: str, unknown: Mapping[str, Any], valid: Sequence[str]) -> None:
    """``gym.make`` keywords the environment does not take: an InputError naming them."""
    if unknown:
        names = ", ".join(sorted(unknown))
        raise InputError(f"{env} got unknown keyword(s) {names}; valid keywords: {', '.join(valid)}")


def positive(x: object, name: str) -> float:
    v = as_float(x, name, finite=True)
    if not v > 0:
        raise InputError(f"{name} must be > 0, got {v:g}")
    return v


def count(x: object, name: str, lowest: int = 1) -> int:
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)) or int(x) < lowest:
        raise InputError(f"{name} must be an integer >= {lowest}, got {x!r}")
    return int(x)


def per_link(x: object, name: str, n: int) -> Array:
    a = as_floats(x, name)
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.shape != (n,):
        raise InputError(f"{name} must be a number or have {n} entries (one per link), got shape {a.shape}")
    return a


def build_chain(n: int, lengths: object, masses: object, links: str, g: Optional[float], damping: object,
                friction: object, friction_velocity: Optional[float], cart: Optional[Cart] = None,
                com: object = None, inertia: object = None) -> Chain:
    """The environment's chain; None keywords take :class:`~multipendulum.Chain`'s defaults.
    ``links``: ``"rods"``, ``"points"``, or ``"general"`` with ``com`` and ``inertia``."""
    extra: Dict[str, Any] = {"damping": damping, "friction": friction, "cart": cart}
    if g is not None:
        extra["g"] = g
    if friction_velocity is not None:
        extra["friction_velocity"] = friction_velocity
    lengths_a, masses_a = per_link(lengths, "lengths", n), per_link(masses, "masses", n)
    if (com is not None or inertia is not None) and links != "general":
        raise InputError(f"com and inertia need links='general', got links={links!r}")
    if links == "rods":
        return Chain.rods(lengths_a, masses_a, **extra)
    if links == "points":
        return Chain(lengths_a, masses_a, **extra)
    if links == "general":
        if com is None or inertia is None:
            raise InputError("links='general' needs com (each centre of mass from its joint) and inertia (about it)")
        return Chain(lengths_a, masses_a, com=per_link(com, "com", n), inertia=per_link(inertia, "inertia", n), **extra)
    raise InputError(f"links must be 'rods', 'points' or 'general', got {links!r}")


def default_step(n: int, upright: bool) -> float:
    """The integrator's step unless ``substeps`` is given (see :data:`MAX_STEP`)."""
    return min(MAX_STEP, 0.01 * ((1 if upright else 3) / n) ** 2.5)


def stepping(dt: object, substeps: object, method: object, n: int, upright: bool) -> Tuple[float, int, str]:
    """-> (dt, substeps, method), checked. ``substeps`` None: ``ceil(dt / default_step)``."""
    dt_ = positive(dt, "dt")
    if not isinstance(method, str) or method not in METHOD_INFO:
        raise InputError(f"method must be one of {', '.join(METHOD_INFO)}, got {method!r}")
    if substeps is None:
        sub = max(1, math.ceil(dt_ / default_step(n, upright) * (1 - 1e-12)))
    else:
        sub = count(substeps, "substeps")
    if sub > MAX_SUBSTEPS:
        raise InputError(f"an env step of dt = {dt_:g} s would take {sub:.3g} integrator steps, more than "
                         f"{MAX_SUBSTEPS:.0e}; use a smaller dt or fewer substeps")
    return dt_, sub, method


class Engine:
    """B copies of ``chain`` in the core. States are rows ``(theta (N), omega (N), [x, v])``."""

    def __init__(self, chain: Chain, num: int, dt: float, substeps: int, method: str) -> None:
        self.chain, self.n, self.num, self.dt = chain, chain.n, num, dt
        self.cart = chain.cart is not None
        fixed = not METHOD_INFO[method]["adaptive"]
        self._st = _core.Steppers(chain._c, num, method=method, rtol=DEFAULTS["rtol"], atol=DEFAULTS["atol"],
                                  max_steps=int(DEFAULTS["max_steps"]), dt=dt / substeps if fixed else None)
        self._no_force = np.zeros(0)
        self._states: Optional[Array] = None
        self._balance: Optional[Array] = None

    def reset(self, i: int, theta: Array, omega: Array, cart: Tuple[float, float] = (0.0, 0.0)) -> None:
        self._st.reset(int(i), np.ascontiguousarray(theta, dtype=float), np.ascontiguousarray(omega, dtype=float),
                       (float(cart[0]), float(cart[1])))
        self._states = self._balance = None

    def reset_rows(self, which: npt.NDArray[np.intp], rows: Array) -> None:
        """Copies ``which`` anew from state rows ``(theta, omega, [x, v])``, one per copy."""
        self._st.reset_rows(np.ascontiguousarray(which, dtype=np.int64), np.ascontiguousarray(rows, dtype=float).ravel())
        self._states = self._balance = None

    def reset_all(self, theta: Array, omega: Array) -> None:
        """Every copy anew from the rows of ``theta``, ``omega`` (B, N), on a fixed pivot."""
        self._st.reset_all(np.ascontiguousarray(theta, dtype=float).ravel(), np.ascontiguousarray(omega, dtype=float).ravel())
        self._states = self._balance = None

    def step(self, torques: Array, forces: Optional[Array], active: Optional[npt.NDArray[np.bool_]] = None) -> None:
        """Hold joint torques (B, N) and cart forces (B,) over one env step of every active copy."""
        f = self._no_force if forces is None else np.ascontiguousarray(forces, dtype=float).ravel()
        act = None if active is None or bool(np.all(active)) else np.ascontiguousarray(active, dtype=bool)
        states, balance = self._st.step(np.ascontiguousarray(torques, dtype=float).ravel(), f, self.dt, act)
        self._states, self._balance = states.reshape(self.num, -1), balance.reshape(self.num, 3)

    def act(self, task: _core.Task, actions: Array, batched: bool, steps: npt.NDArray[np.uint64],
            limit: Optional[int] = None, active: Optional[npt.NDArray[np.bool_]] = None
            ) -> Tuple[Array, Array, npt.NDArray[np.bool_], npt.NDArray[np.bool_], int]:
        """One env step of every active copy under the core's ``task``: flat float64 ``actions``
        (B x the task's width) -> observations (B, k), rewards (B,), ends (B,), truncations (B,)
        at ``limit`` steps of ``steps`` (each copy's count in its episode, advanced in place),
        and how many copies ended. A copy not ``active`` earns 0 and does not end."""
        self._states, self._balance, obs, reward, ended, truncated, count = self._st.act(
            task, actions, self.dt, batched, steps, limit, active)
        return obs, reward, ended, truncated, count

    def _report(self) -> Tuple[Array, Array]:
        """The states and balances of the last step, or (after a reset) the core's report of both."""
        if self._states is None or self._balance is None:
            states, balance = self._st.report()
            self._states, self._balance = states.reshape(self.num, -1), balance.reshape(self.num, 3)
        return self._states, self._balance

    def states(self) -> Array:
        """(B, k): each copy's ``(theta, omega, [x, v])`` (the arrays are the engine's: copy to keep)."""
        return self._report()[0]

    def observe(self, columns: npt.NDArray[np.int64]) -> Array:
        """(B, len(columns) // 2): each copy's observation from its state (``Task.columns``)."""
        return self._st.observe(self.states().reshape(-1), columns).reshape(self.num, -1)

    def balance(self) -> Array:
        """(B, 3): time, energy (lab frame) and the energy-balance residual of each copy."""
        return self._report()[1]
