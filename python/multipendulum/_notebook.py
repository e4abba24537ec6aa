"""Notebook display, the low part: the widgets' browser module, the viewer's link limit, and the
player of a computed solution (:func:`show`, :class:`Player`).

It sits low in the package's layers (below :mod:`multipendulum._simulate`) so that
``Solution.show()`` can call :func:`show` without reaching up; the live widget
(:func:`multipendulum.widget`) is in :mod:`multipendulum.notebook`, above the run driver it
checks its setup with. Both are anywidget widgets (JupyterLab, Notebook 7, VS Code and the
other front ends anywidget supports); anywidget is imported here, so importing this module
without it raises an ImportError that says how to install it.

The browser code is the viewer's own (``web/engine.js``, ``web/draw.js``) plus one entry file per
widget (``web/widget.js``, ``web/player.js``). anywidget loads a widget's code as a single ES
module, where relative imports do not resolve, so :func:`bundle` inlines the files an entry
imports, in dependency order, and refuses anything it does not understand.
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

import numpy as np
import numpy.typing as npt

import multipendulum._core as _core

from ._chain import Chain
from ._convert import as_float, check_single
from ._files import web_dir
from ._frames import frame_times
from .errors import InputError

try:
    import anywidget
    import traitlets
except ImportError as exc:  # pragma: no cover - exercised in a subprocess by the tests
    raise ImportError("multipendulum's notebook widgets (mp.widget, mp.show, Solution.show) need anywidget: "
                      "pip install 'multipendulum[widget]'") from exc

__all__ = ["Player", "show", "bundle", "BundleError", "look", "check_viewer_size", "VIEWER_MAX_LINKS", "WEB", "MAX_FPS",
           "MAX_VALUES"]

#: The viewer's files (the same directory ``multipendulum serve`` serves).
WEB = web_dir()
#: The longest chain the browser viewer shows (the core's fact ``viewer_max_links``).
VIEWER_MAX_LINKS = int(_core.LIMITS["viewer_max_links"])
#: The most frames per simulated second :func:`show` sends (the screen's refresh rate).
MAX_FPS = 60.0
#: The most numbers :func:`show` sends (float32 positions and base positions, 4 bytes each:
#: 16 MB): a longer run is shown at a lower frame rate, said under the player.
MAX_VALUES = 4_000_000


def check_viewer_size(n: int, what: str) -> None:
    """Refuse a chain longer than the browser viewer shows, saying what to use instead."""
    if n > VIEWER_MAX_LINKS:
        raise InputError(f"{what} shows chains of up to {VIEWER_MAX_LINKS} links (the browser viewer's limit), "
                         f"this one has {n}: run it with mp.simulate and write a video with mp.animate(sol, path)")


# ----------------------------------------------------------------------------------------------
# The browser module

# What a web file may import: named bindings of another file of the web directory, no renaming.
_IMPORT = re.compile(r'^import\s*\{([^}]*)\}\s*from\s*"\./([A-Za-z0-9_-]+\.js)"\s*;?\s*$')
_STATIC_IMPORT = re.compile(r"\s*import\b(?!\s*[.(])")
_DYNAMIC_IMPORT = re.compile(r"\bimport\s*\(")
_ODD_EXPORT = re.compile(r"^\s*export\s*(\*|\{|default\b)", re.M)
_DECLARATION = re.compile(r"^(export\s+)?(?:async\s+)?(?:const|let|var|class|function\*?)\s+([A-Za-z_$][\w$]*)", re.M)
_NAME = re.compile(r"^[A-Za-z_$][\w$]*$")


class BundleError(RuntimeError):
    """A web file the bundler does not understand (a packaging bug, never bad user input)."""


def _parse(name: str, text: str) -> Tuple[List[Tuple[str, List[str]]], str]:
    """A web file's imports ``[(file, names)]`` and its code without them."""
    imports: List[Tuple[str, List[str]]] = []
    body: List[str] = []
    for lineno, line in enumerate(text.splitlines(), 1):
        m = _IMPORT.match(line)
        if m:
            names = [s.strip() for s in m.group(1).split(",") if s.strip()]
            bad = [s for s in names if not _NAME.match(s)]
            if bad:
                raise BundleError(f"{name}:{lineno}: the bundler takes plain names only (no `as`), got {', '.join(bad)}")
            imports.append((m.group(2), names))
            body.append("")  # keeps the line numbers of the file's own code
            continue
        if _STATIC_IMPORT.match(line):
            raise BundleError(f"{name}:{lineno}: cannot inline {line.strip()!r}: only "
                              '`import { a, b } from "./file.js";` on one line is understood')
        body.append(line)
    return imports, "\n".join(body)


