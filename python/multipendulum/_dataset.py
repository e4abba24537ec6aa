"""Datasets for learning dynamics (Hamiltonian and Lagrangian neural networks): many trajectories
of random chains from random initial states, sampled on one time grid, with every quantity such a
model is trained or checked on, written reproducibly to NPZ or Zarr with a dataset card.

:func:`make_dataset` takes keyword arguments; :func:`read_dataset_config` reads the same keys
from a TOML file (``multipendulum dataset CONFIG.toml -o DIR``), so a file and a call describe
the same dataset. The format, every key, the fields and their units are documented in
``docs/datasets.md``; in short::

    trajectories = 1000
    t_end = 10.0                       # s, the horizon
    sample_dt = 0.1                    # s between samples: t = k * sample_dt
    seed = 1
    links = 2
    lengths = { low = 0.5, high = 1.5 }   # m; a number, one per link, or a range
    masses = 1.0
    theta = { low = -3.14159, high = 3.14159 }
    energy = { low = -10.0, high = 10.0 }  # optional: rates scaled to a drawn energy (J)
    [split]
    train = 0.8
    validation = 0.1
    test = 0.1

Nothing here is physics: trajectories come from :func:`multipendulum.simulate`, and every field
from the core (``Chain.momenta``, ``accelerations``, ``hamilton``, ``energy``, ``positions``).
What this module adds is the bookkeeping: random streams, chunks on Dask, files, hashes, card.

Reproducibility. Trajectory ``i``'s random draws come from NumPy's ``default_rng`` seeded by
``SeedSequence(seed, spawn_key=(stream, i // 1024))`` (one stream per block of 1024 trajectories,
fixed layout inside it), so they do not depend on how the work is cut into chunks, on the
scheduler or on the number of threads; a trajectory's numbers do not depend on what is computed
beside it (the core's batches are bit-identical to single runs). NPZ files are written with
fixed zip timestamps, so the same config and seed give byte-identical files. The card's
SHA-256 of each array's bytes is the same for NPZ and Zarr and for any chunk size.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import shutil
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Dict, Iterator, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

import multipendulum._core as _core

from ._base import Pivot
from ._chain import Chain
from ._files import atomic_path
from ._progress import Steps, reporter, scaled
from ._progress import check as _check_progress
from ._simulate import METHOD_INFO, METHODS, simulate
from ._torque import Sinusoid, Table, TorqueLike
from .errors import InputError, IntegrationError

if TYPE_CHECKING:
    from ._files import PathLike
    from .sweeps import Scheduler

__all__ = ["make_dataset", "load_dataset", "read_dataset_config", "Dataset", "CONFIG_KEYS", "FIELDS",
           "NPZ_AUTO_LIMIT", "CHUNK_BYTES"]

F64 = npt.NDArray[np.float64]
Progress = Union[None, bool, Callable[[float], object]]

KIND = "multipendulum.dataset"
CARD_VERSION = 1
DATA_NPZ, DATA_ZARR, CARD_JSON, CARD_MD = "data.npz", "data.zarr", "card.json", "card.md"
#: ``format="auto"`` writes NPZ up to this many bytes (uncompressed estimate), Zarr beyond.
NPZ_AUTO_LIMIT = 256 * 2**20
#: Trajectories per chunk when ``chunk`` is not given: about this many bytes of output each.
CHUNK_BYTES = 32 * 2**20
#: Trajectories per random stream (the layout of the draws; changing it changes every dataset).
_BLOCK = 1024
#: The independent random streams (``spawn_key[0]``).
_PARAMS, _STATES, _RETRY, _SPLIT = 0, 1, 2, 3
#: Candidate initial states drawn per trajectory with an energy range, and rounds of them.
_TRIES, _ROUNDS = 8, 125
_SPLITS = ("train", "validation", "test")
_CHAIN_PARAMS = ("lengths", "masses", "com", "inertia", "g", "damping", "friction")
_UNITS = {"lengths": "m", "masses": "kg", "com": "m", "inertia": "kg m^2", "g": "m/s^2",
          "damping": "N m s/rad", "friction": "N m", "theta": "rad", "omega": "rad/s", "energy": "J"}

#: The keys of a config, in the order of :func:`make_dataset`'s keyword arguments.
CONFIG_KEYS = ("name", "trajectories", "t_end", "sample_dt", "seed", "links", "kind", "lengths", "masses", "com",
               "inertia", "g", "damping", "friction", "friction_velocity", "trajectories_per_chain", "theta",
               "omega", "energy", "torque", "pivot", "method", "dt", "rtol", "atol", "split", "frames", "format",
               "chunk")
_DEFAULTS: Dict[str, Any] = {
    "name": "", "seed": 0, "links": None, "kind": "points", "lengths": 1.0, "masses": 1.0, "com": None,
    "inertia": None, "g": 9.81, "damping": None, "friction": None, "friction_velocity": 1e-3,
    "trajectories_per_chain": 1, "theta": {"low": -math.pi, "high": math.pi}, "omega": None, "energy": None,
    "torque": None, "pivot": None, "method": "dop853", "dt": None, "rtol": 1e-10, "atol": 1e-12,
    "split": {"train": 0.8, "validation": 0.1, "test": 0.1}, "frames": None, "format": "auto", "chunk": None,
}
_REQUIRED = ("trajectories", "t_end", "sample_dt")

#: What each field holds: (axes, unit, definition). B trajectories, T samples, N links.
FIELDS: Dict[str, Tuple[str, str, str]] = {
    "t": ("(T,)", "s", "sample times, t_k = k * sample_dt from 0 (the same for every trajectory)"),
    "q": ("(B, T, N)", "rad", "absolute angles theta_i from the downward vertical, counter-clockwise positive"),
    "p": ("(B, T, N)", "kg m^2/s", "canonical momenta p = A(q) qdot (with a moving pivot: in the pivot's frame)"),
    "qdot": ("(B, T, N)", "rad/s", "angular rates omega = dq/dt, as integrated"),
    "qddot": ("(B, T, N)", "rad/s^2", "angular accelerations at (t, q, qdot): the core's equations of motion "
              "with the losses, torques and pivot motion"),
    "dH_dq": ("(B, T, N)", "N m", "dH/dq at fixed p, H(q, p, t) the chain's Hamiltonian (pivot frame with a "
              "moving pivot); pdot = -dH/dq (+ Q)"),
    "dH_dp": ("(B, T, N)", "rad/s", "dH/dp at fixed q, = A(q)^-1 p = qdot"),
    "Q": ("(B, T, N)", "N m", "generalized non-conservative forces conjugate to q (joint damping and friction, "
          "driving torques): pdot = -dH/dq + Q; present only when the config has losses or a torque"),
    "energy": ("(B, T)", "J", "E = T + U in the lab frame, U = sum m_i g y_i from the pivot's origin; equal "
               "to H without a moving pivot"),
    "frames": ("(B, T, S, S)", "uint8 (0 or 255)", "the chain drawn as lines on a black S x S picture, "
               "y up, the view fixed for the whole dataset (card: frames.extent)"),
    "split": ("(B,)", "code", "the trajectory's split: 0 train, 1 validation, 2 test"),
    "lengths": ("(B, N)", "m", "each trajectory's link lengths"),
    "masses": ("(B, N)", "kg", "each trajectory's link masses"),
    "com": ("(B, N)", "m", "each trajectory's centres of mass, from each link's pivot"),
    "inertia": ("(B, N)", "kg m^2", "each trajectory's moments of inertia about the centres of mass"),
    "g": ("(B,)", "m/s^2", "each trajectory's gravitational acceleration"),
    "damping": ("(B, N)", "N m s/rad", "each trajectory's viscous joint damping (when the config has damping)"),
    "friction": ("(B, N)", "N m", "each trajectory's Coulomb joint friction (when the config has friction)"),
    "chain_index": ("(B,)", "index", "which random chain the trajectory belongs to (trajectories_per_chain > 1)"),
}


# ----------------------------------------------------------------------------------------------
# Reading a config


def read_dataset_config(path: PathLike) -> Dict[str, Any]:
    """The keyword arguments for :func:`make_dataset` in the TOML file ``path`` (its top-level
    keys are the argument names, see :data:`CONFIG_KEYS`). Unknown keys are refused here, with
    the valid ones listed; the values are checked by :func:`make_dataset`."""
    import importlib

    try:
        toml: Any = importlib.import_module("tomllib")
    except ModuleNotFoundError:  # pragma: no cover - Python 3.9/3.10
        toml = importlib.import_module("tomli")
    path = Path(path)
    try:
        raw = toml.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputError(f"{path}: cannot read the dataset config: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: the dataset config is not UTF-8 text: {exc}") from None
    except toml.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML: {exc}") from None
    _check_keys(raw, CONFIG_KEYS, "the dataset config", where=f"{path}: ")
    return raw


def _check_keys(d: Mapping[str, Any], valid: Sequence[str], what: str, where: str = "") -> None:
    unknown = [k for k in d if k not in valid]
    if unknown:
        raise InputError(f"{where}unknown key{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))} "
                         f"in {what}; valid keys: {', '.join(valid)}")


# ----------------------------------------------------------------------------------------------
# Checking a config: plain, JSON-ready values (the card keeps them), or InputError


def _number(v: Any, key: str, *, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise InputError(f"{key} must be a number, got {v!r}")
    x = float(v)
    if not math.isfinite(x):
        raise InputError(f"{key} must be finite, got {x}")
    if positive and not x > 0:
        raise InputError(f"{key} must be > 0, got {_g(x)}")
    if nonneg and not x >= 0:
        raise InputError(f"{key} must be >= 0, got {_g(x)}")
    return x


def _count(v: Any, key: str) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
        raise InputError(f"{key} must be a positive integer, got {v!r}")
    if v < 1:
        raise InputError(f"{key} must be a positive integer, got {int(v)}")
    return int(v)


def _g(x: float) -> str:
    return f"{x:.10g}"


def _values(v: Any, key: str) -> Union[float, List[float]]:
    """A number or a list of numbers (one per link)."""
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if isinstance(v, (list, tuple)):
        if not v:
            raise InputError(f"{key} must be a number or one number per link, got an empty list")
        return [_number(x, f"{key}[{i}]") for i, x in enumerate(v)]
    return _number(v, key)


def _quantity(v: Any, key: str) -> Any:
    """A fixed value (a number or one per link) or a range ``{low = ..., high = ...}``."""
    if isinstance(v, Mapping):
        _check_keys(v, ("low", "high"), f"the range {key}")
        for bound in ("low", "high"):
            if bound not in v:
                raise InputError(f"{key} must have both low and high (a range), missing {key}.{bound}")
        return {"low": _values(v["low"], f"{key}.low"), "high": _values(v["high"], f"{key}.high")}
    return _values(v, key)


def _lengths_of(v: Any) -> List[int]:
    if isinstance(v, dict):
        return [len(x) for x in (v["low"], v["high"]) if isinstance(x, list)]
    return [len(v)] if isinstance(v, list) else []


class _Range:
    """A quantity resolved to ``low`` and ``high`` arrays of ``n`` entries; ``ranged`` when it
    was given as a range (it then takes random draws, even with low == high)."""

    def __init__(self, spec: Any, key: str, n: int):
        self.key = key
        self.ranged = isinstance(spec, dict)
        lo, hi = (spec["low"], spec["high"]) if self.ranged else (spec, spec)
        self.low = np.broadcast_to(np.asarray(lo, dtype=np.float64), (n,)).copy()
        self.high = np.broadcast_to(np.asarray(hi, dtype=np.float64), (n,)).copy()
        for i in range(n):
            if self.low[i] > self.high[i]:
                at = f"[{i}]" if isinstance(lo, list) or isinstance(hi, list) else ""
                raise InputError(f"{key} is an empty range: {key}.low{at} = {_g(self.low[i])} > "
                                 f"{key}.high{at} = {_g(self.high[i])}")

    def values(self, u: F64) -> F64:
        """``low + (high - low) u`` for uniforms ``u`` (..., n)."""
        return self.low + (self.high - self.low) * u


def _torque_config(v: Any, n: int) -> Optional[Dict[str, Any]]:
    """A torque as plain data: ``{kind, convention, ...}`` as in a scenario's [torque]."""
    if v is None:
        return None
    if isinstance(v, Sinusoid):
        spec = v._spec(n)
        return {"kind": "sinusoid", "convention": "generalized", "amplitude": spec[1], "frequency": spec[2],
                "phase": spec[3], "offset": spec[4]}
    if isinstance(v, Table):
        spec = v._spec(n)
        return {"kind": "table", "convention": "generalized", "t": spec[1],
                "values": np.asarray(spec[2]).reshape(len(spec[1]), n).tolist(), "interpolation": spec[3]}
    if callable(v):
        raise InputError("torque must be built-in (numbers, mp.Sinusoid, mp.Table or their tables): a Python "
                         "function cannot be kept in the dataset card, so the dataset could not be made again")
    if not isinstance(v, Mapping):
        return {"kind": "constant", "convention": "generalized", "value": _values(v, "torque")}
    kinds = {"constant": ("value",), "sinusoid": ("amplitude", "frequency", "phase", "offset"),
             "table": ("t", "values", "interpolation")}
    kind = v.get("kind")
    if kind not in kinds:
        raise InputError(f'torque.kind must be one of {", ".join(kinds)}, got {kind!r}')
    _check_keys(v, ("kind", "convention") + kinds[kind], f"a {kind} torque")
    convention = v.get("convention", "generalized")
    if convention not in ("generalized", "joint"):
        raise InputError(f'torque.convention must be "generalized" or "joint", got {convention!r}')
    out: Dict[str, Any] = {"kind": kind, "convention": convention}
    if kind == "constant":
        out["value"] = _values(_required(v, "value", "torque"), "torque.value")
    elif kind == "sinusoid":
        for f in kinds[kind]:
            out[f] = _values(v.get(f, 0.0) if f in ("phase", "offset") else _required(v, f, "torque"), f"torque.{f}")
    else:
        t = _required(v, "t", "torque")
        out["t"] = [_number(x, f"torque.t[{i}]") for i, x in enumerate(t if isinstance(t, list) else [t])]
        rows = _required(v, "values", "torque")
        rows = rows.tolist() if isinstance(rows, np.ndarray) else rows
        if not isinstance(rows, list):
            raise InputError(f"torque.values must be a list of rows (one per time in torque.t), got {rows!r}")
        out["values"] = [_values(r, f"torque.values[{i}]") for i, r in enumerate(rows)]
        out["interpolation"] = v.get("interpolation", "linear")
    return out


