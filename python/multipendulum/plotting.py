"""Static plots of a run: angles, energy error, phase portraits and the tip's trace.

Everything drawn comes from the solution (or a loaded results file); nothing is recomputed:
the energy error is the run's own (``sol.energy_error``, its maximum ``sol.stats.energy_error``).
Titles are wrapped to the figure's width; series longer than :data:`MAX_POINTS` samples are
thinned for drawing (the energy error keeps each stretch's largest value).
"""
from __future__ import annotations

import math
import numbers
import os
from pathlib import Path
from typing import Any, List, Optional, Sequence, Union

import numpy as np

from ._files import atomic_path
from .results import series

__all__ = ["plot", "PLOT_KINDS", "fit_title", "MAX_POINTS", "MAX_SIDE"]

PLOT_KINDS = ("angles", "energy", "phase", "tip")
PathLike = Union[str, "os.PathLike[str]"]

_MAX_LEGEND = 8
_SIZE = (7.0, 4.2)
#: Samples drawn per curve at most; longer runs are thinned (a picture has no more pixels).
MAX_POINTS = 100_000
#: The largest picture side in pixels (Agg stops at 2^16).
MAX_SIDE = 16384


def fit_title(text: str, width_inches: float, fontsize: float = 12.0, max_lines: int = 3) -> str:
    """``text`` broken into lines (at spaces, or anywhere in a word too long for a line) that
    each fit ``width_inches`` at ``fontsize`` points, measured with the font Matplotlib draws
    with; at most ``max_lines`` lines, the last ending in an ellipsis when text was left out."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextToPath

    measure = TextToPath()
    prop = FontProperties(size=fontsize)
    limit = width_inches * 72.0

    def fits(line: str) -> bool:
        return measure.get_text_width_height_descent(line, prop, ismath=False)[0] <= limit

    lines: List[str] = []
    for paragraph in str(text).splitlines() or [""]:
        current = ""
        for word in paragraph.split():
            trial = f"{current} {word}" if current else word
            if fits(trial):
                current = trial
                continue
            if current:
                lines.append(current)
            while not fits(word) and len(word) > 1:  # a word wider than a line: cut it
                cut = len(word) - 1
                while cut > 1 and not fits(word[:cut]):
                    cut -= 1
                lines.append(word[:cut])
                word = word[cut:]
            current = word
        lines.append(current)
    if len(lines) > max_lines:
        last = lines[max_lines - 1] + "\u2026"
        while len(last) > 1 and not fits(last):
            last = last[:-2] + "\u2026"
        lines = lines[:max_lines - 1] + [last]
    return "\n".join(lines)


def _check_dpi(dpi) -> None:
    import multipendulum._core as _core

    from .errors import InputError

    if isinstance(dpi, bool) or not isinstance(dpi, numbers.Real) or not math.isfinite(dpi) or not dpi > 0:
        raise InputError(f"dpi must be a finite number > 0, got {dpi!r}")
    width, height = _SIZE[0] * dpi, _SIZE[1] * dpi
    if max(width, height) > MAX_SIDE:
        raise InputError(f"plots at dpi = {dpi:g} would be {width:.0f} x {height:.0f} pixels, larger than "
                         f"{MAX_SIDE} a side; lower dpi (110 gives 770 x 462)")
    # Agg's RGBA buffer, and the PNG encoder's copy of it.
    _core.check_memory(width * height * 8.0, f"a plot of {width:.0f} x {height:.0f} pixels", "lower dpi")


def plot(
    sol: Any,
    outdir: Optional[PathLike] = None,
    kinds: Sequence[str] = PLOT_KINDS,
    dpi: float = 110,
    format: str = "png",
    title: Optional[str] = None,
) -> List[Any]:
    """Draw the plots named in ``kinds`` for a solution or a loaded results file.

    - ``"angles"``: each theta_i against time (rad, not wrapped, so full turns show).
    - ``"energy"``: the run's energy error ``sol.energy_error``, ``|E - E0 - W| / S`` (W the work
      done by the torque, S the core's energy scale: the potential well's depth plus the largest
      kinetic energy so far), against time, log scale: the curve measures the integrator alone.
    - ``"phase"``: omega against theta (wrapped to [-pi, pi]) for the first and the last link.
    - ``"tip"``: the path of the last link's tip, coloured by time, with the pivot marked.

    With ``outdir``, each plot is written (atomically) to ``outdir/<kind>.<format>`` and the
    list of paths is returned; without it, the Matplotlib figures are returned (through pyplot,
    so they show in notebooks and interactive sessions). ``title`` names the run in the plot
    titles (default: the scenario's name for loaded results). A batch
    :class:`~multipendulum.Solution` is refused: plot one trajectory.
    """
    kinds = tuple(kinds)
    unknown = [k for k in kinds if k not in PLOT_KINDS]
    if unknown:
        from .errors import InputError

        raise InputError(f"unknown plot kind {unknown[0]!r}; expected one of {', '.join(PLOT_KINDS)}")
    _check_dpi(dpi)
    view = _thinned(series(sol, "mp.plot"))
    if title is not None:
        view.name = title
    out = []
    for kind in kinds:
        fig = _new_figure(interactive=outdir is None)
        _DRAW[kind](fig, view)
        if outdir is None:
            out.append(fig)
            continue
        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        target = outdir / f"{kind}.{format}"
        with atomic_path(target) as tmp:
            fig.savefig(tmp, dpi=dpi, format=format)
        out.append(target)
    return out


def _thinned(view):
    """At most about MAX_POINTS samples per curve: every k-th sample, and for the energy error
    the largest value of each stretch of k (its peaks are what the plot is read for)."""
    t_count = view.t.shape[0]
    k = int(math.ceil(t_count / MAX_POINTS))
    if k <= 1:
        return view
    idx = np.arange(0, t_count, k)
    err = view.energy_error
    padded = np.full(idx.size * k, -np.inf)
    padded[:t_count] = np.where(np.isfinite(err), err, -np.inf)
    view.energy_error = padded.reshape(idx.size, k).max(axis=1)
    view.t, view.theta, view.omega, view.positions = view.t[idx], view.theta[idx], view.omega[idx], view.positions[idx]
    return view


def _title(fig, text: str) -> None:
    """The figure's title, centred on the figure and wrapped to its width (a long scenario name
    is never clipped)."""
    fig.suptitle(fit_title(text, 0.94 * fig.get_figwidth(), 12.0), fontsize=12)


def _new_figure(interactive: bool, size=_SIZE):
    if interactive:
        import matplotlib.pyplot as plt

        return plt.figure(figsize=size, layout="constrained")
    from matplotlib.figure import Figure

    return Figure(figsize=size, layout="constrained")


def _subtitle(view) -> str:
    parts = [view.name] if view.name else []
    parts.append(f"N = {view.lengths.shape[0]}")
    if view.method:
        parts.append(view.method)
    return ", ".join(parts)


def _link_colors(n: int):
    from matplotlib import colormaps

    if n <= 10:
        return [colormaps["tab10"](i) for i in range(n)]
    cmap = colormaps["viridis"]
    return [cmap(0.9 * i / (n - 1)) for i in range(n)]


def _draw_angles(fig, view) -> None:
    ax = fig.add_subplot()
    n = view.theta.shape[1]
    colors = _link_colors(n)
    thin = n > _MAX_LEGEND
    for i in range(n):
        ax.plot(view.t, view.theta[:, i], color=colors[i], lw=0.8 if thin else 1.3,
                label=None if thin else f"$\\theta_{{{i + 1}}}$")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("angle from the downward vertical (rad)")
    _title(fig, f"Angles: {_subtitle(view)}")
    ax.grid(alpha=0.3)
    if thin:
        ax.text(0.01, 0.98, f"link 1 (dark) to link {n} (light)", transform=ax.transAxes,
                va="top", fontsize=8)
    else:
        ax.legend(loc="upper left", fontsize=8, ncol=min(n, 4))


def _draw_energy(fig, view) -> None:
    ax = fig.add_subplot()
    err = view.energy_error
    positive = np.isfinite(err) & (err > 0)
    ax.set_yscale("log")
    if positive.any():
        ax.plot(view.t[positive], err[positive], color="tab:red", lw=1.0)
    else:
        ax.text(0.5, 0.5, "energy error is exactly zero at every sample", transform=ax.transAxes,
                ha="center", va="center")
    title = f"Energy error: {_subtitle(view)}"
    if view.max_energy_error is not None:
        title += f" (max {view.max_energy_error:.2g})"
    _title(fig, title)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("|E - E0 - W| / S\n(W: work by torque; S: well depth + max kinetic energy)", fontsize=9)
    ax.set_xlim(view.t[0], view.t[-1])
    ax.grid(alpha=0.3, which="both")


def _wrapped_with_breaks(theta: np.ndarray, omega: np.ndarray):
    """theta wrapped to [-pi, pi), with NaN where it jumps so no line crosses the plot."""
    wrapped = (theta + np.pi) % (2 * np.pi) - np.pi
    jumps = np.flatnonzero(np.abs(np.diff(wrapped)) > np.pi) + 1
    return np.insert(wrapped, jumps, np.nan), np.insert(omega, jumps, np.nan)


def _draw_phase(fig, view) -> None:
    n = view.theta.shape[1]
    links = [0] if n == 1 else [0, n - 1]
    axes = fig.subplots(1, len(links), squeeze=False)[0]
    colors = _link_colors(n)
    for ax, i in zip(axes, links):
        x, y = _wrapped_with_breaks(view.theta[:, i], view.omega[:, i])
        ax.plot(x, y, color=colors[i], lw=0.6)
        ax.plot(x[:1], y[:1], "o", color="black", ms=4, label="start")
        ax.set_xlim(-np.pi, np.pi)
        ax.set_xticks([-np.pi, -np.pi / 2, 0, np.pi / 2, np.pi],
                      ["$-\\pi$", "$-\\pi/2$", "0", "$\\pi/2$", "$\\pi$"])
        ax.set_xlabel(f"$\\theta_{{{i + 1}}}$ (rad, wrapped)")
        ax.set_ylabel(f"$\\omega_{{{i + 1}}}$ (rad/s)")
        ax.set_title(f"link {i + 1}", fontsize=10)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    _title(fig, f"Phase portrait: {_subtitle(view)}")


def _draw_tip(fig, view) -> None:
    from matplotlib.collections import LineCollection

    ax = fig.add_subplot()
    tip = view.positions[:, -1, :]
    reach = float(np.sum(view.lengths)) * 1.08
    if tip.shape[0] > 1:
        segments = np.stack([tip[:-1], tip[1:]], axis=1)
        lc = LineCollection(segments, cmap="viridis", linewidths=0.8)
        lc.set_array(0.5 * (view.t[:-1] + view.t[1:]))
        ax.add_collection(lc)
        fig.colorbar(lc, ax=ax, label="t (s)", shrink=0.85)
    ax.plot(tip[0, 0], tip[0, 1], "o", color="tab:green", ms=5, label="start")
    ax.plot(tip[-1, 0], tip[-1, 1], "s", color="tab:red", ms=5, label="end")
    ax.plot(0.0, 0.0, "^", color="black", ms=8, label="pivot")
    ax.set_xlim(-reach, reach)
    ax.set_ylim(-reach, reach)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    _title(fig, f"Tip of link {view.lengths.shape[0]}: {_subtitle(view)}")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)


_DRAW = {"angles": _draw_angles, "energy": _draw_energy, "phase": _draw_phase, "tip": _draw_tip}
