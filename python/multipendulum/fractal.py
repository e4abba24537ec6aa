"""Pictures of flip-time maps (:func:`multipendulum.flip_map`, :func:`multipendulum.sweep_flip_map`)
and of chaos-indicator maps (:func:`multipendulum.indicator_map`, :func:`plot_indicator_map`).

Each pixel is one initial state, coloured by the time its first flip took (a perceptual colour
map, logarithmic in time, with a colour bar in seconds). Two kinds of pixel never flip, and
they are told apart: where the chain's energy is below the least energy any flip needs
(:func:`multipendulum.flip_energy_threshold`), no flip is possible at all: hatched grey, bounded
by the energy-bound curve ``E(x, y) = E_flip``; where a flip was possible but did not happen by
``t_max``: white. Angles are shown in degrees (angular velocities in degrees per second).

Nothing is computed here except the energy on the plotting grid, by the core
(``chain.energy``), to draw the bound as a smooth curve.

An indicator map is coloured by the indicator's value at ``t_end``, on a scale chosen per
indicator (:data:`INDICATOR_STYLES`) so that chaotic orbits are at the bright end of the colour
map for every indicator: MEGNO linear on [0, 8] with its regular value 2 marked, FLI and OFLI
linear, SALI and GALI logarithmic with a floor at 1e-16, the Lyapunov exponent linear in 1/s.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple, Optional, Sequence, Tuple, Union

import numpy as np

from ._chain import Chain, as_state
from .chaos import CHAOS_RULES, FlipMap, FlipVolume, IndicatorMap
from .errors import InputError

__all__ = ["plot_flip_map", "plot_flip_volume", "plot_indicator_map", "indicator_label", "INDICATOR_STYLES", "LOG_FLOOR", "energy_grid",
           "axis_label", "check_picture", "MAX_SIDE"]

PathLike = Union[str, "os.PathLike[str]"]
CMAP = "viridis"
NEVER_COLOR = "white"          # could flip, but had not by t_max (viridis has no white)
FORBIDDEN_COLOR = "#cfcfcf"    # energy too low for any flip
HATCH_COLOR = "#8c8c8c"
BOUND_COLOR = "#e4002b"        # the energy-bound curve: a red no viridis shade comes near
UNCERTAIN_COLOR = "#e7298a"    # a certified map's cells that change with the step: magenta, no viridis shade
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


def _label_axes(ax, extent, vary) -> None:
    """Limits, ticks every 45 or 90 degrees along a wide angle axis, and the axis labels."""
    kx, ix, ky, iy = vary
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    for axis, kind, (lo, hi) in ((ax.xaxis, kx, extent[:2]), (ax.yaxis, ky, extent[2:])):
        if kind == "theta" and hi - lo >= 180:
            step = 90 if hi - lo >= 270 else 45
            axis.set_ticks(np.arange(np.ceil(lo / step - 1e-9) * step, hi + 1e-9 * step, step))
    ax.set_xlabel(axis_label(kx, ix))
    ax.set_ylabel(axis_label(ky, iy))


def _save(fig, path: PathLike) -> Path:
    """Write the figure to ``path`` atomically, in the format its suffix names (PNG by default)."""
    from ._files import atomic_path

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".").lower() or "png")
    return path


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
    read by it. A certified map (``certify=True``) draws its uncertain cells in magenta, counted
    in the legend.
    """
    from matplotlib.figure import Figure

    check_picture(dpi, size)
    from .plotting import fit_title

    fig = Figure(figsize=(size, size * 0.86), dpi=dpi)
    # A long title takes two lines (never clipped); the axes make room for the second.
    heading = fit_title(title or "Time of the first flip", 0.94 * size, 11.0, max_lines=2)
    height = 0.72 - 0.05 * heading.count("\n")
    ax = fig.add_axes((0.12, 0.18, 0.68, height))
    cax = fig.add_axes((0.83, 0.18, 0.03, height))
    drawn = _draw_flip(ax, fm, chain, vary, base_theta, base_omega, log)
    _flip_colorbar(fig, cax, drawn, fm.t_max, log)
    _flip_legend(fig, [drawn], fm)
    fig.suptitle(heading, fontsize=11, y=0.975)
    frac = lambda m: f"{100 * m.mean():.1f}%"  # noqa: E731
    x, y = np.asarray(fm.x), np.asarray(fm.y)
    subtitle = f"{y.size} x {x.size} initial states, {frac(drawn.flipped)} flipped by {fm.t_max:g} s" \
        + ("" if drawn.uncertain is None else f", {frac(drawn.uncertain)} uncertain")
    fixed = _fixed_values(chain, tuple(vary), base_theta, base_omega)
    ax.set_title(subtitle + (f"; {fixed}" if fixed else ""), fontsize=8, color="0.3")
    if path is None:
        return fig
    return _save(fig, path)