def _required(v: Mapping[str, Any], name: str, what: str) -> Any:
    if name not in v:
        raise InputError(f"{what}.{name} is missing")
    return v[name]


def _axis_config(v: Any, key: str) -> Any:
    if isinstance(v, Sinusoid):
        return {"kind": "sinusoid", **{f: _number(np.asarray(getattr(v, f)).item(), f"{key}.{f}")
                                       for f in ("amplitude", "frequency", "phase", "offset")}}
    if isinstance(v, Table):
        return {"kind": "table", "t": np.asarray(v.t, dtype=float).tolist(),
                "values": np.asarray(v.values, dtype=float).ravel().tolist()}
    if callable(v):
        raise InputError(f"{key} must be built-in (a number, mp.Sinusoid or mp.Table): a Python function cannot "
                         "be kept in the dataset card, so the dataset could not be made again")
    if not isinstance(v, Mapping):
        return _number(v, key)
    kind = v.get("kind")
    if kind == "sinusoid":
        _check_keys(v, ("kind", "amplitude", "frequency", "phase", "offset"), f"the pivot motion {key}")
        return {"kind": kind, "amplitude": _number(_required(v, "amplitude", key), f"{key}.amplitude"),
                "frequency": _number(_required(v, "frequency", key), f"{key}.frequency"),
                "phase": _number(v.get("phase", 0.0), f"{key}.phase"),
                "offset": _number(v.get("offset", 0.0), f"{key}.offset")}
    if kind == "table":
        _check_keys(v, ("kind", "t", "values"), f"the pivot motion {key}")
        return {"kind": kind, "t": _values(_required(v, "t", key), f"{key}.t"),
                "values": _values(_required(v, "values", key), f"{key}.values")}
    raise InputError(f'{key}.kind must be "sinusoid" or "table" (or {key} a number), got {kind!r}')


def _pivot_config(v: Any) -> Optional[Dict[str, Any]]:
    if v is None:
        return None
    if isinstance(v, Pivot):
        v = {"x": v.x, "y": v.y}
    if not isinstance(v, Mapping):
        raise InputError(f"pivot must be an mp.Pivot or a table {{x = ..., y = ...}}, got {v!r}")
    _check_keys(v, ("x", "y"), "pivot")
    return {axis: _axis_config(v.get(axis, 0.0), f"pivot.{axis}") for axis in ("x", "y")}


def _build_axis(a: Any) -> Any:
    if not isinstance(a, dict):
        return float(a)
    if a["kind"] == "sinusoid":
        return Sinusoid(a["amplitude"], a["frequency"], phase=a["phase"], offset=a["offset"])
    return Table(np.asarray(a["t"], dtype=float), np.asarray(a["values"], dtype=float), kind="cubic")


