"""Chaos tools: Lyapunov exponents, first-flip times and flip-time maps. The computation runs in
the Rust core, in parallel and without the GIL; this module validates and shapes."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, List, Optional, Sequence, Tuple, Union, cast

import numpy as np
import numpy.typing as npt

import multipendulum._core as _core
from ._base import Pivot, core_pivot, normalise_pivot
from ._chain import Chain, as_state, check_chain
from ._convert import Integer, as_float, as_floats
from ._progress import Progress, reporter
from ._progress import check as _check_progress
from ._torque import TorqueLike, core_torque, normalise_torque
from ._indicators import CHAOS_RULES, INDICATORS, IndicatorResult, certified_indicator, fli, gali, indicator, megno, sali
from ._zero_one import ZeroOneResult, zero_one_test
from ._lyapunov import LyapunovResult, _link, lyapunov, trustworthy_until
from ._simulate import DEFAULTS, Crossing, EventRecord, Flip, simulate
from .errors import InputError

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure, SubFigure
    from zarr import Array as ZarrArray

    from ._files import PathLike

#: ``(kind_x, link_x, kind_y, link_y)``: the two initial values a flip map varies, each
#: ``"theta"`` or ``"omega"`` of a link.
Vary = Tuple[str, Integer, str, Integer]

__all__ = ["ZeroOneResult", "zero_one_test", "INDICATORS", "CHAOS_RULES", "IndicatorResult", "indicator", "certified_indicator", "megno", "fli", "sali", "gali", "IndicatorMap",
           "indicator_map", "EnsembleResult", "ensemble", "PoincareSection", "poincare", "plot_poincare", "LyapunovResult", "lyapunov", "trustworthy_until", "flip_energy_threshold", "flip_times", "certified_flip_times", "flip_map", "FlipMap",
           "flip_volume", "FlipVolume"]


def flip_energy_threshold(chain: Chain, link: Optional[Integer] = None) -> float:
    """The least energy (J) with which link ``link`` (None: any link) can go over the top:
    ``g h_k - g sum_{i != k} |h_i|``. A chain released with less can never flip it."""
    check_chain(chain)
    return _core.flip_energy_threshold(chain._c, _link(link, chain.n))


def flip_times(chain: Chain, theta0: npt.ArrayLike, omega0: Optional[npt.ArrayLike] = None, t_max: float = 10.0,
               dt: float = 0.01, link: Optional[Integer] = None,
               torque: Optional[TorqueLike] = None, progress: Progress = None, *,
               pivot: Optional[Pivot] = None) -> npt.NDArray[np.float64]:
    """First time each initial state's link ``link`` (None: any link) reaches |theta| = pi,
    by rk4 at step ``dt`` and root finding within the step; ``inf`` where it never does by
    ``t_max``. ``theta0`` (..., N); ``omega0`` defaults to rest. ``pivot``: a :class:`Pivot`
    whose motion drives the chain (in the SIMD lanes as the fixed pivot's chain; an axis given
    as a Python function runs trajectory by trajectory). Parallel on all cores; ``progress`` as
    for :func:`lyapunov`, and Ctrl-C stops the work.

    >>> import multipendulum as mp
    >>> shaken = mp.Pivot(x=mp.Sinusoid(amplitude=0.1, frequency=6.0))
    >>> t = mp.flip_times(mp.Chain([1.0], [1.0]), [[2.5], [0.5]], t_max=10.0, pivot=shaken)
    >>> bool(t[0] < t[1])  # the higher start goes over first
    True
    """
    check_chain(chain)
    th0 = as_state(theta0, "theta0", chain.n)
    om0 = np.zeros_like(th0) if omega0 is None else as_state(omega0, "omega0", chain.n)
    if th0.shape != om0.shape:
        raise InputError(f"theta0 and omega0 must have the same shape, got {th0.shape} and {om0.shape}")
    spec, _ = normalise_torque(torque, None, chain.n)
    with reporter(progress, "flip times") as report:
        out = _core.first_flips(chain._c, th0.ravel(), om0.ravel(), as_float(t_max, "t_max"), dt=as_float(dt, "dt"),
                                link=_link(link, chain.n), torque=core_torque(spec, False),
                                pivot=core_pivot(normalise_pivot(pivot)), progress=report)
    return out.reshape(th0.shape[:-1])


@dataclass(frozen=True)
class FlipMap:
    """First-flip times ``times[i, j]`` for the initial values ``x[j]`` (of the first varied
    quantity) and ``y[i]``; ``inf`` never flipped by ``t_max``. ``allowed[i, j]`` is False where
    the energy bound forbids any flip."""

    x: npt.NDArray[np.float64]
    y: npt.NDArray[np.float64]
    #: NumPy arrays, or the on-disk Zarr arrays of a map written to a store (:func:`sweep_flip_map`).
    times: Union[npt.NDArray[np.float64], ZarrArray]
    allowed: Union[npt.NDArray[np.bool_], ZarrArray]
    t_max: float
    threshold: float
    #: A certified map's (``certify=True``): True where the flip decision, or the time by more
    #: than ``time_tolerance``, changed when the step was halved; None for a map not certified.
    uncertain: Union[None, npt.NDArray[np.bool_], ZarrArray] = None
    #: The time tolerance (s) a certified map was judged with; None for a map not certified.
    time_tolerance: Optional[float] = None


def certified_flip_times(chain: Chain, theta0: npt.ArrayLike, omega0: Optional[npt.ArrayLike] = None,
                         t_max: float = 10.0, dt: float = 0.01, link: Optional[Integer] = None,
                         torque: Optional[TorqueLike] = None, time_tolerance: Optional[float] = None,
                         progress: Progress = None, *,
                         pivot: Optional[Pivot] = None) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_], float]:
    """:func:`flip_times` at ``dt`` and again at ``dt / 2``: ``(times, uncertain, tolerance)``,
    the times at ``dt`` and, per initial state, whether it is uncertain: the two runs disagree on
    whether it flips by ``t_max``, or on when by more than ``time_tolerance`` (s; default one step
    ``dt``), the tolerance used. Costs three times :func:`flip_times`."""
    check_chain(chain)
    th0 = as_state(theta0, "theta0", chain.n)
    om0 = np.zeros_like(th0) if omega0 is None else as_state(omega0, "omega0", chain.n)
    if th0.shape != om0.shape:
        raise InputError(f"theta0 and omega0 must have the same shape, got {th0.shape} and {om0.shape}")
    spec, _ = normalise_torque(torque, None, chain.n)
    tolerance = None if time_tolerance is None else as_float(time_tolerance, "time_tolerance")
    with reporter(progress, "certified flip times") as report:
        times, uncertain, used = _core.certified_flips(
            chain._c, th0.ravel(), om0.ravel(), as_float(t_max, "t_max"), dt=as_float(dt, "dt"),
            link=_link(link, chain.n), torque=core_torque(spec, False), pivot=core_pivot(normalise_pivot(pivot)),
            tolerance=tolerance, progress=report)
    return times.reshape(th0.shape[:-1]), uncertain.reshape(th0.shape[:-1]), used


def flip_threshold(chain: Chain, link: Optional[Integer], torque: Optional[TorqueLike],
                   pivot: Optional[Pivot] = None) -> float:
    """The energy bound a map marks: none (-inf) for a driven chain, which can gain energy (under
    a torque, or on a pivot that moves: any axis not a number)."""
    moving = pivot is not None and not all(isinstance(a, (int, float)) for a in (pivot.x, pivot.y))
    return flip_energy_threshold(chain, link) if torque is None and not moving else -np.inf


def _check_vary(vary: Vary, n: int) -> Tuple[str, int, str, int]:
    return cast("Tuple[str, int, str, int]", _check_varied(vary, n, 2))


def _check_varied(vary: Sequence[Any], n: int, dims: int) -> Tuple[Any, ...]:
    """``vary`` as ``dims`` (kind, link) pairs, checked: x's first."""
    axes = "xyz"[:dims]
    shape = ", ".join(f"kind_{a}, link_{a}" for a in axes)
    try:
        pairs = [(vary[2 * d], vary[2 * d + 1]) for d in range(dims)]
        if len(vary) != 2 * dims:
            raise ValueError
    except (TypeError, ValueError, IndexError, KeyError):
        raise InputError(f"vary must be ({shape}), got {vary!r}") from None
    times = {2: "twice", 3: "three times"}[dims]
    for kind, idx in pairs:
        if kind not in ("theta", "omega") or isinstance(idx, bool) or not isinstance(idx, (int, np.integer)) \
                or not 0 <= idx < n:
            raise InputError(f"vary must name ('theta'|'omega', link index < {n}) {times}, got {vary!r}")
    if len(set((k, int(i)) for k, i in pairs)) != dims:
        words = {2: "two", 3: "three"}[dims]
        raise InputError(f"vary must name {words} different quantities, got {vary!r}")
    return tuple(v for kind, idx in pairs for v in (kind, int(idx)))


