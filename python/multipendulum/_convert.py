"""Argument conversion shared by the API: numbers and arrays of numbers, or InputError.

The package's contract: a bad argument value raises :class:`InputError` (a ``ValueError``)
whatever its type -- a string, None, a ragged list, a complex number, an integer too large for
a float. ``TypeError`` is left to Python itself, for calls with missing or unknown arguments.
"""
from __future__ import annotations

import math
from typing import Any, Union

import numpy as np
import numpy.typing as npt

from .errors import InputError

#: An integer argument: a Python ``int`` or a NumPy integer (both are accepted where an index or
#: a count is asked for).
Integer = Union[int, "np.integer[Any]"]


def _shown(x: object) -> str:
    text = repr(x)
    return f"{type(x).__name__} {text if len(text) <= 60 else text[:57] + '...'}"


def as_floats(x: object, name: str) -> npt.NDArray[np.float64]:
    """float64, C-contiguous, from a number or a (nested, rectangular) sequence of real numbers;
    anything else is an :class:`InputError` naming ``name``."""
    try:
        a = np.asarray(x)
    except (TypeError, ValueError, OverflowError) as e:
        raise InputError(f"{name} must be an array of numbers, got {_shown(x)}: {e}") from None
    if a.dtype.kind not in "biuf":
        raise InputError(f"{name} must be an array of numbers, got {_shown(x)}")
    return np.asarray(a, dtype=np.float64, order="C")


def as_float(x: object, name: str, finite: bool = False) -> float:
    """A single real number (NaN and inf pass unless ``finite``: the core checks its ranges)."""
    if type(x) is float and (not finite or math.isfinite(x)):
        return x  # the common case, without NumPy's overhead
    try:
        a = as_floats(x, name)
    except InputError:
        # (not "an array of numbers": one is wanted)
        raise InputError(f"{name} must be a number, got {_shown(x)}") from None
    if a.ndim != 0:
        raise InputError(f"{name} must be a number, got {_shown(x)}")
    if finite and not np.isfinite(a):
        raise InputError(f"{name} must be finite, got {float(a)}")
    return float(a)


def is_float(text: str) -> bool:
    """Whether ``text`` reads as a Python float (table files: a number or a header)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def check_single(sol: Any, what: str) -> None:
    """Refuse anything but one run: a :class:`~multipendulum.Solution` of one trajectory or
    loaded :class:`Results`. A batch run (theta of shape (B, T, N)) is refused saying how to
    get one of its trajectories."""
    theta = getattr(sol, "theta", None)
    if theta is None or not hasattr(sol, "t"):
        raise InputError(f"{what} takes a multipendulum Solution or loaded Results, got {type(sol).__name__}")
    shape = np.shape(theta)
    if len(shape) == 3:
        raise InputError(
            f"{what} takes one run, but this Solution is a batch of {shape[0]} runs (theta shape {shape}); "
            f"pick one trajectory b by simulating it alone, mp.simulate(chain, theta0[b], omega0[b], ...), "
            "which gives the batch's row b (to round-off, or to dop853's tolerance, where the batch ran in "
            "SIMD lanes)")
    if len(shape) != 2:
        raise InputError(f"{what} takes one run with theta of shape (T, N), got shape {shape}")