def bundle(entry: str, root: Optional[Path] = None) -> str:
    """One ES module from the web file ``entry`` and the web files it imports (recursively), for
    anywidget, which loads a widget's code as one module.

    Each imported file is inlined once, before the files that import it; its ``import`` lines
    are dropped and its ``export`` keywords removed (only the entry's exports remain). Checked,
    so a change to the web files cannot break a widget silently: only single-line
    ``import { a, b } from "./file.js";`` imports are understood (no renaming, no dynamic
    ``import()``, no ``export ... from``), each imported name must be exported by its file, and
    no two files may declare the same top-level name (they share one scope here). Anything else
    raises :class:`BundleError`."""
    root = WEB if root is None else Path(root)
    parsed: Dict[str, Tuple[List[Tuple[str, List[str]]], str]] = {}
    order: List[str] = []

    def visit(name: str, path: Tuple[str, ...]) -> None:
        if name in path:
            raise BundleError(f"import cycle: {' -> '.join(path + (name,))}")
        if name in parsed:
            return
        file = root / name
        if not file.is_file():
            raise BundleError(f"{path[-1] if path else 'bundle'} imports {name}, which is not in {root}")
        imports, body = _parse(name, file.read_text(encoding="utf-8"))
        parsed[name] = (imports, body)
        for dep, _ in imports:
            visit(dep, path + (name,))
        order.append(name)

    visit(entry, ())
    exported = {name: {m.group(2) for m in _DECLARATION.finditer(body) if m.group(1)}
                for name, (_, body) in parsed.items()}
    declared: Dict[str, str] = {}
    parts = []
    for name in order:
        imports, body = parsed[name]
        for dep, names in imports:
            missing = [n for n in names if n not in exported[dep]]
            if missing:
                raise BundleError(f"{name} imports {', '.join(missing)} from {dep}, which does not export it")
        for m in _DECLARATION.finditer(body):
            other = declared.setdefault(m.group(2), name)
            if other != name:
                raise BundleError(f"{name} and {other} both declare {m.group(2)} at the top level "
                                  "(inlined into one module they would clash): rename one")
        if _DYNAMIC_IMPORT.search(body):
            raise BundleError(f"{name}: a dynamic import() cannot be inlined")
        if name != entry:
            odd = _ODD_EXPORT.search(body)
            if odd:
                raise BundleError(f"{name}: cannot inline {odd.group(0).strip()!r}: an inlined file exports "
                                  "plain declarations only (export const/let/class/function)")
            body = re.sub(r"^export\s+", "", body, flags=re.M)
        parts.append(f"// ---- {name} " + "-" * max(0, 86 - len(name)) + "\n" + body.rstrip() + "\n")
    return "\n".join(parts)


def _stylesheet() -> str:
    return (WEB / "widget.css").read_text(encoding="utf-8")


def look(chain: Any) -> Dict[str, Any]:
    """How the browser draws ``chain`` (draw.js's ChainView): lengths, masses, and whether its
    links are uniform rods (then drawn as bars) or anything else (drawn with their bobs)."""
    lengths, masses = chain.lengths, chain.masses
    try:
        rods = Chain.rods(lengths, masses)
        is_rods = bool(np.array_equal(rods.com, chain.com) and np.array_equal(rods.inertia, chain.inertia))
    except InputError:
        is_rods = False
    return {"lengths": [float(v) for v in lengths], "masses": [float(v) for v in masses],
            "kind": "rods" if is_rods else "points"}


# ----------------------------------------------------------------------------------------------
# The player of a computed solution


def _speed(value: Any) -> float:
    speed = as_float(value, "speed")
    if not (math.isfinite(speed) and speed > 0):
        raise InputError(f"speed must be > 0 and finite (simulated seconds per second), got {speed:g}")
    return speed


