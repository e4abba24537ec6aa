"""Pictures of flip-time maps (:func:`multipendulum.flip_map`, :func:`multipendulum.sweep_flip_map`).

Each pixel is one initial state, coloured by the time its first flip took (a perceptual colour
map, logarithmic in time, with a colour bar in seconds). Two kinds of pixel never flip, and
they are told apart: where the chain's energy is below the least energy any flip needs
(:func:`multipendulum.flip_energy_threshold`), no flip is possible at all: hatched grey, bounded
by the energy-bound curve ``E(x, y) = E_flip``; where a flip was possible but did not happen by
``t_max``: white. Angles are shown in degrees (angular velocities in degrees per second).

Nothing is computed here except the energy on the plotting grid, by the core
(``chain.energy``), to draw the bound as a smooth curve.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Optional, Sequence, Tuple, Union

import numpy as np

from ._chain import Chain, as_state
from .chaos import FlipMap
from .errors import InputError

__all__ = ["plot_flip_map", "energy_grid", "axis_label", "check_picture", "MAX_SIDE"]

PathLike = Union[str, "os.PathLike[str]"]
CMAP = "viridis"
NEVER_COLOR = "white"          # could flip, but had not by t_max (viridis has no white)
FORBIDDEN_COLOR = "#cfcfcf"    # energy too low for any flip
HATCH_COLOR = "#8c8c8c"
BOUND_COLOR = "#e4002b"        # the energy-bound curve: a red no viridis shade comes near
LOG_DECADES = 2.0              # log colour scale from t_max / 100 to t_max
_MAX_PIXELS = 2048             # plot at most this many samples along an axis (maps of 4096^2)
_BOUND_SAMPLES = 600           # the energy field for the bound curve, per axis
MAX_SIDE = 16384               # the largest picture side in pixels (Agg stops at 2^16)


def check_picture(dpi, size: float = 6.4, names=None) -> None:
    """Refuse a picture resolution that is not a finite number > 0 or would not fit: a side
    beyond :data:`MAX_SIDE` pixels, or more memory than the core allows. ``names`` says how the
    caller names ``dpi`` (the command line: ``--dpi``)."""
    import math
    import numbers

    import multipendulum._core as _core

    name = (names or {}).get("dpi", "dpi")
    if isinstance(dpi, bool) or not isinstance(dpi, numbers.Real) or not math.isfinite(dpi) or not dpi > 0:
        raise InputError(f"{name} must be a finite number > 0, got {dpi!r}")
    width, height = size * dpi, size * 0.86 * dpi
    if width > MAX_SIDE:
        raise InputError(f"a picture {width:.0f} x {height:.0f} pixels ({name} = {dpi:g}) is larger than "
                         f"{MAX_SIDE} a side; lower {name} (150 gives {size * 150:.0f} x {size * 0.86 * 150:.0f})")
    # Agg's RGBA buffer and the PNG encoder's copy; the map itself is thinned to 2048 a side.
    _core.check_memory(width * height * 8.0, f"a picture of {width:.0f} x {height:.0f} pixels", f"lower {name}")


def axis_label(kind: str, link: int) -> str:
    """``"θ₁ (degrees)"`` style label for a varied quantity."""
    sym = "\\theta" if kind == "theta" else "\\omega"
    unit = "degrees" if kind == "theta" else "degrees/s"
    return f"${sym}_{{{link + 1}}}$ at release ({unit})"


def energy_grid(chain: Chain, x, y, vary=("theta", 0, "theta", 1), base_theta=None, base_omega=None) -> np.ndarray:
    """The chain's energy (J) at each initial state of a map's grid, shape (len(y), len(x))."""
    from .sweeps import _check_vary, _grid

    n = chain.n
    th_base = np.zeros(n) if base_theta is None else as_state(base_theta, "base_theta", n)
    om_base = np.zeros(n) if base_omega is None else as_state(base_omega, "base_omega", n)
    theta0, omega0 = _grid(np.asarray(y, float), np.asarray(x, float), _check_vary(vary, n), th_base, om_base)
    return np.asarray(chain.energy(theta0, omega0))


def _every(size: int) -> int:
    return max(1, int(np.ceil(size / _MAX_PIXELS)))


def _edges(v: np.ndarray) -> Tuple[float, float]:
    """Extent of pixel-centred samples (half a spacing beyond the first and last)."""
    if v.size == 1:
        return float(v[0]) - 0.5, float(v[0]) + 0.5
    h = 0.5 * (v[-1] - v[0]) / (v.size - 1)
    return float(v[0] - h), float(v[-1] + h)


def _fixed_values(chain, vary, base_theta, base_omega) -> str:
    """The initial values that are not varied, when they are not all zero: "θ₃ = 150°, ω = 0"."""
    if chain is None:
        return ""
    n = chain.n
    th = np.zeros(n) if base_theta is None else np.asarray(base_theta, dtype=float).reshape(n)
    om = np.zeros(n) if base_omega is None else np.asarray(base_omega, dtype=float).reshape(n)
    varied = {(vary[0], vary[1]), (vary[2], vary[3])}
    parts = []
    for kind, values, sym, unit in (("theta", th, "\\theta", "°"), ("omega", om, "\\omega", "°/s")):
        rest = [i for i in range(n) if (kind, i) not in varied]
        if rest and np.all(values[rest] == 0):
            parts.append(f"${sym}$ = 0" if len(rest) == n else ", ".join(f"${sym}_{{{i + 1}}}$" for i in rest) + " = 0")
        else:
            parts += [f"${sym}_{{{i + 1}}}$ = {np.degrees(values[i]):.4g}{unit}" for i in rest]
    if all(p.endswith("= 0") for p in parts):
        return ""
    return ", ".join(parts)


def plot_flip_map(fm: FlipMap, path: Optional[PathLike] = None, chain: Optional[Chain] = None,
                  vary: Sequence = ("theta", 0, "theta", 1), base_theta=None, base_omega=None,
                  title: Optional[str] = None, dpi: float = 150, log: bool = True, size: float = 6.4):
    """Draw a flip-time map; write it to ``path`` (PNG, atomically) and return the path, or
    return the Matplotlib figure when ``path`` is None.

    ``chain`` (with the ``vary``, ``base_theta`` and ``base_omega`` the map was made with) lets
    the energy bound be drawn as a smooth curve from the chain's energy on a fine grid; without
    it the bound is traced from the map's own ``allowed`` mask. ``log``: colour by log time
    (the structure of a flip map spans decades), else linearly. Grids larger than 2048 along an
    axis are thinned for the picture (and the percentages in the legend are of the pixels shown).
    The energy bound holds for the free chain: a map made with a driving torque should not be
    read by it.
    """
    import matplotlib
    from matplotlib.colors import LogNorm, Normalize
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch
    from matplotlib.lines import Line2D

    check_picture(dpi, size)
    kx, ix, ky, iy = vary
    x = np.asarray(fm.x, dtype=float)
    y = np.asarray(fm.y, dtype=float)
    sx, sy = _every(x.size), _every(y.size)
    times = np.asarray(fm.times[::sy, ::sx], dtype=float)
    allowed = np.asarray(fm.allowed[::sy, ::sx], dtype=bool)
    xs, ys = np.degrees(x[::sx]), np.degrees(y[::sy])
    t_max = float(fm.t_max)
    if times.shape != (ys.size, xs.size):
        raise InputError(f"flip map times must have shape (len(y), len(x)) = {(y.size, x.size)}, got {fm.times.shape}")

    flipped = np.isfinite(times)
    never = ~flipped & allowed
    forbidden = ~allowed
    from .plotting import fit_title

    fig = Figure(figsize=(size, size * 0.86), dpi=dpi)
    # A long title takes two lines (never clipped); the axes make room for the second.
    heading = fit_title(title or "Time of the first flip", 0.94 * size, 11.0, max_lines=2)
    height = 0.72 - 0.05 * heading.count("\n")
    ax = fig.add_axes((0.12, 0.18, 0.68, height))
    cax = fig.add_axes((0.83, 0.18, 0.03, height))
    extent = (*_edges(xs), *_edges(ys))

    vmin = t_max * 10.0 ** -LOG_DECADES
    norm = LogNorm(vmin=vmin, vmax=t_max) if log else Normalize(0.0, t_max)
    below = bool(log and np.any(times[flipped] < vmin))
    cmap = matplotlib.colormaps[CMAP].with_extremes(bad=NEVER_COLOR)
    image = ax.imshow(np.ma.masked_array(times, ~flipped), origin="lower", extent=extent, cmap=cmap, norm=norm,
                      interpolation="antialiased", interpolation_stage="rgba", aspect="auto")
    cb = fig.colorbar(image, cax=cax, extend="min" if below else "neither")
    cb.set_label("time of the first flip (s)")
    if log:
        decades = 10.0 ** np.arange(np.floor(np.log10(vmin)), np.ceil(np.log10(t_max)) + 1)
        ticks = np.unique(np.concatenate([np.outer(decades, [1, 2, 5]).ravel(), [t_max]]))
        ticks = ticks[(ticks >= vmin * (1 - 1e-9)) & (ticks <= t_max * (1 + 1e-9))]
        cb.set_ticks(ticks, labels=[f"{v:g}" for v in ticks])
        cb.ax.minorticks_off()

    # The forbidden region: hatched grey, from the smooth energy field when we have the chain.
    fine_x = fine_y = field = None
    if chain is not None:
        # edge to edge of the picture, so the curve reaches its border
        fine_x = np.radians(np.linspace(extent[0], extent[1], max(_BOUND_SAMPLES, min(xs.size, 1200))))
        fine_y = np.radians(np.linspace(extent[2], extent[3], max(_BOUND_SAMPLES, min(ys.size, 1200))))
        field = energy_grid(chain, fine_x, fine_y, vary, base_theta, base_omega) - fm.threshold
        fine_x, fine_y = np.degrees(fine_x), np.degrees(fine_y)
    elif forbidden.any() and allowed.any():
        fine_x, fine_y, field = xs, ys, np.where(allowed, 1.0, -1.0)
    if field is not None and (field < 0).any():
        big = float(np.max(np.abs(field))) + 1.0
        levels = [-big, 0.0]
        with matplotlib.rc_context({"hatch.color": HATCH_COLOR, "hatch.linewidth": 0.6}):
            ax.contourf(fine_x, fine_y, field, levels=levels, colors=[FORBIDDEN_COLOR], hatches=["////"],
                        zorder=2)
        if (field > 0).any():
            ax.contour(fine_x, fine_y, field, levels=[0.0], colors=[BOUND_COLOR], linewidths=1.6, zorder=4)
    elif forbidden.all():
        ax.imshow(np.ones_like(times), origin="lower", extent=extent, cmap=matplotlib.colors.ListedColormap(
            [FORBIDDEN_COLOR]), aspect="auto", zorder=2)

    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    for axis, kind, (lo, hi) in ((ax.xaxis, kx, extent[:2]), (ax.yaxis, ky, extent[2:])):
        if kind == "theta" and hi - lo >= 180:
            step = 90 if hi - lo >= 270 else 45
            axis.set_ticks(np.arange(np.ceil(lo / step - 1e-9) * step, hi + 1e-9 * step, step))
    ax.set_xlabel(axis_label(kx, ix))
    ax.set_ylabel(axis_label(ky, iy))
    frac = lambda m: f"{100 * m.mean():.1f}%"  # noqa: E731
    handles = [
        Patch(facecolor=NEVER_COLOR, edgecolor="0.3", lw=0.6, label=f"no flip by t = {t_max:g} s ({frac(never)})"),
        Patch(facecolor=FORBIDDEN_COLOR, edgecolor=HATCH_COLOR, hatch="////", lw=0.6,
              label=f"no flip possible: $E < E_\\mathrm{{flip}}$ ({frac(forbidden)})"),
        Line2D([], [], color=BOUND_COLOR, lw=1.6,
               label=f"energy bound $E = E_\\mathrm{{flip}}$ = {fm.threshold:.4g} J"),
    ]
    fig.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.46, 0.0), ncol=2, fontsize=8,
               frameon=False, handlelength=1.8, columnspacing=1.4)
    fig.suptitle(heading, fontsize=11, y=0.975)
    subtitle = f"{y.size} x {x.size} initial states, {frac(flipped)} flipped by {t_max:g} s"
    fixed = _fixed_values(chain, (kx, ix, ky, iy), base_theta, base_omega)
    ax.set_title(subtitle + (f"; {fixed}" if fixed else ""), fontsize=8, color="0.3")
    if path is None:
        return fig
    from ._files import atomic_path

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".").lower() or "png")
    return path
