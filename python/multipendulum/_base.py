"""What moves the chain's base: a prescribed pivot motion (:class:`Pivot`) or a cart
(:class:`Cart`) pushed by a force. Plain data here; the core validates and evaluates them."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

import multipendulum._core as _core

from ._convert import as_float, as_floats
from ._torque import Sinusoid, Table
from .errors import InputError


@dataclass(frozen=True)
class Cart:
    """A cart on a horizontal rail carrying the chain's pivot: ``mass`` (kg, > 0) and viscous
    ``damping`` (N s/m, >= 0: force ``-damping * v``). The base then slides along x as a degree of
    freedom; generalized coordinates ``(x, theta_1..theta_N)``, the cart first.

    >>> import multipendulum as mp
    >>> chain = mp.Chain.rods([0.6], [0.1], cart=mp.Cart(1.0))
    >>> chain.mass_matrix([0.0]).shape    # (x, theta): the cart first
    (2, 2)
    """

    mass: float
    damping: float = 0.0

    def _spec(self) -> Tuple[float, float]:
        return as_float(self.mass, "cart mass"), as_float(self.damping, "cart damping")


#: One axis of a pivot motion: a number (fixed), a :class:`Sinusoid` of scalars, a cubic
#: :class:`Table` of one column, or a function ``f(t) -> (position, velocity, acceleration)``.
AxisLike = Union[float, Sinusoid, Table, Callable[[float], Any]]

#: A cart force: a number, a :class:`Sinusoid` or :class:`Table` of one value, or a feedback
#: function ``f(t, state) -> float`` with ``state = (x, theta_1..theta_N, v, omega_1..omega_N)``.
ForceLike = Union[float, Sinusoid, Table, Callable[[float, npt.NDArray[np.float64]], float]]


def _scalar(v: npt.ArrayLike, name: str) -> float:
    a = as_floats(v, name)
    if a.size != 1:
        raise InputError(f"{name} must be one number, got shape {a.shape}")
    return float(a.reshape(()))


def _axis_spec(a: AxisLike, name: str) -> Tuple[Any, ...]:
    """Plain data for one axis (a checkpoint keeps it as JSON)."""
    where = f"pivot {name}"
    if isinstance(a, Sinusoid):
        return ("sinusoid", *(_scalar(getattr(a, f), f"{where}.{f}") for f in ("amplitude", "frequency", "phase", "offset")))
    if isinstance(a, Table):
        if a.kind != "cubic":
            raise InputError(f'{where}: a pivot Table must be kind="cubic" (the motion needs two derivatives), got "{a.kind}"')
        t, x = as_floats(a.t, f"{where}.t"), as_floats(a.values, f"{where}.values")
        if t.ndim != 1 or x.shape != t.shape:
            raise InputError(f"{where}: values must have shape {t.shape} (one per time), got {x.shape}")
        return ("spline", t.tolist(), x.tolist())
    if callable(a):
        return ("function", a)
    return ("fixed", _scalar(a, where))


def _core_axis(spec: Tuple[Any, ...]) -> _core.Axis:
    kind = spec[0]
    if kind == "fixed":
        return _core.Axis.fixed(spec[1])
    if kind == "sinusoid":
        return _core.Axis.sinusoid(*spec[1:5])
    if kind == "spline":
        return _core.Axis.spline(spec[1], spec[2])
    return _core.Axis.function(spec[1])


@dataclass(frozen=True)
class Pivot:
    """A prescribed motion of the pivot, ``(x_p(t), y_p(t))``. Each axis is a number (fixed), an
    :class:`Sinusoid` of scalars (``offset + amplitude sin(frequency t + phase)``), a
    :class:`Table` of one column with ``kind="cubic"`` (a natural cubic spline, continued by its
    end tangents), or a function ``f(t)`` returning ``(position, velocity, acceleration)``.

    On the angles the pivot's acceleration acts as the gravity vector ``(-a_x, -g - a_y)``; the
    energy a run reports is the lab frame's, and ``sol.work.pivot`` is the work the pivot did.

    >>> import multipendulum as mp
    >>> kapitza = mp.Pivot(y=mp.Sinusoid(amplitude=0.02, frequency=200.0))
    """

    x: AxisLike = 0.0
    y: AxisLike = 0.0

    def _spec(self) -> Tuple[Tuple[Any, ...], Tuple[Any, ...]]:
        return _axis_spec(self.x, "x"), _axis_spec(self.y, "y")

    def position(self, t: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The pivot's position at times ``t``, shape ``t.shape + (2,)`` (evaluated by the core)."""
        return pivot_positions(self._spec(), as_floats(t, "t"))


