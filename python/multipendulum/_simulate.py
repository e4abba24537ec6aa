"""`simulate`: one run, or a batch run in parallel, of the Rust integrators."""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Dict, List, Optional, Sequence, Tuple, Union, cast

import numpy as np
import numpy.typing as npt

import multipendulum._core as _core
from ._base import ForceLike, Pivot, base_inputs, core_force, core_pivot, force_object, pivot_object
from ._chain import Chain, as_state
from ._convert import Integer, as_float, as_floats
from ._lyapunov import lyapunov, trustworthy_until
from ._progress import Progress, reporter
from ._progress import check as _check_progress
from ._torque import Sinusoid, TorqueLike, core_torque, normalise_torque, torque_object
from .checkpoint import Archive, Writer, cadence, load_checkpoint
from .errors import InputError, IntegrationError

if TYPE_CHECKING:
    from pathlib import Path

    from ._files import PathLike
    from ._notebook import Player

#: The integrators' names, as the core states them: ``"rk4"``, ``"dop853"`` (the default),
#: ``"gauss4"``, ``"gauss6"``; each one's facts are in :data:`METHOD_INFO`.
METHODS = tuple(_core.METHODS)
#: Per method, as the core states it: declared ``order``, ``symplectic``, ``implicit``,
#: ``adaptive``, ``needs_dt`` and the ``forms`` it integrates (the first its default).
METHOD_INFO = {name: dict(info) for name, info in _core.METHOD_INFO.items()}
#: The core's defaults of a run (``rtol``, ``atol``, ``max_steps``, ``method``).
DEFAULTS = dict(_core.DEFAULTS)
#: What :func:`simulate`'s ``sensitivities`` can be taken with respect to, as the core names them.
SENSITIVITIES = tuple(_core.SENSITIVITIES)


@dataclass(frozen=True)
class Flip:
    """Event: link ``link`` (None: any link) goes over the top, ``|theta| = pi``. Terminal by
    default: the run stops there (``sol.stopped_at``)."""

    link: Optional[Integer] = None
    direction: int = 1
    terminal: bool = True

    def _spec(self, n: int) -> _core.Event:
        if self.link is not None and not (isinstance(self.link, (int, np.integer)) and 0 <= self.link < n):
            raise InputError(f"Flip.link must be an integer in [0, {n}) or None, got {self.link!r}")
        return _core.Event.flip(None if self.link is None else int(self.link), direction=_direction(self.direction),
                                terminal=bool(self.terminal))


@dataclass(frozen=True)
class Crossing:
    """Event: ``theta . a + omega . b + constant`` crosses zero (``direction`` +1 upward, -1
    downward, 0 both); recorded, or stopping the run when ``terminal``. ``theta``/``omega``: N
    coefficients (default zeros). E.g. ``Crossing(theta=[1, 0])``: theta_1 passes 0 upward."""

    theta: Optional[npt.ArrayLike] = None
    omega: Optional[npt.ArrayLike] = None
    constant: float = 0.0
    direction: int = 1
    terminal: bool = False

    def _spec(self, n: int) -> _core.Event:
        coef: List[List[float]] = []
        for name, v in (("theta", self.theta), ("omega", self.omega)):
            a = np.zeros(n) if v is None else as_floats(v, f"Crossing.{name}")
            if a.shape != (n,):
                raise InputError(f"Crossing.{name} must have {n} coefficients (one per link), got shape {a.shape}")
            coef.append(a.tolist())
        return _core.Event.linear(coef[0], coef[1], as_float(self.constant, "Crossing.constant"),
                                  direction=_direction(self.direction), terminal=bool(self.terminal))


@dataclass(frozen=True)
class Event:
    """Event: any condition ``g(t, theta, omega) -> float`` crossing zero (``direction`` +1
    upward, -1 downward, 0 both), located by root finding on the dense output; recorded, or
    stopping the run when ``terminal``. Called from Rust at every step's end and while
    root finding, so it is slower than :class:`Flip` / :class:`Crossing`. Single runs only."""

    g: Callable[[float, npt.NDArray[np.float64], npt.NDArray[np.float64]], float]
    direction: int = 1
    terminal: bool = False

    def _spec(self, n: int) -> _core.Event:
        if not callable(self.g):
            raise InputError(f"Event.g must be callable as g(t, theta, omega), got {type(self.g).__name__}")
        return _core.Event.function(self.g, direction=_direction(self.direction), terminal=bool(self.terminal))