def _grid(yb: npt.NDArray[np.float64], xb: npt.NDArray[np.float64], vary: Tuple[str, int, str, int],
          th_base: npt.NDArray[np.float64],
          om_base: npt.NDArray[np.float64]) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    # The initial states of a map's grid (values copied, never computed); also per Dask chunk.
    return _grid_of((yb, xb), vary[2:] + vary[:2], th_base, om_base)


def _grid_of(values: Sequence[npt.NDArray[np.float64]], vary: Sequence[Any], th_base: npt.NDArray[np.float64],
             om_base: npt.NDArray[np.float64]) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The initial states of a grid whose axes, outermost first, take ``values[d]`` for the
    quantity ``(vary[2 d], vary[2 d + 1])``: shape ``(len(values[0]), ..., N)``."""
    mesh = np.meshgrid(*values, indexing="ij")
    n = th_base.size
    theta0 = np.broadcast_to(th_base, mesh[0].shape + (n,)).copy()
    omega0 = np.broadcast_to(om_base, mesh[0].shape + (n,)).copy()
    for d, grid in enumerate(mesh):
        kind, idx = vary[2 * d], vary[2 * d + 1]
        (theta0 if kind == "theta" else omega0)[..., idx] = grid
    return theta0, omega0


def flip_map(chain: Chain, x: npt.ArrayLike, y: npt.ArrayLike, t_max: float = 10.0, dt: float = 0.01,
             vary: Vary = ("theta", 0, "theta", 1), base_theta: Optional[npt.ArrayLike] = None,
             base_omega: Optional[npt.ArrayLike] = None, link: Optional[Integer] = None,
             torque: Optional[TorqueLike] = None, certify: bool = False, time_tolerance: Optional[float] = None,
             progress: Progress = None, *, pivot: Optional[Pivot] = None) -> FlipMap:
    """Flip-time map over a grid of two initial values (radians or rad/s).

    ``vary=(kind_x, index_x, kind_y, index_y)`` names the two varied quantities, each ``"theta"``
    or ``"omega"`` of a link (default: theta_1 along x, theta_2 along y, from rest). The rest of
    the initial state is ``base_theta`` / ``base_omega`` (default 0). Under a ``torque``, or on a
    moving ``pivot`` (:func:`flip_times`), the chain can gain energy, so no cell is marked
    impossible (``threshold = -inf``). ``progress`` as for :func:`lyapunov`.

    ``certify=True`` computes every cell again at ``dt / 2`` (as :func:`certified_flip_times`)
    and fills ``uncertain``: the cells whose flip decision, or time by more than
    ``time_tolerance`` (s; default one step ``dt``), depends on the step. The times are still
    those at ``dt``.
    """
    check_chain(chain)
    _check_progress(progress)
    x, y = _grid_axes(x=x, y=y)
    n = chain.n
    # The grid's initial states (2N), times, energies and flags per cell, before they are made.
    _core.check_memory(float(x.size) * y.size * (2 * n + 3) * 8.0, f"a flip map of {y.size} x {x.size} cells",
                       "use fewer points in x and y, or mp.sweep_flip_map, which works chunk by chunk")
    th_base = np.zeros(n) if base_theta is None else as_state(base_theta, "base_theta", n)
    om_base = np.zeros(n) if base_omega is None else as_state(base_omega, "base_omega", n)
    vary = _check_vary(vary, n)
    theta0, omega0 = _grid(y, x, vary, th_base, om_base)
    uncertain, tolerance = None, None
    if check_certify(certify, time_tolerance):
        times, uncertain, tolerance = certified_flip_times(chain, theta0, omega0, t_max=t_max, dt=dt, link=link,
                                                           torque=torque, time_tolerance=time_tolerance,
                                                           progress=progress, pivot=pivot)
    else:
        times = flip_times(chain, theta0, omega0, t_max=t_max, dt=dt, link=link, torque=torque, progress=progress,
                           pivot=pivot)
    threshold = flip_threshold(chain, link, torque, pivot)
    allowed = cast("npt.NDArray[np.bool_]", chain.energy(theta0, omega0) >= threshold)  # theta0 has a grid's axes
    return FlipMap(x, y, times, allowed, float(t_max), threshold, uncertain, tolerance)


#: Three varied quantities of a 3-D map: ``(kind_x, link_x, kind_y, link_y, kind_z, link_z)``.
Vary3 = Tuple[str, Integer, str, Integer, str, Integer]


@dataclass(frozen=True)
class FlipVolume:
    """A 3-D flip-time map: ``times[k, i, j]`` for the initial values ``x[j]``, ``y[i]`` and
    ``z[k]`` of the three varied quantities (``vary``); the rest as :class:`FlipMap`, whose
    slices it holds (:meth:`slice`)."""

    x: npt.NDArray[np.float64]
    y: npt.NDArray[np.float64]
    z: npt.NDArray[np.float64]
    #: NumPy arrays, or the on-disk Zarr arrays of a map written to a store (:func:`sweep_flip_volume`).
    times: Union[npt.NDArray[np.float64], ZarrArray]
    allowed: Union[npt.NDArray[np.bool_], ZarrArray]
    t_max: float
    threshold: float
    vary: Tuple[str, int, str, int, str, int]
    uncertain: Union[None, npt.NDArray[np.bool_], ZarrArray] = None
    time_tolerance: Optional[float] = None

    def slice(self, k: Integer) -> FlipMap:
        """The 2-D map at ``z[k]`` (read from the store for a Zarr volume)."""
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not -self.z.size <= k < self.z.size:
            raise InputError(f"k must be an index of z (length {self.z.size}), got {k!r}")
        k = int(k)
        return FlipMap(self.x, self.y, np.asarray(self.times[k]), np.asarray(self.allowed[k]), self.t_max,
                       self.threshold, None if self.uncertain is None else np.asarray(self.uncertain[k]),
                       self.time_tolerance)


def _grid_axes(**axes: npt.ArrayLike) -> List[npt.NDArray[np.float64]]:
    """A grid's axes (name: values), each checked a non-empty array of finite numbers."""
    out = []
    for name, v in axes.items():
        arr = as_floats(v, name).ravel()
        if arr.size == 0 or not np.isfinite(arr).all():
            raise InputError(f"{name} must be a non-empty array of finite numbers")
        out.append(arr)
    return out