def _build_torque(spec: Optional[Dict[str, Any]]) -> Tuple[Optional[TorqueLike], bool]:
    if spec is None:
        return None, False
    kind = spec["kind"]
    if kind == "constant":
        obj: TorqueLike = np.asarray(spec["value"], dtype=float)
    elif kind == "sinusoid":
        obj = Sinusoid(np.asarray(spec["amplitude"], dtype=float), np.asarray(spec["frequency"], dtype=float),
                       phase=np.asarray(spec["phase"], dtype=float), offset=np.asarray(spec["offset"], dtype=float))
    else:
        obj = Table(np.asarray(spec["t"], dtype=float), np.asarray(spec["values"], dtype=float),
                    kind=spec["interpolation"])
    return obj, spec["convention"] == "joint"


def _split_config(v: Any) -> Dict[str, float]:
    if isinstance(v, (list, tuple)):
        if len(v) != len(_SPLITS):
            raise InputError(f"split must be {{train, validation, test}} fractions or a list of three, got {v!r}")
        v = dict(zip(_SPLITS, v))
    if not isinstance(v, Mapping):
        raise InputError(f"split must be a table of fractions {{train, validation, test}}, got {v!r}")
    _check_keys(v, _SPLITS, "split")
    out = {name: _number(v.get(name, 0.0), f"split.{name}", nonneg=True) for name in _SPLITS}
    total = sum(out.values())
    if abs(total - 1.0) > 1e-9:
        raise InputError("split fractions must sum to 1, got " + " + ".join(_g(out[s]) for s in _SPLITS)
                         + f" = {_g(total)}")
    return out


def _frames_config(v: Any) -> Optional[Dict[str, Any]]:
    if v is None or v is False:
        return None
    if v is True:
        v = {}
    if isinstance(v, (int, np.integer)) and not isinstance(v, bool):
        v = {"size": v}
    if not isinstance(v, Mapping):
        raise InputError(f"frames must be a picture size, a table {{size, line_width, extent}}, true or false, "
                         f"got {v!r}")
    _check_keys(v, ("size", "line_width", "extent"), "frames")
    size = _count(v.get("size", 64), "frames.size")
    if size > 1024:
        raise InputError(f"frames.size must be at most 1024 pixels, got {size}")
    extent = v.get("extent")
    return {"size": size, "line_width": _number(v.get("line_width", 2.0), "frames.line_width", positive=True),
            "extent": None if extent is None else _number(extent, "frames.extent", positive=True)}


def _normalise(kwargs: Dict[str, Any]) -> Dict[str, Any]:
    """The config with its defaults, every value checked and converted to plain JSON data."""
    _check_keys(kwargs, CONFIG_KEYS, "make_dataset's config")
    for key in _REQUIRED:
        if kwargs.get(key) is None:
            raise InputError(f"{key} is required (one of {', '.join(_REQUIRED)})")
    raw = {**_DEFAULTS, **{k: v for k, v in kwargs.items() if v is not None}}
    c: Dict[str, Any] = {}
    name = raw["name"]
    if not isinstance(name, str):
        raise InputError(f"name must be a string, got {name!r}")
    c["name"] = name
    c["trajectories"] = _count(raw["trajectories"], "trajectories")
    c["t_end"] = _number(raw["t_end"], "t_end", positive=True)
    c["sample_dt"] = _number(raw["sample_dt"], "sample_dt", positive=True)
    if c["sample_dt"] > c["t_end"]:
        raise InputError(f"sample_dt must be <= t_end ({_g(c['t_end'])} s), got {_g(c['sample_dt'])} s")
    seed = raw["seed"]
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    c["seed"] = int(seed)
    kind = raw["kind"]
    if kind not in ("points", "rods"):
        raise InputError(f'kind must be "points" (com and inertia as given: point masses by default) or "rods" '
                         f"(uniform rods), got {kind!r}")
    c["kind"] = kind
    if kind == "rods":
        for key in ("com", "inertia"):
            if raw[key] is not None:
                raise InputError(f'{key} cannot be given with kind = "rods" (uniform rods: com = l/2, '
                                 "inertia = m l^2/12)")
    for key in _CHAIN_PARAMS:
        c[key] = None if raw[key] is None else _quantity(raw[key], key)
    sizes = [(key, s) for key in _CHAIN_PARAMS + ("theta", "omega") if raw.get(key) is not None
             for s in _lengths_of(c[key] if key in c else _quantity(raw[key], key))]
    links = raw["links"]
    if links is not None:
        n = _count(links, "links")
    elif sizes:
        n = sizes[0][1]
    else:
        raise InputError("links (the number of links) is required when no quantity is given per link")
    for key, s in sizes:
        if s != n:
            raise InputError(f"{key} must have {n} entries (one per link), got {s}")
    if isinstance(c["g"], list) or (isinstance(c["g"], dict) and any(isinstance(x, list) for x in c["g"].values())):
        raise InputError("g must be a number or a range of numbers")
    c["links"] = n
    c["friction_velocity"] = _number(raw["friction_velocity"], "friction_velocity", positive=True)
    c["trajectories_per_chain"] = _count(raw["trajectories_per_chain"], "trajectories_per_chain")
    c["theta"] = _quantity(raw["theta"], "theta")
    c["energy"] = None
    if raw["energy"] is not None:
        e = raw["energy"]
        if not isinstance(e, Mapping):
            raise InputError(f"energy must be a range {{low = ..., high = ...}} in J, got {e!r}")
        c["energy"] = _quantity(e, "energy")
        if isinstance(c["energy"]["low"], list) or isinstance(c["energy"]["high"], list):
            raise InputError("energy must be a range of numbers (J), not one per link")
    omega = raw["omega"]
    if omega is None:
        omega = {"low": -1.0, "high": 1.0} if c["energy"] is not None else 0.0
    c["omega"] = _quantity(omega, "omega")
    c["torque"] = _torque_config(raw["torque"], n)
    c["pivot"] = _pivot_config(raw["pivot"])
    method = raw["method"]
    if method not in METHODS:
        raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    c["method"] = method
    c["dt"] = None if raw["dt"] is None else _number(raw["dt"], "dt", positive=True)
    if c["dt"] is None and METHOD_INFO[method]["needs_dt"]:
        raise InputError(f"method {method} takes a fixed step: give dt")
    c["rtol"] = _number(raw["rtol"], "rtol", positive=True)
    c["atol"] = _number(raw["atol"], "atol", nonneg=True)
    c["split"] = _split_config(raw["split"])
    c["frames"] = _frames_config(raw["frames"])
    fmt = raw["format"]
    if fmt not in ("auto", "npz", "zarr"):
        raise InputError(f'format must be "auto", "npz" or "zarr", got {fmt!r}')
    c["format"] = fmt
    c["chunk"] = None if raw["chunk"] is None else _count(raw["chunk"], "chunk")
    return c


# ----------------------------------------------------------------------------------------------
# The plan: the checked config, resolved (picklable: each task gets it)


class _Plan:
    """Everything a task needs to make its chunk, from the normalised config ``c``."""

    def __init__(self, c: Dict[str, Any]):
        self.c = c
        n = self.n = c["links"]
        self.count = c["trajectories"]
        self.samples = math.floor(c["t_end"] / c["sample_dt"] + 1e-9) + 1  # t_end itself despite rounding
        self.ranges = {key: _Range(c[key], key, 1 if key == "g" else n) for key in _CHAIN_PARAMS if c[key] is not None}
        self.ranged = [key for key, r in self.ranges.items() if r.ranged]
        self.per_chain = c["trajectories_per_chain"] if self.ranged else self.count
        self.theta = _Range(c["theta"], "theta", n)
        self.omega = _Range(c["omega"], "omega", n)
        self.energy = None if c["energy"] is None else _Range(c["energy"], "energy", 1)
        self.torque, self.joint = _build_torque(c["torque"])
        self.pivot = None if c["pivot"] is None else Pivot(**{k: _build_axis(a) for k, a in c["pivot"].items()})
        self.timed = self.pivot is not None or (c["torque"] is not None and c["torque"]["kind"] != "constant")
        self.forced = c["torque"] is not None or any(
            c[key] is not None and np.any(self.ranges[key].high > 0) for key in ("damping", "friction"))
        self.frames = c["frames"]
        self.extent = 0.0
        self.t_grid: Optional[F64] = None

    @property
    def t(self) -> F64:
        if self.t_grid is None:
            self.t_grid = np.arange(self.samples, dtype=np.float64) * self.c["sample_dt"]
        return self.t_grid

    def drive(self) -> Dict[str, Any]:
        kw: Dict[str, Any] = {"joint_torque" if self.joint else "torque": self.torque}
        if self.pivot is not None:
            kw["pivot"] = self.pivot
        return kw

    # -- sizes ---------------------------------------------------------------------------------
    def fields(self) -> Dict[str, Tuple[Tuple[int, ...], str]]:
        """Per-trajectory arrays: name -> (shape after the trajectory axis, dtype)."""
        T, n = self.samples, self.n
        out: Dict[str, Tuple[Tuple[int, ...], str]] = {}
        for name in ("q", "p", "qdot", "qddot", "dH_dq", "dH_dp"):
            out[name] = ((T, n), "float64")
        if self.forced:
            out["Q"] = ((T, n), "float64")
        out["energy"] = ((T,), "float64")
        for key in ("lengths", "masses", "com", "inertia"):
            out[key] = ((n,), "float64")
        out["g"] = ((), "float64")
        for key in ("damping", "friction"):
            if self.c[key] is not None:
                out[key] = ((n,), "float64")
        if self.c["trajectories_per_chain"] > 1 and self.ranged:
            out["chain_index"] = ((), "int64")
        if self.frames is not None:
            out["frames"] = ((T, self.frames["size"], self.frames["size"]), "uint8")
        out["split"] = ((), "uint8")
        return out

    def bytes_per_trajectory(self) -> float:
        return float(sum(np.dtype(dt).itemsize * math.prod(shape) for shape, dt in self.fields().values()))


