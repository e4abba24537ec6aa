"""Animations of a run: GIF through Pillow, MP4 through the ffmpeg shipped by imageio-ffmpeg.

Frames are drawn with Matplotlib's Agg canvas (no GUI backend, no pyplot state): the static
parts (axes, a fixed pivot's support, a moving pivot's path, a cart's rail) once, then per
frame the rods, the bobs, the pivot (and the cart, a block centred on ``sol.cart_x``), the
fading trail of the last tip and the time and energy-error labels. Joint positions come from
the chain (``chain.positions``, relative to the pivot) at each frame time, so links stay rigid
between samples, plus the pivot's lab position (``sol.pivot``: the run's :class:`Pivot`
evaluated by the core at the frame time, a cart's position interpolated). The axes hold the
whole motion of the base.
"""
from __future__ import annotations

import math
import numbers
import os
from pathlib import Path
from typing import Any, Callable, Optional, Union

import numpy as np

from ._files import atomic_path
from .plotting import base_motion, motion_limits
from .results import series

__all__ = ["animate", "frame_times", "plan", "frame_count", "MAX_FRAMES", "MAX_SIDE", "MAX_PIXEL_FRAMES"]

PathLike = Union[str, "os.PathLike[str]"]
_FORMATS = (".gif", ".mp4")
_ROD = "#2b2b2b"
_BOB = "#1f77b4"
_TRAIL = np.array([0.84, 0.15, 0.16])  # tab:red
_CART = "#9aa5b1"


# The cost of an animation (re-exported here, where callers look for them).
from ._frames import MAX_FRAMES, MAX_PIXEL_FRAMES, MAX_SIDE, frame_count, frame_times, plan  # noqa: E402,F401
from ._frames import _side  # noqa: E402,F401


def animate(
    sol: Any,
    path: PathLike,
    fps: float = 30,
    trail: float = 2.0,
    speed: float = 1.0,
    dpi: float = 80,
    size: float = 5.0,
    title: Optional[str] = None,
    progress: Any = None,
    names: Optional[dict] = None,
) -> Path:
    """Write an animation of a solution (or loaded results) to ``path`` (``.gif`` or ``.mp4``).

    ``fps`` frames per second of the file; ``speed`` simulated seconds per second of playback
    (1 = real time); ``trail`` seconds of simulated time the last link's tip leaves behind
    (0 for none); ``size`` the frame's side in inches at ``dpi`` dots per inch (rounded to a
    multiple of 16 pixels, which video encoders like). The file is written atomically.
    ``progress``: True for a bar on stderr, or a callable given the fraction of frames drawn
    (see :mod:`multipendulum._progress`). Returns the path.

    Settings are checked against the animation's cost before anything is drawn (see
    :func:`plan`): at most :data:`MAX_FRAMES` frames, :data:`MAX_SIDE` pixels a side,
    :data:`MAX_PIXEL_FRAMES` pixels in all, and the memory the core allows. ``names`` (for
    callers such as the command line) says how the messages should name the settings.
    A batch :class:`~multipendulum.Solution` is refused: animate one trajectory.
    """
    from .errors import InputError

    from ._progress import reporter

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in _FORMATS:
        raise InputError(f"animation file must end in .gif or .mp4, got {str(path)!r}")
    view = base_motion(sol, series(sol, "mp.animate"))
    plan(float(view.t[0]), float(view.t[-1]), fps, speed, dpi, size, trail, n=view.theta.shape[1],
         format=suffix, names=names)  # refuses what would not fit before anything is drawn
    times = frame_times(float(view.t[0]), float(view.t[-1]), fps, speed)
    with reporter(progress, "animate") as report:
        joints, bases = _frame_positions(view, times)
        painter = _Painter(view, dpi=dpi, size=size, title=title, speed=speed)
        path.parent.mkdir(parents=True, exist_ok=True)
        frames = (painter.frame(k, times[k], joints[k], trail, base=bases[k]) for k in range(len(times)))
        with atomic_path(path) as tmp:
            if suffix == ".gif":
                _write_gif(tmp, frames, len(times), fps, report)
            else:
                _write_mp4(tmp, frames, len(times), fps, painter.pixels, report)
    return path