def flip_volume(chain: Chain, x: npt.ArrayLike, y: npt.ArrayLike, z: npt.ArrayLike, t_max: float = 10.0,
                dt: float = 0.01, vary: Vary3 = ("theta", 0, "theta", 1, "theta", 2),
                base_theta: Optional[npt.ArrayLike] = None, base_omega: Optional[npt.ArrayLike] = None,
                link: Optional[Integer] = None, torque: Optional[TorqueLike] = None, certify: bool = False,
                time_tolerance: Optional[float] = None, progress: Progress = None, *,
                pivot: Optional[Pivot] = None) -> FlipVolume:
    """A flip-time map over a grid of three initial values (default the triple pendulum's three
    angles): :func:`flip_map` with a third axis ``z``, ``times`` of shape ``(len(z), len(y),
    len(x))``. Held in memory: for large grids :func:`multipendulum.sweeps.sweep_flip_volume`
    writes it to Zarr chunk by chunk. ``FlipVolume.slice(k)`` is the 2-D map at ``z[k]``, and
    :func:`multipendulum.fractal.plot_flip_volume` draws slices.

    >>> import numpy as np, multipendulum as mp
    >>> g = np.linspace(-np.pi, np.pi, 9)
    >>> fv = mp.flip_volume(mp.Chain([1, 1, 1], [1, 1, 1]), g, g, g[3:6], t_max=5.0)
    >>> fv.times.shape
    (3, 9, 9)
    >>> bool(np.array_equal(fv.slice(1).times, mp.flip_map(mp.Chain([1, 1, 1], [1, 1, 1]), g, g, t_max=5.0,
    ...      base_theta=[0, 0, g[4]]).times))
    True
    """
    check_chain(chain)
    _check_progress(progress)
    x, y, z = _grid_axes(x=x, y=y, z=z)
    n = chain.n
    _core.check_memory(float(x.size) * y.size * z.size * (2 * n + 3) * 8.0,
                       f"a flip volume of {z.size} x {y.size} x {x.size} cells",
                       "use fewer points, or mp.sweep_flip_volume, which works chunk by chunk")
    th_base = np.zeros(n) if base_theta is None else as_state(base_theta, "base_theta", n)
    om_base = np.zeros(n) if base_omega is None else as_state(base_omega, "base_omega", n)
    vary3 = cast("Tuple[str, int, str, int, str, int]", _check_varied(vary, n, 3))
    theta0, omega0 = _grid_of((z, y, x), vary3[4:] + vary3[2:4] + vary3[:2], th_base, om_base)
    uncertain, tolerance = None, None
    if check_certify(certify, time_tolerance):
        times, uncertain, tolerance = certified_flip_times(chain, theta0, omega0, t_max=t_max, dt=dt, link=link,
                                                           torque=torque, time_tolerance=time_tolerance,
                                                           progress=progress, pivot=pivot)
    else:
        times = flip_times(chain, theta0, omega0, t_max=t_max, dt=dt, link=link, torque=torque, progress=progress,
                           pivot=pivot)
    threshold = flip_threshold(chain, link, torque, pivot)
    allowed = cast("npt.NDArray[np.bool_]", chain.energy(theta0, omega0) >= threshold)
    return FlipVolume(x, y, z, times, allowed, float(t_max), threshold, vary3, uncertain, tolerance)


