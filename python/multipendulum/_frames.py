"""What an animation will cost, checked before anything is drawn: the frame times, the frame
count, the frame's size, and the limits on frames, pixels and memory. Below the presentation
modules (the animation draws, a scenario checks its ``[output]`` before its run), so both use it
without importing each other."""
from __future__ import annotations

import math
import numbers
from typing import Optional

import numpy as np

import multipendulum._core as _core

from .errors import InputError

#: The most frames an animation may have: 10^5 frames is 55 minutes of playback at 30 fps and
#: about half an hour of drawing at 400 x 400 pixels; more is a typo in fps or speed.
MAX_FRAMES = 100_000
#: The largest frame side in pixels (8K video); Agg stops at 2^16, video encoders sooner.
MAX_SIDE = 8192
#: The most pixels drawn over all frames (frames x width x height): 3e10 is about an hour of
#: drawing on one core (20 ms per 400 x 400 frame).
MAX_PIXEL_FRAMES = 3e10
#: Bytes per pixel while a frame is drawn: Agg's RGBA canvas, the blitting background (RGBA),
#: the RGB frame and the copy the writer takes.
_DRAW_BYTES = 4 + 4 + 3 + 3
#: Python's own names for the settings, used in messages unless a caller (the command line, a
#: scenario file) names them its way.
_NAMES = {"fps": "fps", "speed": "speed", "dpi": "dpi", "size": "size", "trail": "trail",
          "duration": "a shorter run", "format": "write .mp4 (its frames are streamed, not kept)"}


def frame_count(t0: float, t1: float, fps: float, speed: float) -> float:
    """How many frames :func:`frame_times` gives, as a float (it may be astronomically large)."""
    return math.floor((t1 - t0) / (speed / fps) + 1e-9) + 1.0


def frame_times(t0: float, t1: float, fps: float, speed: float) -> np.ndarray:
    """Simulation time of each frame: real-time playback at ``speed`` = 1, frames 1/fps apart."""
    step = speed / fps
    count = int(frame_count(t0, t1, fps, speed))
    return t0 + step * np.arange(count)


def _side(size: float, dpi: float) -> float:
    """The frame's side in pixels: ``size`` inches at ``dpi``, a multiple of 16, at least 64."""
    return max(64.0, 16.0 * round(size * dpi / 16.0))


def plan(t0: float, t1: float, fps: float, speed: float, dpi: float, size: float = 5.0, trail: float = 0.0,
         n: int = 1, format: str = ".gif", names: Optional[dict] = None):
    """Check an animation's settings and its cost before anything is drawn; returns
    ``(frames, side)``, the frame count and the frame's side in pixels.

    Refused with :class:`~multipendulum.InputError` (and advice): a setting that is not a finite
    number > 0 (``trail`` >= 0); more than :data:`MAX_FRAMES` frames; a side beyond
    :data:`MAX_SIDE` pixels; more than :data:`MAX_PIXEL_FRAMES` pixels drawn in all; memory the
    core's limit (``_core.check_memory``) refuses: the drawing buffers, the frames' joint
    positions and, for a GIF, every frame, which the GIF writer keeps until the end.
    ``names`` maps ``fps``, ``speed``, ``dpi``, ``size``, ``trail``, ``duration`` (how to make the
    run shorter) and ``format`` (how to stream the frames) to the caller's own words for them,
    e.g. ``{"fps": "--fps"}`` on the command line or ``"output.fps"`` in a scenario file."""
    say = dict(_NAMES, **(names or {}))
    for key, value, low in (("fps", fps, 0.0), ("speed", speed, 0.0), ("dpi", dpi, 0.0), ("size", size, 0.0)):
        if not (isinstance(value, numbers.Real) and not isinstance(value, bool)):
            raise InputError(f"{say[key]} must be a number > 0, got {value!r}")
        if not math.isfinite(value):
            raise InputError(f"{say[key]} must be finite, got {value!r}")
        if not value > low:
            raise InputError(f"{say[key]} must be > 0, got {value!r}")
    if not (isinstance(trail, numbers.Real) and not isinstance(trail, bool)):
        raise InputError(f"{say['trail']} must be a number >= 0, got {trail!r}")
    if not math.isfinite(trail):
        raise InputError(f"{say['trail']} must be finite, got {trail!r}")
    if not trail >= 0:
        raise InputError(f"{say['trail']} must be >= 0, got {trail!r}")
    duration = max(0.0, float(t1) - float(t0))
    frames = frame_count(float(t0), float(t1), float(fps), float(speed))
    settings = f"{duration:g} s of the run at {say['fps']} = {fps:g} and {say['speed']} = {speed:g}"
    if not frames <= MAX_FRAMES:
        raise InputError(f"an animation of {settings} has {frames:.4g} frames, more than {MAX_FRAMES}; "
                         f"lower {say['fps']}, raise {say['speed']} (simulated seconds per second of playback), "
                         f"or animate {say['duration']}")
    side = _side(float(size), float(dpi))
    if side > MAX_SIDE:
        raise InputError(f"frames of {side:.4g} x {side:.4g} pixels ({say['dpi']} = {dpi:g}, {size:g} inches) are "
                         f"larger than {MAX_SIDE} x {MAX_SIDE}; lower {say['dpi']} (80 gives 400 x 400)")
    pixels = side * side
    what = f"an animation of {int(frames)} frames of {int(side)} x {int(side)} pixels"
    if frames * pixels > MAX_PIXEL_FRAMES:
        raise InputError(f"{what} draws {frames * pixels:.3g} pixels, more than {MAX_PIXEL_FRAMES:.0e} (about an "
                         f"hour of drawing); lower {say['dpi']} or {say['fps']}, raise {say['speed']}, "
                         f"or animate {say['duration']}")
    kept = frames * pixels if format.lower() == ".gif" else 0.0
    need = _DRAW_BYTES * pixels + frames * n * 3 * 8.0 + kept
    advice = f"lower {say['dpi']} or {say['fps']}, raise {say['speed']}, or animate {say['duration']}"
    if kept:
        advice += f"; or {say['format']}"
    _core.check_memory(float(need), what, advice)
    return int(frames), int(side)
