"""Driving torques: built-ins evaluated in Rust, or Python callables."""
from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import Any, Callable, List, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

import multipendulum._core as _core

from ._convert import as_floats
from .errors import InputError

#: A torque as the core takes it, normalised to plain data (a checkpoint keeps it as JSON): a
#: tuple whose first entry names the kind -- ``("constant", values)``, ``("sinusoid", amplitude,
#: frequency, phase, offset)``, ``("table", t, values, kind)`` or ``("callable", f, with_state)``.
TorqueSpec = Tuple[Any, ...]


def _per_link(x: npt.ArrayLike, name: str, n: int) -> List[float]:
    a = as_floats(x, name)
    a = np.broadcast_to(a, (n,)) if a.ndim == 0 else a
    if a.shape != (n,):
        raise InputError(f"{name} must be a number or have {n} entries (one per link), got shape {a.shape}")
    return a.tolist()


@dataclass(frozen=True)
class Sinusoid:
    """``offset_i + amplitude_i sin(frequency_i t + phase_i)``; frequency in rad/s. Each field is a
    number (same for every link) or one value per link. Evaluated in Rust."""

    amplitude: npt.ArrayLike
    frequency: npt.ArrayLike
    phase: npt.ArrayLike = 0.0
    offset: npt.ArrayLike = 0.0

    def _spec(self, n: int) -> TorqueSpec:
        return ("sinusoid", *(_per_link(getattr(self, f), f, n) for f in ("amplitude", "frequency", "phase", "offset")))


@dataclass(frozen=True)
class Table:
    """Tabulated torques: ``values[k, i]`` at time ``t[k]`` (strictly increasing), interpolated
    ``kind="linear"`` or ``"cubic"`` (natural spline), held at the end values outside the table.
    Evaluated in Rust."""

    t: npt.ArrayLike
    values: npt.ArrayLike
    kind: str = "linear"

    def _spec(self, n: int) -> TorqueSpec:
        t = as_floats(self.t, "t")
        v = as_floats(self.values, "values")
        if self.kind not in ("linear", "cubic"):
            got = f'"{self.kind}"' if isinstance(self.kind, str) else repr(self.kind)
            raise InputError(f'kind must be "linear" or "cubic", got {got}')
        if v.ndim == 1 and n == 1:
            v = v[:, None]
        if t.ndim != 1 or v.shape != (t.size, n):
            raise InputError(f"values must have shape ({t.size}, {n}) for t of shape {t.shape}, got {v.shape}")
        return ("table", t.tolist(), v.ravel().tolist(), self.kind)


#: A torque as the API takes it (``torque=`` / ``joint_torque=``): N values (constant), a built-in
#: evaluated in Rust, or a Python function of time, ``f(t)``, or of the state, ``f(t, theta, omega)``
#: (theta and omega as float64 arrays (N,)), returning N values.
TorqueLike = Union[
    npt.ArrayLike,
    Sinusoid,
    Table,
    Callable[[float], npt.ArrayLike],
    Callable[[float, npt.NDArray[np.float64], npt.NDArray[np.float64]], npt.ArrayLike],
]


def _arity(f: Callable[..., object]) -> bool:
    """True for ``f(t, theta, omega)``, False for ``f(t)``."""
    try:
        params = [p for p in inspect.signature(f).parameters.values()
                  if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) and p.default is p.empty]
        varargs = any(p.kind == p.VAR_POSITIONAL for p in inspect.signature(f).parameters.values())
    except (TypeError, ValueError):
        return False
    if len(params) == 3 or (varargs and len(params) < 3):
        return True
    if len(params) == 1:
        return False
    raise InputError(f"a torque function must take (t) or (t, theta, omega), got {len(params)} required arguments")


def normalise_torque(torque: Optional[TorqueLike], joint_torque: Optional[TorqueLike],
                     n: int) -> Tuple[Optional[TorqueSpec], bool]:
    """-> (spec tuple for the core or None, joint convention?)."""
    if torque is not None and joint_torque is not None:
        raise InputError("give torque (generalized, on absolute angles) or joint_torque (joint motors), not both")
    joint = joint_torque is not None
    x = joint_torque if joint else torque
    name = "joint_torque" if joint else "torque"
    if x is None:
        return None, False
    if isinstance(x, (Sinusoid, Table)):
        return x._spec(n), joint
    if callable(x):
        return ("callable", x, _arity(x)), joint
    a = as_floats(x, name)
    if a.shape != (n,) and not (n == 1 and a.ndim == 0):
        raise InputError(f"{name} must have {n} entries (one per link), got shape {a.shape}")
    a = a.reshape(n)
    if not np.isfinite(a).all():
        i = int(np.argwhere(~np.isfinite(a))[0][0])
        raise InputError(f"{name}[{i}] must be finite, got {a[i]}")
    return ("constant", a.tolist()), joint


def torque_object(spec: Optional[TorqueSpec], n: int) -> Union[None, npt.NDArray[np.float64], Sinusoid, Table]:
    """The user-level torque (array, Sinusoid, Table) for a built-in spec as the core takes it."""
    if spec is None:
        return None
    kind = spec[0]
    if kind == "constant":
        return np.asarray(spec[1], dtype=np.float64)
    if kind == "sinusoid":
        return Sinusoid(*(np.asarray(v, dtype=np.float64) for v in spec[1:5]))
    if kind == "table":
        t = np.asarray(spec[1], dtype=np.float64)
        return Table(t, np.asarray(spec[2], dtype=np.float64).reshape(t.size, n), kind=spec[3])
    raise InputError(f"checkpoint: unknown torque kind {kind!r}")


def core_torque(spec: Optional[TorqueSpec], joint: bool) -> Optional[_core.Torque]:
    """The core's typed torque (:class:`multipendulum._core.Torque`) for a normalised spec, in
    the joint-motor convention when ``joint``; None for no torque. Specs stay plain data (a
    checkpoint keeps them as JSON); only this crosses into the core."""
    if spec is None:
        return None
    kind = spec[0]
    if kind == "constant":
        return _core.Torque.constant(spec[1], joint=joint)
    if kind == "sinusoid":
        return _core.Torque.sinusoid(*spec[1:5], joint=joint)
    if kind == "table":
        return _core.Torque.table(spec[1], spec[2], spec[3], joint=joint)
    if kind == "callable":
        return _core.Torque.function(spec[1], with_state=spec[2], joint=joint)
    raise InputError(f"unknown torque kind {kind!r}")