def _frame_positions(view, times: np.ndarray):
    """``(joints, bases)`` at the frame times: (F, N, 2) joint positions and (F, 2) pivot
    positions, both in the lab frame. The joints are the chain's positions of the angles
    interpolated between samples (exact at sample times) plus the pivot's position: the run's
    :class:`Pivot` evaluated by the core, else (a cart, a results file) the samples interpolated.
    Without a chain, the nearest sample of the stored positions."""
    t = view.t
    if view.chain is not None and len(t) > 1:
        theta = np.empty((len(times), view.theta.shape[1]))
        for i in range(view.theta.shape[1]):
            theta[:, i] = np.interp(times, t, view.theta[:, i])
        if view.pivot_path is not None:
            bases = np.asarray(view.pivot_path.position(times), dtype=float).reshape(len(times), 2)
        else:
            bases = np.stack([np.interp(times, t, view.pivot[:, 0]), np.interp(times, t, view.pivot[:, 1])], axis=1)
        joints = np.asarray(view.chain.positions(theta), dtype=float) + bases[:, None, :]
        return joints, bases
    idx = np.clip(np.searchsorted(t, times), 0, len(t) - 1)
    prev = np.clip(idx - 1, 0, len(t) - 1)
    nearest = np.where(np.abs(times - t[prev]) < np.abs(t[idx] - times), prev, idx)
    return view.positions[nearest], view.pivot[nearest]