class _Drawn(NamedTuple):
    """What :func:`_draw_flip` drew: the image (for a colour bar) and the pixels' classes."""

    image: object
    flipped: np.ndarray
    never: np.ndarray
    forbidden: np.ndarray
    uncertain: Optional[np.ndarray]
    below: bool


def _draw_flip(ax, fm: FlipMap, chain: Optional[Chain], vary: Sequence, base_theta, base_omega, log: bool) -> _Drawn:
    """One flip map onto ``ax``: the times coloured by log time (or linearly), the certified
    map's uncertain cells in magenta, the forbidden region hatched with its energy bound, the
    axes labelled."""
    import matplotlib
    from matplotlib.colors import LogNorm, Normalize

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
    uncertain = None if fm.uncertain is None else np.asarray(fm.uncertain[::sy, ::sx], dtype=bool)
    extent = (*_edges(xs), *_edges(ys))
    vmin = t_max * 10.0 ** -LOG_DECADES
    norm = LogNorm(vmin=vmin, vmax=t_max) if log else Normalize(0.0, t_max)
    below = bool(log and np.any(times[flipped] < vmin))
    cmap = matplotlib.colormaps[CMAP].with_extremes(bad=NEVER_COLOR)
    image = ax.imshow(np.ma.masked_array(times, ~flipped), origin="lower", extent=extent, cmap=cmap, norm=norm,
                      interpolation="antialiased", interpolation_stage="rgba", aspect="auto")
    if uncertain is not None and uncertain.any():
        ax.imshow(np.ma.masked_array(np.ones_like(times), ~uncertain), origin="lower", extent=extent,
                  cmap=matplotlib.colors.ListedColormap([UNCERTAIN_COLOR]), interpolation="nearest", aspect="auto",
                  zorder=1.5)

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
    _label_axes(ax, extent, (kx, ix, ky, iy))
    return _Drawn(image, flipped, never, forbidden, uncertain, below)


def _flip_colorbar(fig, cax, drawn: _Drawn, t_max: float, log: bool) -> None:
    cb = fig.colorbar(drawn.image, cax=cax, extend="min" if drawn.below else "neither")
    cb.set_label("time of the first flip (s)")
    if log:
        vmin = t_max * 10.0 ** -LOG_DECADES
        decades = 10.0 ** np.arange(np.floor(np.log10(vmin)), np.ceil(np.log10(t_max)) + 1)
        ticks = np.unique(np.concatenate([np.outer(decades, [1, 2, 5]).ravel(), [t_max]]))
        ticks = ticks[(ticks >= vmin * (1 - 1e-9)) & (ticks <= t_max * (1 + 1e-9))]
        cb.set_ticks(ticks, labels=[f"{v:g}" for v in ticks])
        cb.ax.minorticks_off()


