"""Scenario files: a small TOML description of a chain, its start, the run and its outputs.

A scenario is read strictly: an unknown key, a wrong type, a missing field or an out-of-range
value raises :class:`ScenarioError` naming the key, the value and what was expected, e.g.
``key 'chain.lengths[2]': must be > 0, got -1``. Array indices count from 0, as in the core's
messages. Nothing is simulated or written until the whole file has been checked, including
building the chain and the torque, so a bad file leaves no output behind.

The format is documented, with an annotated example, in ``docs/cli.md``. In short::

    name = "Chaotic double pendulum"
    [chain]                      # lengths (m), masses (kg), optional com (m) and inertia (kg m^2)
    lengths = [1.0, 1.0]
    masses = [1.0, 1.0]
    [initial]
    unit = "degrees"             # or "radians"; applies to theta and omega (per second)
    theta = [120, -10]
    [simulation]
    t_end = 10.0
    method = "dop853"
    [torque]                     # optional
    kind = "sinusoid"            # "constant" | "sinusoid" | "table"
    convention = "generalized"   # or "joint" (motor torque between link i-1 and link i)
    amplitude = [0.5, 0.0]
    frequency = [3.1, 0.0]
    [output]
    animation = "pendulum.gif"

Losses and a moving base (all optional)::

    [chain]
    damping = 0.05               # N m s/rad at each joint; friction (N m), friction_velocity (rad/s)
    [pivot]                      # a prescribed pivot motion (m): a number, or a signal table
    y = { kind = "sinusoid", amplitude = 0.02, frequency = 200.0 }
    [cart]                       # or the pivot on a cart (not both)
    mass = 1.0
    force = { kind = "sinusoid", amplitude = 2.0, frequency = 3.0 }

This module validates and converts; the physics (and its own validation) is in the core.
"""
from __future__ import annotations

import copy
import dataclasses
import difflib
import io
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

try:  # Python >= 3.11
    import tomllib as _toml
except ModuleNotFoundError:  # pragma: no cover - Python 3.9/3.10
    import tomli as _toml  # type: ignore[no-redef]

import multipendulum._core as _core

from ._base import Cart, Pivot
from ._chain import Chain
from ._convert import is_float
from ._simulate import simulate
from ._torque import Sinusoid, Table
from .errors import InputError

__all__ = [
    "Scenario",
    "TorqueSpec",
    "SignalSpec",
    "CartSpec",
    "Outputs",
    "ScenarioError",
    "load_scenario",
    "loads_scenario",
    "default_scenario_path",
    "PLOT_KINDS",
]

PathLike = Union[str, "os.PathLike[str]"]

#: Plot kinds known to :func:`multipendulum.plot`, in the order they are drawn.
PLOT_KINDS = ("angles", "energy", "phase", "tip")
# The core's facts, as it states them (never restated here): its methods, which need dt, the
# forms each integrates, the defaults and the limits.
_METHODS = tuple(_core.METHODS)
_FIXED_STEP = tuple(m for m in _METHODS if _core.METHOD_INFO[m]["needs_dt"])
_DEFAULTS = dict(_core.DEFAULTS)


class ScenarioError(InputError):
    """A scenario file (or text) that cannot be used.

    ``key`` is the dotted TOML key at fault (``"chain.lengths[2]"``), or ``None`` for a file that
    cannot be read or parsed at all; ``path`` is the file, when there is one. ``str(error)`` is
    the message without the path; the command line prefixes the path.
    """

    def __init__(self, message: str, key: Optional[str] = None, path: Optional[PathLike] = None):
        self.key = key
        self.path = None if path is None else Path(path)
        self.detail = message
        super().__init__(message if key is None else f"key '{key}': {message}")


# ----------------------------------------------------------------------------------------------
# The parsed scenario


@dataclass(frozen=True)
class TorqueSpec:
    """A built-in driving torque read from ``[torque]``.

    ``convention`` is ``"generalized"`` (the seed's torques conjugate to the absolute angles,
    passed as ``torque=``) or ``"joint"`` (motor torques between link i-1 and link i, passed as
    ``joint_torque=``). ``params`` holds per-link float lists: ``value`` for ``constant``;
    ``amplitude``, ``frequency`` (rad/s), ``phase`` (rad), ``offset`` for ``sinusoid``; ``t``
    and ``values`` (shape (K, N)) plus ``interpolation`` for ``table``.
    """

    kind: str
    convention: str
    params: Dict[str, Any]
    file: Optional[str] = None

    def build(self) -> Any:
        """The torque object for :func:`multipendulum.simulate`."""
        p = self.params
        if self.kind == "constant":
            return np.asarray(p["value"], dtype=float)
        if self.kind == "sinusoid":
            return Sinusoid(
                np.asarray(p["amplitude"], dtype=float),
                np.asarray(p["frequency"], dtype=float),
                phase=np.asarray(p["phase"], dtype=float),
                offset=np.asarray(p["offset"], dtype=float),
            )
        if self.kind == "table":
            return Table(
                np.asarray(p["t"], dtype=float),
                np.asarray(p["values"], dtype=float),
                kind=p["interpolation"],
            )
        raise AssertionError(self.kind)  # kinds are checked when the file is read

    def simulate_kwargs(self) -> Dict[str, Any]:
        name = "torque" if self.convention == "generalized" else "joint_torque"
        return {name: self.build()}


@dataclass(frozen=True)
class SignalSpec:
    """One number as a function of time, read from a scenario: a pivot axis (m) or the cart's
    force (N). ``kind`` is ``"constant"`` (``params["value"]``), ``"sinusoid"``
    (``amplitude``, ``frequency`` in rad/s, ``phase`` in rad, ``offset``) or ``"table"`` (``t``,
    ``values`` and ``interpolation``; a pivot's table is always ``"cubic"``). ``file`` is the CSV
    file a table came from, if any."""

    kind: str
    params: Dict[str, Any]
    file: Optional[str] = None

    def build(self) -> Any:
        """A number, an :class:`multipendulum.Sinusoid` or a :class:`multipendulum.Table`."""
        p = self.params
        if self.kind == "constant":
            return float(p["value"])
        if self.kind == "sinusoid":
            return Sinusoid(p["amplitude"], p["frequency"], phase=p["phase"], offset=p["offset"])
        if self.kind == "table":
            return Table(np.asarray(p["t"], dtype=float), np.asarray(p["values"], dtype=float),
                         kind=p["interpolation"])
        raise AssertionError(self.kind)  # kinds are checked when the file is read


