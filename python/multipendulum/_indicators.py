"""Chaos indicators from the variational equations, computed in the core: MEGNO, FLI (and the
orthogonal FLI), SALI and GALI_k, for one state (with the indicator's history) or a batch of
states (the values at ``t_end``, in parallel). Re-exported by :mod:`multipendulum.chaos` and the
package. The definitions and their references are in the core's
``crates/core/src/chaos/indicators.rs``."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Dict, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

import multipendulum._core as _core
from ._base import Pivot, core_pivot, normalise_pivot
from ._chain import Chain, as_state, check_chain
from ._convert import Integer, as_float, as_floats
from ._progress import Progress, reporter
from ._torque import TorqueLike, core_torque, normalise_torque
from .errors import InputError

#: The indicators' names, as the core states them.
INDICATORS = tuple(_core.INDICATORS)
#: The rule of thumb that calls a value chaotic, per indicator, as the core states it:
#: ``(above, threshold)``, chaotic above (True) or below the threshold; ``None`` where the level
#: depends on the time and the system (FLI, OFLI, the Lyapunov estimate: chaotic above a stated one).
CHAOS_RULES = {name: (bool(above), level) for name, (above, level) in _core.CHAOS_RULES.items()}


@dataclass(frozen=True)
class IndicatorResult:
    """An indicator of one run: ``value`` at ``t_end``, and its history ``values`` at ``times``."""

    name: str
    value: float
    times: npt.NDArray[np.float64]
    values: npt.NDArray[np.float64]


def indicator(chain: Chain, theta0: npt.ArrayLike, omega0: npt.ArrayLike, t_end: float, indicator: str = "megno",
              k: Optional[Integer] = None, dt: float = 0.005, torque: Optional[TorqueLike] = None,
              deviations: Optional[npt.ArrayLike] = None, record_every: Integer = 1,
              progress: Progress = None, *, pivot: Optional[Pivot] = None) -> Union[IndicatorResult, npt.NDArray[np.float64]]:
    """A chaos indicator of the chain from ``(theta0, omega0)``, integrated with rk4 at step ``dt``
    together with the variational equations (damping, friction and a moving ``pivot``, a
    :class:`Pivot`, included; not on a cart).

    ``indicator``: ``"megno"`` (time-averaged MEGNO ``<Y>``: -> 2 on regular orbits, ~ lambda t / 2
    on chaotic ones), ``"fli"`` (fast Lyapunov indicator ``sup ln |d|``), ``"ofli"`` (its
    orthogonal variant), ``"sali"`` (-> 0 exponentially on chaotic orbits, positive on regular
    ones), ``"gali"`` with order ``k`` (2 <= k <= 2N) or ``"lyapunov"`` (the largest Lyapunov
    exponent's finite-time estimate, for maps). The deviation vectors start from a fixed
    generic orthonormal set (reproducible), or ``deviations`` (the indicator's number of
    vectors, each of 2N values ``(d_theta, d_omega)``). ``torque`` may depend on time (a built-in).

    One state (shape (N,)): an :class:`IndicatorResult` with the history every ``record_every``
    steps. A batch (shape (..., N)): the values at ``t_end``, shape (...), in parallel.

    >>> import multipendulum as mp
    >>> chain = mp.Chain([1, 1], [1, 1])
    >>> regular = mp.megno(chain, [0.3, 0.2], [0, 0], t_end=500.0)
    >>> bool(1.5 < regular.value < 2.5)
    True
    >>> chaotic = mp.megno(chain, [2.0, 2.5], [0, 0], t_end=100.0)   # ~ lambda t / 2
    >>> bool(chaotic.value > 30)
    True
    """
    th0, om0, args = _arguments(chain, theta0, omega0, t_end, indicator, k, dt, torque, deviations, pivot)
    if isinstance(record_every, bool) or not isinstance(record_every, (int, np.integer)) or not 1 <= record_every < 2**64:
        raise InputError(f"record_every must be a positive integer (steps), got {record_every!r}")
    with reporter(progress, indicator) as report:
        if th0.ndim == 1:
            value, times, values = _core.indicator(chain._c, th0.tolist(), om0.tolist(), **args,
                                                   record_every=int(record_every), progress=report)
            return IndicatorResult(indicator, value, times, values)
        out = _core.indicators(chain._c, np.ascontiguousarray(th0).ravel(), np.ascontiguousarray(om0).ravel(), **args,
                               progress=report)
    return out.reshape(th0.shape[:-1])


def certified_indicator(chain: Chain, theta0: npt.ArrayLike, omega0: npt.ArrayLike, t_end: float,
                        indicator: str = "megno", k: Optional[Integer] = None, dt: float = 0.005,
                        torque: Optional[TorqueLike] = None, deviations: Optional[npt.ArrayLike] = None,
                        threshold: Optional[float] = None, progress: Progress = None, *,
                        pivot: Optional[Pivot] = None) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_], float]:
    """:func:`indicator` of a batch at ``dt`` and again at ``dt / 2``: ``(values, uncertain,
    threshold)``, the values at ``dt`` (shape ``theta0.shape[:-1]``) and, per state, whether it is uncertain: the two runs fall
    on different sides of ``threshold``, so that whether the state looks chaotic depends on the
    step. The threshold is the indicator's rule of thumb (:data:`CHAOS_RULES`: MEGNO above 4,
    SALI and GALI below 1e-8) unless given; FLI, OFLI and the Lyapunov estimate have none, and
    need one (chaotic above it). Costs three times :func:`indicator`.

    >>> import multipendulum as mp
    >>> values, uncertain, threshold = mp.certified_indicator(
    ...     mp.Chain([1, 1], [1, 1]), [[0.3, 0.2], [2.0, 2.5]], [[0, 0], [0, 0]], t_end=40.0)
    >>> bool(values[0] < threshold < values[1]), uncertain.tolist(), threshold
    (True, [False, False], 4.0)
    """
    th0, om0, args = _arguments(chain, theta0, omega0, t_end, indicator, k, dt, torque, deviations, pivot)
    if th0.ndim < 2:
        raise InputError(f"a certified indicator is of a batch: theta0 and omega0 of shape (..., {chain.n}), "
                         f"got {th0.shape}")
    limit = None if threshold is None else as_float(threshold, "threshold")
    with reporter(progress, f"certified {indicator}") as report:
        values, uncertain, used = _core.certified_indicators(
            chain._c, np.ascontiguousarray(th0).ravel(), np.ascontiguousarray(om0).ravel(), **args, threshold=limit,
            progress=report)
    return values.reshape(th0.shape[:-1]), uncertain.reshape(th0.shape[:-1]), used


def _arguments(chain: Chain, theta0: npt.ArrayLike, omega0: npt.ArrayLike, t_end: float, indicator: str,
               k: Optional[Integer], dt: float, torque: Optional[TorqueLike], deviations: Optional[npt.ArrayLike],
               pivot: Optional[Pivot] = None) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], Dict[str, Any]]:
    """The states and the core's keyword arguments of an indicator request, checked."""
    check_chain(chain)
    if not isinstance(indicator, str) or indicator not in INDICATORS:
        raise InputError(f"indicator must be one of {', '.join(INDICATORS)}, got {indicator!r}")
    n = chain.n
    if indicator == "gali":
        if k is None or isinstance(k, bool) or not isinstance(k, (int, np.integer)):
            raise InputError(f"gali needs its order k, an integer between 2 and 2N = {2 * n}, got {k!r}")
        k_: Optional[int] = int(k)
    elif k is not None:
        raise InputError(f"k is GALI's order; {indicator} takes none")
    else:
        k_ = None
    th0, om0 = as_state(theta0, "theta0", n), as_state(omega0, "omega0", n)
    if th0.shape != om0.shape:
        raise InputError(f"theta0 and omega0 must have the same shape, got {th0.shape} and {om0.shape}")
    dev = None if deviations is None else as_floats(deviations, "deviations").ravel().tolist()
    spec, joint = normalise_torque(torque, None, n)
    return th0, om0, dict(t_end=as_float(t_end, "t_end"), dt=as_float(dt, "dt"), name=indicator, k=k_,
                          torque=core_torque(spec, joint), pivot=core_pivot(normalise_pivot(pivot)), deviations=dev)