def check_certify(certify: object, tolerance: Optional[float], name: str = "time_tolerance") -> bool:
    """Whether a map is certified; a tolerance (``name``) given without ``certify`` is refused."""
    if not isinstance(certify, (bool, np.bool_)):
        raise InputError(f"certify must be True or False, got {certify!r}")
    if tolerance is not None and not certify:
        raise InputError(f"{name} applies to a certified map: pass certify=True with it")
    return bool(certify)

@dataclass(frozen=True)
class IndicatorMap:
    """A chaos indicator ``values[i, j]`` at ``t_end`` for the initial values ``x[j]`` (of the
    first varied quantity) and ``y[i]``."""

    x: npt.NDArray[np.float64]
    y: npt.NDArray[np.float64]
    #: A NumPy array, or the on-disk Zarr array of a map written to a store (:func:`sweep_indicator_map`).
    values: Union[npt.NDArray[np.float64], ZarrArray]
    indicator: str
    t_end: float
    #: GALI's order (None for the other indicators).
    k: Optional[int] = None
    #: A certified map's cells whose side of ``threshold`` changes at ``dt / 2`` (None: not certified).
    uncertain: Union[None, npt.NDArray[np.bool_], ZarrArray] = None
    #: The value separating regular from chaotic cells a certified map was judged by.
    threshold: Optional[float] = None


