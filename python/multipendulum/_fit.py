"""Parameter identification: fit a chain's parameters to measured angles.

:func:`fit` runs SciPy's trust-region reflective least squares (``scipy.optimize.least_squares``,
a Gauss–Newton method with bounds) on the angles' misfit, with the exact Jacobian from the
run's forward sensitivities (:func:`multipendulum.simulate`'s ``sensitivities``): one run per
iteration gives both the residuals and their derivatives.

A chain's parameters are moved as its kind ties them: on a chain of point masses (``com`` equal
to ``lengths``, no inertia) a length carries its mass along, and on uniform rods (``com = l/2``,
``I = m l^2 / 12``) a length or a mass carries the rod's centre and inertia; asking for ``com``
or ``inertia`` fits every parameter on its own. The covariance is the Gauss–Newton one at the
optimum, ``s^2 (J^T J)^-1``, with ``s`` the measurements' noise (``sigma``) or, when it is not
given, the residuals' own scatter; the intervals are Student-t intervals of that covariance.

>>> import numpy as np, multipendulum as mp
>>> truth = mp.Chain([1.0, 0.8], [1.0, 0.6], damping=[0.05, 0.03])
>>> t = np.linspace(0, 6, 301)
>>> measured = mp.simulate(truth, [1.0, -0.5], [0, 0], 6.0, t_eval=t).theta
>>> guess = mp.Chain([1.3, 0.6], [1.0, 0.8], damping=[0.07, 0.02])
>>> result = mp.fit(guess, t, measured, params={"lengths": None, "masses": [1], "damping": None})
>>> bool(np.allclose(result.chain.lengths, [1.0, 0.8], rtol=1e-6))
True
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

from ._chain import Chain, as_state
from ._convert import as_float, as_floats
from ._simulate import SENSITIVITIES, simulate
from .errors import InputError, IntegrationError

#: What :func:`fit` can fit: the chain's parameters, and the initial state.
PARAMETERS = tuple(SENSITIVITIES)
_POSITIVE = {"lengths", "masses"}  # kept > 0; damping, friction, inertia >= 0; the rest free
_FREE = {"g", "theta0", "omega0", "com"}
#: least_squares' arguments that fit() sets itself.
_RESERVED = {"fun", "x0", "jac", "bounds", "x_scale", "args", "kwargs"}
_INITIAL = ("theta0", "omega0")

Params = Union[Sequence[str], Mapping[str, Optional[Sequence[int]]]]


@dataclass
class FitResult:
    """The outcome of :func:`fit`."""

    #: The fitted chain (the guess's kind, cart and the parameters not fitted kept).
    chain: Chain
    #: The fitted values by name: only the entries fitted (``"g"``: one value), which are
    #: :attr:`indices`.
    values: Dict[str, npt.NDArray[np.float64]]
    #: The entries fitted, by name.
    indices: Dict[str, List[int]]
    #: Their standard errors, laid out as ``values``.
    stderr: Dict[str, npt.NDArray[np.float64]]
    #: The covariance of all fitted values, in the order of :attr:`names`.
    covariance: npt.NDArray[np.float64]
    #: ``(name, index)`` of each fitted value, in the covariance's order.
    names: List[Tuple[str, int]]
    #: The initial state of the fitted run.
    theta0: npt.NDArray[np.float64]
    omega0: npt.NDArray[np.float64]
    #: The misfit at the optimum, measured minus model (T, N), and its root mean square.
    residuals: npt.NDArray[np.float64]
    rms: float
    #: Degrees of freedom: measurements minus fitted values.
    dof: int
    #: Runs made, and SciPy's verdict.
    nfev: int
    success: bool
    message: str

    def interval(self, level: float = 0.95) -> Dict[str, npt.NDArray[np.float64]]:
        """Confidence intervals at ``level``: per name, an array (k, 2) of (low, high)."""
        level = as_float(level, "level")
        if not 0 < level < 1:
            raise InputError(f"level must lie in (0, 1), got {level}")
        from scipy import stats

        q = float(stats.t.ppf(0.5 + level / 2, self.dof))
        return {k: np.stack([v - q * self.stderr[k], v + q * self.stderr[k]], axis=-1) for k, v in self.values.items()}

    def __repr__(self) -> str:
        def show(a: npt.NDArray[np.float64], spec: str) -> str:
            return "[" + ", ".join(format(x, spec) for x in a) + "]"
        parts = ", ".join(f"{k}={show(v, '.6g')} ± {show(self.stderr[k], '.2g')}" for k, v in self.values.items())
        return f"FitResult({parts}, rms={self.rms:.3g}, nfev={self.nfev})"


def _kind(chain: Chain) -> str:
    """How the chain's parameters are tied: "points", "rods" or "general"."""
    l, m, c, i = chain.lengths, chain.masses, chain.com, chain.inertia
    if np.array_equal(c, l) and not i.any():
        return "points"
    if np.allclose(c, l / 2, rtol=1e-12, atol=0) and np.allclose(i, m * l**2 / 12, rtol=1e-12, atol=0):
        return "rods"
    return "general"


