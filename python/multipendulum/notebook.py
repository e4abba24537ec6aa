"""Notebook widgets: the browser viewer in a cell.

:func:`widget` (``mp.widget``) runs a chain live in the cell with the viewer's WebAssembly
engine, with two-way state: Python reads the time and state the browser reports, sets the start
state, gravity, the losses and the integrator (each change restarts the run from its start
state), and plays or pauses it. :func:`show` (``mp.show(sol)`` or ``sol.show()``) plays a
computed solution. Both are `anywidget <https://anywidget.dev>`_ widgets, shown by JupyterLab,
Notebook 7, VS Code and the other front ends anywidget supports: ``pip install
'multipendulum[widget]'``.

Everything given is checked in Python as :func:`multipendulum.simulate` checks it (the same
messages, :class:`~multipendulum.InputError`), and again by the core in the browser: a value
that reaches the browser and is refused there is not applied, and the widget says why (its
``error``). A chain longer than the viewer shows (:data:`VIEWER_MAX_LINKS` links) is refused
with the advice to write a video with :func:`multipendulum.animate` instead.
"""
from __future__ import annotations

import functools
from typing import Any, Dict, Optional, Tuple

import numpy as np
import numpy.typing as npt

# First: without anywidget it raises the ImportError that says how to install it.
from ._notebook import VIEWER_MAX_LINKS, WEB, Player, _flag, _height, _speed, _stylesheet, bundle, check_viewer_size, look, show  # isort: skip
import anywidget  # noqa: E402
import traitlets  # noqa: E402

from ._base import ForceLike, Pivot, normalise_force, normalise_pivot
from ._chain import Chain, as_state, check_chain
from ._convert import as_float
from ._simulate import DEFAULTS, simulate
from ._torque import TorqueLike, normalise_torque
from .errors import InputError

__all__ = ["widget", "Widget", "show", "Player", "VIEWER_MAX_LINKS"]

#: The values Python may set on a live widget; each change restarts the run from its start state.
PARAMETERS = ("theta0", "omega0", "g", "damping", "friction", "method", "dt", "rtol", "atol", "cart_x0", "cart_v0")
#: The state the browser reports (read-only in Python), about ten times a second.
STATE = ("t", "theta", "omega", "energy", "kinetic", "potential", "work", "dissipated", "energy_error", "base", "error")
# The check run: long enough for one step of any method, too short to cost anything.
_CHECK_T_END = 1e-9
_PYTHON_FUNCTION = ("mp.widget runs the chain in the browser, where a Python function cannot be called: give {what} as "
                    "{instead}, or run mp.simulate with the function and play the solution with sol.show()")


@functools.lru_cache(maxsize=1)
def _wasm() -> bytes:
    path = WEB / "multipendulum.wasm"
    if not path.is_file():
        raise InputError(f"the viewer is not built: {path} is missing (run `make build`)")
    return path.read_bytes()


def _floats(a: npt.ArrayLike) -> list:
    return [float(v) for v in np.asarray(a, dtype=np.float64).ravel()]


# ----------------------------------------------------------------------------------------------
# The drive, as the page's setup takes it (engine.js `simulation`)


def _signal(spec: Tuple[Any, ...]) -> Any:
    """A pivot axis or a cart force (normalised by _base) as the page's signal."""
    kind = spec[0]
    if kind in ("fixed", "constant"):
        return float(spec[1])
    if kind == "sinusoid":
        return dict(zip(("kind", "amplitude", "frequency", "phase", "offset"), ("sinusoid", *map(float, spec[1:5]))))
    if kind == "spline":
        return {"kind": "table", "t": _floats(spec[1]), "values": _floats(spec[2]), "interpolation": "cubic"}
    assert kind == "table", kind
    return {"kind": "table", "t": _floats(spec[1]), "values": _floats(spec[2]), "interpolation": spec[3]}