def indicator_map(chain: Chain, x: npt.ArrayLike, y: npt.ArrayLike, t_end: float = 50.0, indicator: str = "megno",
                  k: Optional[Integer] = None, dt: float = 0.005, vary: Vary = ("theta", 0, "theta", 1),
                  base_theta: Optional[npt.ArrayLike] = None, base_omega: Optional[npt.ArrayLike] = None,
                  torque: Optional[TorqueLike] = None, certify: bool = False, threshold: Optional[float] = None,
                  progress: Progress = None, *, pivot: Optional[Pivot] = None) -> IndicatorMap:
    """A chaos-indicator map over a grid of two initial values, as :func:`flip_map` varies them
    (``vary``, ``base_theta``, ``base_omega``); each cell :func:`indicator` at ``t_end``, in
    parallel (undriven chains in SIMD lanes, eight cells at a time, damping and friction included).

    ``certify=True`` computes every cell again at ``dt / 2`` (as :func:`certified_indicator`)
    and fills ``uncertain``: the cells that fall on different sides of ``threshold`` (default:
    the indicator's rule of thumb, :data:`CHAOS_RULES`) at the two steps, so that whether they
    look chaotic depends on the step. The values are still those at ``dt``.

    >>> import multipendulum as mp
    >>> m = mp.indicator_map(mp.Chain([1, 1], [1, 1]), [0.2, 2.0], [0.2, 2.5], t_end=40.0)
    >>> bool(m.values[0, 0] < 3 < m.values[1, 1])       # regular near rest, chaotic high up
    True
    """
    check_chain(chain)
    _check_progress(progress)
    x, y = _grid_axes(x=x, y=y)
    n = chain.n
    _core.check_memory(float(x.size) * y.size * (2 * n + 1) * 8.0, f"an indicator map of {y.size} x {x.size} cells",
                       "use fewer points in x and y")
    th_base = np.zeros(n) if base_theta is None else as_state(base_theta, "base_theta", n)
    om_base = np.zeros(n) if base_omega is None else as_state(base_omega, "base_omega", n)
    theta0, omega0 = _grid(y, x, _check_vary(vary, n), th_base, om_base)
    uncertain, used = None, None
    values: npt.NDArray[np.float64]
    if check_certify(certify, threshold, "threshold"):
        values, uncertain, used = certified_indicator(chain, theta0, omega0, t_end, indicator, k=k, dt=dt, torque=torque,
                                                      threshold=threshold, progress=progress, pivot=pivot)
    else:
        values = cast("npt.NDArray[np.float64]",  # a batch: the values at t_end
                      indicator_fn(chain, theta0, omega0, t_end, indicator, k=k, dt=dt, torque=torque, progress=progress,
                                   pivot=pivot))
    return IndicatorMap(x, y, values, indicator, float(t_end), None if k is None else int(k), uncertain, used)