def _direction(d: object) -> int:
    if isinstance(d, bool) or not isinstance(d, (int, np.integer)) or d not in (-1, 0, 1):
        raise InputError(f"direction must be -1, 0 or +1, got {d!r}")
    return int(d)


@dataclass(frozen=True)
class EventRecord:
    """The crossings of one event: times (K,), and theta, omega, p (K, N) there."""

    t: npt.NDArray[np.float64]
    theta: npt.NDArray[np.float64]
    omega: npt.NDArray[np.float64]
    p: npt.NDArray[np.float64]


def _records(hits: Sequence[Sequence[Any]], count: int, n: int) -> List[EventRecord]:
    out = []
    for i in range(count):
        mine = [h for h in hits if h[0] == i]
        stack = (lambda k: np.array([h[k] for h in mine]).reshape(len(mine), n))
        out.append(EventRecord(np.array([h[1] for h in mine]), stack(2), stack(3), stack(4)))
    return out


class Work(np.lib.mixins.NDArrayOperatorsMixin):
    """The work done on the chain since t = 0, by source. It behaves as the array of the net
    work ``torque + pivot + cart - dissipated`` (so ``sol.energy - sol.energy[0] - sol.work``
    is the energy balance's residual); its parts are arrays of the same shape:

    - ``torque``: by the torques (generalized or joint);
    - ``pivot``: by a moving pivot (its force on the chain times its velocity);
    - ``cart``: by the force applied to the cart;
    - ``dissipated``: the energy the joints' damping and friction and the cart's damping took
      (never negative, never decreasing).
    """

    def __init__(self, torque: npt.NDArray[np.float64], pivot: npt.NDArray[np.float64],
                 cart: npt.NDArray[np.float64], dissipated: npt.NDArray[np.float64]) -> None:
        self.torque, self.pivot, self.cart, self.dissipated = torque, pivot, cart, dissipated

    @property
    def net(self) -> npt.NDArray[np.float64]:
        """``torque + pivot + cart - dissipated``"""
        return self.torque + self.pivot + self.cart - self.dissipated

    def __array__(self, dtype: Any = None, copy: Any = None) -> npt.NDArray[Any]:
        return self.net if dtype is None else self.net.astype(dtype)

    def __array_ufunc__(self, ufunc: Any, method: str, *inputs: Any, **kwargs: Any) -> Any:
        args = [x.net if isinstance(x, Work) else x for x in inputs]
        return getattr(ufunc, method)(*args, **kwargs)

    def __getitem__(self, key: Any) -> Any:
        return self.net[key]

    def __len__(self) -> int:
        return len(self.torque)

    @property
    def shape(self) -> Tuple[int, ...]:
        return self.torque.shape

    @property
    def ndim(self) -> int:
        return self.torque.ndim

    @property
    def dtype(self) -> np.dtype[Any]:
        return self.torque.dtype

    def __repr__(self) -> str:
        return f"Work(shape={self.shape}, net[-1]={self.net.reshape(-1)[-1] if self.net.size else None})"


@dataclass(frozen=True)
class Stats:
    """Counters of a run (arrays of shape (B,) for a batch run)."""

    steps: Union[int, npt.NDArray[np.int64]]
    rejected: Union[int, npt.NDArray[np.int64]]
    evaluations: Union[int, npt.NDArray[np.int64]]
    iterations: Union[int, npt.NDArray[np.int64]]
    energy_error: Union[float, npt.NDArray[np.float64]]
    wall_time: float

    @classmethod
    def _from(cls, d: Dict[str, Any], batch: bool, wall: float) -> Stats:
        conv = (lambda v: v.astype(np.int64)) if batch else (lambda v: int(v[0]))
        return cls(conv(d["steps"]), conv(d["rejected"]), conv(d["evaluations"]), conv(d["iterations"]),
                   d["energy_error"] if batch else float(d["energy_error"][0]), wall)