def _chain_values(plan: _Plan, start: int, stop: int) -> Dict[str, F64]:
    """The chain parameters drawn for chains ``start..stop`` (stream _PARAMS, by blocks)."""
    width = sum(plan.ranges[k].low.size for k in plan.ranged)
    u = _uniforms(plan.c["seed"], _PARAMS, start, stop, width)
    out: Dict[str, F64] = {}
    col = 0
    for key, r in plan.ranges.items():
        if r.ranged:
            out[key] = r.values(u[:, col:col + r.low.size])
            col += r.low.size
        else:
            out[key] = np.broadcast_to(r.low, (stop - start, r.low.size))
    return out


def _uniforms(seed: int, stream: int, start: int, stop: int, width: int) -> F64:
    """Rows ``start..stop`` of the uniforms of ``stream``: row i from block i // _BLOCK's own
    generator, so a row's numbers do not depend on which rows are asked for with it."""
    if width == 0 or stop <= start:
        return np.zeros((max(stop - start, 0), width))
    first, last = start // _BLOCK, (stop - 1) // _BLOCK
    blocks = [np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(stream, b))).random((_BLOCK, width))
              for b in range(first, last + 1)]
    rows = np.concatenate(blocks) if len(blocks) > 1 else blocks[0]
    return rows[start - first * _BLOCK:stop - first * _BLOCK]


def _make_chain(plan: _Plan, values: Mapping[str, F64], j: int) -> Chain:
    def get(key: str) -> Optional[List[float]]:
        return None if key not in values else [float(x) for x in values[key][j]]

    lengths, masses = values["lengths"][j], values["masses"][j]
    g = float(values["g"][j][0])
    losses: Dict[str, Any] = {"damping": get("damping"), "friction": get("friction"),
                              "friction_velocity": plan.c["friction_velocity"]}
    if plan.c["kind"] == "rods":
        return Chain.rods(lengths, masses, g=g, **losses)
    return Chain(lengths, masses, com=get("com"), inertia=get("inertia"), g=g, **losses)


def _conservative(chain: Chain) -> Chain:
    """The same chain without its losses: its Hamilton's equations give -dH/dq."""
    return Chain(chain.lengths, chain.masses, com=chain.com, inertia=chain.inertia, g=chain.g)


def _initial_states(plan: _Plan, chain: Chain, first: int, u: F64) -> Tuple[F64, F64]:
    """Initial (theta, omega) of trajectories ``first, first+1, ...`` on ``chain`` from their rows
    of uniforms ``u`` (k candidates each). With an energy range a candidate is kept when its
    potential energy is below its drawn energy, and its rates (the drawn ones, as a direction)
    are scaled so that T + U is that energy; the first candidate kept is the state."""
    n, b = plan.n, u.shape[0]
    tries = _TRIES if plan.energy is not None else 1
    u = u.reshape(b, tries, -1)
    theta = plan.theta.values(u[..., :n])
    omega = plan.omega.values(u[..., n:2 * n])
    if plan.energy is None:
        return theta[:, 0], omega[:, 0]
    th0, om0 = np.empty((b, n)), np.empty((b, n))
    todo = np.arange(b)
    for rnd in range(_ROUNDS):
        if rnd:
            u = np.stack([np.random.default_rng(np.random.SeedSequence(
                plan.c["seed"], spawn_key=(_RETRY, first + int(i), rnd))).random((tries, 2 * n + 1)) for i in todo])
            theta, omega = plan.theta.values(u[..., :n]), plan.omega.values(u[..., n:2 * n])
        else:
            theta, omega, u = theta[todo], omega[todo], u[todo]
        energy = plan.energy.values(u[..., 2 * n:2 * n + 1])[..., 0]
        pot = np.asarray(chain.potential_energy(theta))
        kin = np.asarray(chain.kinetic_energy(theta, omega))
        ok = (pot <= energy) & ((kin > 0) | (pot == energy))
        scale = np.sqrt(np.where(ok & (kin > 0), (energy - pot) / np.where(kin > 0, kin, 1.0), 0.0))
        found = ok.any(axis=1)
        pick = np.argmax(ok, axis=1)
        rows = np.arange(todo.size)
        th0[todo[found]] = theta[rows, pick][found]
        om0[todo[found]] = (omega[rows, pick] * scale[rows, pick][:, None])[found]
        todo = todo[~found]
        if todo.size == 0:
            return th0, om0
    e = plan.energy
    raise InputError(f"trajectory {first + int(todo[0])}: none of {_TRIES * _ROUNDS} drawn states has a potential "
                     f"energy below its drawn energy (energy = [{_g(e.low[0])}, {_g(e.high[0])}] J, theta in the "
                     "range given); raise energy.high or narrow theta towards the hanging state")


# ----------------------------------------------------------------------------------------------
# One chunk: trajectories start..stop, every field, from the core


def _groups(plan: _Plan, start: int, stop: int) -> Iterator[Tuple[int, int, int, Chain, F64, F64]]:
    """Trajectories ``start..stop`` by chain: ``(chain number, first, end, chain, theta0, omega0)``."""
    n, k = plan.n, plan.per_chain
    c0, c1 = start // k, (stop - 1) // k + 1
    values = _chain_values(plan, c0, c1)
    width = (2 * n + 1) * _TRIES if plan.energy is not None else 2 * n
    u = _uniforms(plan.c["seed"], _STATES, start, stop, width)
    for j in range(c0, c1):
        lo, hi = max(start, j * k), min(stop, (j + 1) * k)
        chain = _make_chain(plan, values, j - c0)
        th0, om0 = _initial_states(plan, chain, lo, u[lo - start:hi - start])
        yield j, lo, hi, chain, th0, om0


def _chunk(plan: _Plan, start: int, stop: int) -> Dict[str, npt.NDArray[Any]]:
    """Every field of trajectories ``start..stop`` (one task's work)."""
    t = plan.t
    out: Dict[str, npt.NDArray[Any]] = {name: np.zeros((stop - start,) + shape, dtype=dt)
                                        for name, (shape, dt) in plan.fields().items() if name != "split"}
    drive = plan.drive()
    for j, lo, hi, chain, th0, om0 in _groups(plan, start, stop):
        rows = slice(lo - start, hi - start)
        try:
            sol = simulate(chain, th0, om0, float(t[-1]), method=plan.c["method"], dt=plan.c["dt"],
                           rtol=plan.c["rtol"], atol=plan.c["atol"], t_eval=t, **drive)
        except IntegrationError as exc:
            err = IntegrationError(f"trajectories {lo}..{hi - 1}: {exc}")
            err.t = exc.t
            raise err from exc
        _fields(plan, chain, sol.theta, sol.omega, out, rows)
        for key in ("lengths", "masses", "com", "inertia", "damping", "friction"):
            if key in out:
                out[key][rows] = getattr(chain, key)
        out["g"][rows] = chain.g
        if "chain_index" in out:
            out["chain_index"][rows] = j
    return out