indicator_fn = indicator


@dataclass(frozen=True)
class PoincareSection:
    """Points ``(theta, p)`` of link ``record`` each time link ``through`` passes theta = 0
    upward; ``t`` their times; ``energy`` of the run."""

    t: npt.NDArray[np.float64]
    theta: npt.NDArray[np.float64]
    p: npt.NDArray[np.float64]
    energy: float
    record: int
    through: int


def poincare(chain: Chain, theta0: npt.ArrayLike, omega0: npt.ArrayLike, t_end: float, through: int = 0,
             record: int = 1, rtol: float = DEFAULTS["rtol"], atol: float = DEFAULTS["atol"]) -> List[PoincareSection]:
    """Poincaré sections: ``(theta_record, p_record)`` whenever ``theta_through`` crosses 0 upward,
    located by root finding on dop853's dense output. ``theta0``/``omega0`` may carry a batch axis
    (several energies), run in parallel; returns a list of :class:`PoincareSection`."""

    check_chain(chain)
    n = chain.n
    for name, k in (("through", through), ("record", record)):
        if not isinstance(k, (int, np.integer)) or not 0 <= k < n:
            raise InputError(f"{name} must be a link index in [0, {n}), got {k!r}")
    th0 = as_state(theta0, "theta0", n)
    om0 = as_state(omega0, "omega0", n)
    coef = np.zeros(n)
    coef[through] = 1.0
    t_end = as_float(t_end, "t_end")
    sol = simulate(chain, th0, om0, t_end, rtol=rtol, atol=atol, t_eval=[t_end], events=[Crossing(theta=coef)])
    runs = cast("List[List[EventRecord]]", sol.events if th0.ndim == 2 else [sol.events])
    energies = np.atleast_1d(sol.energy[..., 0])
    return [PoincareSection(r[0].t, r[0].theta[:, record], r[0].p[:, record], float(e), record, through)
            for r, e in zip(runs, energies)]