class _Painter:
    def __init__(self, view, dpi: float, size: float, title: Optional[str], speed: float):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.collections import LineCollection
        from matplotlib.figure import Figure

        if not hasattr(view, "moving"):  # a bare series(): the base recovered from its positions
            view = base_motion(None, view)
        self.view = view
        pixels = int(_side(size, dpi))
        self.pixels = pixels
        self.fig = Figure(figsize=(pixels / dpi, pixels / dpi), dpi=dpi)
        self.canvas = FigureCanvasAgg(self.fig)
        ax = self.fig.add_axes((0.11, 0.09, 0.85, 0.82))
        self.ax = ax
        lengths, masses = view.lengths, view.masses
        reach = float(np.sum(lengths)) * 1.1
        xlim, ylim = motion_limits(view, 1.1)
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)", fontsize=8)
        ax.set_ylabel("y (m)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.25)
        if title is None:
            title = view.name or f"{lengths.shape[0]}-link pendulum"
            if view.method:
                title += f" ({view.method})"
        from .plotting import fit_title

        # Two lines fit above the axes; a longer title ends in an ellipsis rather than being clipped.
        self.fig.suptitle(fit_title(title, 0.94 * pixels / dpi, 9.0, max_lines=2), fontsize=9, y=0.985)
        if speed != 1:
            ax.text(0.99, 0.99, f"speed x{speed:g}", transform=ax.transAxes, ha="right", va="top", fontsize=7)

        # Sizes in points from the axes' scale, so a 50-link chain has small bobs and thin rods.
        ax_width_pt = 0.85 * pixels / dpi * 72.0
        pt_per_m = ax_width_pt / (xlim[1] - xlim[0])
        shortest = float(np.min(lengths)) * pt_per_m
        rod_width = float(np.clip(0.08 * shortest, 0.8, 3.5))
        biggest = float(np.clip(0.45 * shortest, 2.0, 16.0))
        m_max = float(np.max(masses)) if np.max(masses) > 0 else 1.0
        diameters = biggest * np.sqrt(np.clip(masses, 0, None) / m_max)
        self.bob_sizes = diameters ** 2
        self.com_fraction = view.com / lengths  # where on each link its mass sits, for the bobs

        # Static: a fixed pivot's support; a moving pivot's path (faint); a cart's rail, spanning
        # the cart's travel and the chain's reach either side of it.
        self.cart = None
        if view.cart_x is not None:
            from matplotlib.patches import Rectangle

            ax.plot(list(xlim), [0.0, 0.0], color="0.3", lw=1.2, zorder=1, solid_capstyle="butt")
            self.cart_size = (0.25 * reach, 0.12 * reach)  # width, height (m)
            w, h = self.cart_size
            self.cart = Rectangle((-0.5 * w, -0.5 * h), w, h, facecolor=_CART, edgecolor="black", lw=0.8, zorder=2)
            ax.add_patch(self.cart)
        elif view.moving:
            ax.plot(view.pivot[:, 0], view.pivot[:, 1], color="0.55", lw=0.8, ls=":", zorder=1)
        else:
            ax.plot([-0.08 * reach, 0.08 * reach], [0, 0], color="black", lw=2.0, solid_capstyle="butt")
        self.trail = LineCollection([], linewidths=1.4, capstyle="round")
        ax.add_collection(self.trail)
        (self.rods,) = ax.plot([], [], "-", color=_ROD, lw=rod_width, solid_capstyle="round", zorder=3)
        self.bobs = ax.scatter([], [], s=[], c=_BOB, edgecolors="black", linewidths=0.5, zorder=4)
        (self.pivot,) = ax.plot([0], [0], "o", color="black", ms=max(3.0, 0.6 * rod_width + 2.5), zorder=5)
        self.time_text = ax.text(0.02, 0.98, "", transform=ax.transAxes, va="top", fontsize=8,
                                 family="monospace")
        self.err_text = ax.text(0.02, 0.92, "", transform=ax.transAxes, va="top", fontsize=8,
                                family="monospace")
        # Blitting: the static picture is rendered once; each frame restores it and draws only
        # the moving artists on top (ten times faster than redrawing the axes every frame).
        self.moving = [self.trail, self.rods, self.bobs, self.pivot, self.time_text, self.err_text]
        if self.cart is not None:
            self.moving.insert(0, self.cart)
        for artist in self.moving:
            artist.set_animated(True)
        self.canvas.draw()
        self.background = self.canvas.copy_from_bbox(self.fig.bbox)

    def frame(self, k: int, t: float, joints: np.ndarray, trail: float, base=(0.0, 0.0),
              err: Optional[float] = None) -> np.ndarray:
        """Draw the chain at time t and return the frame as an (H, W, 3) uint8 array.
        ``joints`` (N, 2) and ``base`` (2,), the pivot (on a cart, the cart's centre), in the lab frame;
        ``err``: the energy error shown (None: the view's, at t)."""
        view = self.view
        base = np.asarray(base, dtype=float).reshape(2)
        chain = np.vstack([base, joints])
        self.pivot.set_data([base[0]], [base[1]])
        if self.cart is not None:
            w, h = self.cart_size
            self.cart.set_xy((base[0] - 0.5 * w, base[1] - 0.5 * h))
        self.rods.set_data(chain[:, 0], chain[:, 1])
        starts = chain[:-1]
        bobs = starts + self.com_fraction[:, None] * (chain[1:] - starts)
        self.bobs.set_offsets(bobs)
        self.bobs.set_sizes(self.bob_sizes)
        self.trail.set_segments(self._trail_segments(t, joints[-1], trail))
        self.trail.set_color(self._trail_colors)
        self.time_text.set_text(f"t = {t:7.2f} s")
        if err is None:
            err = float(np.interp(t, view.t, view.energy_error))
        self.err_text.set_text(f"energy error {err:8.1e}")
        self.canvas.restore_region(self.background)
        for artist in self.moving:  # in zorder: cart, trail, rods, bobs, pivot, labels
            self.ax.draw_artist(artist)
        rgba = np.asarray(self.canvas.buffer_rgba())
        return np.ascontiguousarray(rgba[..., :3])

    def _trail_segments(self, t: float, tip: np.ndarray, trail: float):
        view = self.view
        if trail <= 0:
            self._trail_colors = np.zeros((0, 4))
            return []
        lo = np.searchsorted(view.t, t - trail, side="left")
        hi = np.searchsorted(view.t, t, side="left")
        pts = np.vstack([view.positions[lo:hi, -1, :], tip[None, :]])
        times = np.append(view.t[lo:hi], t)
        if len(pts) < 2:
            self._trail_colors = np.zeros((0, 4))
            return []
        segments = np.stack([pts[:-1], pts[1:]], axis=1)
        age = t - 0.5 * (times[:-1] + times[1:])
        alpha = np.clip(1.0 - age / trail, 0.0, 1.0) ** 1.5 * 0.9
        colors = np.empty((len(segments), 4))
        colors[:, :3] = _TRAIL
        colors[:, 3] = alpha
        self._trail_colors = colors
        return segments


def _report(progress, done: int, total: int) -> None:
    if progress is not None:
        progress(done / total)


def _exact_palette(palette):
    """Median cut averages colours, and Pillow maps pixels to a given palette through a coarse
    cache, so the white background could come out grey: snap near-white (and near-black)
    entries to pure white (black)."""
    colors = np.array(palette.getpalette()[: 3 * 256], dtype=int).reshape(-1, 3)
    colors[(colors >= 246).all(axis=1)] = 255
    colors[(colors <= 9).all(axis=1)] = 0
    from PIL import Image

    fresh = Image.new("P", (1, 1))  # quantize(palette=...) reads a palette image's own palette
    fresh.putpalette(colors.astype(np.uint8).ravel().tolist())
    return fresh


def _write_gif(path: Path, frames, count: int, fps: float, progress) -> None:
    from PIL import Image

    # Pillow >= 9.1 has the enums; older ones the module constants (same values).
    _MEDIANCUT = getattr(getattr(Image, "Quantize", Image), "MEDIANCUT")
    _NO_DITHER = getattr(getattr(Image, "Dither", Image), "NONE")

    images = []
    palette = None
    for k, frame in enumerate(frames):
        image = Image.fromarray(frame)
        if palette is None:
            # One palette for every frame (no flicker). It is taken from the first frame plus the
            # colours the trail will fade through, which the first frame does not show yet.
            alpha = 0.9 * np.linspace(0.0, 1.0, 64)[:, None]
            fade = np.round(255 * (1 - alpha + alpha * _TRAIL[None, :])).astype(np.uint8)
            swatch = np.repeat(np.repeat(fade[:, None, :], frame.shape[1], axis=1), 2, axis=0)
            sample = np.ascontiguousarray(np.concatenate([frame, swatch], axis=0))
            palette = _exact_palette(Image.fromarray(sample).quantize(colors=255, method=_MEDIANCUT))
        images.append(image.quantize(palette=palette, dither=_NO_DITHER))
        _report(progress, k + 1, count)
    # GIF delays are in hundredths of a second: spread the rounding so playback stays real-time.
    ticks = np.round(np.arange(count + 1) * 100.0 / fps).astype(int)
    durations = [int(10 * max(1, d)) for d in np.diff(ticks)] or [int(1000 / fps)]
    images[0].save(path, format="GIF", save_all=True, append_images=images[1:], duration=durations,
                   loop=0, optimize=False, disposal=1)


def _write_mp4(path: Path, frames, count: int, fps: float, pixels: int, progress) -> None:
    import imageio_ffmpeg

    writer = imageio_ffmpeg.write_frames(
        str(path), (pixels, pixels), fps=fps, codec="libx264", pix_fmt_in="rgb24",
        pix_fmt_out="yuv420p", quality=7, macro_block_size=16, ffmpeg_log_level="error",
        output_params=["-movflags", "+faststart"],
    )
    writer.send(None)
    try:
        for k, frame in enumerate(frames):
            writer.send(np.ascontiguousarray(frame))
            _report(progress, k + 1, count)
    finally:
        writer.close()