def _selection(params: Params, chain: Chain) -> List[Tuple[str, int]]:
    """``(name, index)`` of every value to fit, checked."""
    if isinstance(params, str):
        params = (params,)
    if isinstance(params, Mapping):
        items = list(params.items())
    elif isinstance(params, (list, tuple)):
        items = [(p, None) for p in params]
    else:
        raise InputError(f"params must be names or a dict of name -> indices, got {type(params).__name__}")
    out: List[Tuple[str, int]] = []
    for name, idx in items:
        if name not in PARAMETERS:
            raise InputError(f"cannot fit {name!r}: the parameters are {', '.join(PARAMETERS)}")
        # The initial state has N entries; a parameter as many as the chain holds (g: one).
        size = chain.n if name in _INITIAL else int(np.size(getattr(chain, name)))
        if idx is None:
            chosen = list(range(size))
        else:
            given = list(np.atleast_1d(np.asarray(idx, dtype=object)))
            if not all(isinstance(j, (int, np.integer)) and not isinstance(j, bool) for j in given):
                raise InputError(f"params[{name!r}] must be None or a list of integer indices, got {idx!r}")
            chosen = [int(j) for j in given]
            if any(not 0 <= j < size for j in chosen) or len(set(chosen)) != len(chosen):
                raise InputError(f"params[{name!r}] must be distinct indices in [0, {size}), got {chosen}")
        if any(nm == name for nm, _ in out):
            raise InputError(f"{name!r} is given twice in params")
        out += [(name, j) for j in chosen]
    if not out:
        raise InputError("params is empty: name at least one parameter to fit")
    return out


class _Model:
    """The chain and initial state as functions of the fitted vector."""

    def __init__(self, guess: Chain, names: List[Tuple[str, int]], theta0: npt.ArrayLike, omega0: npt.ArrayLike) -> None:
        self.guess, self.names = guess, names
        fitted = {nm for nm, _ in names}
        self.kind = "general" if fitted & {"com", "inertia"} else _kind(guess)
        self.base: Dict[str, Any] = dict(lengths=guess.lengths.copy(), masses=guess.masses.copy(),
                                         com=guess.com.copy(), inertia=guess.inertia.copy(), g=guess.g,
                                         damping=guess.damping.copy(), friction=guess.friction.copy(),
                                         theta0=np.array(theta0, dtype=float), omega0=np.array(omega0, dtype=float))

    def start(self) -> npt.NDArray[np.float64]:
        return np.array([self.base[nm] if nm == "g" else self.base[nm][j] for nm, j in self.names])

    def values(self, x: npt.NDArray[np.float64]) -> Dict[str, Any]:
        v = {k: (a.copy() if isinstance(a, np.ndarray) else a) for k, a in self.base.items()}
        for (nm, j), xi in zip(self.names, x):
            if nm == "g":
                v["g"] = float(xi)
            else:
                v[nm][j] = xi
        if self.kind == "points":
            v["com"] = v["lengths"].copy()
        elif self.kind == "rods":
            v["com"] = v["lengths"] / 2
            v["inertia"] = v["masses"] * v["lengths"] ** 2 / 12
        return v

    def chain(self, v: Dict[str, Any]) -> Chain:
        return Chain(v["lengths"], v["masses"], com=v["com"], inertia=v["inertia"], g=v["g"], damping=v["damping"],
                     friction=v["friction"], friction_velocity=self.guess.friction_velocity, cart=self.guess.cart)

    def jacobian(self, sens: Dict[str, npt.NDArray[np.float64]], v: Dict[str, Any], n: int) -> npt.NDArray[np.float64]:
        """d theta / d x, (T, N, k), through the kind's ties."""
        cols = []
        for nm, j in self.names:
            col = sens[nm][..., :n, 0 if nm == "g" else j]
            if nm == "lengths" and self.kind == "points":
                col = col + sens["com"][..., :n, j]
            elif nm == "lengths" and self.kind == "rods":
                col = col + 0.5 * sens["com"][..., :n, j] + v["masses"][j] * v["lengths"][j] / 6 * sens["inertia"][..., :n, j]
            elif nm == "masses" and self.kind == "rods":
                col = col + v["lengths"][j] ** 2 / 12 * sens["inertia"][..., :n, j]
            cols.append(col)
        return np.stack(cols, axis=-1)

    def inputs(self) -> List[str]:
        """The sensitivities a run must carry."""
        need = list(dict.fromkeys(nm for nm, _ in self.names))
        if self.kind != "general" and "lengths" in need:
            need.append("com")
        if self.kind == "rods" and ("lengths" in need or "masses" in need):
            need.append("inertia")
        return need