def _flip_legend(fig, drawn: Sequence[_Drawn], fm) -> None:
    """The legend of one map or of a volume's slices (the percentages over all the pixels drawn)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    frac = lambda m: f"{100 * np.mean(np.concatenate([x.ravel() for x in m])):.1f}%"  # noqa: E731
    handles = [
        Patch(facecolor=NEVER_COLOR, edgecolor="0.3", lw=0.6,
              label=f"no flip by t = {fm.t_max:g} s ({frac([d.never for d in drawn])})"),
        Patch(facecolor=FORBIDDEN_COLOR, edgecolor=HATCH_COLOR, hatch="////", lw=0.6,
              label=f"no flip possible: $E < E_\\mathrm{{flip}}$ ({frac([d.forbidden for d in drawn])})"),
        Line2D([], [], color=BOUND_COLOR, lw=1.6,
               label=f"energy bound $E = E_\\mathrm{{flip}}$ = {fm.threshold:.4g} J"),
    ]
    if fm.uncertain is not None:
        unsure = frac([d.uncertain for d in drawn if d.uncertain is not None])
        handles.insert(1, Patch(facecolor=UNCERTAIN_COLOR, edgecolor="0.3", lw=0.6,
                                label=f"uncertain: changes at dt / 2 (by > {fm.time_tolerance:g} s) ({unsure})"))
    fig.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.46, 0.0), ncol=2, fontsize=8,
               frameon=False, handlelength=1.8, columnspacing=1.4)


def plot_flip_volume(fv: FlipVolume, path: Optional[PathLike] = None, chain: Optional[Chain] = None,
                     base_theta=None, base_omega=None, slices: Optional[Sequence[int]] = None,
                     title: Optional[str] = None, dpi: float = 120, log: bool = True, size: float = 10.0):
    """Draw a 3-D flip map (:func:`multipendulum.flip_volume` or
    :func:`multipendulum.sweeps.sweep_flip_volume`) as slices: one panel per index of ``z`` in
    ``slices`` (default: up to nine evenly spaced), each drawn as :func:`plot_flip_map` draws a map
    (the energy bound of that slice from ``chain``, with ``base_theta``/``base_omega`` the volume
    was made with), one colour scale and one legend for all (its percentages over the panels
    drawn). Writes ``path`` (PNG, atomically) and returns it, or returns the figure.
    """
    from matplotlib.figure import Figure

    from .plotting import fit_title

    if not isinstance(fv, FlipVolume):
        raise InputError(f"fv must be a multipendulum.FlipVolume, got {type(fv).__name__}")
    nz = int(np.asarray(fv.z).size)
    if slices is None:
        slices = sorted({int(round(v)) for v in np.linspace(0, nz - 1, min(9, nz))})
    picked = []
    for k in slices:
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < nz:
            raise InputError(f"slices must be indices of z (0 <= k < {nz}), got {k!r}")
        picked.append(int(k))
    if not picked or len(picked) > 36:
        raise InputError(f"slices must name between 1 and 36 slices, got {len(picked)}")
    check_picture(dpi, size)
    cols = min(3, len(picked))
    rows = -(-len(picked) // cols)
    panel = size / cols
    fig = Figure(figsize=(size, panel * rows * 0.9 + 1.6), dpi=dpi)
    height_in = panel * rows * 0.9 + 1.6
    heading = fit_title(title or "Time of the first flip, in slices", 0.94 * size, 11.0, max_lines=2)
    kz, iz = fv.vary[4], fv.vary[5]
    drawn = []
    top, bottom = 1.0 - 0.9 / height_in, 0.9 / height_in
    cell_h = (top - bottom) / rows
    for p, k in enumerate(picked):
        r, c = divmod(p, cols)
        ax = fig.add_axes((0.08 + c * 0.84 / cols, top - (r + 1) * cell_h + 0.12 * cell_h, 0.84 / cols * 0.72,
                           cell_h * 0.72))
        z = float(np.asarray(fv.z)[k])
        th = om = None
        if chain is not None:
            # The slice's own base state: the volume's, with the third quantity at z[k].
            th = np.zeros(chain.n) if base_theta is None else as_state(base_theta, "base_theta", chain.n).copy()
            om = np.zeros(chain.n) if base_omega is None else as_state(base_omega, "base_omega", chain.n).copy()
            (th if kz == "theta" else om)[iz] = z
        drawn.append(_draw_flip(ax, fv.slice(k), chain, fv.vary[:4], th, om, log))
        unit, value = ("°" if kz == "theta" else "°/s"), np.degrees(z)
        sym = "\\theta" if kz == "theta" else "\\omega"
        ax.set_title(f"${sym}_{{{iz + 1}}}$ = {value:.4g}{unit}", fontsize=9)
        for label in (ax.xaxis.label, ax.yaxis.label):
            label.set_fontsize(8)
        ax.tick_params(labelsize=7)
    cax = fig.add_axes((0.87, bottom + 0.1 * (top - bottom), 0.015, 0.8 * (top - bottom)))
    _flip_colorbar(fig, cax, drawn[0], fv.t_max, log)
    _flip_legend(fig, drawn, fv)
    fig.suptitle(heading, fontsize=11, y=1.0 - 0.25 / height_in)
    if path is None:
        return fig
    return _save(fig, path)


# ----------------------------------------------------------------------------------------------
# Chaos-indicator maps


class IndicatorStyle(NamedTuple):
    """How an indicator's map is drawn."""

    #: its name in titles and summaries (GALI gets its order appended)
    name: str
    #: the colour bar's label
    label: str
    #: "linear" or "log" (log: values below :data:`LOG_FLOOR` drawn at the floor)
    scale: str
    #: the colour scale's limits, or None for the map's own range
    limits: Optional[Tuple[float, float]]
    #: reversed colours: for the indicators that are small on chaotic orbits
    reverse: bool = False
    #: a value marked on the colour bar, and its label
    mark: Optional[Tuple[float, str]] = None


