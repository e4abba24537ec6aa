"""Static plots of a run: angles, energy error, phase portraits and the tip's trace.

Everything drawn comes from the solution (or a loaded results file); nothing is recomputed.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, List, Optional, Sequence, Union

import numpy as np

from .results import atomic_path, series

__all__ = ["plot", "PLOT_KINDS"]

PLOT_KINDS = ("angles", "energy", "phase", "tip")
PathLike = Union[str, "os.PathLike[str]"]

_MAX_LEGEND = 8


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
    - ``"energy"``: the relative energy error ``|E - E0 - W| / |E0|`` against time, log scale
      (W is the work done by the torque, so the curve measures the integrator alone).
    - ``"phase"``: omega against theta (wrapped to [-pi, pi]) for the first and the last link.
    - ``"tip"``: the path of the last link's tip, coloured by time, with the pivot marked.

    With ``outdir``, each plot is written (atomically) to ``outdir/<kind>.<format>`` and the
    list of paths is returned; without it, the Matplotlib figures are returned (through pyplot,
    so they show in notebooks and interactive sessions). ``title`` names the run in the plot
    titles (default: the scenario's name for loaded results).
    """
    kinds = tuple(kinds)
    unknown = [k for k in kinds if k not in PLOT_KINDS]
    if unknown:
        from multipendulum import InputError

        raise InputError(f"unknown plot kind {unknown[0]!r}; expected one of {', '.join(PLOT_KINDS)}")
    view = series(sol)
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


def _new_figure(interactive: bool, size=(7.0, 4.2)):
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
    ax.set_title(f"Angles: {_subtitle(view)}")
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
    ax.set_title(title)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("|E - E0 - W| / |E0|   (W: work by torque)")
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
    fig.suptitle(f"Phase portrait: {_subtitle(view)}")


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
    ax.set_title(f"Tip of link {view.lengths.shape[0]}: {_subtitle(view)}")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)


_DRAW = {"angles": _draw_angles, "energy": _draw_energy, "phase": _draw_phase, "tip": _draw_tip}