def _torque(spec: Optional[Tuple[Any, ...]], joint: bool, n: int) -> Optional[Dict[str, Any]]:
    if spec is None:
        return None
    out: Dict[str, Any] = {"convention": "joint" if joint else "generalized", "kind": spec[0]}
    if spec[0] == "constant":
        out["value"] = _floats(spec[1])
    elif spec[0] == "sinusoid":
        out.update(zip(("amplitude", "frequency", "phase", "offset"), map(_floats, spec[1:5])))
    else:
        t = _floats(spec[1])
        out.update(t=t, values=np.asarray(spec[2], dtype=np.float64).reshape(len(t), n).tolist(), interpolation=spec[3])
    return out


def _drive(chain: Chain, torque: Optional[TorqueLike], joint_torque: Optional[TorqueLike], pivot: Optional[Pivot],
           cart_force: Optional[ForceLike]) -> Dict[str, Any]:
    """The drive as the page takes it; Python functions refused (the browser cannot call them)."""
    spec, joint = normalise_torque(torque, joint_torque, chain.n)
    if spec is not None and spec[0] == "callable":
        raise InputError(_PYTHON_FUNCTION.format(what="joint_torque" if joint else "torque",
                                                 instead="numbers (one per link), mp.Sinusoid or mp.Table"))
    axes = normalise_pivot(pivot)
    if axes is not None and any(a[0] == "function" for a in axes):
        raise InputError(_PYTHON_FUNCTION.format(what="each pivot axis", instead="a number, mp.Sinusoid or mp.Table(kind=\"cubic\")"))
    force = normalise_force(cart_force)
    if force is not None and force[0] == "function":
        raise InputError(_PYTHON_FUNCTION.format(what="cart_force", instead="a number, mp.Sinusoid or mp.Table"))
    cart = chain.cart
    return {
        "pivot": None if axes is None else {"x": _signal(axes[0]), "y": _signal(axes[1])},
        "torque": _torque(spec, joint, chain.n),
        "cart": None if cart is None else {"mass": float(cart.mass), "damping": float(cart.damping),
                                           "force": None if force is None else _signal(force)},
    }


# ----------------------------------------------------------------------------------------------
# The checks


class _Setup:
    """A checked setup: the normalised values Python may change, the chain they make with the
    fixed parameters, and the state at t = 0 as the core computes it."""

    def __init__(self, base: Chain, drive: Dict[str, Any], values: Dict[str, Any]) -> None:
        n = base.n
        d = base.to_dict()
        d.update(g=as_float(values["g"], "g"), friction_velocity=base.friction_velocity,
                 damping=base.damping if values["damping"] is None else values["damping"],
                 friction=base.friction if values["friction"] is None else values["friction"])
        chain = Chain.from_dict(d)  # the core checks g and the losses
        theta0 = as_state(values["theta0"], "theta0", n)
        omega0 = np.zeros(n) if values["omega0"] is None else as_state(values["omega0"], "omega0", n)
        for name, a in (("theta0", theta0), ("omega0", omega0)):
            if a.shape != (n,):
                raise InputError(f"{name} must have shape ({n},): a widget runs one chain (batches are mp.simulate's), "
                                 f"got shape {a.shape}")
        method = values["method"]
        dt = None if values["dt"] is None else as_float(values["dt"], "dt")
        rtol, atol = as_float(values["rtol"], "rtol", finite=True), as_float(values["atol"], "atol", finite=True)
        cart_x0 = as_float(values["cart_x0"], "cart_x0", finite=True)
        cart_v0 = as_float(values["cart_v0"], "cart_v0", finite=True)
        # One step of the real run: mp.simulate's checks and the core's, with their messages.
        sol = simulate(chain, theta0, omega0, _CHECK_T_END, method=method, dt=dt, rtol=rtol, atol=atol,
                       t_eval=[0.0], cart_x0=cart_x0, cart_v0=cart_v0, **drive)
        self.chain = chain
        self.values: Dict[str, Any] = {
            "theta0": _floats(theta0), "omega0": _floats(omega0), "g": chain.g, "damping": _floats(chain.damping),
            "friction": _floats(chain.friction), "method": method, "dt": dt, "rtol": rtol, "atol": atol,
            "cart_x0": cart_x0, "cart_v0": cart_v0,
        }
        pivot = drive.get("pivot")
        kinetic = float(chain.kinetic_energy(theta0, omega0, pivot=pivot, cart_v=cart_v0))
        potential = float(chain.potential_energy(theta0, pivot=pivot))
        self.start: Dict[str, Any] = {
            "t": 0.0, "theta": _floats(theta0), "omega": _floats(omega0), "energy": float(sol.energy[0]),
            "kinetic": kinetic, "potential": potential, "work": 0.0, "dissipated": 0.0, "energy_error": 0.0,
            "base": _floats(sol.pivot[0]), "error": "",
        }