def megno(chain: Chain, theta0: npt.ArrayLike, omega0: npt.ArrayLike, t_end: float, dt: float = 0.005,
          torque: Optional[TorqueLike] = None, record_every: Integer = 1,
          progress: Progress = None, *, pivot: Optional[Pivot] = None) -> Union[IndicatorResult, npt.NDArray[np.float64]]:
    """Time-averaged MEGNO ``<Y>`` (Cincotta & Simo 2000): :func:`indicator` with ``"megno"``."""
    return indicator(chain, theta0, omega0, t_end, "megno", dt=dt, torque=torque, record_every=record_every,
                     progress=progress, pivot=pivot)


def fli(chain: Chain, theta0: npt.ArrayLike, omega0: npt.ArrayLike, t_end: float, dt: float = 0.005,
        orthogonal: bool = False, torque: Optional[TorqueLike] = None, record_every: Integer = 1,
        progress: Progress = None, *, pivot: Optional[Pivot] = None) -> Union[IndicatorResult, npt.NDArray[np.float64]]:
    """Fast Lyapunov indicator (Froeschle et al. 1997), or with ``orthogonal`` the OFLI (Fouchard
    et al. 2002): :func:`indicator` with ``"fli"`` / ``"ofli"``."""
    return indicator(chain, theta0, omega0, t_end, "ofli" if orthogonal else "fli", dt=dt, torque=torque,
                     record_every=record_every, progress=progress, pivot=pivot)


def sali(chain: Chain, theta0: npt.ArrayLike, omega0: npt.ArrayLike, t_end: float, dt: float = 0.005,
         torque: Optional[TorqueLike] = None, record_every: Integer = 1,
         progress: Progress = None, *, pivot: Optional[Pivot] = None) -> Union[IndicatorResult, npt.NDArray[np.float64]]:
    """Smaller alignment index (Skokos 2001): :func:`indicator` with ``"sali"``."""
    return indicator(chain, theta0, omega0, t_end, "sali", dt=dt, torque=torque, record_every=record_every,
                     progress=progress, pivot=pivot)


def gali(chain: Chain, theta0: npt.ArrayLike, omega0: npt.ArrayLike, t_end: float, k: Integer, dt: float = 0.005,
         torque: Optional[TorqueLike] = None, record_every: Integer = 1,
         progress: Progress = None, *, pivot: Optional[Pivot] = None) -> Union[IndicatorResult, npt.NDArray[np.float64]]:
    """Generalized alignment index GALI_k (Skokos et al. 2007), ``2 <= k <= 2N``."""
    return indicator(chain, theta0, omega0, t_end, "gali", k=k, dt=dt, torque=torque, record_every=record_every,
                     progress=progress, pivot=pivot)