def _fields(plan: _Plan, chain: Chain, theta: F64, omega: F64, out: Dict[str, npt.NDArray[Any]], rows: slice) -> None:
    """The derived fields of a group of trajectories on one chain, (b, T, N) each, by the core."""
    t = plan.t
    cons = _conservative(chain)
    out["q"][rows], out["qdot"][rows] = theta, omega
    p = chain.momenta(theta, omega)
    out["p"][rows] = p
    drive = plan.drive()
    torque = {k: v for k, v in drive.items() if k != "pivot"}
    pivot = drive.get("pivot")
    if not plan.timed:
        out["qddot"][rows] = chain.accelerations(theta, omega, **torque)
        rate, p_dot = cons.hamilton(theta, p)
        out["dH_dp"][rows], out["dH_dq"][rows] = rate, -p_dot
        if "Q" in out:
            out["Q"][rows] = chain.hamilton(theta, p, **torque)[1] - p_dot
        out["energy"][rows] = chain.energy(theta, omega)
    else:
        for i, ti in enumerate(t.tolist()):
            th, om, pp = theta[:, i], omega[:, i], p[:, i]
            out["qddot"][rows, i] = chain.accelerations(th, om, t=ti, pivot=pivot, **torque)
            rate, p_dot = cons.hamilton(th, pp, t=ti, pivot=pivot)
            out["dH_dp"][rows, i], out["dH_dq"][rows, i] = rate, -p_dot
            if "Q" in out:
                out["Q"][rows, i] = chain.hamilton(th, pp, t=ti, pivot=pivot, **torque)[1] - p_dot
            out["energy"][rows, i] = chain.energy(th, om, t=ti, pivot=pivot)
    if plan.frames is not None:
        b, T = theta.shape[:2]
        base = (np.zeros((T, 2)) if pivot is None else pivot.position(t))[None, :, None, :]
        joints = chain.positions(theta) + base  # (b, T, N, 2) in the lab frame
        points = np.concatenate([np.broadcast_to(base, (b, T, 1, 2)), joints], axis=2)
        size = plan.frames["size"]
        out["frames"][rows] = _render(points.reshape(b * T, plan.n + 1, 2), size, plan.extent,
                                      plan.frames["line_width"]).reshape(b, T, size, size)


def _render(points: F64, size: int, extent: float, width: float) -> npt.NDArray[np.uint8]:
    """Frames (F, size, size) of 0 with the polylines ``points`` (F, K, 2) drawn at 255: each
    segment sampled every half pixel, each sample stamped with a disc of diameter ``width``
    pixels. The view is the square [-extent, extent]^2, y up; nothing is anti-aliased, so the
    picture is a deterministic function of the positions."""
    frames = np.zeros((points.shape[0], size, size), dtype=np.uint8)
    r = width / 2
    reach = int(math.ceil(r))
    stencil = [(dy, dx) for dy in range(-reach, reach + 1) for dx in range(-reach, reach + 1)
               if dy * dy + dx * dx <= r * r] or [(0, 0)]
    s = np.linspace(0.0, 1.0, 2 * size + 1)[:, None]
    px = size / (2 * extent)
    flat = frames.reshape(-1)
    for lo in range(0, points.shape[0], 512):  # a few MB at a time
        pts = points[lo:lo + 512]
        a, d = pts[:, :-1, None, :], (pts[:, 1:] - pts[:, :-1])[:, :, None, :]
        xy = a + d * s  # (f, K-1, S, 2)
        col = np.floor((xy[..., 0] + extent) * px).astype(np.int64)
        row = np.floor((extent - xy[..., 1]) * px).astype(np.int64)
        frame = (np.arange(pts.shape[0], dtype=np.int64) + lo)[:, None, None]
        for dy, dx in stencil:
            rr, cc = row + dy, col + dx
            inside = (rr >= 0) & (rr < size) & (cc >= 0) & (cc < size)
            flat[((frame * size + rr) * size + cc)[inside]] = 255
    return frames


# ----------------------------------------------------------------------------------------------
# Files


def _fmt_bytes(x: float) -> str:
    for unit, scale in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if x >= scale:
            return f"{x / scale:.1f} {unit}"
    return f"{x:.0f} B"


def _sha256(a: npt.NDArray[Any]) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).data).hexdigest()


def _write_npz(path: Path, arrays: Mapping[str, npt.NDArray[Any]]) -> None:
    """An uncompressed NPZ (what ``np.load`` reads) with fixed timestamps and modes, so the same
    arrays always give the same bytes (``np.savez`` stamps the time of writing)."""
    with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name in sorted(arrays):
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.ascontiguousarray(arrays[name]), allow_pickle=False)


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(2**20), b""):
            h.update(block)
    return h.hexdigest()


def _zarr_create(group: Any, name: str, shape: Tuple[int, ...], chunks: Tuple[int, ...], dtype: str) -> Any:
    if hasattr(group, "create_array"):  # zarr 3
        return group.create_array(name, shape=shape, chunks=chunks, dtype=dtype, fill_value=0)
    return group.zeros(name, shape=shape, chunks=chunks, dtype=dtype)  # zarr 2


def _zarr_task(plan: _Plan, path: str, start: int, stop: int) -> int:
    """One Dask task: make trajectories start..stop and write them into their Zarr chunk."""
    import zarr

    data = _chunk(plan, start, stop)
    group: Any = zarr.open_group(path, mode="r+")
    for name, a in data.items():
        group[name][start:stop] = a
    return stop - start


def _npz_task(plan: _Plan, start: int, stop: int) -> Dict[str, npt.NDArray[Any]]:
    return _chunk(plan, start, stop)


@contextlib.contextmanager
def _output_dir(path: Path) -> Iterator[Path]:
    """The directory ``path`` for a new dataset: created, or an empty directory, or a dataset
    written here before (its data and card are removed first). Anything else is refused,
    never wiped. If the block fails or is interrupted, what it wrote is removed."""
    created = not path.exists()
    if not created:
        if not path.is_dir():
            raise InputError(f"output {str(path)!r} exists and is not a directory")
        entries = set(os.listdir(path))
        ours = {DATA_NPZ, DATA_ZARR, CARD_JSON, CARD_MD}
        if entries and not (CARD_JSON in entries and _is_card(path / CARD_JSON)):
            raise InputError(f"output directory {str(path)!r} is not empty and holds no dataset written by "
                             "multipendulum; remove it or choose another directory")
        if entries - ours:
            extra = ", ".join(sorted(entries - ours))
            raise InputError(f"output directory {str(path)!r} holds a dataset and other files ({extra}); "
                             "remove them or choose another directory")
    try:
        if created:
            path.mkdir(parents=True)
        else:
            for name in (CARD_JSON, CARD_MD, DATA_NPZ, DATA_ZARR):  # the card first: no half dataset is "ours"
                _remove(path / name)
        yield path
    except BaseException:
        for name in (CARD_JSON, CARD_MD, DATA_NPZ, DATA_ZARR):
            _remove(path / name)
        if created:
            with contextlib.suppress(OSError):
                path.rmdir()
        raise


def _remove(p: Path) -> None:
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            p.unlink()


def _is_card(p: Path) -> bool:
    try:
        return bool(json.loads(p.read_text(encoding="utf-8")).get("kind") == KIND)
    except (OSError, ValueError, AttributeError):
        return False


# ----------------------------------------------------------------------------------------------
# make_dataset