#: The smallest SALI or GALI drawn: round-off level, where a chaotic orbit's index ends up.
LOG_FLOOR = 1e-16
#: How each of :data:`multipendulum.INDICATORS` is drawn (an indicator not listed: linear, its
#: own range).
INDICATOR_STYLES = {
    "megno": IndicatorStyle("MEGNO", r"MEGNO $\langle Y \rangle$ (2: regular; grows ~ $\lambda t / 2$ if chaotic)",
                            "linear", (0.0, 8.0), mark=(2.0, "2 regular")),
    "fli": IndicatorStyle("FLI", r"FLI $\sup\, \ln |d|$ (~ $\ln t$ regular, ~ $\lambda t$ chaotic)", "linear", None),
    "ofli": IndicatorStyle("OFLI", r"OFLI, orthogonal FLI (bounded on periodic orbits)", "linear", None),
    "sali": IndicatorStyle("SALI", r"SALI (log scale; -> 0 chaotic, > 0 regular)", "log", (LOG_FLOOR, np.sqrt(2.0)),
                           reverse=True),
    "gali": IndicatorStyle("GALI", r"GALI (log scale; -> 0 fast if chaotic)", "log", (LOG_FLOOR, 1.0), reverse=True),
    "lyapunov": IndicatorStyle("Lyapunov exponent", "largest Lyapunov exponent, finite-time estimate (1/s)",
                               "linear", None),
}


def _style(name: str) -> IndicatorStyle:
    return INDICATOR_STYLES.get(name, IndicatorStyle(name.upper(), name, "linear", None))


def indicator_label(name: str, k=None) -> str:
    """The indicator's name as titles give it: ``"MEGNO"``, ``"GALI_3"`` (with its order ``k``)."""
    base = _style(name).name
    return f"{base}_{int(k)}" if name == "gali" and k is not None else base


def _chain_words(chain: Optional[Chain]) -> str:
    """The chain in a few words: "double pendulum, l = 1, 1 m, m = 1, 1 kg"."""
    if chain is None:
        return ""
    n = chain.n
    kind = {1: "pendulum", 2: "double pendulum", 3: "triple pendulum"}.get(n, f"{n}-link chain")
    fmt = lambda v: ", ".join(f"{float(a):.3g}" for a in v)  # noqa: E731
    if n <= 4:
        words = f"{kind}, l = {fmt(chain.lengths)} m, m = {fmt(chain.masses)} kg"
    else:
        words = f"{kind}, length {float(np.sum(chain.lengths)):.3g} m, mass {float(np.sum(chain.masses)):.3g} kg"
    if chain.dissipative:
        words += ", with losses"
    return words