def _flag(value: Any, name: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise InputError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def _height(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 80 <= value <= 4000:
        raise InputError(f"height must be a whole number of pixels from 80 to 4000, got {value!r}")
    return int(value)


class Player(anywidget.AnyWidget):
    """A computed solution played in a notebook cell, drawn as the browser viewer draws it: play
    and pause, a time slider, the time shown. Made by :func:`show` (or ``sol.show()``), which
    sends the chain's joint positions at up to :data:`MAX_FPS` frames per simulated second
    (float32, relative to the base) and the base's (the pivot's or the cart's); no video is
    encoded. ``playing``, ``speed``, ``loop`` and ``time`` (the time shown, s; set it to seek)
    are synced both ways; :attr:`frames` holds what was sent.
    """

    _esm = bundle("player.js")
    _css = _stylesheet()

    _chain = traitlets.Dict().tag(sync=True)
    _t = traitlets.Bytes().tag(sync=True)
    _positions = traitlets.Bytes().tag(sync=True)
    _base = traitlets.Bytes().tag(sync=True)
    _note = traitlets.Unicode("").tag(sync=True)
    #: Whether it is playing (the play button and Python both set it).
    playing = traitlets.Any(False).tag(sync=True)
    #: Simulated seconds per second of playback.
    speed = traitlets.Any(1.0).tag(sync=True)
    #: Start again at the end (else stop there).
    loop = traitlets.Any(True).tag(sync=True)
    #: The time shown (s): the browser reports it while playing; set it to seek.
    time = traitlets.Any(0.0).tag(sync=True)
    #: The canvas's height in pixels.
    height = traitlets.Any(360).tag(sync=True)

    @traitlets.validate("playing", "loop")
    def _check_flag(self, proposal: Any) -> bool:
        return _flag(proposal.value, proposal.trait.name)

    @traitlets.validate("speed")
    def _check_speed(self, proposal: Any) -> float:
        return _speed(proposal.value)

    @traitlets.validate("time")
    def _check_time(self, proposal: Any) -> float:
        return as_float(proposal.value, "time", finite=True)

    @traitlets.validate("height")
    def _check_height(self, proposal: Any) -> int:
        return _height(proposal.value)

    @property
    def frames(self) -> Dict[str, npt.NDArray[Any]]:
        """What the browser got: ``t`` (F,) float64, ``positions`` (F, N, 2) and ``base`` (F, 2)
        float32, the joints relative to the base and the base in the lab frame (m)."""
        t = np.frombuffer(self._t, dtype="<f8")
        n = len(self._chain["lengths"])
        return {"t": t, "positions": np.frombuffer(self._positions, dtype="<f4").reshape(t.size, n, 2),
                "base": np.frombuffer(self._base, dtype="<f4").reshape(t.size, 2)}


def _single(sol: Any) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    check_single(sol, "show")
    if not hasattr(sol, "chain") or not hasattr(sol, "pivot"):
        raise InputError(f"show takes a multipendulum Solution (or loaded Results), got {type(sol).__name__}")
    t, theta = np.asarray(sol.t, dtype=np.float64), np.asarray(sol.theta, dtype=np.float64)
    if t.ndim != 1 or t.size != theta.shape[0] or t.size == 0:
        raise InputError(f"show takes one run: t of shape (T,) and theta of shape (T, N), got {t.shape} and {theta.shape}")
    return t, theta


def show(sol: Any, *, fps: float = MAX_FPS, speed: float = 1.0, playing: bool = True, loop: bool = True,
         height: int = 360) -> Player:
    """Play a computed solution inline in a notebook: ``mp.show(sol)`` or ``sol.show()``.

    The chain is drawn by the browser viewer's own code at ``speed`` simulated seconds per second
    of playback, from frames at ``fps`` per simulated second (at most :data:`MAX_FPS`): the angles
    interpolated linearly between the solution's outputs (exact at the output times) as
    :func:`multipendulum.animate` does, the base (pivot or cart) likewise. At most
    :data:`MAX_VALUES` numbers are sent: a longer run gets a lower frame rate, said under the
    player. No video is encoded. ``playing``: start at once; ``loop``: start again at the end;
    ``height``: the canvas's height in pixels.

    A chain longer than the viewer shows (:data:`VIEWER_MAX_LINKS`) and a batch solution are
    refused (:class:`~multipendulum.InputError`); ``mp.animate(sol, "run.mp4")`` writes a video.

    >>> import multipendulum as mp
    >>> sol = mp.simulate(mp.Chain([1, 1], [1, 1]), [2.0, 2.5], [0, 0], t_end=2.0)
    >>> player = sol.show()              # displays itself as a cell's last expression
    >>> player.frames["t"].size          # 60 frames per simulated second, and the last state
    121
    """
    t, theta = _single(sol)
    chain = sol.chain
    n = theta.shape[1]
    check_viewer_size(n, "show")
    fps = as_float(fps, "fps")
    if not (math.isfinite(fps) and 0 < fps <= MAX_FPS):
        raise InputError(f"fps must be > 0 and at most {MAX_FPS:g} (frames per simulated second), got {fps:g}")
    speed, playing, loop, height = _speed(speed), _flag(playing, "playing"), _flag(loop, "loop"), _height(height)
    pivot = np.asarray(sol.pivot, dtype=np.float64).reshape(t.size, 2)
    t0, t1 = float(t[0]), float(t[-1])
    most = max(2, min(MAX_VALUES // (2 * n + 2), 100_000))
    note = ""
    if t1 > t0 and (t1 - t0) * fps + 1 > most:
        fps = (most - 1) / (t1 - t0)
        note = f"{t1 - t0:g} s shown at {fps:.3g} frames per simulated second (at most {most} frames are sent)"
    times = frame_times(t0, t1, fps, 1.0) if t1 > t0 else np.array([t0])
    if times[-1] < t1:
        times = np.append(times, t1)  # the last state too
    if t.size > 1:
        angles = np.stack([np.interp(times, t, theta[:, i]) for i in range(n)], axis=1)
        base = np.stack([np.interp(times, t, pivot[:, k]) for k in range(2)], axis=1)
    else:
        angles, base = theta[:1], pivot[:1]
    joints = np.asarray(chain.positions(angles), dtype=np.float64)
    cart = chain.cart
    info = look(chain)
    info.update(cart=cart is not None, x0=float(base[0, 0]),
                reach=0.0 if cart is not None else float(np.max(np.hypot(base[:, 0], base[:, 1]))))
    return Player(_chain=info, _t=np.ascontiguousarray(times, dtype="<f8").tobytes(),
                  _positions=np.ascontiguousarray(joints, dtype="<f4").tobytes(),
                  _base=np.ascontiguousarray(base, dtype="<f4").tobytes(), _note=note,
                  playing=playing, speed=speed, loop=loop, time=t0, height=height)