def fit(chain_guess: Chain, t: npt.ArrayLike, theta_measured: npt.ArrayLike, params: Params = ("lengths", "masses", "damping"),
        *, theta0: Optional[npt.ArrayLike] = None, omega0: Optional[npt.ArrayLike] = None, sigma: Optional[float] = None,
        method: str = "dop853", dt: Optional[float] = None, rtol: float = 1e-10, atol: float = 1e-12,
        torque: Any = None, pivot: Any = None, cart_x0: float = 0.0, cart_v0: float = 0.0, cart_force: Any = None,
        max_nfev: Optional[int] = None, **least_squares: Any) -> FitResult:
    """Fit the parameters ``params`` of ``chain_guess`` (and, if named, ``"theta0"`` /
    ``"omega0"``) to angles ``theta_measured`` (T, N) measured at times ``t`` (T,).

    ``params``: names from :data:`PARAMETERS` (every entry of each), or a dict of name to the
    entries to fit (``None``: all), e.g. ``{"lengths": None, "masses": [1]}``. The run starts
    at t = 0 from ``theta0`` (default: the first measurement, which must then be at t = 0) and
    ``omega0`` (default: rest), with ``torque``, ``pivot``, the cart's start and ``cart_force``
    (depending on time only) and the other run options as in :func:`simulate`. ``sigma``: the measurements' noise (rad), known; default:
    estimated from the residuals. Other keywords go to ``scipy.optimize.least_squares``.

    Not every set of parameters can be told apart by angles alone: scaling every mass (and the
    damping with it) leaves the motion unchanged, so fit all masses but one. A Jacobian of
    lower rank than the number of parameters is refused with that advice.
    """
    try:
        from scipy.optimize import least_squares as solve
    except ImportError as exc:  # pragma: no cover - scipy is in the fit extra
        raise ImportError("mp.fit needs SciPy: pip install 'multipendulum[fit]'") from exc
    if not isinstance(chain_guess, Chain):
        raise InputError(f"chain_guess must be a multipendulum.Chain, got {type(chain_guess).__name__}")
    n = chain_guess.n
    times = as_floats(t, "t").ravel()
    measured = as_floats(theta_measured, "theta_measured")
    if measured.shape != (times.size, n):
        raise InputError(f"theta_measured must have shape (len(t), N) = ({times.size}, {n}), got {measured.shape}")
    if not np.all(np.isfinite(measured)):
        raise InputError("theta_measured must be finite (drop the missing samples and their times)")
    if times.size < 2 or not np.all(np.isfinite(times)) or times[0] < 0 or np.any(np.diff(times) <= 0):
        raise InputError("t must hold at least two ascending times, from t >= 0 (the run starts at t = 0)")
    names = _selection(params, chain_guess)
    count = measured.size
    if count < len(names):
        raise InputError(f"a fit of {len(names)} values needs at least as many measurements, got {count} "
                         f"({times.size} times x {n} angles)")
    if theta0 is None:
        if times[0] != 0.0:
            raise InputError(f"give theta0: the measurements start at t = {times[0]}, not at the run's start t = 0")
        theta0 = measured[0]
    th0 = as_state(theta0, "theta0", n)
    om0 = np.zeros(n) if omega0 is None else as_state(omega0, "omega0", n)
    if sigma is not None:
        sigma = as_float(sigma, "sigma")
        if not sigma > 0:
            raise InputError(f"sigma must be > 0, got {sigma}")
    reserved = sorted(_RESERVED & set(least_squares))
    if reserved:
        raise InputError(f"fit sets {', '.join(reserved)} of least_squares itself; pass the solver's other options")
    model = _Model(chain_guess, names, th0, om0)
    x0 = model.start()
    lower = np.array([1e-12 * max(abs(v), 1e-300) if nm in _POSITIVE else
                      (-np.inf if nm in _FREE else 0.0) for (nm, _), v in zip(names, x0)])
    x0 = np.maximum(x0, lower)
    weight = 1.0 if sigma is None else 1.0 / sigma
    kw = dict(method=method, dt=dt, rtol=rtol, atol=atol, t_eval=times, torque=torque, pivot=pivot,
              cart_x0=cart_x0, cart_v0=cart_v0, cart_force=cart_force)
    cache: Dict[bytes, Tuple[Any, Any]] = {}

    def evaluate(x: npt.NDArray[np.float64]) -> Tuple[Any, Any]:
        key = x.tobytes()
        if key not in cache:
            v = model.values(x)
            sol = simulate(model.chain(v), v["theta0"], v["omega0"], float(times[-1]), sensitivities=model.inputs(), **kw)
            cache.clear()
            cache[key] = (sol.theta - measured, model.jacobian(sol.sensitivities, v, n))
        return cache[key]

    try:
        res = solve(lambda x: evaluate(x)[0].ravel() * weight, x0, jac=lambda x: evaluate(x)[1].reshape(count, -1) * weight,
                    bounds=(lower, np.full_like(x0, np.inf)), x_scale="jac", max_nfev=max_nfev, **least_squares)
    except IntegrationError as exc:
        raise IntegrationError(f"the fit's run failed on the way ({exc}); start from a closer guess") from exc
    resid, jac = evaluate(res.x)
    jm = jac.reshape(count, -1)
    rank = np.linalg.matrix_rank(jm)
    if rank < len(names):
        raise InputError(f"the parameters cannot be told apart from these measurements: the Jacobian has rank "
                         f"{rank} for {len(names)} values (scaling every mass and the damping together leaves "
                         f"the motion unchanged: fit all masses but one, e.g. params={{'masses': [1], ...}})")
    dof = count - len(names)
    if sigma is not None:
        s2 = sigma**2
    else:
        s2 = float(np.sum(resid**2)) / dof if dof > 0 else np.inf
    cov = s2 * np.linalg.inv(jm.T @ jm)
    err = np.sqrt(np.diag(cov))
    v = model.values(res.x)
    values: Dict[str, List[float]] = {}
    stderr: Dict[str, List[float]] = {}
    indices: Dict[str, List[int]] = {}
    for (nm, j), xi, ei in zip(names, res.x, err):
        values.setdefault(nm, []).append(float(xi))
        stderr.setdefault(nm, []).append(float(ei))
        indices.setdefault(nm, []).append(j)
    return FitResult(chain=model.chain(v), values={k: np.array(a) for k, a in values.items()}, indices=indices,
                     stderr={k: np.array(a) for k, a in stderr.items()}, covariance=cov, names=names,
                     theta0=np.asarray(v["theta0"]), omega0=np.asarray(v["omega0"]), residuals=-resid,
                     rms=float(np.sqrt(np.mean(resid**2))), dof=dof, nfev=int(res.nfev), success=bool(res.success),
                     message=str(res.message))
