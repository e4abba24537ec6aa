"""Progress reporting for long calls: one small helper that every long-running function uses.

The convention (for :func:`multipendulum.simulate`, ``lyapunov``, ``flip_map``, ``ensemble``,
the sweeps, ``Scenario.run`` and the command line) is a keyword argument ``progress=``:

- ``None`` or ``False``: no reporting at all (nothing is called, nothing is printed);
- ``True``: a bar on stderr with the time elapsed and the time remaining: tqdm's when tqdm is
  installed (``pip install 'multipendulum[progress]'``), else the package's own one-line bar
  (:class:`TextBar`);
- a callable ``f(fraction)``: called as it is with fractions in [0, 1], rising, the last one
  1.0 when the work completes; an exception it raises (e.g. to stop) passes through;
- anything else is refused with :class:`~multipendulum.InputError`.

Wiring a function to it takes two lines; ``report`` is ``None`` when no progress is wanted, so
it can be handed straight to the core, which then skips its callbacks::

    from ._progress import reporter

    def flip_map(..., progress=None):
        with reporter(progress, "flip map") as report:   # checks `progress` before any work
            times = _core.first_flips(..., report)      # the core calls report(fraction)

On leaving the ``with`` block normally the bar is completed (``report(1.0)``) and closed; on an
exception it is closed where it stood. Work done in pieces reports through :class:`Steps`
(thread-safe counting of completed pieces) and a part of a larger job through :func:`scaled`::

    with reporter(progress, "sweep") as report:
        done = Steps(report, total=len(chunks))
        for chunk in chunks:
            run(chunk, progress=scaled(report, done.fraction, done.fraction_after(1)))
            done.add(1)

API: :func:`check`, :func:`reporter`, :func:`make`, :class:`Steps`, :func:`scaled`,
:class:`TextBar`, :func:`format_seconds`. Nothing here imports tqdm until a bar is asked for.
"""
from __future__ import annotations

import contextlib
import math
import sys
import threading
import time
from typing import Any, Callable, Iterator, Optional, Protocol, TextIO, Union

__all__ = ["check", "reporter", "make", "Steps", "scaled", "TextBar", "format_seconds", "Report", "Reporter"]

#: What a progress callback looks like: ``report(fraction)`` with a fraction in [0, 1].
Report = Callable[[float], Any]
#: What a ``progress=`` argument may be: None or False (none), True (a bar), or a :data:`Report`.
Progress = Union[None, bool, Report]


def format_seconds(seconds: float) -> str:
    """``"4.2 s"``, ``"3 min 05 s"``, ``"2 h 07 min"``: short, for a progress line."""
    if not math.isfinite(seconds) or seconds < 0:
        return "?"
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, secs = divmod(int(round(seconds)), 60)
    if minutes < 60:
        return f"{minutes} min {secs:02d} s"
    hours, minutes = divmod(minutes, 60)
    if hours < 48:
        return f"{hours} h {minutes:02d} min"
    return f"{hours / 24:.1f} days"


class TextBar:
    """A one-line bar on ``stream`` (default stderr): label, bar, percentage, time elapsed and
    time remaining (from the rate so far). Call it with a fraction in [0, 1]; ``close()`` ends
    the line. It draws at most ten times a second and only once ``delay`` seconds have passed
    (a short job shows nothing); with ``tty_only`` only on a terminal; with ``quiet`` never."""

    def __init__(self, label: str, stream: Optional[TextIO] = None, delay: float = 1.0, width: int = 30,
                 quiet: bool = False, tty_only: bool = True):
        self.stream = sys.stderr if stream is None else stream
        isatty = getattr(self.stream, "isatty", None)
        on_tty = bool(isatty and isatty())
        self.enabled = not quiet and (on_tty or not tty_only)
        self.label = label
        self.delay = delay
        self.width = width
        self.start = time.monotonic()
        self.shown = False
        self._last = 0.0
        self._fraction = 0.0
        self._length = 0

    def line(self, fraction: float, elapsed: float) -> str:
        """The text drawn for ``fraction`` done after ``elapsed`` seconds."""
        filled = int(round(self.width * fraction))
        bar = "#" * filled + "-" * (self.width - filled)
        text = f"{self.label} [{bar}] {100 * fraction:5.1f}%  {format_seconds(elapsed)}"
        if 0 < fraction < 1:
            text += f", ~{format_seconds(elapsed * (1 - fraction) / fraction)} left"
        return text

    def __call__(self, fraction: float) -> None:
        if not self.enabled:
            return
        fraction = min(max(float(fraction), 0.0), 1.0)
        if not fraction >= 0:  # NaN
            return
        self._fraction = fraction
        now = time.monotonic()
        if now - self.start < self.delay or (now - self._last < 0.1 and fraction < 1.0):
            return
        self._last = now
        self.shown = True
        text = self.line(fraction, now - self.start)
        pad = max(0, self._length - len(text))  # wipe what a longer line left behind
        self._length = len(text)
        self.stream.write("\r" + text + " " * pad)
        self.stream.flush()

    def close(self) -> None:
        if self.shown:
            self.stream.write("\n")
            self.stream.flush()
            self.shown = False

    def __enter__(self) -> "TextBar":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _TqdmBar:
    """tqdm's bar driven by fractions: 100 units, so it shows percent, elapsed and remaining."""

    def __init__(self, label: str, tqdm_class: Any):
        self.bar = tqdm_class(total=100, desc=label or None, unit="%", leave=True,
                              bar_format="{l_bar}{bar}| {n:.0f}/{total_fmt}% [{elapsed}<{remaining}]")
        self._n = 0.0

    def __call__(self, fraction: float) -> None:
        value = 100.0 * min(max(float(fraction), 0.0), 1.0)
        if value > self._n:  # tqdm rate-limits the drawing itself
            self.bar.update(value - self._n)
            self._n = value

    def close(self) -> None:
        self.bar.close()