# ----------------------------------------------------------------------------------------------
# The live widget


class Widget(anywidget.AnyWidget):
    """A chain running live in a notebook cell, in the browser viewer's WebAssembly engine.

    Made by :func:`widget` (same arguments). Python sets, each change checked as
    :func:`~multipendulum.simulate` checks it (:class:`~multipendulum.InputError` on assignment,
    nothing changed) and restarting the run from its start state: ``theta0``, ``omega0`` (rad,
    rad/s, one per link), ``g``, ``damping``, ``friction`` (one per joint), ``method``, ``dt``,
    ``rtol``, ``atol``, ``cart_x0``, ``cart_v0``; several at once with :meth:`set`. Synced both ways: ``playing`` (the play button
    too) and ``speed`` (simulated seconds per second); ``height`` is the canvas's in pixels.

    Reported by the browser about ten times a second while it plays (read-only here): ``t`` (s),
    ``theta``, ``omega`` (lists, one per link), ``energy``, ``kinetic``, ``potential``, ``work``
    (done on the chain by the torque, the pivot and the cart force), ``dissipated`` (J, lab
    frame, since t = 0), ``energy_error`` (the residual of the energy balance, as
    ``sol.energy_error``), ``base`` (the pivot's or the cart's position, m), and ``error``: the
    message the widget shows ('' when none), e.g. a step that failed. Until the browser reports,
    they hold the start state (again after each change).

    The pivot (or the cart) can be dragged with the pointer while the chain runs, as on the page.
    """

    _esm = bundle("widget.js")
    _css = _stylesheet()

    _wasm = traitlets.Bytes().tag(sync=True)
    _chain = traitlets.Dict().tag(sync=True)
    _restart = traitlets.Int(0).tag(sync=True)

    theta0 = traitlets.Any().tag(sync=True)
    omega0 = traitlets.Any().tag(sync=True)
    g = traitlets.Any().tag(sync=True)
    damping = traitlets.Any().tag(sync=True)
    friction = traitlets.Any().tag(sync=True)
    method = traitlets.Any().tag(sync=True)
    dt = traitlets.Any().tag(sync=True)
    rtol = traitlets.Any().tag(sync=True)
    atol = traitlets.Any().tag(sync=True)
    cart_x0 = traitlets.Any().tag(sync=True)
    cart_v0 = traitlets.Any().tag(sync=True)
    playing = traitlets.Any(False).tag(sync=True)
    speed = traitlets.Any(1.0).tag(sync=True)
    height = traitlets.Any(400).tag(sync=True)

    t = traitlets.Float(read_only=True).tag(sync=True)
    theta = traitlets.List(traitlets.Float(), read_only=True).tag(sync=True)
    omega = traitlets.List(traitlets.Float(), read_only=True).tag(sync=True)
    energy = traitlets.Float(read_only=True).tag(sync=True)
    kinetic = traitlets.Float(read_only=True).tag(sync=True)
    potential = traitlets.Float(read_only=True).tag(sync=True)
    work = traitlets.Float(read_only=True).tag(sync=True)
    dissipated = traitlets.Float(read_only=True).tag(sync=True)
    energy_error = traitlets.Float(read_only=True).tag(sync=True)
    base = traitlets.List(traitlets.Float(), read_only=True).tag(sync=True)
    error = traitlets.Unicode(read_only=True).tag(sync=True)

    def __init__(self, chain: Chain, theta0: npt.ArrayLike, omega0: Optional[npt.ArrayLike] = None, *,
                 method: str = DEFAULTS["method"], dt: Optional[float] = None, rtol: float = DEFAULTS["rtol"],
                 atol: float = DEFAULTS["atol"], torque: Optional[TorqueLike] = None,
                 joint_torque: Optional[TorqueLike] = None, pivot: Optional[Pivot] = None, cart_x0: float = 0.0,
                 cart_v0: float = 0.0, cart_force: Optional[ForceLike] = None, speed: float = 1.0,
                 playing: bool = False, height: int = 400) -> None:
        check_chain(chain)
        check_viewer_size(chain.n, "mp.widget")
        page = _drive(chain, torque, joint_torque, pivot, cart_force)
        self._given = chain
        self._drive: Dict[str, Any] = {"torque": torque, "joint_torque": joint_torque, "pivot": pivot,
                                       "cart_force": cart_force}
        self._ready = False
        self._pending: Optional[_Setup] = None  # checked by a validator, applied by its observer
        setup = _Setup(chain, self._drive, {
            "theta0": theta0, "omega0": omega0, "g": chain.g, "damping": None, "friction": None, "method": method,
            "dt": dt, "rtol": rtol, "atol": atol, "cart_x0": cart_x0, "cart_v0": cart_v0})
        self._setup = setup
        info = {"lengths": _floats(chain.lengths), "masses": _floats(chain.masses), "com": _floats(chain.com),
                "inertia": _floats(chain.inertia), "friction_velocity": chain.friction_velocity,
                "look": look(chain)["kind"], **page}
        super().__init__(_wasm=_wasm(), _chain=info, speed=_speed(speed), playing=_flag(playing, "playing"),
                         height=_height(height), **setup.values)
        self._ready = True

    # The start state until the browser reports (the traits are read-only to Python).
    @traitlets.default("t")
    def _t0(self) -> float:
        return float(self._setup.start["t"])

    @traitlets.default("theta")
    def _theta0(self) -> list:
        return list(self._setup.start["theta"])

    @traitlets.default("omega")
    def _omega0(self) -> list:
        return list(self._setup.start["omega"])

    @traitlets.default("energy")
    def _energy0(self) -> float:
        return float(self._setup.start["energy"])

    @traitlets.default("kinetic")
    def _kinetic0(self) -> float:
        return float(self._setup.start["kinetic"])

    @traitlets.default("potential")
    def _potential0(self) -> float:
        return float(self._setup.start["potential"])

    @traitlets.default("base")
    def _base0(self) -> list:
        return list(self._setup.start["base"])

    @traitlets.validate(*PARAMETERS)
    def _check_parameter(self, proposal: Any) -> Any:
        name = proposal.trait.name
        if not self._ready:
            return proposal.value  # the constructor's, already checked
        values = dict(self._setup.values, **{name: proposal.value})
        self._pending = _Setup(self._given, self._drive, values)
        return self._pending.values[name]

    @traitlets.observe(*PARAMETERS)
    def _parameter_changed(self, change: Any) -> None:
        if self._ready and self._pending is not None:
            self._setup, self._pending = self._pending, None
            self._show_start()

    @traitlets.validate("playing")
    def _check_playing(self, proposal: Any) -> bool:
        return _flag(proposal.value, "playing")

    @traitlets.validate("speed")
    def _check_speed(self, proposal: Any) -> float:
        return _speed(proposal.value)

    @traitlets.validate("height")
    def _check_height(self, proposal: Any) -> int:
        return _height(proposal.value)

    def _show_start(self) -> None:
        with self.hold_sync(), self.hold_trait_notifications():
            for name, value in self._setup.start.items():
                self.set_trait(name, value)

    def set(self, **values: Any) -> None:
        """Change several of the parameters at once (one check, one restart), e.g.
        ``w.set(method="rk4", dt=0.005)``: one at a time, ``w.method = "rk4"`` alone would be
        refused while ``dt`` is still None. Nothing changes if any value is refused."""
        unknown = sorted(set(values) - set(PARAMETERS))
        if unknown:
            raise InputError(f"set takes {', '.join(PARAMETERS)}; got {', '.join(unknown)}")
        setup = _Setup(self._given, self._drive, dict(self._setup.values, **values))
        self._ready = False  # checked together above: not one by one
        try:
            with self.hold_sync():  # one message: the browser restarts once, with all of them
                for name in values:
                    setattr(self, name, setup.values[name])
        finally:
            self._ready = True
        self._setup, self._pending = setup, None
        self._show_start()

    @property
    def chain(self) -> Chain:
        """The chain running: the one given, with the current ``g``, ``damping`` and ``friction``."""
        return self._setup.chain

    def restart(self) -> None:
        """Start the run again from its start state (the widget's Reset button)."""
        self._show_start()
        self._restart += 1

    def __repr__(self) -> str:
        return (f"<multipendulum.notebook.Widget: {self.chain.n} links, {self.method}, t = {self.t:.3f} s"
                f"{', playing' if self.playing else ''}{f', error: {self.error}' if self.error else ''}>")