def _limits(values: np.ndarray, style: IndicatorStyle, vmin, vmax) -> Tuple[float, float]:
    lo, hi = style.limits if style.limits is not None else (None, None)
    finite = values[np.isfinite(values)]
    if lo is None:
        lo = float(finite.min()) if finite.size else 0.0
    if hi is None:
        hi = float(finite.max()) if finite.size else 1.0
    lo = lo if vmin is None else float(vmin)
    hi = hi if vmax is None else float(vmax)
    if not hi > lo:
        pad = 0.5 if style.scale == "linear" else 10.0
        lo, hi = (lo - pad, hi + pad) if style.scale == "linear" else (lo / pad, hi * pad)
    return lo, hi


def plot_indicator_map(im: IndicatorMap, path: Optional[PathLike] = None, chain: Optional[Chain] = None,
                       vary: Sequence = ("theta", 0, "theta", 1), base_theta=None, base_omega=None, k=None,
                       title: Optional[str] = None, dpi: float = 150, size: float = 6.4, vmin=None, vmax=None):
    """Draw a chaos-indicator map (:func:`multipendulum.indicator_map` or
    :func:`multipendulum.sweep_indicator_map`); write it to ``path`` (PNG, atomically) and return
    the path, or return the Matplotlib figure when ``path`` is None.

    Each pixel is one initial state, coloured by the indicator at ``t_end`` on its own scale
    (:data:`INDICATOR_STYLES`): MEGNO linear on [0, 8] with 2 (regular) marked on the colour bar,
    FLI and OFLI linear over the map's range, SALI and GALI logarithmic down to
    :data:`LOG_FLOOR` (smaller values, zero included, drawn at the floor), the largest Lyapunov
    exponent linear in 1/s. Chaotic orbits are at the bright end for every indicator; values
    beyond the scale get an arrow on the colour bar; a cell without a finite value is white. A
    certified map (``certify=True``) draws its uncertain cells in magenta, counted in the legend.
    ``vmin``/``vmax`` override the scale's limits. The title names the indicator (``k``: GALI's
    order), ``t_end`` and, given ``chain``, the chain (``title`` replaces it); ``vary``,
    ``base_theta`` and ``base_omega`` (those the map was made with) label the axes and list the
    initial values not varied. Grids larger than 2048 along an axis are thinned for the picture.
    """
    import matplotlib
    from matplotlib.colors import LogNorm, Normalize
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    from .plotting import fit_title

    if not isinstance(im, IndicatorMap):
        raise InputError(f"im must be a multipendulum.IndicatorMap, got {type(im).__name__}")
    check_picture(dpi, size)
    kx, ix, ky, iy = vary
    x = np.asarray(im.x, dtype=float)
    y = np.asarray(im.y, dtype=float)
    sx, sy = _every(x.size), _every(y.size)
    values = np.asarray(im.values[::sy, ::sx], dtype=float)
    uncertain = None if im.uncertain is None else np.asarray(im.uncertain[::sy, ::sx], dtype=bool)
    xs, ys = np.degrees(x[::sx]), np.degrees(y[::sy])
    if values.shape != (ys.size, xs.size):
        raise InputError(f"indicator map values must have shape (len(y), len(x)) = {(y.size, x.size)}, "
                         f"got {tuple(im.values.shape)}")
    style = _style(im.indicator)
    k = getattr(im, "k", None) if k is None else k  # the map's own order unless given
    name = indicator_label(im.indicator, k)
    t_end = float(im.t_end)
    finite = np.isfinite(values)
    shown = np.maximum(values, LOG_FLOOR) if style.scale == "log" else values
    lo, hi = _limits(shown, style, vmin, vmax)
    norm = LogNorm(vmin=lo, vmax=hi) if style.scale == "log" else Normalize(lo, hi)
    below = bool(np.any(shown[finite] < lo * (1 - 1e-12) if lo > 0 else shown[finite] < lo))
    above = bool(np.any(shown[finite] > hi))
    extend = {(True, True): "both", (True, False): "min", (False, True): "max"}.get((below, above), "neither")

    fig = Figure(figsize=(size, size * 0.86), dpi=dpi)
    words = _chain_words(chain)
    default = f"{name} at t = {t_end:g} s" + (f": {words}" if words else "")
    heading = fit_title(title or default, 0.94 * size, 11.0, max_lines=2)
    bottom = 0.16 if finite.all() and uncertain is None else 0.2
    height = 0.90 - bottom - 0.05 * heading.count("\n")
    ax = fig.add_axes((0.12, bottom, 0.66, height))
    cax = fig.add_axes((0.81, bottom, 0.03, height))
    extent = (*_edges(xs), *_edges(ys))
    cmap = matplotlib.colormaps[CMAP + ("_r" if style.reverse else "")].with_extremes(bad=NEVER_COLOR)
    image = ax.imshow(np.ma.masked_array(shown, ~finite), origin="lower", extent=extent, cmap=cmap, norm=norm,
                      interpolation="antialiased", interpolation_stage="rgba", aspect="auto")
    if uncertain is not None and uncertain.any():
        ax.imshow(np.ma.masked_array(np.ones_like(values), ~uncertain), origin="lower", extent=extent,
                  cmap=matplotlib.colors.ListedColormap([UNCERTAIN_COLOR]), interpolation="nearest", aspect="auto")
    cb = fig.colorbar(image, cax=cax, extend=extend)
    label = style.label.replace("GALI", f"GALI$_{{{int(k)}}}$", 1) if im.indicator == "gali" and k is not None \
        else style.label
    cb.set_label(label, fontsize=8)
    if style.scale == "log":
        decades = np.arange(np.ceil(np.log10(lo) - 1e-9), np.floor(np.log10(hi) + 1e-9) + 1)
        step = max(1, int(np.ceil(decades.size / 9)))
        ticks = 10.0 ** decades[::-1][::step][::-1]
        cb.set_ticks(ticks, labels=[f"$10^{{{int(round(np.log10(t)))}}}$" for t in ticks])
        cb.ax.minorticks_off()
    if style.mark is not None and lo <= style.mark[0] <= hi:
        level, text = style.mark
        cb.ax.axhline(level, color="white", lw=1.6)
        cb.ax.axhline(level, color="black", lw=0.6)
        ticks = sorted(set(np.round(cb.get_ticks(), 12)) | {level})
        ticks = [t for t in ticks if lo <= t <= hi]
        cb.set_ticks(ticks, labels=[text if t == level else f"{t:g}" for t in ticks])
    _label_axes(ax, extent, (kx, ix, ky, iy))
    handles = []
    if not finite.all():
        handles.append(Patch(facecolor=NEVER_COLOR, edgecolor="0.3", lw=0.6,
                             label=f"no finite value ({100 * (~finite).mean():.1f}%)"))
    if uncertain is not None:
        side = ">" if CHAOS_RULES.get(im.indicator, (True, None))[0] else "<"
        handles.append(Patch(facecolor=UNCERTAIN_COLOR, edgecolor="0.3", lw=0.6,
                             label=f"uncertain: {name} {side} {im.threshold:g} changes at dt / 2 "
                                   f"({100 * uncertain.mean():.1f}%)"))
    if handles:
        fig.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.46, 0.0), fontsize=8, frameon=False,
                   handlelength=1.8, ncol=len(handles))
    fig.suptitle(heading, fontsize=11, y=0.975)
    # The chain is named in the heading, or here when a title replaced it.
    subtitle = f"{y.size} x {x.size} initial states" + (f"; {words}" if title and words else "")
    fixed = _fixed_values(chain, (kx, ix, ky, iy), base_theta, base_omega)
    ax.set_title(subtitle + (f"; {fixed}" if fixed else ""), fontsize=8, color="0.3")
    if path is None:
        return fig
    return _save(fig, path)