class Solution:
    """The result of :func:`simulate`.

    ``t`` (T,); ``theta``, ``omega``, ``p`` (T, N); ``energy``, ``work`` (T,): with a leading
    batch axis B when the initial state had one. ``work`` is the work done by the torque since
    t = 0, so ``energy - energy[0] - work`` is the integrator's energy error.
    """

    # Set by the run that made it: the torque to recompute with (None for a Python function) and
    # its convention, and the run's rtol.
    _torque: Optional[TorqueLike]
    _pivot: Optional[Pivot]
    _cart_force: Optional[ForceLike]
    _joint: bool
    _rtol: float
    _initial: Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]
    _cart0: Tuple[float, float]

    def __init__(self, chain: Chain, method: str, form: str, data: Dict[str, Any], batch_shape: Tuple[int, ...],
                 stats: Stats, n_events: int = 0) -> None:
        self.chain, self.method, self.form, self.stats = chain, method, form, stats
        per_run = [_records(h, n_events, chain.n) for h in data["events"]]
        #: One :class:`EventRecord` per event given (a list of such lists for a batch run).
        self.events: Union[List[EventRecord], List[List[EventRecord]]] = per_run if batch_shape else per_run[0]
        #: The time a terminal event stopped the run, or None (a list for a batch run).
        self.stopped_at: Union[Optional[float], List[Optional[float]]] = (
            data["stopped_at"] if batch_shape else data["stopped_at"][0])
        self.t: npt.NDArray[np.float64] = data["t"]
        T, n = self.t.size, chain.n
        shape = batch_shape + (T,)
        self.theta: npt.NDArray[np.float64] = data["theta"].reshape(shape + (n,))
        self.omega: npt.NDArray[np.float64] = data["omega"].reshape(shape + (n,))
        self.p: npt.NDArray[np.float64] = data["p"].reshape(shape + (n,))
        self.energy: npt.NDArray[np.float64] = data["energy"].reshape(shape)
        zeros = np.zeros(shape)
        part = (lambda k: data[k].reshape(shape) if data[k].size else zeros)
        #: The work done on the chain by source (:class:`Work`; as an array, the net work).
        self.work: Work = Work(data["work"].reshape(shape), part("work_pivot"), part("work_cart"), part("dissipated"))
        cart = data["cart_x"].size > 0
        #: The cart's position and velocity (..., T), or None without a cart.
        self.cart_x: Optional[npt.NDArray[np.float64]] = data["cart_x"].reshape(shape) if cart else None
        self.cart_v: Optional[npt.NDArray[np.float64]] = data["cart_v"].reshape(shape) if cart else None
        #: The pivot's position (..., T, 2): zeros on a fixed pivot; on a cart, (cart_x, 0).
        self.pivot: npt.NDArray[np.float64] = (data["pivot"].reshape(shape + (2,)) if data["pivot"].size
                                               else np.zeros(shape + (2,)))
        if cart:
            self.pivot[..., 0] = self.cart_x
        self._energy_error: npt.NDArray[np.float64] = data["energy_error"].reshape(shape)
        self._positions: Optional[npt.NDArray[np.float64]] = None
        #: The forward sensitivities by input name, each (..., T, S, k) (:func:`simulate`'s
        #: ``sensitivities``); empty when none were asked for.
        self.sensitivities: Dict[str, npt.NDArray[np.float64]] = {}
        #: A Hamiltonian-form run's derivatives of ``(theta, p)`` (and ``(x, p_x)``), laid out
        #: as :attr:`sensitivities` (the Gauss methods always; rk4 and dop853 with
        #: ``form="hamiltonian"``); None in the Lagrangian form.
        self.canonical_sensitivities: Optional[Dict[str, npt.NDArray[np.float64]]] = None

    @property
    def positions(self) -> npt.NDArray[np.float64]:
        """Joint positions (..., T, N, 2) in the lab frame (with the pivot's or the cart's
        displacement), computed by the core on first use."""
        if self._positions is None:
            self._positions = self.chain.positions(self.theta) + self.pivot[..., None, :]
        return self._positions

    @property
    def energy_error(self) -> npt.NDArray[np.float64]:
        """The energy error at each output, as the core defines it once for every report:
        ``|E(t) - E(0) - W(t)| / S(t)`` against the initial state, ``W`` the net work
        (:class:`Work`: torques, pivot and cart force, minus the energy dissipated), with the scale
        ``S = g sum |h_i| + max T`` (the potential well's depth plus the largest kinetic energy so
        far), which never vanishes for a chain under gravity."""
        return self._energy_error

    @property
    def n(self) -> int:
        return self.chain.n

    def trustworthy_until(self, tolerance: float = 1e-2, horizon: float = 100.0) -> Optional[float]:
        """How long this run stays within ``tolerance`` (radians) of the true motion:
        ``ln(tolerance / eps) / lambda_max``, with lambda_max from the variational equations over
        the run (at most ``horizon`` seconds of it) and eps the run's own error level (dop853:
        its rtol; fixed-step methods: the measured energy error). ``inf`` for regular motion;
        None where it cannot be computed (:meth:`trustworthy` says why). An auxiliary estimate:
        it never fails the run it describes."""
        return self.trustworthy(tolerance, horizon)[0]

    #: The most rk4 steps the estimate takes (it shortens its span to stay within them).
    TRUST_STEPS = 200_000
    #: The longest chain whose fastest time scale the estimate measures (a dense eigenvalue solve).
    TRUST_MAX_LINKS = 200

    def trustworthy(self, tolerance: float = 1e-2, horizon: float = 100.0) -> Tuple[Optional[float], str]:
        """:meth:`trustworthy_until` and a sentence on how it was found, or why it could not be.

        The Lyapunov run resolves the chain's fastest motion: its step is a twentieth of the
        shortest time scale of the linearised motion at the initial state (``1 / max |eigenvalue|``
        of :meth:`Chain.jacobian`) and of the fastest sinusoidal drive (torque, pivot or cart
        force: ``1 / frequency``), at most 0.005 s, and it spans at most :attr:`TRUST_STEPS` of
        them (a stiff chain gets a shorter span, said in the sentence)."""
        if self.theta.ndim != 2:
            return None, "not estimated for a batch (estimate one trajectory at a time)"
        if callable(self._torque):
            return None, "not estimated under a torque given as a Python function"
        if self._joint:
            return None, "not estimated under joint-motor torques"
        pivot, cart_force = self._pivot, self._cart_force
        if callable(cart_force):
            return None, "not estimated under a cart force given as a Python function"
        if self.n > self.TRUST_MAX_LINKS:
            return None, f"not estimated for chains of more than {self.TRUST_MAX_LINKS} links"
        span = float(min(self.t[-1], horizon))
        if span <= 0:
            return None, "the run has no time span"
        theta0, omega0 = self._initial
        try:
            rho = float(np.max(np.abs(np.linalg.eigvals(self.chain.jacobian(theta0, omega0)))))
        except (np.linalg.LinAlgError, InputError, IntegrationError) as exc:
            return None, f"the linearisation at the initial state failed ({exc})"
        drives = [self._torque, cart_force] + ([] if pivot is None else [pivot.x, pivot.y])
        rho = max([rho] + [float(np.max(np.abs(d.frequency))) for d in drives if isinstance(d, Sinusoid)])
        dt = min(0.005, span / 20, 0.05 / rho if rho > 0 else 0.005)
        note = ""
        if span / dt > self.TRUST_STEPS:
            span = self.TRUST_STEPS * dt
            note = f", over the first {span:.3g} s (a stiff chain: steps of {dt:.2g} s)"
        try:
            lam = lyapunov(self.chain, theta0, omega0, span, dt=dt, k=1, torque=self._torque, pivot=pivot,
                           cart_x0=self._cart0[0], cart_v0=self._cart0[1], cart_force=cart_force).largest
        except (InputError, IntegrationError) as exc:
            return None, f"the Lyapunov run for the estimate failed ({exc})"
        eps = self._rtol if self.method == "dop853" else max(float(self.stats.energy_error), 1e-16)
        if eps >= tolerance:
            return 0.0, f"the run's own error level {eps:.2g} is already beyond the tolerance {tolerance:g}"
        # Below ~0.05/s over this span the separation is not exponential: regular motion.
        until = trustworthy_until(lam if lam > 0.05 else 0.0, tolerance, eps)
        return until, f"largest Lyapunov exponent {lam:.3g}/s{note}"

    def show(self, **options: Any) -> Player:
        """Play this run in a notebook cell, drawn by the browser viewer's code, without encoding
        a video: :func:`multipendulum.show` (its ``options``: ``fps``, ``speed``, ``playing``,
        ``loop``, ``height``). Needs anywidget (``pip install 'multipendulum[widget]'``)."""
        from ._notebook import show  # on use only: anywidget and ipywidgets are slow to import

        return show(self, **options)

    def __repr__(self) -> str:
        return (f"Solution(method={self.method!r}, n={self.n}, outputs={self.t.size}, "
                f"theta shape={self.theta.shape}, steps={self.stats.steps}, "
                f"energy_error={self.stats.energy_error})")