def widget(chain: Chain, theta0: npt.ArrayLike, omega0: Optional[npt.ArrayLike] = None, *,
           method: str = DEFAULTS["method"], dt: Optional[float] = None, rtol: float = DEFAULTS["rtol"],
           atol: float = DEFAULTS["atol"], torque: Optional[TorqueLike] = None,
           joint_torque: Optional[TorqueLike] = None, pivot: Optional[Pivot] = None, cart_x0: float = 0.0,
           cart_v0: float = 0.0, cart_force: Optional[ForceLike] = None, speed: float = 1.0, playing: bool = False,
           height: int = 400) -> Widget:
    """The browser viewer running ``chain`` live in a notebook cell (a :class:`Widget`; it shows
    itself as a cell's last expression, or with ``IPython.display.display(w)``).

    The arguments are :func:`~multipendulum.simulate`'s and mean the same: the start state
    ``theta0``, ``omega0`` (rad, rad/s; omega0 defaults to zeros), the integrator (``method``,
    ``dt``, ``rtol``, ``atol``), the drive (``torque`` or ``joint_torque``, ``pivot``, and on a
    chain with a cart ``cart_x0``, ``cart_v0``, ``cart_force``) as numbers, :class:`Sinusoid`
    or :class:`Table`: not Python functions, which the browser cannot call. ``speed``:
    simulated seconds per second; ``playing``: start at once; ``height``: the canvas's in
    pixels. The run has no end: it goes on while it is shown and playing.

    Checked as :func:`~multipendulum.simulate` checks them (one step of the run is taken in
    Python): :class:`~multipendulum.InputError` for bad values, and for a chain longer than the
    viewer shows (:data:`VIEWER_MAX_LINKS`). Needs anywidget (``pip install
    'multipendulum[widget]'``).

    >>> import multipendulum as mp
    >>> w = mp.widget(mp.Chain([1, 1], [1, 1]), theta0=[2.0, 2.5], playing=True)
    >>> w.g = 1.62                      # the Moon's: the run restarts from theta0
    >>> w.t, w.theta                    # the browser's report (here: the start state)
    (0.0, [2.0, 2.5])
    """
    return Widget(chain, theta0, omega0, method=method, dt=dt, rtol=rtol, atol=atol, torque=torque,
                  joint_torque=joint_torque, pivot=pivot, cart_x0=cart_x0, cart_v0=cart_v0, cart_force=cart_force,
                  speed=speed, playing=playing, height=height)