@dataclass(frozen=True)
class CartSpec:
    """The cart read from ``[cart]``: ``mass`` (kg), viscous ``damping`` (N s/m), the initial
    position ``x0`` (m) and velocity ``v0`` (m/s), and the applied ``force`` (or ``None``)."""

    mass: float
    damping: float = 0.0
    x0: float = 0.0
    v0: float = 0.0
    force: Optional[SignalSpec] = None


@dataclass(frozen=True)
class Outputs:
    """What ``multipendulum run`` writes, from ``[output]`` (file names are inside ``-o DIR``)."""

    results: str = "results.npz"
    animation: Optional[str] = "animation.gif"
    plots: Tuple[str, ...] = PLOT_KINDS
    fps: float = 30.0
    trail: float = 2.0
    speed: float = 1.0
    dpi: float = 80.0

    @property
    def format(self) -> str:
        return Path(self.results).suffix.lower().lstrip(".")


@dataclass
class Scenario:
    """A checked scenario. Angles are in radians here, whatever unit the file used."""

    name: str
    description: str
    chain: Dict[str, Any]
    theta0: np.ndarray
    omega0: np.ndarray
    t_end: float
    method: str = _DEFAULTS["method"]
    dt: Optional[float] = None
    rtol: float = _DEFAULTS["rtol"]
    atol: float = _DEFAULTS["atol"]
    sample_dt: float = 0.01
    form: Optional[str] = None
    torque: Optional[TorqueSpec] = None
    pivot: Optional[Dict[str, SignalSpec]] = None
    cart: Optional[CartSpec] = None
    outputs: Outputs = field(default_factory=Outputs)
    raw: Dict[str, Any] = field(default_factory=dict, repr=False)
    text: str = field(default="", repr=False)
    path: Optional[Path] = None
    files: Dict[str, str] = field(default_factory=dict, repr=False)
    overrides: Dict[str, Any] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.chain["lengths"])

    def build_chain(self):
        """The :class:`multipendulum.Chain` this scenario describes."""
        c = self.chain
        # Only what the file gives: the core's defaults stand for the rest.
        losses = {k: c[k] for k in ("damping", "friction", "friction_velocity") if k in c}
        cart = None if self.cart is None else Cart(self.cart.mass, self.cart.damping)
        try:
            if c["kind"] == "rods":
                return Chain.rods(lengths=c["lengths"], masses=c["masses"], g=c["g"], cart=cart, **losses)
            return Chain(
                lengths=c["lengths"], masses=c["masses"], com=c.get("com"),
                inertia=c.get("inertia"), g=c["g"], cart=cart, **losses,
            )
        except ScenarioError:
            raise
        except InputError as exc:
            raise ScenarioError(compact_numbers(str(exc)), key="chain", path=self.path) from exc

    def build_torque(self) -> Dict[str, Any]:
        """``{"torque": ...}`` or ``{"joint_torque": ...}`` (empty without a torque)."""
        if self.torque is None:
            return {}
        try:
            return self.torque.simulate_kwargs()
        except ScenarioError:
            raise
        except InputError as exc:
            raise ScenarioError(compact_numbers(str(exc)), key="torque", path=self.path) from exc

    def build_base(self) -> Dict[str, Any]:
        """What moves the chain's base, as :func:`multipendulum.simulate` takes it:
        ``{"pivot": ...}``, or ``{"cart_x0": ..., "cart_v0": ..., "cart_force": ...}`` (the force
        only when the file gives one), or nothing for a fixed pivot at the origin."""
        if self.pivot is not None:
            return {"pivot": Pivot(**{axis: spec.build() for axis, spec in self.pivot.items()})}
        if self.cart is not None:
            kwargs: Dict[str, Any] = {"cart_x0": self.cart.x0, "cart_v0": self.cart.v0}
            if self.cart.force is not None:
                kwargs["cart_force"] = self.cart.force.build()
            return kwargs
        return {}

    def check_base(self, chain: Any) -> None:
        """Have the core evaluate the pivot's motion and the cart's force once, so what it
        refuses (a table it cannot fit, a non-finite value) is refused now, naming the key."""
        for axis, spec in (self.pivot or {}).items():
            try:
                Pivot(**{axis: spec.build()}).position(np.zeros(1))
            except InputError as exc:
                raise ScenarioError(compact_numbers(str(exc)), key=f"pivot.{axis}", path=self.path) from None
        if self.cart is not None and self.cart.force is not None:
            try:
                chain.accelerations(self.theta0, self.omega0, cart_v=self.cart.v0, cart_force=self.cart.force.build())
            except InputError as exc:
                raise ScenarioError(compact_numbers(str(exc)), key="cart.force", path=self.path) from None

    def sample_count(self) -> float:
        """How many samples :meth:`t_eval` gives (a float: it is checked before it is made)."""
        return max(1.0, math.ceil(self.t_end / self.sample_dt - 1e-9)) + 1.0

    def _t_end_words(self) -> str:
        if "t_end" in self.overrides:
            return f"--t-end {_num(self.t_end)} on the command line"
        return f"simulation.t_end = {_num(self.t_end)} s"

    def check_limits(self) -> None:
        """Refuse, before anything is allocated or run, a scenario whose run would not fit: a
        fixed-step run longer than ``max_steps``, or more output samples than the memory the
        core allows (``t_end / sample_dt`` rows of ``5 N + 6`` numbers). The messages name the
        file and the keys to change. :meth:`t_eval` (so :meth:`run`) checks it first; the command
        line calls it before anything else."""
        steps_limit = _max_steps()
        if self.dt is not None and self.method in _FIXED_STEP:
            steps = self.t_end / self.dt
            if steps > steps_limit:
                raise ScenarioError(
                    f"{self.method} with dt = {_num(self.dt)} s takes {_num(steps, 4)} steps to reach "
                    f"t_end = {_num(self.t_end)} s, more than the {_num(steps_limit)} steps a run may take "
                    f"(max_steps); raise simulation.dt or shorten the run ({self._t_end_words()})",
                    key="simulation.dt", path=self.path)
        count = self.sample_count()
        n = self.n
        what = f"storing {_num(count, 4)} samples of {n} link{'s' if n != 1 else ''}"
        advice = (f"raise simulation.sample_dt (now {_num(self.sample_dt)} s between samples) or shorten "
                  f"the run ({self._t_end_words()})")
        try:
            # The sample times themselves, then each output row as the core counts it (5 N + 6 numbers).
            _core.check_memory(count * (8.0 + (5 * n + 6) * 8.0), what, advice)
        except InputError as exc:
            raise ScenarioError(str(exc), key="simulation.sample_dt", path=self.path) from None

    def check_animation(self, names: Optional[Mapping[str, str]] = None) -> Tuple[int, int]:
        """Refuse, before the run, an ``[output]`` animation that would not fit (see
        :func:`multipendulum.animation.plan`: frames, pixels, memory), naming the scenario's
        keys, or the caller's ``names`` for them (the command line's options). Returns
        ``(frames, side in pixels)``."""
        from ._frames import plan

        out = self.outputs
        words = {"fps": "output.fps", "speed": "output.speed", "dpi": "output.dpi", "trail": "output.trail",
                 "duration": f"a shorter run ({self._t_end_words()})",
                 "format": "write .mp4 (output.animation; its frames are streamed, not kept)"}
        words.update(names or {})
        suffix = Path(out.animation or "animation.gif").suffix.lower()
        try:
            return plan(0.0, self.t_end, out.fps, out.speed, out.dpi, trail=out.trail, n=self.n, format=suffix,
                        names=words)
        except ScenarioError:
            raise
        except InputError as exc:
            key = next((k for k in ("fps", "speed", "dpi") if words[k] in str(exc).split(" must")[0]), None)
            raise ScenarioError(str(exc), key=None if key is None else words[key], path=self.path) from None

    def t_eval(self) -> np.ndarray:
        """Sample times: from 0 to ``t_end`` inclusive, evenly spaced, at most ``sample_dt`` apart.
        Refused (a :class:`ScenarioError` naming ``sample_dt`` and ``t_end``) before it is made
        when the run's samples would not fit in memory."""
        self.check_limits()
        return np.linspace(0.0, self.t_end, int(self.sample_count()))

    def simulate_kwargs(self) -> Dict[str, Any]:
        kwargs: Dict[str, Any] = dict(
            method=self.method, dt=self.dt, rtol=self.rtol, atol=self.atol, t_eval=self.t_eval()
        )
        if self.form is not None:  # only when the file asks: the core picks the natural one otherwise
            kwargs["form"] = self.form
        kwargs.update(self.build_torque())
        kwargs.update(self.build_base())
        return kwargs

    def run(self, progress: Any = None):
        """Simulate with :func:`multipendulum.simulate` and return its solution. ``progress``:
        True for a bar on stderr, or a callable given the fraction done (see
        :mod:`multipendulum._progress`). What the core refuses is a :class:`ScenarioError`
        naming this scenario's file."""
        from ._progress import reporter

        chain = self.build_chain()
        kwargs = self.simulate_kwargs()
        with reporter(progress, "simulate") as report:
            try:
                return simulate(chain, self.theta0, self.omega0, self.t_end, progress=report, **kwargs)
            except ScenarioError:
                raise
            except InputError as exc:
                raise ScenarioError(compact_numbers(str(exc)), path=self.path) from None

    def replace(self, **changes: Any) -> "Scenario":
        """A copy with some fields changed (e.g. ``t_end``); the changes are kept in ``overrides``
        so a results file says how its run differed from the scenario text."""
        overrides = dict(self.overrides)
        for key, value in changes.items():
            if key not in {"t_end", "method", "dt", "rtol", "atol", "sample_dt", "form", "outputs"}:
                raise TypeError(f"cannot override {key!r}")
            if key != "outputs":
                overrides[key] = value
        if "t_end" in changes:
            _positive("simulation.t_end", changes["t_end"], self.path)
        return dataclasses.replace(self, overrides=overrides, **changes)

    def metadata(self) -> Dict[str, Any]:
        """JSON-ready description for results files: enough to rerun the scenario."""
        return {
            "name": self.name,
            "path": None if self.path is None else str(self.path),
            "text": self.text,
            "files": dict(self.files),
            "overrides": {k: _jsonable(v) for k, v in self.overrides.items()},
        }