def simulate(chain: Chain, theta0: npt.ArrayLike, omega0: npt.ArrayLike, t_end: float, method: str = DEFAULTS["method"],
             dt: Optional[float] = None, rtol: float = DEFAULTS["rtol"], atol: float = DEFAULTS["atol"],
             torque: Optional[TorqueLike] = None, joint_torque: Optional[TorqueLike] = None,
             t_eval: Optional[npt.ArrayLike] = None, form: Optional[str] = None, adaptive: bool = True,
             max_steps: Integer = int(DEFAULTS["max_steps"]), progress: Progress = None,
             events: Optional[Sequence[Union[Flip, Crossing, Event]]] = None, checkpoint: Optional[PathLike] = None,
             checkpoint_every: Optional[Integer] = None, checkpoint_seconds: Optional[float] = None,
             checkpoint_info: Optional[Dict[str, Any]] = None, pivot: Optional[Pivot] = None,
             cart_x0: float = 0.0, cart_v0: float = 0.0, cart_force: Optional[ForceLike] = None,
             sensitivities: Optional[Sequence[str]] = None) -> Solution:
    """Integrate ``chain`` from ``(theta0, omega0)`` at t = 0 to ``t_end`` (seconds).

    Methods (:data:`METHODS`): ``"rk4"`` classical Runge–Kutta, order 4, fixed ``dt``;
    ``"dop853"`` Dormand–Prince 8(5,3), order 8, adaptive to ``rtol``/``atol`` (``dt`` is then
    the first step; ``adaptive=False`` makes it fixed); ``"gauss4"`` / ``"gauss6"`` implicit
    Gauss–Legendre, order 4 / 6, symplectic, fixed ``dt``, on Hamilton's equations.
    ``form``: ``"lagrangian"`` (theta, omega) or ``"hamiltonian"`` (theta, p) for rk4/dop853.

    ``torque`` (generalized, conjugate to the absolute angles) or ``joint_torque`` (joint motors):
    an array (N,), :class:`Sinusoid`, :class:`Table`, or a callable ``f(t)`` or
    ``f(t, theta, omega)`` returning N values.

    ``t_eval``: output times in [0, t_end] (ascending); default: every step. dop853 interpolates
    with its 7th-order dense output; the fixed-step methods return step values exactly where
    ``t_eval`` falls on the step grid and cubic Hermite interpolation elsewhere.

    A leading batch axis on ``theta0``/``omega0`` (B, N) runs the B trajectories in parallel on
    all cores (GIL released); a Python torque function runs them one after another. An rk4 or
    dop853 batch (Lagrangian form; a pivot fixed, or moving by sinusoids or tables, or a cart
    without a cart force; no events or sensitivities; damping, friction and built-in torques
    included) runs in SIMD lanes, eight trajectories at a time, several times faster: rk4 in
    agreement with the trajectories' own runs to round-off, dop853 (each trajectory with its own
    steps) to its tolerance; a trajectory's bits depend neither on the batch it is in nor on the
    number of threads. ``MULTIPENDULUM_LANES=scalar`` runs such a batch trajectory by trajectory.
    ``progress``: True for a bar on stderr (tqdm's when installed), or a callable given the
    fraction done about ten times a second (:mod:`multipendulum._progress`). Ctrl-C stops any
    run within a fraction of a second (``KeyboardInterrupt``; a checkpointed run writes a last
    checkpoint first).
    ``events``: :class:`Flip` / :class:`Crossing` / :class:`Event` conditions, located by root finding on the
    dense output; ``sol.events[i]`` holds event i's crossings, ``sol.stopped_at`` the time a
    terminal one ended the run.

    ``pivot``: a :class:`Pivot` moving the chain's pivot along a prescribed path (its
    acceleration acts on the angles; the energy is the lab frame's and ``sol.work.pivot`` the
    pivot's work). On a chain with a :class:`Cart`: ``cart_x0``, ``cart_v0`` its initial
    position and velocity, ``cart_force`` the horizontal force on it (a number,
    :class:`Sinusoid`/:class:`Table` of one value, or a feedback ``f(t, state)`` with
    ``state = (x, theta_1..theta_N, v, omega_1..omega_N)``); ``sol.cart_x``, ``sol.cart_v``.
    With damping or friction the energy error is the residual of the energy balance
    ``E(t) - E(0) - W_torque - W_pivot - W_cart + D`` (:class:`Work`).

    ``checkpoint``: a file to which the run's complete state is written every
    ``checkpoint_every`` steps and/or every ``checkpoint_seconds`` of wall time (default: every
    60 s), and once more when the run is interrupted (Ctrl-C); :func:`resume` continues from it
    and returns bit-for-bit the arrays this call would have. Atomic: the file is always a
    complete archive. ``checkpoint_info``: a JSON-ready dict kept in it (the CLI keeps the
    scenario). Not with a batch, a Python torque function or events (refused). See
    :mod:`multipendulum.checkpoint`.

    ``sensitivities``: names of :data:`SENSITIVITIES` (any subset: ``"theta0"``, ``"omega0"``,
    ``"lengths"``, ``"masses"``, ``"com"``, ``"inertia"``, ``"g"``, ``"damping"``,
    ``"friction"``): ``sol.sensitivities[name]``, shape (..., T, S, k), is the derivative of the
    state ``(theta, omega)`` (S = 2N; with a cart ``(theta, omega, x, v)``, S = 2N + 2) at each
    output time with respect to the k entries of that input (k = N; 1 for ``g``), each of the
    chain's parameters moved alone (a point-mass chain's ``com`` does not follow its
    ``lengths``: see :func:`fit`). They come from the variational equations integrated by the
    run's own method, O(N) per direction: for rk4 and the Gauss methods they are the exact
    derivatives of the computed trajectory; dop853 controls the error of the state only (its
    steps do not depend on the sensitivities). A Hamiltonian-form run (the Gauss methods
    always) also gives ``sol.canonical_sensitivities``, the derivatives of ``(theta, p)``: for
    the Gauss methods their map of the initial ``(theta, p)`` is symplectic. Torques must depend on time only (an array,
    :class:`Sinusoid`, :class:`Table` or ``f(t)``); not with checkpoints. See
    :doc:`sensitivities`.

    Raises :class:`InputError` for bad input, :class:`IntegrationError` (with ``.t``) when the
    run cannot continue; a torque function's own exception passes through.

    >>> import multipendulum as mp
    >>> chain = mp.Chain(lengths=[1, 1], masses=[1, 1])
    >>> sol = mp.simulate(chain, [2.0, 2.5], [0, 0], t_end=5.0)
    >>> bool(sol.stats.energy_error < 1e-9)
    True
    """
    if not isinstance(chain, Chain):
        raise InputError(f"chain must be a multipendulum.Chain, got {type(chain).__name__}")
    th0 = as_state(theta0, "theta0", chain.n)
    om0 = as_state(omega0, "omega0", chain.n)
    if th0.shape != om0.shape:
        raise InputError(f"theta0 and omega0 must have the same shape, got {th0.shape} and {om0.shape}")
    if th0.ndim > 2:
        raise InputError(f"theta0 must have shape ({chain.n},) or (B, {chain.n}), got {th0.shape}")
    batch_shape = th0.shape[:-1]
    if not isinstance(method, str) or method not in METHODS:
        got = f'"{method}"' if isinstance(method, str) else repr(method)
        raise InputError(f"method must be one of {', '.join(METHODS)}, got {got}")
    t_end = as_float(t_end, "t_end")
    dt = None if dt is None else as_float(dt, "dt")
    rtol, atol = as_float(rtol, "rtol", finite=True), as_float(atol, "atol", finite=True)
    if t_eval is not None:
        t_eval = as_floats(t_eval, "t_eval").ravel()
    if form not in (None, "lagrangian", "hamiltonian"):
        got = f'"{form}"' if isinstance(form, str) else repr(form)
        raise InputError(f'form must be "lagrangian" or "hamiltonian", got {got}')
    if not isinstance(adaptive, (bool, np.bool_)):
        raise InputError(f"adaptive must be True or False, got {adaptive!r}")
    _check_progress(progress)
    if not isinstance(max_steps, (int, np.integer)) or not 0 < max_steps < 2**64:
        raise InputError(f"max_steps must be a positive integer below 2^64, got {max_steps!r}")
    spec, joint = normalise_torque(torque, joint_torque, chain.n)
    if events is not None and not isinstance(events, (list, tuple)):
        raise InputError(f"events must be a list of mp.Flip, mp.Crossing or mp.Event, got {type(events).__name__}")
    events = list(events or [])
    for e in events:
        if not isinstance(e, (Flip, Crossing, Event)):
            raise InputError(f"events must be mp.Flip, mp.Crossing or mp.Event objects, got {type(e).__name__}")
        if isinstance(e, Event) and batch_shape:
            raise InputError("a Python event function (mp.Event) runs in single runs only; "
                             "use mp.Flip or mp.Crossing for batches")
        if e.terminal and batch_shape:
            raise InputError(f"a terminal event ({type(e).__name__}(terminal=True), mp.Flip's default) would stop "
                             "each trajectory of a batch at its own time, which the batch's arrays cannot hold: "
                             "give terminal=False (the crossings are still recorded) or run the trajectories one by one")
    event_specs = [e._spec(chain.n) for e in events]
    pivot_spec, force_spec, cart0 = base_inputs(chain.cart is not None, pivot, cart_x0, cart_v0, cart_force)
    run: Dict[str, Any] = dict(method=method, form=form, t_end=t_end, dt=dt, rtol=rtol, atol=atol,
                               adaptive=bool(adaptive), max_steps=int(max_steps), torque=spec, joint=joint,
                               has_t_eval=t_eval is not None)
    # Only runs with a drive record it (checkpoints of other runs stay as they were).
    if pivot_spec is not None:
        run["pivot"] = pivot_spec
    if force_spec is not None:
        run["cart_force"] = force_spec
    if cart0 != (0.0, 0.0):
        run["cart0"] = list(cart0)
    writer = None
    if checkpoint is not None:
        if batch_shape:
            raise InputError(f"checkpoints are for single runs; theta0 has a batch axis, shape {th0.shape}")
        if spec is not None and spec[0] == "callable":
            raise InputError("checkpoints need a built-in torque (an array, mp.Sinusoid, mp.Table): "
                             "a Python torque function cannot be saved")
        if events:
            raise InputError("checkpoints cannot be combined with events (the event tracker's state is not saved)")
        if (force_spec is not None and force_spec[0] == "function") or (
                pivot_spec is not None and any(a[0] == "function" for a in pivot_spec)):
            raise InputError("checkpoints need a built-in pivot motion and cart force (numbers, mp.Sinusoid, "
                             "mp.Table): a Python function cannot be saved")
        if not isinstance(checkpoint, (str, os.PathLike)):
            raise InputError(f"checkpoint must be a file path, got {type(checkpoint).__name__}")
        every_steps, every_seconds = cadence(checkpoint_every, checkpoint_seconds)
        writer = Writer(checkpoint, chain, th0, om0, t_eval, run, every_steps, every_seconds, info=checkpoint_info)
    elif checkpoint_every is not None or checkpoint_seconds is not None:
        raise InputError("checkpoint_every / checkpoint_seconds need checkpoint=FILE")
    names = _sensitivity_names(sensitivities)
    if names and writer is not None:
        raise InputError("checkpoints cannot be combined with sensitivities (resume the run without them)")
    sol = _run(chain, th0, om0, run, t_eval, progress, event_specs, writer, batch_shape=batch_shape,
               sensitivities=names)
    sol._torque = joint_torque if joint else torque
    sol._pivot, sol._cart_force = pivot, cart_force
    return sol


