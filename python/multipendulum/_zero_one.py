"""The 0-1 test for chaos (Gottwald & Melbourne) on any scalar time series.

The modified test with the correlation method of G. A. Gottwald and I. Melbourne, "On the
implementation of the 0-1 test for chaos", SIAM J. Appl. Dyn. Syst. 8 (2009) 129-145. From a
series ``phi(1..N)`` and a frequency ``c`` it builds the translation variables

    p_c(n) = sum_{j=1}^{n} phi(j) cos(j c),    q_c(n) = sum_{j=1}^{n} phi(j) sin(j c),

whose path is bounded for regular dynamics and a diffusion (a random walk) for chaotic ones; their
mean square displacement, for n = 1..n_cut,

    M_c(n) = 1/(N - n) sum_{j=1}^{N-n} [(p_c(j+n) - p_c(j))^2 + (q_c(j+n) - q_c(j))^2],

less the oscillatory term of a series with a non-zero mean (the "modified" test),

    D_c(n) = M_c(n) - mean(phi)^2 (1 - cos(n c)) / (1 - cos c),

grows linearly in n for chaotic dynamics and stays bounded for regular ones. ``K_c`` is the
correlation coefficient of ``(n, D_c(n))``, and ``K`` the median of ``K_c`` over many ``c``
(the median discards the few ``c`` resonant with a frequency of a regular series).

Cost: ``O(n_c * n_cut * N)`` arithmetic, no FFT (two sums of squares of differences per ``c`` and
``n``), about 3-4 ns per unit of ``n_c * n_cut * N`` on one core (measured): 0.3 s for N = 3000
and 3 s for N = 10^4 at the defaults (n_c = 100, n_cut = N // 10), growing as N^2; memory
O(n_c * n_cut + N) beyond the series. Inputs above :data:`MAX_WORK` (about 7 s) are refused
(:class:`InputError`) with advice; the test needs a few thousand well-spaced samples, not more.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional, Union

import numpy as np
import numpy.typing as npt

from ._convert import as_floats
from .errors import InputError

#: Fewest samples accepted. The test's statistics converge slowly: G&M use N of a few thousand;
#: below ~1000 samples expect K to be only roughly 0 or 1.
MIN_SAMPLES = 100
#: Smallest ``n_cut`` accepted (a correlation over fewer lags means little).
MIN_N_CUT = 10
#: Largest ``n_c * n_cut * N`` accepted (some seconds of work; see the module's docstring).
MAX_WORK = 2_000_000_000
#: The interval G&M draw ``c`` from, away from the resonances at c = 0 and c = pi.
C_LOW, C_HIGH = np.pi / 5, 4 * np.pi / 5

_Int = Union[int, "np.integer[Any]"]


@dataclass(frozen=True)
class ZeroOneResult:
    """The 0-1 test's result: ``k`` the median of ``k_c`` (the correlation coefficient of
    ``(n, D_c(n))``) over the frequencies ``c`` (rad per sample).

    ``k`` near 0 means regular (periodic or quasi-periodic) dynamics, near 1 chaotic ones. A
    stochastic series (noise) also gives ``k`` near 1: the test tells a bounded from a diffusive
    path, not determinism from chance. In between, the series is too short or too finely sampled
    for a verdict.

    The series must be sampled coarser than the system's fastest time scale. An oversampled
    series (many samples per oscillation) looks locally smooth, its ``p_c``/``q_c`` paths move
    only slowly, and ``k`` takes spurious values: a chaotic flow can come out near 0 and a
    regular one away from 0 (G&M 2009 discuss this). Sample at about the period of the dominant
    oscillation, or at most a few samples per period (subsample a finely resolved series, e.g.
    ``x[::m]``), and take a few thousand samples. (The chaotic double pendulum, whose periods
    are 1-3 s, reads as chaotic sampled every 0.1-2 s and as regular sampled every 0.01 s.)

    The observable must be bounded, as the test assumes a stationary series: of an angle that
    can wind (a pendulum going over the top), take its sine or cosine, not the angle itself.
    """

    k: float
    k_c: npt.NDArray[np.float64]
    c: npt.NDArray[np.float64]


def _count(value: object, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InputError(f"{name} must be an integer, got {type(value).__name__} {value!r}")
    return int(value)


def _frequencies(c: Optional[npt.ArrayLike], n_c: int, seed: Optional[_Int]) -> npt.NDArray[np.float64]:
    if c is None:
        if seed is not None:
            seed = _count(seed, "seed")
            if seed < 0:
                raise InputError(f"seed must be a non-negative integer or None, got {seed}")
        return np.random.default_rng(seed).uniform(C_LOW, C_HIGH, n_c)
    cs = as_floats(c, "c")
    if cs.ndim == 0:
        cs = cs.reshape(1)
    if cs.ndim != 1 or cs.size == 0:
        raise InputError(f"c must be a number or a 1-D array of at least one number, got shape {cs.shape}")
    bad = ~((cs > 0) & (cs < np.pi))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"c must lie in (0, pi) (rad per sample; G&M draw it from (pi/5, 4 pi/5)), "
                         f"got c[{i}] = {cs[i]}")
    return cs


def zero_one_test(series: npt.ArrayLike, *, c: Optional[npt.ArrayLike] = None, n_c: _Int = 100,
                  n_cut: Optional[_Int] = None, seed: Optional[_Int] = 0,
                  detrend: bool = True) -> ZeroOneResult:
    """The 0-1 test for chaos on the scalar time series ``series`` (1-D, at least
    :data:`MIN_SAMPLES` finite values, not constant): ``K`` near 0 regular, near 1 chaotic.

    ``c``: the frequencies (rad per sample, each in (0, pi)); by default ``n_c`` values drawn
    uniformly from (pi/5, 4 pi/5) by ``numpy.random.default_rng(seed)`` (the same seed, the same
    result; ``seed=None`` draws fresh ones). ``n_cut``: the largest lag n (default ``N // 10``,
    in [:data:`MIN_N_CUT`, N // 2]). ``detrend``: subtract the oscillatory term
    ``mean(phi)^2 (1 - cos nc) / (1 - cos c)`` from ``M_c(n)`` (the modified test, G&M 2009);
    False correlates ``M_c(n)`` itself (the original test: for a series with a large mean the
    oscillatory term swamps the linear growth and a chaotic series can read as regular). See :class:`ZeroOneResult` for how to sample the series, and the module's
    docstring for the formulas and the cost (``O(n_c * n_cut * N)``; above :data:`MAX_WORK` the
    call is refused).

    >>> import numpy as np
    >>> def logistic(r, n, x=0.3):
    ...     out = np.empty(n)
    ...     for _ in range(1000):             # the transient
    ...         x = r * x * (1 - x)
    ...     for i in range(n):
    ...         x = r * x * (1 - x)
    ...         out[i] = x
    ...     return out
    >>> bool(zero_one_test(logistic(3.97, 2000)).k > 0.9)   # chaotic
    True
    >>> bool(zero_one_test(logistic(3.55, 2000)).k < 0.1)   # period 8
    True
    """
    phi = as_floats(series, "series")
    if phi.ndim != 1:
        raise InputError(f"series must be 1-D (one scalar observable per sample), got shape {phi.shape}")
    n = phi.size
    if n < MIN_SAMPLES:
        raise InputError(f"series needs at least {MIN_SAMPLES} samples (a few thousand are better), got {n}")
    finite = np.isfinite(phi)
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise InputError(f"series must be finite, got series[{i}] = {phi[i]}")
    if np.all(phi == phi[0]):
        raise InputError(f"series is constant ({phi[0]}): K is undefined for it")
    n_c = _count(n_c, "n_c")
    if n_c < 1:
        raise InputError(f"n_c must be at least 1, got {n_c}")
    if n_cut is None:
        n_cut = max(MIN_N_CUT, n // 10)
    else:
        n_cut = _count(n_cut, "n_cut")
        if not MIN_N_CUT <= n_cut <= n // 2:
            raise InputError(f"n_cut must be in [{MIN_N_CUT}, {n // 2}] (at most half the series' "
                             f"{n} samples; G&M take N // 10), got {n_cut}")
    if not isinstance(detrend, (bool, np.bool_)):
        raise InputError(f"detrend must be True or False, got {type(detrend).__name__} {detrend!r}")
    cs = _frequencies(c, n_c, seed)
    work = cs.size * n_cut * n
    if work > MAX_WORK:
        raise InputError(f"the test would take n_c * n_cut * N = {cs.size} * {n_cut} * {n} = {work:.3g} operations "
                         f"(at most {MAX_WORK:.3g}): subsample the series (it needs only a few samples per "
                         f"oscillation and a few thousand samples), or pass a smaller n_cut or n_c")
    d = _displacement(phi, cs, n_cut)
    lags = np.arange(1, n_cut + 1, dtype=np.float64)
    if detrend:
        d -= np.mean(phi) ** 2 * (1 - np.cos(np.outer(cs, lags))) / (1 - np.cos(cs))[:, None]
    k_c = _correlation(lags, d)
    return ZeroOneResult(k=float(np.median(k_c)), k_c=k_c, c=cs)


def _displacement(phi: npt.NDArray[np.float64], cs: npt.NDArray[np.float64], n_cut: int) -> npt.NDArray[np.float64]:
    """M_c(n), shape (len(cs), n_cut): the mean square displacement of (p_c, q_c) at lags 1..n_cut."""
    n = phi.size
    out = np.empty((cs.size, n_cut))
    scale = 1.0 / (n - np.arange(1, n_cut + 1))
    # c in blocks whose paths (p and q, rows) stay in a fast cache while every lag passes over them.
    block = max(1, min(cs.size, 16384 // n))
    j = np.arange(1, n + 1, dtype=np.float64)
    for b in range(0, cs.size, block):
        angle = np.outer(cs[b:b + block], j)
        path = np.concatenate([np.cumsum(phi * np.cos(angle), axis=1), np.cumsum(phi * np.sin(angle), axis=1)])
        rows = angle.shape[0]
        for lag in range(1, n_cut + 1):
            step = path[:, lag:] - path[:, :-lag]
            sq = np.einsum("ij,ij->i", step, step)
            out[b:b + rows, lag - 1] = (sq[:rows] + sq[rows:]) * scale[lag - 1]
    return out


def _correlation(x: npt.NDArray[np.float64], y: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """The correlation coefficient of x (n,) with each row of y (m, n); 0 for a row with no spread."""
    xc = x - x.mean()
    yc = y - y.mean(axis=1, keepdims=True)
    sy = np.sqrt(np.einsum("ij,ij->i", yc, yc))
    cov = yc @ xc
    with np.errstate(invalid="ignore", divide="ignore"):
        r = cov / (np.sqrt(xc @ xc) * sy)
    return np.where(sy > 0, np.clip(r, -1.0, 1.0), 0.0)