def make_dataset(path: PathLike, *, trajectories: int, t_end: float, sample_dt: float, seed: int = 0,
                 name: str = "", links: Optional[int] = None, kind: str = "points", lengths: Any = 1.0,
                 masses: Any = 1.0, com: Any = None, inertia: Any = None, g: Any = 9.81, damping: Any = None,
                 friction: Any = None, friction_velocity: float = 1e-3, trajectories_per_chain: int = 1,
                 theta: Any = None, omega: Any = None, energy: Any = None, torque: Any = None,
                 pivot: Any = None, method: str = "dop853", dt: Optional[float] = None, rtol: float = 1e-10,
                 atol: float = 1e-12, split: Any = None, frames: Any = None, format: str = "auto",
                 chunk: Optional[int] = None, scheduler: Scheduler = None, progress: Progress = None) -> Dataset:
    """Simulate ``trajectories`` random trajectories and write them, with a card, into the
    directory ``path``; returns the :class:`Dataset` (as :func:`load_dataset` would).

    The chain: ``links`` links (or as many as a per-link list gives), ``kind`` ``"points"``
    (``com`` defaults to ``lengths``, ``inertia`` to 0) or ``"rods"`` (uniform rods); each of
    ``lengths``, ``masses``, ``com``, ``inertia`` (one per link), ``g``, ``damping``, ``friction``
    (one per joint) is a number, one number per link, or a range ``{"low": ..., "high": ...}``
    (numbers or one per link) drawn uniformly for each chain. A chain serves
    ``trajectories_per_chain`` consecutive trajectories (default 1: every trajectory has its own
    parameters); without any range all trajectories share one chain and run as one batch.

    The initial state: ``theta`` (default ``{"low": -pi, "high": pi}``) and ``omega`` (default 0)
    are a number, one per link, or a range, drawn uniformly. With ``energy = {"low", "high"}``
    (J) a state is drawn with its energy: the angles from ``theta``, an energy from the range
    (redrawn, with the angles, while the potential energy is above it), and the rates drawn from
    ``omega`` (default ``{"low": -1, "high": 1}``) scaled so that ``T + U`` is that energy.

    The run: sampled at ``t = k * sample_dt`` for ``k = 0 .. floor(t_end / sample_dt)``, by
    :func:`multipendulum.simulate` with ``method``, ``dt``, ``rtol``, ``atol``; optionally a
    ``torque`` (N values, an :class:`~multipendulum.Sinusoid` or :class:`~multipendulum.Table`,
    or their tables ``{"kind": "sinusoid", "convention": "generalized" | "joint", ...}``) and a
    ``pivot`` (an :class:`~multipendulum.Pivot` of built-in axes, or ``{"x": ..., "y": ...}``).

    The output: the fields of :data:`FIELDS` (``q, p, qdot, qddot, dH_dq, dH_dp, energy``, ``Q``
    with losses or a torque, the parameters of each trajectory, ``split``, ``t``; ``frames`` when
    ``frames`` is a size or ``{"size": 64, "line_width": 2.0, "extent": None}``), split by
    trajectory into ``split = {"train": 0.8, "validation": 0.1, "test": 0.1}``. ``format``:
    ``"npz"`` (gathered in memory, one file), ``"zarr"`` (written chunk by chunk by the Dask
    tasks, memory bounded by ``chunk`` trajectories per task and core) or ``"auto"`` (NPZ up to
    :data:`NPZ_AUTO_LIMIT` bytes). ``card.json`` and ``card.md`` describe it: package version,
    full config, seed, SHA-256 of each array and file, fields with shapes and units.

    ``scheduler`` as for :func:`multipendulum.sweep` (Dask's threads by default; a run without
    Dask installed writes NPZ in this thread). ``progress``: True for a bar, or a callable given
    the fraction done. Everything is checked before any work: bad values, empty ranges, a size
    that would not fit in memory or on disk (refused with the estimate). Ctrl-C (or an error)
    removes what was written.
    """
    kwargs = {k: v for k, v in locals().items() if k in CONFIG_KEYS}
    _check_progress(progress)
    c = _normalise(kwargs)
    plan = _Plan(c)
    fmt, rows = _check_sizes(plan, Path(path))
    _check_core(plan)
    stored = dict(c, format=fmt, chunk=rows if fmt == "zarr" else None)
    out = Path(path)
    dask_mods = _maybe_dask(scheduler, fmt)
    if dask_mods is not None and (scheduler is None or (isinstance(scheduler, str) and ":" not in scheduler)):
        from .sweeps import _scheduler

        with _scheduler(scheduler):  # a bad name is refused now, before an old dataset is replaced
            pass
    codes = _split_codes(plan)
    with _output_dir(out), reporter(progress, "dataset") as report:
        done = 0.9 if fmt == "zarr" else 0.95
        if fmt == "zarr":
            arrays_meta = _run_zarr(plan, out / DATA_ZARR, rows, codes, scheduler, dask_mods,
                                    scaled(report, 0.0, done))
            hashes = _zarr_hashes(out / DATA_ZARR, scaled(report, done, 1.0))
            files: Dict[str, Dict[str, Any]] = {}
        else:
            arrays = _run_npz(plan, rows, codes, scheduler, dask_mods, scaled(report, 0.0, done))
            arrays_meta = {k: (tuple(a.shape), str(a.dtype)) for k, a in arrays.items()}
            hashes = {k: _sha256(a) for k, a in arrays.items()}
            _write_npz(out / DATA_NPZ, arrays)
            del arrays
            files = {DATA_NPZ: {"sha256": _file_sha256(out / DATA_NPZ), "bytes": (out / DATA_NPZ).stat().st_size}}
        card = _card(plan, stored, arrays_meta, hashes, files, codes)
        with atomic_path(out / CARD_MD) as tmp:
            tmp.write_text(_card_markdown(card), encoding="utf-8")
        with atomic_path(out / CARD_JSON) as tmp:
            tmp.write_text(json.dumps(card, indent=1, sort_keys=False) + "\n", encoding="utf-8")
    return load_dataset(out)


def _check_core(plan: _Plan) -> None:
    """The core checks what it will be given, on the chains at both ends of every range and a
    short run of each: a bad parameter, torque or pivot fails now, not in the middle."""
    c = plan.c
    steps = c["t_end"] / c["dt"] if c["dt"] is not None and METHOD_INFO[c["method"]]["needs_dt"] else 0.0
    max_steps = float(_core.DEFAULTS["max_steps"])
    if steps > max_steps:
        raise InputError(f"{c['method']} with dt = {_g(c['dt'])} s takes {steps:.4g} steps to reach t_end = "
                         f"{_g(c['t_end'])} s, more than the {max_steps:.4g} a run may take; raise dt or shorten t_end")
    for end in ("low", "high"):
        values = {key: np.asarray(getattr(r, end))[None] for key, r in plan.ranges.items()}
        try:
            chain = _make_chain(plan, values, 0)
        except InputError as exc:
            what = "the chain" if not plan.ranged else f"the chain at the {end} end of every range"
            raise InputError(f"{what}: {exc}") from None
        state = np.zeros((1, plan.n))
        try:
            simulate(chain, state, state, float(plan.t[1]), method=c["method"], dt=c["dt"], rtol=c["rtol"],
                     atol=c["atol"], t_eval=plan.t[:2], **plan.drive())
        except IntegrationError:
            pass  # a property of a state, not of the arguments: the real runs say where
    if plan.energy is not None:
        if not np.any(plan.omega.high - plan.omega.low > 0) and not np.any(plan.omega.low):
            raise InputError("omega is 0 for every link, so the rates have no direction to scale to the drawn "
                             "energy; give omega a range (e.g. {low = -1, high = 1})")
        # The first block's initial states, drawn as the run draws them: an energy range that the
        # angles cannot reach fails here, before any work.
        for _ in _groups(plan, 0, min(plan.count, _BLOCK)):
            pass
    if plan.frames is not None:
        reach = float(np.sum(plan.ranges["lengths"].high))
        if plan.pivot is not None:
            ts = np.linspace(0.0, float(plan.t[-1]), max(plan.samples, 2049))
            reach += float(np.max(np.abs(plan.pivot.position(np.concatenate([ts, plan.t])))))
        plan.extent = plan.frames["extent"] or 1.05 * reach
        plan.frames = dict(plan.frames, extent=plan.extent)