# ----------------------------------------------------------------------------------------------
# Reading


def default_scenario_path() -> Path:
    """The demo scenario shipped with the package (the chaotic double pendulum)."""
    return Path(__file__).resolve().parent / "data" / "default.toml"


MAX_FILE_BYTES = 64 * 1024 * 1024
#: The largest initial angle the core takes (|theta| <= 1e15 rad, where a step of 1e-15 rad is
#: still resolved); a scenario in degrees is told its bound in degrees.
MAX_ANGLE_RAD = _core.LIMITS["max_angle"]
#: The smallest rtol dop853 takes (below it the error estimate is round-off).
MIN_RTOL = _core.LIMITS["min_rtol"]
#: The most links a scenario may ask for with a single number broadcast to every link (a
#: million links is 0.1 s per rk4 step; more is a typo, not a simulation).
MAX_LINKS = 1_000_000


def _read_limited(path: Path) -> bytes:
    """A scenario or table file's bytes; one larger than MAX_FILE_BYTES (or endless, like
    /dev/zero) is an OSError rather than a hang or a full memory."""
    with open(path, "rb") as f:
        data = f.read(MAX_FILE_BYTES + 1)
    if len(data) > MAX_FILE_BYTES:
        raise OSError(f"larger than {MAX_FILE_BYTES // 2**20} MiB, which is more than any scenario or table needs")
    return data