def plot_poincare(sections: Sequence[PoincareSection], path: Optional[PathLike] = None,
                  ax: Optional[Axes] = None) -> Union[Figure, SubFigure]:
    """Scatter the sections, one colour per energy; returns the figure (saved to ``path`` if given)."""
    import matplotlib

    if path is not None:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig: Optional[Union[Figure, SubFigure]] = None
    if ax is None:
        fig, ax = plt.subplots(figsize=(7, 6))
    colours = plt.cm.viridis(np.linspace(0, 0.95, len(sections)))
    for sec, col in zip(sections, colours):
        theta = (sec.theta + np.pi) % (2 * np.pi) - np.pi
        ax.scatter(np.degrees(theta), sec.p, s=2, color=col, label=f"E = {sec.energy:.2f} J")
    s0 = sections[0]
    ax.set_xlabel(f"theta_{s0.record + 1} (deg)")
    ax.set_ylabel(f"p_{s0.record + 1} (kg m^2/s)")
    ax.set_title(f"Poincaré section: theta_{s0.through + 1} = 0, increasing")
    ax.legend(markerscale=4, fontsize=8)
    fig = fig or ax.figure
    if path is not None:
        # (given the Axes of a SubFigure, which cannot be saved on its own, this fails)
        fig.savefig(path, dpi=110, bbox_inches="tight")  # type: ignore[union-attr]
        plt.close(fig)  # type: ignore[arg-type]
    return fig


@dataclass(frozen=True)
class EnsembleResult:
    """Final states ``theta``, ``omega``, ``p`` (B, N) at ``t_end``; per trajectory the relative
    ``energy_error`` (B,), integrator ``steps`` (B,), and ``first_flip`` (B,): the first time any
    link went over the top (inf: never)."""

    t_end: float
    theta: npt.NDArray[np.float64]
    omega: npt.NDArray[np.float64]
    p: npt.NDArray[np.float64]
    energy_error: npt.NDArray[np.float64]
    steps: npt.NDArray[np.int64]
    first_flip: npt.NDArray[np.float64]