def _check_sizes(plan: _Plan, path: Path) -> Tuple[str, int]:
    """The format and the trajectories per chunk; refuses, with the estimate, a dataset whose
    chunks would not fit in memory, or that would not fit on disk (or, as NPZ, in memory)."""
    c = plan.c
    per = plan.bytes_per_trajectory()
    total = per * plan.count
    T = plan.samples
    shape = f"{plan.count} trajectories x {T} samples ({_fmt_bytes(per)} each)"
    # A trajectory as it is made: the run's own arrays (t, theta, omega, p, energy, work ...) and
    # the fields derived from them.
    work = 2.0 * per + T * (5 * plan.n + 8) * 8.0
    _core.check_memory(work, f"one trajectory of {T} samples", "raise sample_dt or shorten t_end")
    fmt = c["format"]
    if fmt == "auto":
        import importlib.util

        fmt = "npz" if total <= NPZ_AUTO_LIMIT or importlib.util.find_spec("zarr") is None else "zarr"
    rows = c["chunk"] or max(1, min(plan.count, int(CHUNK_BYTES // per)))
    rows = min(rows, plan.count)
    at_once = min(-(-plan.count // rows), os.cpu_count() or 1)
    _core.check_memory(at_once * rows * work, f"{at_once} chunks of {rows} trajectories at once",
                       "use a smaller chunk")
    if fmt == "npz":
        _core.check_memory(2.0 * total, f"gathering a dataset of {shape} as NPZ",
                           'use format = "zarr" (written chunk by chunk)')
    where = path
    while not where.exists() and where != where.parent:
        where = where.parent
    free = shutil.disk_usage(where).free
    if total > free:
        raise InputError(f"the dataset needs about {_fmt_bytes(total)} on disk ({shape}, uncompressed) but "
                         f"{str(where)!r} has {_fmt_bytes(free)} free; write fewer trajectories or samples "
                         "(raise sample_dt), or to another disk")
    return fmt, rows


def _split_codes(plan: _Plan) -> npt.NDArray[np.uint8]:
    """Each trajectory's split (0 train, 1 validation, 2 test): a random permutation of the
    trajectories (its own stream) cut at the rounded fractions."""
    n = plan.count
    frac = plan.c["split"]
    sizes = [0, int(round(frac["validation"] * n)), int(round(frac["test"] * n))]
    sizes[2] = min(sizes[2], n - sizes[1])
    sizes[0] = n - sizes[1] - sizes[2]
    order = np.random.default_rng(np.random.SeedSequence(plan.c["seed"], spawn_key=(_SPLIT,))).permutation(n)
    codes = np.empty(n, dtype=np.uint8)
    codes[order[:sizes[0]]] = 0
    codes[order[sizes[0]:sizes[0] + sizes[1]]] = 1
    codes[order[sizes[0] + sizes[1]:]] = 2
    return codes


def _maybe_dask(scheduler: Scheduler, fmt: str) -> Optional[Tuple[Any, Any]]:
    """Dask's modules, or None to run in this thread (NPZ without Dask installed)."""
    import importlib.util

    if fmt == "zarr":
        if importlib.util.find_spec("zarr") is None:
            raise ImportError("writing a dataset to Zarr needs zarr and Dask, which are not installed: "
                              "pip install 'multipendulum[dask]'")
    if importlib.util.find_spec("dask") is None:
        if fmt == "zarr" or scheduler is not None:
            raise ImportError("this dataset needs Dask, which is not installed: pip install 'multipendulum[dask]'")
        return None
    from .sweeps import _dask

    return _dask()


def _bounds(count: int, rows: int) -> List[Tuple[int, int]]:
    return [(s, min(s + rows, count)) for s in range(0, count, rows)]


def _run_npz(plan: _Plan, rows: int, codes: npt.NDArray[np.uint8], scheduler: Scheduler,
             dask_mods: Optional[Tuple[Any, Any]], report: Optional[Callable[[float], object]]
             ) -> Dict[str, npt.NDArray[Any]]:
    bounds = _bounds(plan.count, rows)
    if dask_mods is None:
        steps = Steps(report, len(bounds))
        parts = []
        for s, e in bounds:
            parts.append(_chunk(plan, s, e))
            steps.add(1)
    else:
        from .sweeps import _compute, _scheduler

        dask, _ = dask_mods
        tasks = [dask.delayed(_npz_task, pure=False)(plan, s, e) for s, e in bounds]
        with _scheduler(scheduler) as how:
            parts = list(_compute(dask, how, report, *tasks))
    arrays = {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}
    arrays["split"] = codes
    arrays["t"] = plan.t
    return arrays


def _run_zarr(plan: _Plan, path: Path, rows: int, codes: npt.NDArray[np.uint8], scheduler: Scheduler,
              dask_mods: Optional[Tuple[Any, Any]], report: Optional[Callable[[float], object]]
              ) -> Dict[str, Tuple[Tuple[int, ...], str]]:
    import zarr

    from .sweeps import _compute, _scheduler

    assert dask_mods is not None
    dask, _ = dask_mods
    group: Any = zarr.open_group(str(path), mode="w")
    meta: Dict[str, Tuple[Tuple[int, ...], str]] = {}
    for name, (shape, dt) in plan.fields().items():
        full = (plan.count,) + shape
        _zarr_create(group, name, full, (rows,) + shape, dt)
        meta[name] = (full, dt)
    group["split"][:] = codes
    _zarr_create(group, "t", (plan.samples,), (plan.samples,), "float64")[:] = plan.t
    meta["t"] = ((plan.samples,), "float64")
    group.attrs.update({"kind": KIND, "card_version": CARD_VERSION, "trajectories": plan.count,
                        "samples": plan.samples, "links": plan.n, "chunk": rows})
    where = str(path.resolve())  # the tasks may run elsewhere (a cluster on a shared file system)
    tasks = [dask.delayed(_zarr_task, pure=False)(plan, where, s, e) for s, e in _bounds(plan.count, rows)]
    with _scheduler(scheduler) as how:
        _compute(dask, how, report, *tasks)
    return meta


def _zarr_hashes(path: Path, report: Optional[Callable[[float], object]]) -> Dict[str, str]:
    """SHA-256 of each array's bytes (C order, as NumPy holds it), read back chunk by chunk."""
    import zarr

    group: Any = zarr.open_group(str(path), mode="r")
    names = sorted(group.array_keys())
    steps = Steps(report, sum(-(-group[k].shape[0] // group[k].chunks[0]) for k in names))

    def one(name: str) -> str:
        arr = group[name]
        h = hashlib.sha256()
        step = arr.chunks[0]
        for s in range(0, arr.shape[0], step):
            h.update(np.ascontiguousarray(arr[s:s + step]).data)
            steps.add(1)
        return h.hexdigest()

    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        return dict(zip(names, pool.map(one, names)))


# ----------------------------------------------------------------------------------------------
# The card


def _card(plan: _Plan, config: Dict[str, Any], meta: Mapping[str, Tuple[Tuple[int, ...], str]],
          hashes: Mapping[str, str], files: Dict[str, Dict[str, Any]], codes: npt.NDArray[np.uint8]) -> Dict[str, Any]:
    counts = np.bincount(codes, minlength=3)
    conservative = not plan.forced and plan.pivot is None
    arrays = {}
    for name in sorted(meta):
        shape, dt = meta[name]
        axes, unit, definition = FIELDS[name]
        arrays[name] = {"shape": list(shape), "dtype": dt, "axes": axes, "unit": unit, "definition": definition,
                        "sha256": hashes[name]}
    version = {"multipendulum": _core.__version__, "numpy": np.__version__}
    if config["format"] == "zarr":
        import zarr

        version["zarr"] = zarr.__version__
    return {
        "kind": KIND,
        "card_version": CARD_VERSION,
        "name": config["name"],
        "versions": version,
        "seed": config["seed"],
        "config": config,
        "trajectories": plan.count,
        "samples": plan.samples,
        "links": plan.n,
        "format": config["format"],
        "data": DATA_ZARR if config["format"] == "zarr" else DATA_NPZ,
        "files": files,
        "splits": {s: {"code": i, "count": int(counts[i]), "fraction": config["split"][s]}
                   for i, s in enumerate(_SPLITS)},
        "arrays": arrays,
        "frames": plan.frames,
        "conventions": {
            "angles": "absolute, from the downward vertical, counter-clockwise positive; link 1 hangs from the pivot",
            "hamiltonian": ("H(q, p, t) = T + U with p = A(q) qdot; with a moving pivot, in the pivot's frame: "
                            "T the kinetic energy relative to the pivot and U the potential of the effective "
                            "gravity (-a_x, -g - a_y), so H is not the lab-frame energy field"),
            "equations": ("qdot = dH/dp and pdot = -dH/dq" + (" + Q" if "Q" in meta else "")
                          + " at every record, to rounding" + ("" if conservative else
                                                               "; the energy is not conserved")),
            "units": "SI: m, kg, s, rad, J",
            "random_streams": (f"numpy default_rng(SeedSequence(seed, spawn_key=(stream, i // {_BLOCK}))): stream "
                               f"{_PARAMS} chain parameters (by chain), {_STATES} initial states (by trajectory), "
                               f"{_RETRY} redraws of states with an energy range, {_SPLIT} the split permutation"),
        },
    }


def _card_markdown(card: Mapping[str, Any]) -> str:
    c = card["config"]
    title = card["name"] or "multipendulum dataset"
    L = [f"# {title}", "",
         f"{card['trajectories']} trajectories of a {card['links']}-link chain, {card['samples']} samples each "
         f"(t = k x {_g(c['sample_dt'])} s up to {_g(c['t_end'])} s), made by multipendulum "
         f"{card['versions']['multipendulum']} with seed {card['seed']}, stored as {card['format'].upper()} "
         f"(`{card['data']}`).", "",
         "Load it with:", "", "```python", "import multipendulum as mp",
         "ds = mp.load_dataset(\"DIR\")          # this directory", "train = ds.split(\"train\")",
         "record = train[0]                     # one trajectory: a dict of NumPy arrays", "```", "",
         "## Splits (by trajectory)", "", "| split | code | trajectories | fraction |", "|---|---|---|---|"]
    for s, v in card["splits"].items():
        L.append(f"| {s} | {v['code']} | {v['count']} | {_g(v['fraction'])} |")
    L += ["", "## Fields", "", "B trajectories, T samples, N links.", "",
          "| name | shape | dtype | unit | definition | SHA-256 of the bytes |", "|---|---|---|---|---|---|"]
    for name, a in card["arrays"].items():
        L.append(f"| `{name}` | {tuple(a['shape'])} | {a['dtype']} | {a['unit']} | {a['definition']} | "
                 f"`{a['sha256']}` |")
    L += ["", "## Conventions", ""]
    L += [f"- **{k}**: {v}" for k, v in card["conventions"].items()]
    if card["files"]:
        L += ["", "## Files", ""]
        L += [f"- `{k}`: {v['bytes']} bytes, SHA-256 `{v['sha256']}`" for k, v in card["files"].items()]
    L += ["", "## Versions", ""]
    L += [f"- {k} {v}" for k, v in card["versions"].items()]
    L += ["", "## Full config", "", "`mp.make_dataset(path, **config)` with this config makes the same dataset.", "",
          "```json", json.dumps(c, indent=1), "```", ""]
    return "\n".join(L)


# ----------------------------------------------------------------------------------------------
# Reading a dataset


class Dataset:
    """A dataset written by :func:`make_dataset`, or one of its splits.

    - ``len(ds)``: its trajectories; ``ds[i]``: trajectory i as a dict of NumPy arrays (every
      per-trajectory field, ``t`` and ``index``, its number in the whole dataset), so that a
      PyTorch ``DataLoader`` takes the dataset as it is (its default collation stacks them);
      iterating gives the same dicts in order.
    - ``ds["q"]``: a field for all its trajectories as one NumPy array (read whole: refused when it
      would not fit in memory; for a Zarr set prefer :meth:`chunks`).
    - :meth:`split`, ``"train"``, ``"validation"`` or ``"test"``: the trajectories of one split;
      :meth:`chunks`: the dataset chunk by chunk (dicts of NumPy arrays), reading each Zarr chunk
      once; ``fields``, ``t``, ``card`` (the card's dict), ``format``, ``path``, ``indices``.

    Zarr sets stay on disk: ``ds[i]`` reads (and keeps) the chunk holding i, so reading in order
    is fast and random order reads a chunk per item. The object pickles (for DataLoader workers)
    and reopens the store in the worker.
    """

    def __init__(self, path: Path, card: Dict[str, Any], indices: Optional[npt.NDArray[np.int64]] = None,
                 split_name: Optional[str] = None):
        self.path = path
        self.card = card
        self.format: str = card["format"]
        self.split_name = split_name
        self._indices = indices
        self._store: Any = self._open()
        self._cache: Dict[str, Tuple[int, npt.NDArray[Any]]] = {}
        names = [k for k in card["arrays"] if k != "t"]
        self.fields: Tuple[str, ...] = tuple(names)
        self.t: F64 = np.asarray(self._store["t"][:])

    def _open(self) -> Any:
        """The arrays: the Zarr group (on disk), or the NPZ file's arrays (read into memory)."""
        if self.format == "zarr":
            import zarr

            return zarr.open_group(str(self.path / DATA_ZARR), mode="r")
        with np.load(self.path / DATA_NPZ, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}

    def __getstate__(self) -> Dict[str, Any]:
        state = dict(self.__dict__)
        if self.format == "zarr":
            state["_store"], state["_cache"] = None, {}
        return state

    def __setstate__(self, state: Dict[str, Any]) -> None:
        self.__dict__.update(state)
        if self._store is None:
            self._store = self._open()

    @property
    def count(self) -> int:
        """trajectories in the whole dataset"""
        return int(self.card["trajectories"])

    @property
    def indices(self) -> npt.NDArray[np.int64]:
        """the trajectories of this view, as indices into the whole dataset"""
        return np.arange(self.count, dtype=np.int64) if self._indices is None else self._indices

    def __len__(self) -> int:
        return self.count if self._indices is None else int(self._indices.size)

    def _row(self, name: str, i: int) -> npt.NDArray[Any]:
        arr = self._store[name]
        if self.format != "zarr":
            return np.asarray(arr[i])
        step = int(arr.chunks[0])
        k = i // step
        hit = self._cache.get(name)
        if hit is None or hit[0] != k:
            hit = (k, np.asarray(arr[k * step:(k + 1) * step]))
            self._cache[name] = hit
        return hit[1][i - k * step]

    def __getitem__(self, key: Union[int, np.integer, str]) -> Any:
        if isinstance(key, str):
            return self._field(key)
        if isinstance(key, bool) or not isinstance(key, (int, np.integer)):
            raise TypeError(f"a Dataset is indexed by a trajectory number or a field name, got {type(key).__name__}")
        size = len(self)
        i = int(key) + size if key < 0 else int(key)
        if not 0 <= i < size:
            raise IndexError(f"trajectory {int(key)} is out of range for {size} trajectories")
        index = i if self._indices is None else int(self._indices[i])
        record: Dict[str, Any] = {name: self._row(name, index) for name in self.fields}
        record["t"] = self.t
        record["index"] = np.int64(index)
        return record

    def __iter__(self) -> Iterator[Dict[str, Any]]:
        for i in range(len(self)):
            yield self[i]

    def _field(self, name: str) -> npt.NDArray[Any]:
        if name == "t":
            return self.t
        if name not in self.fields:
            raise KeyError(f"no field {name!r}; the fields are: {', '.join(self.fields)}")
        arr = self._store[name]
        if self.format == "zarr":
            row = np.dtype(arr.dtype).itemsize * math.prod(arr.shape[1:])
            _core.check_memory(float(row) * len(self), f"reading field {name} of {len(self)} trajectories",
                               "read it chunk by chunk (Dataset.chunks)")
        if self._indices is None:
            return np.asarray(arr[:])
        if self.format == "zarr":
            return np.concatenate([c[name] for c in self.chunks((name,))]) if len(self) else \
                np.zeros((0,) + tuple(arr.shape[1:]), dtype=arr.dtype)
        return np.asarray(arr[self._indices])

    def chunks(self, fields: Optional[Sequence[str]] = None) -> Iterator[Dict[str, npt.NDArray[Any]]]:
        """The dataset piece by piece: dicts of NumPy arrays of the ``fields`` (default all) with
        a leading trajectory axis, and ``index`` (their numbers in the whole dataset), one per
        Zarr chunk (one for an NPZ set), in order, only this view's trajectories."""
        names = self.fields if fields is None else tuple(fields)
        for name in names:
            if name not in self.fields:
                raise KeyError(f"no field {name!r}; the fields are: {', '.join(self.fields)}")
        step = int(self._store["split"].chunks[0]) if self.format == "zarr" else max(1, self.count)
        wanted = self.indices
        for s in range(0, self.count, step):
            e = min(s + step, self.count)
            pick = wanted[(wanted >= s) & (wanted < e)]
            if pick.size == 0:
                continue
            out = {}
            for name in names:
                block = np.asarray(self._store[name][s:e])
                out[name] = block if pick.size == e - s else block[pick - s]
            out["index"] = pick
            yield out

    def split(self, name: str) -> Dataset:
        """The trajectories of split ``name`` (``"train"``, ``"validation"`` or ``"test"``)."""
        if name not in _SPLITS:
            raise InputError(f"split must be one of {', '.join(_SPLITS)}, got {name!r}")
        code = self.card["splits"][name]["code"]
        codes = np.asarray(self._store["split"][:])
        mine = np.flatnonzero(codes == code).astype(np.int64)
        if self._indices is not None:
            mine = np.intersect1d(mine, self._indices)
        return Dataset(self.path, self.card, mine, name)

    @property
    def splits(self) -> Dict[str, int]:
        """trajectories per split (of the whole dataset)"""
        return {s: int(v["count"]) for s, v in self.card["splits"].items()}

    def __repr__(self) -> str:
        part = f", split={self.split_name!r}" if self.split_name else ""
        return (f"Dataset({str(self.path)!r}, {len(self)} trajectories{part}, {self.card['samples']} samples, "
                f"N={self.card['links']}, format={self.format!r})")


def load_dataset(path: PathLike) -> Dataset:
    """The dataset in the directory ``path`` (written by :func:`make_dataset` or ``multipendulum
    dataset``; ``path`` may also name its ``card.json``). See :class:`Dataset`."""
    p = Path(path)
    if p.name == CARD_JSON:
        p = p.parent
    card_path = p / CARD_JSON
    if not card_path.exists():
        raise InputError(f"{str(p)!r} holds no dataset (no {CARD_JSON}; a dataset is a directory written by "
                         "mp.make_dataset or `multipendulum dataset`)")
    try:
        card = json.loads(card_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{card_path}: not a readable dataset card ({exc})") from None
    if not isinstance(card, dict) or card.get("kind") != KIND:
        raise InputError(f"{card_path}: not a dataset card written by multipendulum")
    if card.get("card_version") != CARD_VERSION:
        raise InputError(f"{card_path}: a dataset card of version {card.get('card_version')}, this multipendulum "
                         f"reads version {CARD_VERSION}")
    return Dataset(p, card)
