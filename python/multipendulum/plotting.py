"""Static plots of a run: angles, energy error, phase portraits and the tip's trace.

Everything drawn comes from the solution (or a loaded results file); nothing is recomputed:
the energy error is the run's own (``sol.energy_error``, its maximum ``sol.stats.energy_error``),
the pivot's and the cart's motion the run's ``sol.pivot`` and ``sol.cart_x``, the work terms
``sol.work``'s parts. Titles are wrapped to the figure's width; series longer than
:data:`MAX_POINTS` samples are thinned for drawing (the energy error keeps each stretch's
largest value).
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

__all__ = ["plot", "PLOT_KINDS", "fit_title", "base_motion", "MAX_POINTS", "MAX_SIDE"]

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


#: Work terms of a run, in the order drawn: (attribute of ``sol.work``, label, sign in the balance
#: ``E - E0 = W_torque + W_pivot + W_cart - D``).
_WORK_TERMS = (("torque", "$W_{torque}$ (torques)", 1.0), ("pivot", "$W_{pivot}$ (moving pivot)", 1.0),
               ("cart", "$W_{cart}$ (cart force)", 1.0), ("dissipated", "$-D$ (dissipated)", -1.0))


def base_motion(sol: Any, view: Any) -> Any:
    """Add what the run says about its base to ``view`` (from :func:`multipendulum.results.series`):

    - ``pivot`` (T, 2): the pivot's lab position (``sol.pivot``; on a cart ``(cart_x, 0)``).
      A loaded results file stores no pivot: it is recovered as the stored (lab-frame) first
      joint minus the chain's own first joint, exact to round-off;
    - ``cart_x`` (T,) or None: the cart's position (``sol.cart_x``);
    - ``moving``: whether the pivot moves at all (a fixed pivot is drawn as before);
    - ``pivot_path``: the run's :class:`~multipendulum.Pivot` (its position evaluated by the core
      at any time) or None;
    - ``energy`` (T,) or None and ``work`` (a dict of the work terms that are not all zero,
      each (T,), keyed as in ``sol.work``; ``"net"`` alone for a results file, which stores
      only the net work).

    ``sol`` None: from ``view`` alone. (Belongs in ``series`` itself, which these keys extend.)"""
    t_count = view.t.shape[0]
    pivot = getattr(sol, "pivot", None)
    if pivot is not None:
        pivot = np.asarray(pivot, dtype=float).reshape(t_count, 2)
    elif view.chain is not None:
        pivot = view.positions[:, 0, :] - np.asarray(view.chain.positions(view.theta), dtype=float)[:, 0, :]
        reach = float(np.sum(view.lengths))
        pivot = np.where(np.abs(pivot) > 1e-12 * reach, pivot, 0.0)  # a fixed pivot, up to round-off
    else:
        pivot = np.zeros((t_count, 2))
    cart_x = getattr(sol, "cart_x", None)
    view.cart_x = None if cart_x is None else np.asarray(cart_x, dtype=float).reshape(t_count)
    view.pivot = pivot
    view.moving = bool(np.any(pivot != 0.0))
    from ._base import Pivot

    path = getattr(sol, "_pivot", None)
    view.pivot_path = path if isinstance(path, Pivot) else None
    energy = getattr(sol, "energy", None)
    view.energy = None if energy is None else np.asarray(energy, dtype=float).reshape(t_count)
    work = getattr(sol, "work", None)
    terms = {}
    if work is not None and all(hasattr(work, name) for name, _, _ in _WORK_TERMS):
        for name, _, _ in _WORK_TERMS:
            values = np.asarray(getattr(work, name), dtype=float).reshape(t_count)
            if np.any(values != 0.0):
                terms[name] = values
    elif work is not None:
        net = np.asarray(work, dtype=float).reshape(t_count)
        if np.any(net != 0.0):
            terms["net"] = net
    view.work = terms
    return view


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
    - ``"energy"``: the run's energy error ``sol.energy_error``, ``|E - E0 - W| / S`` (W the net
      work: by the torques, a moving pivot and the cart force, minus what damping and friction
      dissipated; S the core's energy scale: the potential well's depth plus the largest kinetic
      energy so far), against time, log scale: the curve measures the integrator alone. A run
      that exchanges energy (any work term not zero) gets a second panel above it: ``E - E0``
      and each work term, whose signed sum it should equal (the residual is the curve below).
    - ``"phase"``: omega against theta (wrapped to [-pi, pi]) for the first and the last link.
    - ``"tip"``: the path of the last link's tip (lab frame), coloured by time, with the pivot
      marked (a moving pivot's path, a cart's rail, drawn too).

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
    view = _thinned(base_motion(sol, series(sol, "mp.plot")))
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
    view.pivot = view.pivot[idx]
    if view.cart_x is not None:
        view.cart_x = view.cart_x[idx]
    if view.energy is not None:
        view.energy = view.energy[idx]
    view.work = {name: values[idx] for name, values in view.work.items()}
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
    if view.work and view.energy is not None:
        top, ax = fig.subplots(2, 1, sharex=True, height_ratios=(1.3, 1.0))
        _draw_balance(top, view)
    else:
        ax = fig.add_subplot()
    err = view.energy_error
    positive = np.isfinite(err) & (err > 0)
    ax.set_yscale("log")
    if positive.any():
        ax.plot(view.t[positive], err[positive], color="tab:red", lw=1.0, label="balance residual")
    else:
        ax.text(0.5, 0.5, "energy error is exactly zero at every sample", transform=ax.transAxes,
                ha="center", va="center")
    balance = bool(view.work) and view.energy is not None
    title = f"{'Energy balance' if balance else 'Energy error'}: {_subtitle(view)}"
    if view.max_energy_error is not None:
        title += f" (max residual {view.max_energy_error:.2g})" if balance else f" (max {view.max_energy_error:.2g})"
    _title(fig, title)
    ax.set_xlabel("t (s)")
    if balance:
        ax.set_ylabel("residual\n|E - E0 - W| / S", fontsize=9)
    else:
        ax.set_ylabel("|E - E0 - W| / S\n(W: work by torque; S: well depth + max kinetic energy)", fontsize=9)
    ax.set_xlim(view.t[0], view.t[-1])
    ax.grid(alpha=0.3, which="both")


def _draw_balance(ax, view) -> None:
    """E - E0 and the signed work terms whose sum it equals (J), on a linear scale."""
    ax.plot(view.t, view.energy - view.energy[0], color="black", lw=1.6, label="$E - E_0$")
    colors = {"torque": "tab:blue", "pivot": "tab:green", "cart": "tab:purple", "dissipated": "tab:orange",
              "net": "tab:blue"}
    labels = {name: label for name, label, _ in _WORK_TERMS}
    labels["net"] = "$W$ (net work)"
    signs = {name: sign for name, _, sign in _WORK_TERMS}
    for name, values in view.work.items():
        ax.plot(view.t, signs.get(name, 1.0) * values, color=colors[name], lw=1.1, ls="--", label=labels[name])
    ax.set_ylabel("energy (J)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=7.5, ncol=2)


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
    (x_lo, x_hi), (y_lo, y_hi) = motion_limits(view, 1.08)
    if tip.shape[0] > 1:
        segments = np.stack([tip[:-1], tip[1:]], axis=1)
        lc = LineCollection(segments, cmap="viridis", linewidths=0.8)
        lc.set_array(0.5 * (view.t[:-1] + view.t[1:]))
        ax.add_collection(lc)
        fig.colorbar(lc, ax=ax, label="t (s)", shrink=0.85)
    ax.plot(tip[0, 0], tip[0, 1], "o", color="tab:green", ms=5, label="start")
    ax.plot(tip[-1, 0], tip[-1, 1], "s", color="tab:red", ms=5, label="end")
    if view.cart_x is not None:
        ax.plot([x_lo, x_hi], [0.0, 0.0], color="0.35", lw=1.0, zorder=1, label="rail")
    if view.moving:
        ax.plot(view.pivot[:, 0], view.pivot[:, 1], color="black", lw=0.8, alpha=0.6, zorder=2)
        ax.plot(view.pivot[0, 0], view.pivot[0, 1], "^", color="black", ms=8, label="pivot (at start)")
    else:
        ax.plot(0.0, 0.0, "^", color="black", ms=8, label="pivot")
    ax.set_xlim(x_lo, x_hi)
    ax.set_ylim(y_lo, y_hi)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    _title(fig, f"Tip of link {view.lengths.shape[0]}: {_subtitle(view)}")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)


def motion_limits(view, margin: float = 1.1):
    """Square axis limits ``((x_lo, x_hi), (y_lo, y_hi))`` that hold the chain wherever its base
    goes: the pivot's range (lab frame, from ``view.pivot``) widened by ``margin`` times the
    chain's reach on every side (``(-reach, reach)`` for a fixed pivot)."""
    reach = float(np.sum(view.lengths)) * margin
    px, py = view.pivot[:, 0], view.pivot[:, 1]
    x_lo, x_hi = float(np.min(px)) - reach, float(np.max(px)) + reach
    y_lo, y_hi = float(np.min(py)) - reach, float(np.max(py)) + reach
    half = 0.5 * max(x_hi - x_lo, y_hi - y_lo)  # square, so an equal-aspect picture fills its axes
    cx, cy = 0.5 * (x_lo + x_hi), 0.5 * (y_lo + y_hi)
    return (cx - half, cx + half), (cy - half, cy + half)


_DRAW = {"angles": _draw_angles, "energy": _draw_energy, "phase": _draw_phase, "tip": _draw_tip}