class Reporter(Protocol):
    """What :func:`make` returns: called with a fraction in [0, 1]; ``close()`` when done."""

    def __call__(self, fraction: float) -> Any: ...

    def close(self) -> None: ...


class _Callback:
    """A user's callable, passed through (and never closed)."""

    def __init__(self, fn: Report):
        self.fn = fn

    def __call__(self, fraction: float) -> Any:
        return self.fn(fraction)

    def close(self) -> None:
        pass


def check(progress: Any, name: str = "progress") -> None:
    """Refuse a ``progress`` that is not None, a bool or a callable, before any work starts."""
    if progress is None or isinstance(progress, bool) or callable(progress):
        return
    from .errors import InputError

    raise InputError(f"{name} must be True, False, None or a callable f(fraction), got {type(progress).__name__}")


def _tqdm() -> Any:
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return None
    return tqdm


def make(progress: Any, label: str = "", stream: Optional[TextIO] = None) -> Optional["Reporter"]:
    """The reporter for ``progress`` (see the module docstring), or None for no reporting. The
    result is callable with a fraction and has ``close()``. ``progress=True`` gives a tqdm bar
    when tqdm is installed, else a :class:`TextBar` on ``stream`` (default stderr), shown
    whether or not it is a terminal (it was asked for) after half a second."""
    check(progress)
    if progress is None or progress is False:
        return None
    if progress is True:
        tqdm = _tqdm() if stream is None else None
        if tqdm is not None:
            return _TqdmBar(label, tqdm)
        return TextBar(label or "progress", stream=stream, delay=0.5, tty_only=False)
    return _Callback(progress)


@contextlib.contextmanager
def reporter(progress: Any, label: str = "", stream: Optional[TextIO] = None) -> Iterator[Optional[Report]]:
    """``with reporter(progress, "label") as report:`` -- ``report`` is None or a callable
    ``report(fraction)``; completed (``report(1.0)``) and closed when the block succeeds, closed
    where it stood when the block raises."""
    rep = make(progress, label, stream)
    if rep is None:
        yield None
        return
    try:
        yield rep
        rep(1.0)
    finally:
        rep.close()


class Steps:
    """Counts completed pieces of a job of ``total`` pieces and reports ``done / total`` to
    ``report`` (which may be None: then it only counts). Thread-safe: pieces finishing on
    several threads at once each count once and the reported fraction never goes back."""

    def __init__(self, report: Optional[Report], total: float):
        self.report = report
        self.total = max(float(total), 1e-300)
        self.done = 0.0
        self._lock = threading.Lock()

    @property
    def fraction(self) -> float:
        return min(self.done / self.total, 1.0)

    def fraction_after(self, pieces: float) -> float:
        return min((self.done + pieces) / self.total, 1.0)

    def add(self, pieces: float = 1.0) -> None:
        with self._lock:
            self.done += pieces
            fraction = self.fraction
            if self.report is not None:
                self.report(fraction)


def scaled(report: Optional[Report], start: float, stop: float) -> Optional[Report]:
    """A reporter for a part of a job that maps its own 0..1 onto ``start..stop`` of
    ``report`` (None stays None)."""
    if report is None:
        return None
    span = stop - start

    def part(fraction: float) -> Any:
        return report(start + span * min(max(float(fraction), 0.0), 1.0))

    return part
