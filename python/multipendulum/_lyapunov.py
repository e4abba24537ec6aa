"""Lyapunov exponents from the variational equations, and how long a run stays trustworthy.
Below :mod:`multipendulum._simulate` (whose ``Solution.trustworthy_until`` uses it) and
re-exported by :mod:`multipendulum.chaos`."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import numpy.typing as npt

import multipendulum._core as _core
from ._base import ForceLike, Pivot, base_inputs, core_force, core_pivot
from ._chain import Chain, as_state, check_chain
from ._convert import Integer, as_float
from ._progress import Progress, reporter
from ._torque import TorqueLike, core_torque, normalise_torque
from .errors import InputError


@dataclass(frozen=True)
class LyapunovResult:
    """``exponents`` (k,) in 1/s, largest first; ``times`` (R,) of the re-orthonormalisations and
    ``history`` (R, k) of the running estimates, to judge convergence."""

    exponents: npt.NDArray[np.float64]
    times: npt.NDArray[np.float64]
    history: npt.NDArray[np.float64]

    @property
    def largest(self) -> float:
        return float(self.exponents[0])


def _link(link: Optional[Integer], n: int) -> Optional[int]:
    if link is None:
        return None
    if not isinstance(link, (int, np.integer)) or not 0 <= link < n:
        raise InputError(f"link must be an integer in [0, {n}) or None (any link), got {link!r}")
    return int(link)


def lyapunov(chain: Chain, theta0: npt.ArrayLike, omega0: npt.ArrayLike, t_end: float, dt: float = 0.005,
             k: Optional[Integer] = None, renorm_every: Integer = 10,
             torque: Optional[TorqueLike] = None, progress: Progress = None, *, pivot: Optional[Pivot] = None,
             cart_x0: float = 0.0, cart_v0: float = 0.0, cart_force: Optional[ForceLike] = None) -> LyapunovResult:
    """The ``k`` largest Lyapunov exponents (default: the full spectrum, k = 2N; on a cart
    2N + 2, of the state ``(theta, omega, x, v)``).

    Integrates the variational (tangent) equations of the Lagrangian form with rk4 at step ``dt``
    and re-orthonormalises the tangent vectors every ``renorm_every`` steps (Benettin et al. 1980).
    For an undamped chain the spectrum comes in +/- pairs summing to ~0; with damping or friction
    it sums to the phase-space contraction rate. ``torque`` may depend on time (a constant,
    :class:`Sinusoid` or :class:`Table`), as may a moving ``pivot`` (:class:`Pivot`, the
    Kapitza pendulum's) and, on a chain with a :class:`Cart`, ``cart_force`` (a number,
    :class:`Sinusoid` or :class:`Table`; not a function of the state, whose derivative is not
    known); ``cart_x0``, ``cart_v0`` start the cart (its position is a neutral direction: one
    exponent is zero). ``progress``: True for a bar on stderr, or a callable given the fraction
    done (:mod:`multipendulum._progress`); Ctrl-C stops the run within a fraction of a second
    (``KeyboardInterrupt``).

    >>> import multipendulum as mp
    >>> res = mp.lyapunov(mp.Chain([1, 1], [1, 1]), [2.0, 2.5], [0, 0], t_end=100.0)
    >>> bool(res.largest > 0.5)
    True
    >>> shaken = mp.Pivot(y=mp.Sinusoid(amplitude=0.02, frequency=200.0))
    >>> res = mp.lyapunov(mp.Chain([0.5], [1.0]), [3.0], [0.0], t_end=20.0, dt=0.0005, pivot=shaken)
    >>> bool(abs(res.exponents.sum()) < 1e-3)  # undamped: phase-space volume is kept
    True
    """
    check_chain(chain)
    th0, om0 = as_state(theta0, "theta0", chain.n), as_state(omega0, "omega0", chain.n)
    if th0.ndim != 1 or om0.ndim != 1:
        raise InputError(f"theta0 and omega0 must have shape ({chain.n},)")
    if k is not None and (isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1):
        raise InputError(f"k must be a positive integer (at most the state's size), got {k!r}")
    if isinstance(renorm_every, bool) or not isinstance(renorm_every, (int, np.integer)) \
            or not 1 <= renorm_every < 2**64:
        raise InputError(f"renorm_every must be a positive integer (steps), got {renorm_every!r}")
    spec, joint = normalise_torque(torque, None, chain.n)
    pivot_spec, force_spec, cart0 = base_inputs(chain.cart is not None, pivot, cart_x0, cart_v0, cart_force)
    with reporter(progress, "lyapunov") as report:
        exps, times, hist = _core.lyapunov(chain._c, th0.tolist(), om0.tolist(), as_float(t_end, "t_end"),
                                           dt=as_float(dt, "dt"), k=None if k is None else int(k),
                                           renorm_every=int(renorm_every), torque=core_torque(spec, joint),
                                           pivot=core_pivot(pivot_spec), cart_force=core_force(force_spec),
                                           cart0=cart0, progress=report)
    return LyapunovResult(exps, times, hist.reshape(times.size, exps.size))


def trustworthy_until(lyapunov_exponent: float, tolerance: float = 1e-2, eps: float = 1e-16) -> float:
    """How long a chaotic run stays within ``tolerance`` of the true trajectory when it starts
    off by ``eps`` (round-off): ``ln(tolerance / eps) / lambda_max``; infinite when lambda <= 0."""
    if lyapunov_exponent <= 0:
        return float("inf")
    return float(np.log(tolerance / eps) / lyapunov_exponent)