def load_scenario(path: PathLike) -> Scenario:
    """Read and check a scenario file. Relative file names inside it (a torque table) are
    resolved against the scenario's own directory."""
    path = Path(path)
    try:
        data = _read_limited(path)
    except OSError as exc:
        raise ScenarioError(f"cannot read scenario file: {exc.strerror or exc}", path=path) from exc
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"scenario file is not UTF-8 text: {exc}", path=path) from exc
    return loads_scenario(text, base_dir=path.parent, path=path, files=None)


def loads_scenario(
    text: str,
    base_dir: Optional[PathLike] = None,
    path: Optional[PathLike] = None,
    files: Optional[Mapping[str, str]] = None,
) -> Scenario:
    """Check a scenario given as TOML text (a ``str``, or UTF-8 ``bytes``).

    ``files`` maps file names used in the text (a torque table) to their contents; it lets a
    scenario stored in a results file be rerun without the original files. Names not in it are
    read from ``base_dir``.
    """
    path = None if path is None else Path(path)
    if isinstance(text, (bytes, bytearray)):
        try:
            text = bytes(text).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ScenarioError(f"scenario is not UTF-8 text: {exc}", path=path) from exc
    if not isinstance(text, str):
        raise ScenarioError(f"scenario text must be a str, got {type(text).__name__}", path=path)
    try:
        raw = _toml.loads(text)
    except _toml.TOMLDecodeError as exc:
        raise ScenarioError(f"not valid TOML: {exc}", path=path) from exc
    except ValueError as exc:  # the parser's own limits, e.g. an integer of over 4300 digits
        raise ScenarioError(f"not a usable TOML file: {exc}", path=path) from exc
    except RecursionError:
        raise ScenarioError("not a usable TOML file: arrays or tables nested too deeply", path=path) from None
    reader = _Reader(path, Path(base_dir) if base_dir is not None else None, files)
    scenario = reader.scenario(raw, text)
    # Build what the core will be given, so its own checks fail now rather than mid-run. (The
    # run's own limits, check_limits, are checked by what runs it: the viewer and flip maps
    # take a scenario's chain without storing its samples.)
    chain = scenario.build_chain()
    scenario.build_torque()
    scenario.check_base(chain)
    return scenario


# ----------------------------------------------------------------------------------------------
# The checker


_TOP_KEYS = ("name", "description", "chain", "initial", "simulation", "torque", "pivot", "cart", "output")
_CHAIN_KEYS = ("kind", "n", "lengths", "masses", "com", "inertia", "g", "damping", "friction", "friction_velocity")
_INITIAL_KEYS = ("unit", "theta", "omega")
_SIM_KEYS = ("t_end", "method", "dt", "rtol", "atol", "sample_dt", "form")
_TORQUE_KEYS = {
    "constant": ("kind", "convention", "value"),
    "sinusoid": ("kind", "convention", "amplitude", "frequency", "phase", "offset"),
    "table": ("kind", "convention", "file", "interpolation"),
}
_PIVOT_KEYS = ("x", "y")
_CART_KEYS = ("mass", "damping", "x0", "v0", "force")
#: The keys of a signal given as a table (a pivot axis, the cart force), by kind; a constant
#: signal is a plain number.
_SIGNAL_KEYS = {
    "sinusoid": ("kind", "amplitude", "frequency", "phase", "offset"),
    "table": ("kind", "t", "values", "file", "interpolation"),
}
_OUTPUT_KEYS = ("results", "animation", "plots", "fps", "trail", "speed", "dpi")
_RAMP_KEYS = ("from", "to")