def pivot_positions(spec: Optional[Tuple[Any, ...]], t: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Positions ``(..., 2)`` of a pivot spec at times ``t`` (zeros without one)."""
    out = np.zeros(t.shape + (2,))
    if spec is None:
        return out
    axes = core_pivot(spec)
    assert axes is not None
    flat = np.ascontiguousarray(t, dtype=np.float64).ravel().tolist()
    for k, axis in enumerate(axes):
        out[..., k] = np.asarray(_core.axis_eval(axis, flat)).reshape(-1, 3)[:, 0].reshape(t.shape)
    return out


def normalise_pivot(pivot: Optional[Pivot]) -> Optional[Tuple[Any, ...]]:
    if pivot is None:
        return None
    if not isinstance(pivot, Pivot):
        raise InputError(f"pivot must be a multipendulum.Pivot, got {type(pivot).__name__}")
    return pivot._spec()


def core_pivot(spec: Optional[Tuple[Any, ...]]) -> Optional[Tuple[_core.Axis, _core.Axis]]:
    if spec is None:
        return None
    return _core_axis(tuple(spec[0])), _core_axis(tuple(spec[1]))


def normalise_force(force: Optional[ForceLike]) -> Optional[Tuple[Any, ...]]:
    """Plain data for a cart force (a checkpoint keeps it as JSON)."""
    if force is None:
        return None
    if isinstance(force, Sinusoid):
        return ("sinusoid", *(_scalar(getattr(force, f), f"cart_force.{f}") for f in ("amplitude", "frequency", "phase", "offset")))
    if isinstance(force, Table):
        spec = force._spec(1)
        return ("table", spec[1], spec[2], spec[3])
    if callable(force):
        return ("function", force)
    return ("constant", _scalar(force, "cart_force"))


def core_force(spec: Optional[Tuple[Any, ...]]) -> Optional[_core.CartForce]:
    if spec is None:
        return None
    kind = spec[0]
    if kind == "constant":
        return _core.CartForce.constant(spec[1])
    if kind == "sinusoid":
        return _core.CartForce.sinusoid(*spec[1:5])
    if kind == "table":
        return _core.CartForce.table(spec[1], spec[2], spec[3])
    return _core.CartForce.function(spec[1])


def base_inputs(has_cart: bool, pivot: Optional[Pivot], cart_x0: object, cart_v0: object,
                force: Optional[ForceLike]) -> Tuple[Optional[Tuple[Any, ...]], Optional[Tuple[Any, ...]], Tuple[float, float]]:
    """The plain data of a run's base inputs: the pivot's and the cart force's specs and the
    cart's initial ``[x, v]``; the cart's inputs refused on a chain without one."""
    pivot_spec, force_spec = normalise_pivot(pivot), normalise_force(force)
    cart0 = (as_float(cart_x0, "cart_x0", finite=True), as_float(cart_v0, "cart_v0", finite=True))
    if not has_cart and (cart0 != (0.0, 0.0) or force_spec is not None):
        raise InputError("cart_x0, cart_v0 and cart_force need a chain with a cart (mp.Chain(..., cart=mp.Cart(mass)))")
    return pivot_spec, force_spec, cart0


def force_object(spec: Optional[Tuple[Any, ...]]) -> Optional[ForceLike]:
    """The user-level cart force of a built-in spec (a checkpoint's)."""
    if spec is None:
        return None
    if spec[0] == "constant":
        return float(spec[1])
    if spec[0] == "sinusoid":
        return Sinusoid(*spec[1:5])
    if spec[0] == "table":
        return Table(np.asarray(spec[1]), np.asarray(spec[2]), kind=spec[3])
    return None


def pivot_object(spec: Optional[Tuple[Any, ...]]) -> Optional[Pivot]:
    """The user-level pivot of a built-in spec (a checkpoint's)."""
    if spec is None:
        return None

    def axis(s: Any) -> AxisLike:
        if s[0] == "fixed":
            return float(s[1])
        if s[0] == "sinusoid":
            return Sinusoid(*s[1:5])
        if s[0] == "spline":
            return Table(np.asarray(s[1]), np.asarray(s[2]), kind="cubic")
        return s[1]

    return Pivot(axis(spec[0]), axis(spec[1]))