def ensemble(chain: Chain, theta0: npt.ArrayLike, omega0: npt.ArrayLike, t_end: float, method: str = DEFAULTS["method"],
             dt: Optional[float] = None, rtol: float = DEFAULTS["rtol"], atol: float = DEFAULTS["atol"],
             torque: Optional[TorqueLike] = None,
             joint_torque: Optional[TorqueLike] = None, progress: Progress = None, *,
             pivot: Optional[Pivot] = None) -> EnsembleResult:
    """Run B trajectories (rows of ``theta0``, ``omega0``: (B, N)) in parallel in the Rust core
    and keep only their final states and per-trajectory reductions: memory O(B N), not
    O(B N steps). Results are identical whatever the number of threads. ``progress`` as for
    :func:`lyapunov`.

    Chains with damping, friction or a cart, undriven or driven by built-in torques (constant,
    :class:`Sinusoid`, :class:`Table`; not a Python function), on a fixed pivot or one moved by
    ``pivot`` (:class:`Pivot` of sinusoids or tables; not on a cart), run by ``rk4`` or
    ``dop853``, go through SIMD lanes (eight trajectories at a time, several times faster), each
    trajectory with its own steps under ``dop853``; the energy error is the balance with the
    work of the torques, the pivot and the losses. A pivot axis given as a Python function takes
    the per-trajectory route. They do not depend on the CPU's vector width or on the
    other rows, and agree with the per-trajectory route (a batch :func:`simulate` with a
    non-terminal :class:`Flip` event): ``rk4`` to round-off; ``dop853`` to its tolerance, taking
    the same number of steps give or take one (its error estimate cancels to round-off, which
    steers the steps apart). ``MULTIPENDULUM_LANES=scalar`` forces the per-trajectory route.

    >>> import numpy as np, multipendulum as mp
    >>> chain = mp.Chain([1, 1], [1, 1])
    >>> res = mp.ensemble(chain, np.full((4, 2), 0.1), np.zeros((4, 2)), 5.0)
    >>> bool(np.all(res.energy_error < 1e-9)), res.steps.shape
    (True, (4,))
    """

    check_chain(chain)
    t_end = as_float(t_end, "t_end")
    th0, om0 = as_state(theta0, "theta0", chain.n), as_state(omega0, "omega0", chain.n)
    if th0.ndim != 2 or th0.shape != om0.shape:
        raise InputError(f"theta0 and omega0 must both have shape (B, {chain.n}), got {th0.shape} and {om0.shape}")
    if isinstance(method, str):
        # The core runs it in SIMD lanes where the method and torque allow (else None).
        spec, joint = normalise_torque(torque, joint_torque, chain.n)
        _check_progress(progress)
        with reporter(progress, "ensemble") as report:
            lanes = _core.ensemble(chain._c, th0.ravel(), om0.ravel(), t_end, method=method,
                                   dt=None if dt is None else as_float(dt, "dt"), rtol=as_float(rtol, "rtol"),
                                   atol=as_float(atol, "atol"), torque=core_torque(spec, joint),
                                   pivot=core_pivot(normalise_pivot(pivot)), progress=report)
        if lanes is not None:
            theta, omega, p, error, steps, first = lanes
            return EnsembleResult(float(t_end), theta.reshape(th0.shape), omega.reshape(th0.shape), p.reshape(th0.shape),
                                  error, steps.astype(np.int64), first)
    sol = simulate(chain, th0, om0, t_end, method=method, dt=dt, rtol=rtol, atol=atol, torque=torque,
                   joint_torque=joint_torque, t_eval=[t_end], events=[Flip(terminal=False)], progress=progress,
                   pivot=pivot)
    first = np.array([rec[0].t[0] if rec[0].t.size else np.inf
                      for rec in cast("List[List[EventRecord]]", sol.events)])  # a batch: a list per trajectory
    return EnsembleResult(float(t_end), sol.theta[:, -1], sol.omega[:, -1], sol.p[:, -1],
                          np.asarray(sol.stats.energy_error), np.asarray(sol.stats.steps), first)