def _describe(value: Any) -> str:
    """A TOML value as the user wrote it, for messages."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, dict):
        return "a table {" + ", ".join(value) + "}"
    if isinstance(value, list):
        text = "[" + ", ".join(_describe(v) for v in value[:6]) + (", ..." if len(value) > 6 else "") + "]"
        return text
    return str(value)


def _type_name(value: Any) -> str:
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, dict):
        return "a table"
    return type(value).__name__


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


def _positive(key: str, value: Any, path: Optional[Path]) -> float:
    if not _is_number(value):
        raise ScenarioError(f"expected a number > 0, got {_type_name(value)} {_describe(value)}", key, path)
    if not math.isfinite(value):
        raise ScenarioError(f"must be finite, got {_describe(value)}", key, path)
    if not value > 0:
        raise ScenarioError(f"must be > 0, got {_describe(value)}", key, path)
    return float(value)


def _num(value: float, digits: int = 6) -> str:
    """A number for a message, compactly: ``0.01``, ``1e-12``, ``5e+06``, ``123456``; an integral
    value below 10^6 without a decimal point. Never ``0.000000000001``."""
    value = float(value)
    if value.is_integer() and abs(value) < 1e6:
        return str(int(value))
    return f"{value:.{digits}g}"


_LONG_NUMBER = re.compile(r"(?<![\w.])-?(?:\d+\.\d{7,}|\d{13,}(?:\.\d*)?|0\.0{5,}\d+)(?:e[-+]?\d+)?(?![\w.])")


def compact_numbers(message: str) -> str:
    """A message with every long decimal number in it (``0.000000000001``, 300 digits of
    ``1e308``, ``1745329251994329.5``) written compactly (``1e-12``, ``1e+308``, ``1.74533e+15``)."""
    return _LONG_NUMBER.sub(lambda m: _num(float(m.group(0))), message)


def _max_steps() -> int:
    """The longest run :func:`multipendulum.simulate` takes by default (the core's ``max_steps``)."""
    return int(_DEFAULTS["max_steps"])


class _Reader:
    def __init__(self, path: Optional[Path], base_dir: Optional[Path], files: Optional[Mapping[str, str]]):
        self.path = path
        self.base_dir = base_dir
        self.files = dict(files or {})
        self.used_files: Dict[str, str] = {}

    # -- primitives ----------------------------------------------------------------------------

    def error(self, key: str, message: str) -> ScenarioError:
        return ScenarioError(message, key, self.path)

    def table(self, raw: Any, key: str, allowed: Sequence[str]) -> Dict[str, Any]:
        if not isinstance(raw, dict):
            raise self.error(key, f"expected a table ([{key}]), got {_type_name(raw)} {_describe(raw)}")
        for name in raw:
            if name not in allowed:
                full = f"{key}.{name}" if key else name
                close = difflib.get_close_matches(name, allowed, n=1)
                hint = f"did you mean '{close[0]}'? " if close else ""
                raise self.error(full, f"unknown key; {hint}expected one of: {', '.join(allowed)}")
        return raw

    def require(self, table: Mapping[str, Any], key: str, name: str, expected: str) -> Any:
        if name not in table:
            raise self.error(_join(key, name), f"missing; expected {expected}")
        return table[name]

    def number(self, value: Any, key: str, *, positive=False, nonneg=False, integer=False) -> float:
        if integer:
            if not isinstance(value, int) or isinstance(value, bool):
                raise self.error(key, f"expected an integer, got {_type_name(value)} {_describe(value)}")
        elif not _is_number(value):
            rule = " > 0" if positive else " >= 0" if nonneg else ""
            raise self.error(key, f"expected a number{rule}, got {_type_name(value)} {_describe(value)}")
        if not math.isfinite(value):
            raise self.error(key, f"must be finite, got {_describe(value)}")
        if positive and not value > 0:
            raise self.error(key, f"must be > 0, got {_describe(value)}")
        if nonneg and not value >= 0:
            raise self.error(key, f"must be >= 0, got {_describe(value)}")
        return value if integer else float(value)

    def choice(self, value: Any, key: str, options: Sequence[str]) -> str:
        if not isinstance(value, str) or value not in options:
            listed = ", ".join(f'"{o}"' for o in options)
            got = f"{_type_name(value)} {_describe(value)}" if not isinstance(value, str) else _describe(value)
            close = difflib.get_close_matches(value, options, n=1) if isinstance(value, str) else []
            hint = f" (did you mean \"{close[0]}\"?)" if close else ""
            raise self.error(key, f"expected one of {listed}, got {got}{hint}")
        return value

    def per_link(self, value: Any, key: str, n: Optional[int], *, positive=False, nonneg=False,
                 allow_ramp=False) -> List[float]:
        """A number for every link, or one number for all of them (or a ``{from, to}`` ramp)."""
        what = "a number or an array of numbers (one per link)"
        if allow_ramp:
            what += " or a table {from = ..., to = ...}"
        if _is_number(value):
            if n is None:
                raise self.error(key, "a single number needs the number of links: give chain.n or lists")
            self.number(value, key, positive=positive, nonneg=nonneg)
            return [float(value)] * n
        if isinstance(value, dict) and allow_ramp:
            ramp = self.table(value, key, _RAMP_KEYS)
            a = self.number(self.require(ramp, key, "from", "a number"), f"{key}.from")
            b = self.number(self.require(ramp, key, "to", "a number"), f"{key}.to")
            if n is None:
                raise self.error(key, "a ramp needs the number of links")
            return np.linspace(a, b, n).tolist() if n > 1 else [a]
        if not isinstance(value, list):
            raise self.error(key, f"expected {what}, got {_type_name(value)} {_describe(value)}")
        if n is not None and len(value) != n:
            raise self.error(key, f"expected {n} values (one per link), got {len(value)}")
        if not value:
            raise self.error(key, "expected at least one value, got an empty array")
        return [self.number(v, f"{key}[{i}]", positive=positive, nonneg=nonneg) for i, v in enumerate(value)]

    def read_file(self, name: str, key: str) -> str:
        if name in self.files:
            text = self.files[name]
        else:
            if self.base_dir is None:
                raise self.error(key, f"cannot read {name!r}: the scenario has no directory to look in")
            target = Path(name) if Path(name).is_absolute() else self.base_dir / name
            try:
                text = _read_limited(target).decode("utf-8")
            except OSError as exc:
                raise self.error(key, f"cannot read {str(target)!r}: {exc.strerror or exc}") from exc
            except UnicodeDecodeError as exc:
                raise self.error(key, f"{str(target)!r} is not UTF-8 text: {exc}") from exc
        self.used_files[name] = text
        return text

    # -- sections ------------------------------------------------------------------------------

    def scenario(self, raw: Dict[str, Any], text: str) -> Scenario:
        self.table(raw, "", _TOP_KEYS)
        name = raw.get("name", "")
        if not isinstance(name, str):
            raise self.error("name", f"expected a string, got {_type_name(name)} {_describe(name)}")
        description = raw.get("description", "")
        if not isinstance(description, str):
            raise self.error("description", f"expected a string, got {_type_name(description)} {_describe(description)}")
        chain = self.chain(self.require(raw, "", "chain", "a [chain] table with lengths and masses"))
        n = len(chain["lengths"])
        theta0, omega0 = self.initial(self.require(raw, "", "initial", "an [initial] table with unit and theta"), n)
        sim = self.simulation(self.require(raw, "", "simulation", "a [simulation] table with t_end"))
        torque = self.torque(raw["torque"], n) if "torque" in raw else None
        pivot = self.pivot(raw["pivot"]) if "pivot" in raw else None
        cart = self.cart(raw["cart"]) if "cart" in raw else None
        if pivot is not None and cart is not None:
            raise self.error("pivot", "cannot be given with [cart]: the cart carries the pivot (push it with "
                             "cart.force instead)")
        outputs = self.outputs(raw.get("output", {}))
        if not name and self.path is not None:
            name = self.path.stem
        return Scenario(
            name=name, description=description, chain=chain, theta0=theta0, omega0=omega0,
            torque=torque, pivot=pivot, cart=cart, outputs=outputs, raw=copy.deepcopy(raw), text=text, path=self.path,
            files=dict(self.used_files), **sim,
        )

    def chain(self, raw: Any) -> Dict[str, Any]:
        t = self.table(raw, "chain", _CHAIN_KEYS)
        kind = self.choice(t.get("kind", "points"), "chain.kind", ("points", "rods"))
        n = None
        if "n" in t:
            n = int(self.number(t["n"], "chain.n", integer=True))
            if not 1 <= n <= MAX_LINKS:
                raise self.error("chain.n", f"must be from 1 to {MAX_LINKS}, got {_describe(n)}")
        if n is None:
            for name in ("lengths", "masses", "com", "inertia"):
                if isinstance(t.get(name), list):
                    n = len(t[name])
                    break
        lengths = self.per_link(self.require(t, "chain", "lengths", "link lengths in m (numbers > 0)"),
                                "chain.lengths", n, positive=True)
        n = len(lengths)
        masses = self.per_link(self.require(t, "chain", "masses", "link masses in kg (numbers >= 0)"),
                               "chain.masses", n, nonneg=True)
        out: Dict[str, Any] = {"kind": kind, "lengths": lengths, "masses": masses}
        for name, rule in (("com", {}), ("inertia", {"nonneg": True})):
            if name in t:
                if kind == "rods":
                    raise self.error(f"chain.{name}", f'cannot be given with kind = "rods" (uniform rods '
                                     f'have com = l/2 and inertia = m l^2/12); use kind = "points" '
                                     f"to give {name} explicitly")
                out[name] = self.per_link(t[name], f"chain.{name}", n, **rule)
        out["g"] = self.number(t.get("g", 9.81), "chain.g")
        for name in ("damping", "friction"):  # one value per joint; joint i hangs link i
            if name in t:
                out[name] = self.per_link(t[name], f"chain.{name}", n, nonneg=True)
        if "friction_velocity" in t:
            out["friction_velocity"] = self.number(t["friction_velocity"], "chain.friction_velocity", positive=True)
        return out

    def initial(self, raw: Any, n: int) -> Tuple[np.ndarray, np.ndarray]:
        t = self.table(raw, "initial", _INITIAL_KEYS)
        unit = self.choice(self.require(t, "initial", "unit", '"degrees" or "radians"'), "initial.unit",
                           ("degrees", "radians"))
        scale = math.pi / 180.0 if unit == "degrees" else 1.0
        theta_raw = self.require(t, "initial", "theta", "initial angles, one per link")
        theta = self.per_link(theta_raw, "initial.theta", n, allow_ramp=True)
        omega = self.per_link(t.get("omega", 0.0), "initial.omega", n, allow_ramp=True)
        # The core's bound on angles, said in the file's own unit.
        bound = MAX_ANGLE_RAD / scale
        for i, value in enumerate(theta):
            if abs(value) > bound:
                key = "initial.theta" + ("" if isinstance(theta_raw, (int, float)) else
                                         (".from" if i == 0 else ".to") if isinstance(theta_raw, dict) else f"[{i}]")
                raise self.error(key, f"must be within +-{_num(bound, 4)} {unit} (1e15 rad), got {_num(value)}")
        return np.asarray(theta) * scale, np.asarray(omega) * scale

    def simulation(self, raw: Any) -> Dict[str, Any]:
        t = self.table(raw, "simulation", _SIM_KEYS)
        t_end = self.number(self.require(t, "simulation", "t_end", "the duration in s (a number > 0)"),
                            "simulation.t_end", positive=True)
        method = self.choice(t.get("method", _DEFAULTS["method"]), "simulation.method", _METHODS)
        dt = None
        if "dt" in t:
            dt = self.number(t["dt"], "simulation.dt", positive=True)
        elif method in _FIXED_STEP:
            raise self.error("simulation.dt", f'missing; method "{method}" takes fixed steps and needs '
                             f"dt in s (a number > 0)")
        rtol = self.number(t.get("rtol", _DEFAULTS["rtol"]), "simulation.rtol", positive=True)
        if rtol < MIN_RTOL and _core.METHOD_INFO[method]["adaptive"]:
            raise self.error("simulation.rtol", f"must be >= {_num(MIN_RTOL)} (dop853's error estimate is "
                             f"round-off below it), got {_describe(rtol)}")
        out = {
            "t_end": t_end, "method": method, "dt": dt,
            "rtol": rtol,
            # The core accepts atol = 0 (a purely relative tolerance): so does a scenario.
            "atol": self.number(t.get("atol", _DEFAULTS["atol"]), "simulation.atol", nonneg=True),
            "sample_dt": self.number(t.get("sample_dt", 0.01), "simulation.sample_dt", positive=True),
            "form": None,
        }
        if "form" in t:
            out["form"] = self.choice(t["form"], "simulation.form", tuple(_core.FORMS))
            # A form is a choice only for the methods that integrate more than one.
            if len(_core.METHOD_INFO[method]["forms"]) < 2:
                takes = " and ".join('"' + m + '"' for m in _METHODS if len(_core.METHOD_INFO[m]["forms"]) > 1)
                raise self.error("simulation.form", f'only applies to {takes} (method "{method}" always '
                                 f"integrates Hamilton's equations), got {_describe(out['form'])}")
        if dt is not None and dt > t_end:
            raise self.error("simulation.dt", f"must be <= t_end ({_describe(t_end)}), got {_describe(dt)}")
        return out

    def torque(self, raw: Any, n: int) -> TorqueSpec:
        if not isinstance(raw, dict):
            raise self.error("torque", f"expected a table ([torque]), got {_type_name(raw)} {_describe(raw)}")
        kind = self.choice(self.require(raw, "torque", "kind", '"constant", "sinusoid" or "table"'),
                           "torque.kind", tuple(_TORQUE_KEYS))
        t = self.table(raw, "torque", _TORQUE_KEYS[kind])
        convention = self.choice(
            self.require(t, "torque", "convention",
                         '"generalized" (torques on the absolute angles, as in seed 000) or "joint" '
                         "(motor torques between link i-1 and link i)"),
            "torque.convention", ("generalized", "joint"))
        if kind == "constant":
            value = self.per_link(self.require(t, "torque", "value", "torques in N m, one per link"),
                                  "torque.value", n)
            return TorqueSpec(kind, convention, {"value": value})
        if kind == "sinusoid":
            params = {
                "amplitude": self.per_link(self.require(t, "torque", "amplitude", "amplitudes in N m"),
                                           "torque.amplitude", n),
                "frequency": self.per_link(self.require(t, "torque", "frequency", "angular frequencies in rad/s"),
                                           "torque.frequency", n),
                "phase": self.per_link(t.get("phase", 0.0), "torque.phase", n),
                "offset": self.per_link(t.get("offset", 0.0), "torque.offset", n),
            }
            return TorqueSpec(kind, convention, params)
        # table
        name = self.require(t, "torque", "file", "a CSV file name (columns: t, then one torque per link)")
        if not isinstance(name, str) or not name:
            raise self.error("torque.file", f"expected a file name, got {_type_name(name)} {_describe(name)}")
        interpolation = self.choice(t.get("interpolation", "linear"), "torque.interpolation", ("linear", "cubic"))
        times, values, lines, header = self.csv_table(self.read_file(name, "torque.file"), name, n)
        if interpolation == "cubic":
            self.check_spline("torque.interpolation", times, values, _csv_place(name, lines, header),
                              'use interpolation = "linear" or smaller torques')
        return TorqueSpec(kind, convention, {"t": times, "values": values, "interpolation": interpolation}, file=name)

    def pivot(self, raw: Any) -> Dict[str, SignalSpec]:
        t = self.table(raw, "pivot", _PIVOT_KEYS)
        return {axis: self.signal(t[axis], f"pivot.{axis}", "m", cubic=True) for axis in _PIVOT_KEYS if axis in t}

    def cart(self, raw: Any) -> CartSpec:
        t = self.table(raw, "cart", _CART_KEYS)
        force = self.signal(t["force"], "cart.force", "N", cubic=False) if "force" in t else None
        return CartSpec(
            mass=self.number(self.require(t, "cart", "mass", "the cart's mass in kg (a number > 0)"), "cart.mass",
                             positive=True),
            damping=self.number(t.get("damping", 0.0), "cart.damping", nonneg=True),
            x0=self.number(t.get("x0", 0.0), "cart.x0"),
            v0=self.number(t.get("v0", 0.0), "cart.v0"),
            force=force,
        )

    def signal(self, raw: Any, key: str, unit: str, *, cubic: bool) -> SignalSpec:
        """A number (constant), or a table ``{kind = "sinusoid", amplitude, frequency, phase,
        offset}`` or ``{kind = "table", t = [...], values = [...]}`` / ``{kind = "table", file =
        "x.csv"}`` (columns t and the value, as a torque table). ``cubic``: a table is always a
        cubic spline (a pivot's motion needs two derivatives), so it takes no interpolation."""
        if _is_number(raw):
            return SignalSpec("constant", {"value": self.number(raw, key)})
        if not isinstance(raw, dict):
            raise self.error(key, f'expected a number ({unit}) or a table {{kind = "sinusoid" or "table", ...}}, '
                             f"got {_type_name(raw)} {_describe(raw)}")
        kind = self.choice(self.require(raw, key, "kind", '"sinusoid" or "table"'), f"{key}.kind", tuple(_SIGNAL_KEYS))
        allowed = tuple(k for k in _SIGNAL_KEYS[kind] if not (cubic and k == "interpolation"))
        t = self.table(raw, key, allowed)
        if kind == "sinusoid":
            return SignalSpec(kind, {
                "amplitude": self.number(self.require(t, key, "amplitude", f"the amplitude in {unit}"),
                                         f"{key}.amplitude"),
                "frequency": self.number(self.require(t, key, "frequency", "the angular frequency in rad/s"),
                                         f"{key}.frequency"),
                "phase": self.number(t.get("phase", 0.0), f"{key}.phase"),
                "offset": self.number(t.get("offset", 0.0), f"{key}.offset"),
            })
        interpolation = "cubic" if cubic else self.choice(t.get("interpolation", "linear"), f"{key}.interpolation",
                                                          ("linear", "cubic"))
        where = _join(key, "interpolation") if not cubic else key
        advice = ('use interpolation = "linear" or smaller values' if not cubic
                  else "use smaller values or samples further apart")
        if "file" in t:
            for name in ("t", "values"):
                if name in t:
                    raise self.error(f"{key}.{name}", "cannot be given with file: a table is either a CSV file "
                                     "or the arrays t and values")
            name = t["file"]
            if not isinstance(name, str) or not name:
                raise self.error(f"{key}.file", f"expected a file name, got {_type_name(name)} {_describe(name)}")
            label = key.rsplit(".", 1)[-1]
            times, rows, lines, header = self.csv_table(
                self.read_file(name, f"{key}.file"), name, 1, key=f"{key}.file", labels=(label,),
                columns=f"t, then {label} in {unit}", limit=f"values must be below about 1e307 {unit}")
            if interpolation == "cubic":
                self.check_spline(where, times, rows, _csv_place(name, lines, header, (label,)), advice)
            return SignalSpec(kind, {"t": times, "values": [r[0] for r in rows], "interpolation": interpolation},
                              file=name)
        times = self.numbers(self.require(t, key, "t", 'sample times in s (an array), or file = "NAME.csv"'),
                             f"{key}.t")
        values = self.numbers(self.require(t, key, "values", f"values in {unit}, one per time in t"), f"{key}.values")
        if len(values) != len(times):
            raise self.error(f"{key}.values", f"expected {len(times)} values (one per time in t), got {len(values)}")
        # How many samples a spline needs, and that times increase, the core checks (check_base).
        if interpolation == "cubic" and len(times) >= 2 and all(b > a for a, b in zip(times, times[1:])):
            self.check_spline(where, times, [[v] for v in values],
                              lambda row, j: f"values[{row}] and values[{row + 1}]", advice)
        return SignalSpec(kind, {"t": times, "values": values, "interpolation": interpolation})

    def numbers(self, value: Any, key: str) -> List[float]:
        if not isinstance(value, list):
            raise self.error(key, f"expected an array of numbers, got {_type_name(value)} {_describe(value)}")
        return [self.number(v, f"{key}[{i}]") for i, v in enumerate(value)]

    def check_spline(self, key: str, times, values, place: Callable[[int, int], str], advice: str) -> None:
        """The natural cubic spline the core fits must stay finite: its second derivatives grow
        like 6 |du| / dt^2, which overflows for huge values on close times. ``place(row, j)``
        names sample ``row`` of column ``j`` in the message."""
        t = np.asarray(times, dtype=float)
        u = np.asarray(values, dtype=float)
        with np.errstate(over="ignore", invalid="ignore"):
            slopes = np.diff(u, axis=0) / np.diff(t)[:, None]
            curvature = 6.0 * np.diff(slopes, axis=0) / np.diff(t)[1:, None]
        bad = ~np.isfinite(slopes)
        if not bad.any():
            bad2 = ~np.isfinite(curvature)
            if not bad2.any():
                return
            row, j = (int(v) for v in np.argwhere(bad2)[0])
            row += 1
        else:
            row, j = (int(v) for v in np.argwhere(bad)[0])
        raise self.error(key, f"{place(row, j)}: the cubic spline through {_num(u[row, j])} at t = {_num(t[row])} "
                         f"and {_num(u[row + 1, j])} at t = {_num(t[row + 1])} overflows; {advice}")

    def csv_table(self, text: str, name: str, n: int, *, key: str = "torque.file",
                  labels: Optional[Sequence[str]] = None, columns: str = "t, then one torque per link",
                  limit: str = "torques must be below about 1e307 N m") -> Tuple[List[float], List[List[float]], List[int], Optional[List[str]]]:
        """A table of ``n`` values a time: lines of ``t, u_1, ..., u_n`` (``#`` comments and one
        header line allowed); a torque table by default. Every message names the file's line
        and, for a bad value, its column (1 is ``t``, column k + 1 the value ``labels[k - 1]``,
        ``link k`` for a torque, or the header's name for it). Returns the times, the rows of
        values, their line numbers and the header (or ``None``)."""
        rows: List[List[float]] = []
        lines: List[int] = []
        header: Optional[List[str]] = None

        def column(j: int) -> str:
            label = "t" if j == 0 else (labels[j - 1] if labels is not None else f"link {j}")
            if header is not None and j < len(header) and header[j]:
                return f"column {j + 1} ({header[j]!r}, {label})"
            return f"column {j + 1} ({label})"

        for lineno, line in enumerate(io.StringIO(text), start=1):
            stripped = line.split("#", 1)[0].strip()
            if not stripped:
                continue
            cells = [c.strip() for c in stripped.split(",")]
            if not rows and not any(is_float(c) for c in cells):
                header = cells  # a header line (names for the columns)
                continue
            if len(cells) != n + 1:
                raise self.error(key, f"{name} line {lineno}: expected {n + 1} columns ({columns}), "
                                 f"got {len(cells)}")
            numbers = []
            for j, cell in enumerate(cells):
                if not is_float(cell):
                    raise self.error(key, f"{name} line {lineno}, {column(j)}: expected a number, got {cell!r}")
                value = float(cell)
                if not math.isfinite(value):
                    raise self.error(key, f"{name} line {lineno}, {column(j)}: must be finite, got {cell!r}")
                numbers.append(value)
            if rows and not numbers[0] > rows[-1][0]:
                raise self.error(key, f"{name} line {lineno}, {column(0)}: times must increase, got "
                                 f"{_num(numbers[0])} after {_num(rows[-1][0])} on line {lines[-1]}")
            if rows:
                for j in range(1, n + 1):
                    if not math.isfinite(numbers[j] - rows[-1][j]):
                        raise self.error(key, f"{name} line {lineno}, {column(j)}: the change from line "
                                         f"{lines[-1]} ({_num(rows[-1][j])} to {_num(numbers[j])}) overflows; "
                                         f"{limit}")
            rows.append(numbers)
            lines.append(lineno)
        if len(rows) < 2:
            raise self.error(key, f"{name}: expected at least 2 rows of numbers, got {len(rows)}")
        return [r[0] for r in rows], [r[1:] for r in rows], lines, header

    def outputs(self, raw: Any) -> Outputs:
        t = self.table(raw, "output", _OUTPUT_KEYS)
        results = t.get("results", "results.npz")
        if not isinstance(results, str) or Path(results).suffix.lower() not in (".npz", ".csv") \
                or Path(results).name != results:
            raise self.error("output.results", f"expected a file name ending in .npz or .csv, got {_describe(results)}")
        animation = t.get("animation", "animation.gif")
        if animation is False:
            animation = None
        elif not isinstance(animation, str) or Path(animation).suffix.lower() not in (".gif", ".mp4") \
                or Path(animation).name != animation:
            raise self.error("output.animation",
                             f"expected a file name ending in .gif or .mp4, or false, got {_describe(animation)}")
        plots = t.get("plots", True)
        if plots is True:
            kinds: Tuple[str, ...] = PLOT_KINDS
        elif plots is False:
            kinds = ()
        elif isinstance(plots, list):
            kinds = tuple(self.choice(k, f"output.plots[{i}]", PLOT_KINDS) for i, k in enumerate(plots))
        else:
            raise self.error("output.plots", f"expected true, false or an array of plot kinds "
                             f"({', '.join(PLOT_KINDS)}), got {_describe(plots)}")
        return Outputs(
            results=results, animation=animation, plots=kinds,
            fps=self.number(t.get("fps", 30), "output.fps", positive=True),
            trail=self.number(t.get("trail", 2.0), "output.trail", nonneg=True),
            speed=self.number(t.get("speed", 1.0), "output.speed", positive=True),
            dpi=self.number(t.get("dpi", 80), "output.dpi", positive=True),
        )


def _csv_place(name: str, lines: Sequence[int], header: Optional[Sequence[str]],
               labels: Optional[Sequence[str]] = None) -> Callable[[int, int], str]:
    """Names sample ``row``, value column ``j`` of a CSV table for a message: its lines and column."""
    def place(row: int, j: int) -> str:
        label = labels[j] if labels is not None else f"link {j + 1}"
        if header is not None and j + 1 < len(header):
            label += f", {header[j + 1]!r}"
        return f"{name} lines {lines[row]}-{lines[row + 1]}, column {j + 2} ({label})"
    return place


def _join(key: str, name: str) -> str:
    return f"{key}.{name}" if key else name