def _sensitivity_names(sensitivities: Optional[Sequence[str]]) -> List[str]:
    """The names of ``sensitivities`` as a list (the core checks each one)."""
    if sensitivities is None:
        return []
    if isinstance(sensitivities, str):
        sensitivities = (sensitivities,)
    if not isinstance(sensitivities, (list, tuple)) or not all(isinstance(s, str) for s in sensitivities):
        raise InputError(f"sensitivities must be a list of names from {', '.join(SENSITIVITIES)}, "
                         f"got {sensitivities!r}")
    return list(sensitivities)


def _split_sensitivities(flat: npt.NDArray[np.float64], names: Sequence[str], sizes: Sequence[int], states: int,
                         shape: Tuple[int, ...]) -> Dict[str, npt.NDArray[np.float64]]:
    """The core's (..., T, S, K) derivatives split by input (``sizes``: each one's directions, as
    the core counts them), in the order asked."""
    whole = flat.reshape(shape + (states, sum(sizes)))
    out, start = {}, 0
    for name, k in zip(names, sizes):
        out[name] = whole[..., start:start + k]
        start += k
    return out


def _refuse_nan(data: Dict[str, Any]) -> None:
    """A last guard against a silent NaN: a run that blew up between its checks (e.g. dop853's
    dense output over a step whose rates overflow) fails as an IntegrationError at that time."""
    for name in ("theta", "omega", "p", "energy"):
        bad = np.isnan(data[name])
        if bad.any():
            t = data["t"]
            per_row = max(1, data[name].size // max(1, data["energy"].size))  # N, or 1 for energy
            row = int(np.argmax(bad)) // per_row  # rows run (B, T) in order
            when = float(t[row % t.size]) if t.size else 0.0
            err = IntegrationError(f"integration failed at t = {when}: {name} became NaN (the motion blew up; "
                                   "reduce dt or the tolerances, or start from smaller rates)")
            err.t = when
            raise err


def _run(chain: Chain, th0: npt.NDArray[Any], om0: npt.NDArray[Any], run: Dict[str, Any],
         t_eval: Optional[npt.NDArray[Any]], progress: Progress,
         event_specs: Sequence[_core.Event] = (), writer: Optional[Writer] = None, resume: Optional[bytes] = None,
         wall_before: float = 0.0, batch_shape: Tuple[int, ...] = (),
         sensitivities: Sequence[str] = ()) -> Solution:
    """Call the core with checked arguments (``run``: as stored in a checkpoint archive)."""
    spec = run["torque"]
    spec = None if spec is None else tuple(spec)
    ckpt = None if writer is None else (writer.every_steps or 0, writer.every_seconds, writer)
    start = time.perf_counter()
    with reporter(progress, "simulate") as report:
        data = _core.simulate(chain._c, np.ascontiguousarray(th0, dtype=np.float64).ravel(),
                              np.ascontiguousarray(om0, dtype=np.float64).ravel(), run["t_end"], method=run["method"],
                              form=run["form"], dt=run["dt"], rtol=run["rtol"], atol=run["atol"],
                              adaptive=run["adaptive"], t_eval=t_eval, max_steps=run["max_steps"],
                              torque=core_torque(spec, run["joint"]), progress=report, events=list(event_specs),
                              checkpoint=ckpt, resume=resume, pivot=core_pivot(run.get("pivot")),
                              cart_force=core_force(run.get("cart_force")),
                              cart0=tuple(run.get("cart0", (0.0, 0.0))),
                              sensitivities=list(sensitivities) or None, batch=bool(batch_shape))
    wall = wall_before + time.perf_counter() - start
    _refuse_nan(data)
    stats = Stats._from(data["stats"], bool(batch_shape), wall)
    sol = Solution(chain, run["method"], data["form"], data, batch_shape, stats, len(event_specs))
    sol._joint, sol._rtol = run["joint"], run["rtol"]
    if sensitivities:
        shape, states = batch_shape + (sol.t.size,), 2 * chain.n + (2 if chain.cart is not None else 0)
        sizes = data["sensitivity_sizes"]
        sol.sensitivities = _split_sensitivities(data["sensitivities"], sensitivities, sizes, states, shape)
        if data["canonical"].size:
            sol.canonical_sensitivities = _split_sensitivities(data["canonical"], sensitivities, sizes, states, shape)
    sol._initial = (np.asarray(th0, dtype=np.float64), np.asarray(om0, dtype=np.float64))
    x0, v0 = run.get("cart0", (0.0, 0.0))
    sol._cart0 = (float(x0), float(v0))
    if spec is not None and spec[0] != "callable":
        sol._torque = torque_object(spec, chain.n)
    else:
        sol._torque = None
    sol._pivot, sol._cart_force = pivot_object(run.get("pivot")), force_object(run.get("cart_force"))
    return sol


def resume(path: Union[PathLike, Archive], progress: Progress = None,
           checkpoint: bool = True, any_version: bool = False) -> Solution:
    """Continue the run saved in the checkpoint archive ``path`` to its ``t_end`` and return its
    :class:`~multipendulum.Solution`: all of it from t = 0, bit-for-bit the arrays the
    uninterrupted run would have returned. ``checkpoint`` (default True): keep writing
    checkpoints to the same archive at the same cadence. ``progress`` as for
    :func:`~multipendulum.simulate`. Raises :class:`InputError` for a damaged archive or one of
    another version (see :func:`load_checkpoint`).

    >>> import multipendulum as mp, tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "run.ckpt")
    >>> chain = mp.Chain(lengths=[1, 1], masses=[1, 1])
    >>> full = mp.simulate(chain, [2.0, 2.5], [0, 0], t_end=1.0, method="gauss6", dt=0.01,
    ...                    checkpoint=path, checkpoint_every=40)
    >>> again = mp.resume(path)      # from the last checkpoint, step 80, to t_end
    >>> bool((again.theta == full.theta).all())
    True
    """
    archive = path if isinstance(path, Archive) else load_checkpoint(path, any_version=any_version)
    meta, a = archive.metadata, archive.arrays
    run = meta["run"]
    chain = archive.chain()
    t_eval = a["t_eval"] if run["has_t_eval"] else None
    every = meta["checkpoint"]
    writer = None
    if checkpoint:
        # An Archive from load_checkpoint always has its path (one built by hand may not).
        writer = Writer(cast("Path", archive.path), chain, a["theta0"], a["omega0"], t_eval, run, every["every_steps"],
                        every["every_seconds"], info=meta.get("info"), wall_before=float(meta.get("wall_time", 0.0)))
    return _run(chain, a["theta0"], a["omega0"], run, t_eval, progress, writer=writer, resume=archive.state(),
                wall_before=float(meta.get("wall_time", 0.0)))
