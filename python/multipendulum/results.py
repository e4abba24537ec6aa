"""Results files: a solution's arrays plus what is needed to reproduce it.

NPZ (the default) holds the arrays ``t`` (T,), ``theta``, ``omega``, ``p`` (T, N), ``energy``,
``work`` (the net work), ``energy_error`` (T,), ``positions`` (T, N, 2, lab frame), ``pivot``
(T, 2), the work's parts ``work_torque``, ``work_pivot``, ``work_cart``, ``dissipated`` (T,),
with a cart ``cart_x`` and ``cart_v`` (T,); the chain's ``lengths``, ``masses``, ``com``,
``inertia``, ``damping``, ``friction`` (N,), ``g`` and ``friction_velocity``, with a cart
``cart`` (its mass and damping); and ``metadata``: a JSON string with the package version, the
method, the run statistics, and the scenario text (with the contents of any file it names) when
the run came from a scenario. CSV holds one row per sample with the metadata JSON on a
``# metadata:`` comment line; links are numbered from 1 in its column names (``theta_1`` hangs
from the pivot). Files of format 1 (before the pivot, the cart and the work's parts) still
load: a fixed pivot, the work all the torque's, no losses.

Files are written atomically: to a temporary file in the target directory, flushed and fsynced,
then renamed over the target. An interrupt or an error leaves either the old file or none.
"""
from __future__ import annotations

import contextlib
import datetime as _dt
import io
import json
import os
import platform
import tempfile
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Callable, Dict, Iterator, Optional, Union

import numpy as np

import multipendulum._core as _core

from ._base import Cart
from ._chain import Chain
from ._convert import check_single, is_float
from ._simulate import Work
from .errors import InputError

__all__ = ["Results", "save_results", "load_results", "atomic_path", "series", "check_single", "scenario_from_metadata",
           "FORMATS"]

PathLike = Union[str, "os.PathLike[str]"]
FORMATS = ("npz", "csv")
_FORMAT_NAME = "multipendulum-results"
_FORMAT_VERSION = 2
_SERIES = ("t", "theta", "omega", "p", "energy", "work", "energy_error", "positions")
#: Series of format 2: the pivot's position and the work's parts (every run), the cart's
#: position and velocity (a run with a cart).
_BASE_SERIES = ("pivot", "work_torque", "work_pivot", "work_cart", "dissipated")
_CART_SERIES = ("cart_x", "cart_v")
_WORK_PARTS = {"work_torque": "torque", "work_pivot": "pivot", "work_cart": "cart", "dissipated": "dissipated"}
_CHAIN_ARRAYS = ("lengths", "masses", "com", "inertia")
_LOSS_ARRAYS = ("damping", "friction")
_STATS = ("steps", "rejected", "evaluations", "iterations", "energy_error", "wall_time")


class Results:
    """A loaded results file. It has the arrays of a solution (``t``, ``theta``, ``omega``,
    ``p``, ``energy``, ``work`` (a :class:`multipendulum.Work`: the net work, with its parts),
    ``energy_error``, ``positions``, ``pivot``, ``cart_x``, ``cart_v``), the chain's parameters
    (``cart`` a :class:`multipendulum.Cart` or ``None``), and ``metadata`` (a dict: ``version``,
    ``method``, ``stats``, ``scenario`` ...), so it can be passed to :func:`multipendulum.plot`
    and :func:`multipendulum.animate` like a solution."""

    def __init__(self, arrays: Dict[str, np.ndarray], metadata: Dict[str, Any], path: Optional[Path] = None):
        self.t = arrays["t"]
        self.theta = arrays["theta"]
        self.omega = arrays["omega"]
        self.p = arrays["p"]
        self.energy = arrays["energy"]
        self.work = Work(*(arrays[name] for name in _WORK_PARTS))
        self.energy_error = arrays["energy_error"]
        self.positions = arrays["positions"]
        self.pivot = arrays["pivot"]
        self.cart_x: Optional[np.ndarray] = arrays.get("cart_x")
        self.cart_v: Optional[np.ndarray] = arrays.get("cart_v")
        self.lengths = arrays["lengths"]
        self.masses = arrays["masses"]
        self.com = arrays["com"]
        self.inertia = arrays["inertia"]
        self.damping = arrays["damping"]
        self.friction = arrays["friction"]
        self.g = float(np.asarray(arrays["g"]).reshape(()))
        self.friction_velocity = float(np.asarray(arrays["friction_velocity"]).reshape(()))
        cart = arrays.get("cart")
        self.cart: Optional[Cart] = None if cart is None else Cart(float(cart[0]), float(cart[1]))
        self.metadata = metadata
        self.path = path
        self._chain = None

    @property
    def n(self) -> int:
        return int(self.lengths.shape[0])

    @property
    def method(self) -> str:
        return str(self.metadata.get("method", ""))

    @property
    def version(self) -> str:
        return str(self.metadata.get("version", ""))

    @property
    def stats(self) -> SimpleNamespace:
        return SimpleNamespace(**{k: self.metadata.get("stats", {}).get(k) for k in _STATS})

    @property
    def chain(self):
        """The :class:`multipendulum.Chain` rebuilt from the stored parameters."""
        if self._chain is None:
            self._chain = Chain(
                lengths=self.lengths, masses=self.masses, com=self.com, inertia=self.inertia, g=self.g,
                damping=self.damping, friction=self.friction, friction_velocity=self.friction_velocity,
                cart=self.cart,
            )
        return self._chain

    def scenario(self):
        """The scenario this run came from (``None`` if it was saved from a plain solution)."""
        info = self.metadata.get("scenario")
        if not info:
            return None
        return scenario_from_metadata(info)

    def __repr__(self) -> str:
        where = f" from {str(self.path)!r}" if self.path else ""
        return (f"<Results{where}: N = {self.n}, {self.t.shape[0]} samples, "
                f"t = {self.t[0]:g}..{self.t[-1]:g} s, method {self.method!r}>")


def scenario_from_metadata(info: Dict[str, Any]):
    """The scenario described by ``Scenario.metadata()`` (as stored in results files and
    checkpoint archives), with its overrides (e.g. ``--t-end``) applied."""
    from .scenario import loads_scenario

    scenario = loads_scenario(info["text"], files=info.get("files") or {}, path=info.get("path"))
    overrides = info.get("overrides") or {}
    return scenario.replace(**overrides) if overrides else scenario


# ----------------------------------------------------------------------------------------------
# Atomic writes


from ._files import atomic_path  # noqa: E402  (the one atomic writer, re-exported here)


# ----------------------------------------------------------------------------------------------
# Saving


def _version() -> str:
    version = getattr(_core, "__version__", None)
    if version:
        return str(version)
    try:
        from importlib.metadata import version as _dist_version

        return _dist_version("multipendulum")
    except Exception:  # pragma: no cover - not installed
        return "unknown"


def _plain(value: Any) -> Any:
    """Numbers from NumPy (or the core) as plain JSON values."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    try:
        return float(value)
    except (TypeError, ValueError):
        return str(value)


def _floats(value: Any) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(value, dtype=np.float64))


def _collect(sol: Any) -> Dict[str, np.ndarray]:
    """The arrays of a solution or of loaded results, as float64 C-contiguous arrays."""
    check_single(sol, "save_results")
    arrays = {}
    for name in _SERIES:
        arrays[name] = _floats(getattr(sol, name))
    arrays["pivot"] = _floats(sol.pivot)
    for name, part in _WORK_PARTS.items():
        arrays[name] = _floats(getattr(sol.work, part))
    chain = sol if isinstance(sol, Results) else sol.chain
    if chain.cart is not None:
        for name in _CART_SERIES:
            arrays[name] = _floats(getattr(sol, name))
        arrays["cart"] = _floats([chain.cart.mass, chain.cart.damping])
    for name in _CHAIN_ARRAYS + _LOSS_ARRAYS:
        arrays[name] = _floats(getattr(chain, name))
    arrays["g"] = np.asarray(float(chain.g), dtype=np.float64)
    arrays["friction_velocity"] = np.asarray(float(chain.friction_velocity), dtype=np.float64)
    t_count, n = arrays["theta"].shape
    for name in ("omega", "p"):
        if arrays[name].shape != (t_count, n):
            raise InputError(f"{name} must have shape {(t_count, n)}, got {arrays[name].shape}")
    if arrays["positions"].shape != (t_count, n, 2):
        raise InputError(f"positions must have shape {(t_count, n, 2)}, got {arrays['positions'].shape}")
    return arrays


def _metadata(sol: Any, scenario: Any) -> Dict[str, Any]:
    if isinstance(sol, Results):
        meta = dict(sol.metadata)
        if scenario is not None:
            meta["scenario"] = scenario.metadata()
        return meta
    stats = getattr(sol, "stats", None)
    return {
        "format": _FORMAT_NAME,
        "format_version": _FORMAT_VERSION,
        "version": _version(),
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "method": str(getattr(sol, "method", "")),
        "form": getattr(sol, "form", None),
        "stats": {k: _plain(getattr(stats, k, None)) for k in _STATS},
        "scenario": None if scenario is None else scenario.metadata(),
        "python": platform.python_version(),
        "numpy": np.__version__,
    }


def save_results(sol: Any, path: PathLike, scenario: Any = None, format: Optional[str] = None) -> Path:
    """Write a solution (or loaded :class:`Results`) to ``path`` atomically and return the path.

    ``format`` is ``"npz"`` or ``"csv"``; by default it follows the file suffix (``.csv`` for
    CSV, NPZ otherwise). ``scenario`` (a :class:`~multipendulum.scenario.Scenario`) is stored in
    the metadata so the run can be repeated.
    """
    path = Path(path)
    if format is None:
        format = "csv" if path.suffix.lower() == ".csv" else "npz"
    if format not in FORMATS:
        raise InputError(f"format must be one of {', '.join(FORMATS)}, got {format!r}")
    arrays = _collect(sol)
    meta = _metadata(sol, scenario)
    writer: Callable[[Any], None]
    if format == "npz":
        def writer(f):
            np.savez_compressed(f, metadata=np.asarray(json.dumps(meta)), **arrays)
    else:
        def writer(f):
            f.write(_csv_text(arrays, meta).encode("utf-8"))
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            writer(f)
    return path


def _csv_columns(n: int, cart: bool = False, version: int = _FORMAT_VERSION) -> list:
    cols = ["t"]
    for name in ("theta", "omega", "p"):
        cols += [f"{name}_{i + 1}" for i in range(n)]
    cols += ["energy", "work", "energy_error"]
    for i in range(n):
        cols += [f"x_{i + 1}", f"y_{i + 1}"]
    if version >= 2:
        cols += ["pivot_x", "pivot_y", *_BASE_SERIES[1:]] + (list(_CART_SERIES) if cart else [])
    return cols


def _csv_text(arrays: Dict[str, np.ndarray], meta: Dict[str, Any]) -> str:
    n = arrays["theta"].shape[1]
    t_count = arrays["t"].shape[0]
    chain: Dict[str, Any] = {k: arrays[k].tolist() for k in _CHAIN_ARRAYS + _LOSS_ARRAYS}
    chain["g"] = float(arrays["g"])
    chain["friction_velocity"] = float(arrays["friction_velocity"])
    cart = arrays.get("cart")
    chain["cart"] = None if cart is None else {"mass": float(cart[0]), "damping": float(cart[1])}
    meta = dict(meta, chain=chain)
    table = np.column_stack([
        arrays["t"], arrays["theta"], arrays["omega"], arrays["p"],
        arrays["energy"], arrays["work"], arrays["energy_error"],
        arrays["positions"].reshape(t_count, 2 * n), arrays["pivot"],
        *(arrays[k] for k in _BASE_SERIES[1:]), *(arrays[k] for k in _CART_SERIES if cart is not None),
    ])
    buf = io.StringIO()
    buf.write(f"# {_FORMAT_NAME} (format {_FORMAT_VERSION}), CSV; one row per sample, SI units, angles in rad\n")
    buf.write("# metadata: " + json.dumps(meta) + "\n")
    buf.write(",".join(_csv_columns(n, cart is not None)) + "\n")
    np.savetxt(buf, table, fmt="%.17g", delimiter=",")
    return buf.getvalue()


def series(sol: Any, what: str = "plotting") -> SimpleNamespace:
    """What plots and animations draw, from a solution or loaded results: the time series, the
    chain's parameters, a chain object when one can be had, and a short title. ``what`` names
    the caller when a batch run (or anything but one run) is refused."""
    check_single(sol, what)
    is_results = isinstance(sol, Results)
    params = sol if is_results else sol.chain
    cart_x = getattr(sol, "cart_x", None)
    view = SimpleNamespace(
        t=np.asarray(sol.t, dtype=float),
        theta=np.asarray(sol.theta, dtype=float),
        omega=np.asarray(sol.omega, dtype=float),
        energy_error=np.asarray(sol.energy_error, dtype=float),
        positions=np.asarray(sol.positions, dtype=float),
        # The base: the pivot's lab position (T, 2) and, with a cart, its x (T,) and parameters.
        pivot=np.asarray(sol.pivot, dtype=float),
        cart_x=None if cart_x is None else np.asarray(cart_x, dtype=float),
        cart=params.cart,
        work=sol.work,
        lengths=np.asarray(params.lengths, dtype=float),
        masses=np.asarray(params.masses, dtype=float),
        com=np.asarray(params.com, dtype=float),
        method=str(getattr(sol, "method", "")),
        max_energy_error=None,
        name="",
        chain=None,
    )
    stats = getattr(sol, "stats", None)
    if stats is not None and getattr(stats, "energy_error", None) is not None:
        view.max_energy_error = float(stats.energy_error)
    if is_results:
        view.name = ((sol.metadata.get("scenario") or {}).get("name")) or ""
        try:
            view.chain = sol.chain
        except Exception:  # the stored parameters no longer build a chain: draw stored positions
            view.chain = None
    else:
        view.chain = sol.chain
        view.name = str(getattr(sol, "name", "") or "")
    return view


# ----------------------------------------------------------------------------------------------
# Loading


def _damaged(path: Path, problem: str) -> InputError:
    return InputError(f"{str(path)!r}: {problem}")


def load_results(path: PathLike) -> Results:
    """Read a results file written by :func:`save_results` (NPZ or CSV, told apart by content).

    Raises :class:`~multipendulum.InputError` naming the file and the problem for anything that
    is not a complete results file: no such file, empty, truncated or corrupt (a damaged zip
    member, a bad CRC), not a results file at all, or arrays whose shapes or values do not fit
    together. Nothing else escapes (no ``zipfile.BadZipFile`` or ``zlib.error``)."""
    path = Path(path)
    if not path.exists():
        raise _damaged(path, "no such results file")
    if not path.is_file():
        raise _damaged(path, "not a file (a results file is an .npz or .csv file)")
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError as exc:
        raise _damaged(path, f"cannot be read: {exc.strerror or exc}") from None
    if not head:
        raise _damaged(path, "the file is empty (0 bytes): not a results file (was its run interrupted?)")
    if head.startswith(b"PK"):
        return _load_npz(path)
    if path.suffix.lower() == ".npz":
        raise _damaged(path, "not an NPZ archive: it does not begin like one (truncated or corrupt, or "
                             "another kind of file named .npz)")
    return _load_csv(path)


#: Members a results file of format 2 may hold beyond format 1's (absent from format 1 files).
_OPTIONAL = _BASE_SERIES + _CART_SERIES + _LOSS_ARRAYS + ("friction_velocity", "cart")


def _load_npz(path: Path) -> Results:
    members = ("metadata",) + _SERIES + _CHAIN_ARRAYS + ("g",)
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in members if k not in data.files]
            if missing:
                raise _damaged(path, f"not a multipendulum results file: missing {', '.join(missing)}")
            arrays = {k: np.asarray(data[k]) for k in members[1:] + _OPTIONAL if k in data.files}
            text = data["metadata"][()]
    except InputError:
        raise
    except Exception as exc:  # zipfile, zlib, EOF, CRC, .npy header errors: the file is damaged
        raise _damaged(path, f"not a readable NPZ archive (truncated or corrupt?): "
                             f"{type(exc).__name__}: {exc}") from None
    metadata = _parse_metadata(path, str(text))
    return Results(_checked(path, arrays), metadata, path)


def _parse_metadata(path: Path, text: str) -> Dict[str, Any]:
    try:
        metadata = json.loads(text)
    except ValueError as exc:
        raise _damaged(path, f"its metadata is not valid JSON ({exc})") from None
    if not isinstance(metadata, dict):
        raise _damaged(path, f"its metadata must be a JSON object, got {type(metadata).__name__}")
    fmt = metadata.get("format", _FORMAT_NAME)
    if fmt != _FORMAT_NAME:
        raise _damaged(path, f"not a multipendulum results file (format {fmt!r})")
    return metadata


def _checked(path: Path, arrays: Dict[str, Any]) -> Dict[str, np.ndarray]:
    """The arrays as float64, refused unless their shapes fit one run of N links and T samples
    and every value is finite (what plots, animations and reruns rely on)."""
    out: Dict[str, np.ndarray] = {}
    for name, value in arrays.items():
        a = np.asarray(value)
        if a.dtype.kind not in "fiu" or a.dtype.kind == "b":
            raise _damaged(path, f"member {name!r} must hold numbers, got dtype {a.dtype}")
        out[name] = np.asarray(a, dtype=np.float64, order="C")  # (ascontiguousarray makes g 1-d)
    t, theta = out["t"], out["theta"]
    if theta.ndim != 2 or theta.shape[0] < 1 or theta.shape[1] < 1:
        raise _damaged(path, f"theta must have shape (T, N) with T, N >= 1, got {theta.shape}")
    t_count, n = theta.shape
    if ("cart" in out) != ("cart_x" in out and "cart_v" in out):
        raise _damaged(path, "a run with a cart stores cart (its mass and damping), cart_x and cart_v; "
                             f"got only {', '.join(k for k in ('cart', 'cart_x', 'cart_v') if k in out)}")
    _fill_format_1(out, t_count, n)
    expected = {"t": (t_count,), "omega": (t_count, n), "p": (t_count, n), "energy": (t_count,),
                "work": (t_count,), "energy_error": (t_count,), "positions": (t_count, n, 2),
                "pivot": (t_count, 2), "work_torque": (t_count,), "work_pivot": (t_count,),
                "work_cart": (t_count,), "dissipated": (t_count,),
                "lengths": (n,), "masses": (n,), "com": (n,), "inertia": (n,), "damping": (n,), "friction": (n,),
                "g": (), "friction_velocity": ()}
    if "cart" in out:
        expected.update(cart_x=(t_count,), cart_v=(t_count,), cart=(2,))
    for name, shape in expected.items():
        if out[name].shape != shape:
            raise _damaged(path, f"{name} must have shape {shape} to fit theta's {theta.shape} "
                                 f"(T = {t_count} samples, N = {n} links), got {out[name].shape}")
    for name, a in out.items():
        bad = ~np.isfinite(a)
        if bad.any():
            index = tuple(int(i) for i in np.argwhere(bad)[0])
            where = f"[{', '.join(map(str, index))}]" if index else ""
            raise _damaged(path, f"{name}{where} is {float(a[index])!r}: a results file holds finite numbers only")
    if t_count > 1 and not np.all(np.diff(t) >= 0):
        i = int(np.argmax(np.diff(t) < 0)) + 1
        raise _damaged(path, f"t must be ascending, got t[{i}] = {float(t[i])!r} after t[{i - 1}] = "
                             f"{float(t[i - 1])!r}")
    return out


def _fill_format_1(arrays: Dict[str, np.ndarray], t_count: int, n: int) -> None:
    """What a file of format 1 did not store, as it was then: a fixed pivot at the origin, all
    the work the torque's, no losses (friction_velocity: the API's default, unused)."""
    import inspect

    if "work_torque" not in arrays and "work" in arrays:
        arrays["work_torque"] = arrays["work"]
    arrays.setdefault("pivot", np.zeros((t_count, 2)))
    for name in ("work_pivot", "work_cart", "dissipated"):
        arrays.setdefault(name, np.zeros(t_count))
    for name in _LOSS_ARRAYS:
        arrays.setdefault(name, np.zeros(n))
    arrays.setdefault("friction_velocity",
                      np.asarray(float(inspect.signature(Chain).parameters["friction_velocity"].default)))


def _load_csv(path: Path) -> Results:
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        raise _damaged(path, f"cannot be read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise _damaged(path, f"neither an NPZ archive nor UTF-8 text (a CSV results file): {exc}") from None
    lines = text.splitlines()
    metadata = None
    header_index = None
    for i, line in enumerate(lines):
        if line.startswith("# metadata:"):
            metadata = _parse_metadata(path, line[len("# metadata:"):])
        elif not line.startswith("#"):
            header_index = i
            break
    if metadata is None or header_index is None or "chain" not in metadata:
        raise _damaged(path, "not a multipendulum results file (no '# metadata:' line with the chain, "
                             "then a header line)")
    chain = metadata.pop("chain")
    if not isinstance(chain, dict) or any(k not in chain for k in _CHAIN_ARRAYS + ("g",)):
        raise _damaged(path, f"the metadata's chain must give {', '.join(_CHAIN_ARRAYS + ('g',))}")
    try:
        n = len(chain["lengths"])
    except TypeError:
        raise _damaged(path, "the metadata's chain lengths must be a list") from None
    cart = chain.get("cart")
    if cart is not None and (not isinstance(cart, dict) or any(k not in cart for k in ("mass", "damping"))):
        raise _damaged(path, "the metadata's chain cart must be null or give mass and damping")
    version = 1 if metadata.get("format_version", 1) == 1 else 2
    wanted = _csv_columns(n, cart is not None, version)
    columns = lines[header_index].split(",")
    if columns != wanted:
        raise _damaged(path, f"unexpected CSV columns for N = {n} links: expected "
                             f"{','.join(wanted[:4])},... ({len(wanted)} columns), "
                             f"got {len(columns)} starting {','.join(columns[:4])!r}")
    body = lines[header_index + 1:]
    if not any(line.strip() for line in body):
        raise _damaged(path, "no samples after the header line (truncated?)")
    try:
        table = np.loadtxt(io.StringIO("\n".join(body)), delimiter=",", ndmin=2, dtype=np.float64)
    except ValueError:
        raise _csv_problem(path, body, header_index + 2, columns) from None
    if table.shape[1] != len(columns):
        raise _csv_problem(path, body, header_index + 2, columns)
    t_count = table.shape[0]
    cuts = np.cumsum([1, n, n, n, 1, 1, 1, 2 * n])
    parts = np.split(table, cuts, axis=1)
    arrays = {
        "t": parts[0][:, 0], "theta": parts[1], "omega": parts[2], "p": parts[3],
        "energy": parts[4][:, 0], "work": parts[5][:, 0], "energy_error": parts[6][:, 0],
        "positions": parts[7].reshape(t_count, n, 2),
    }
    if version >= 2:
        rest = parts[8]
        arrays["pivot"] = rest[:, :2]
        names = _BASE_SERIES[1:] + (_CART_SERIES if cart is not None else ())
        arrays.update({name: rest[:, 2 + k] for k, name in enumerate(names)})
    try:
        arrays["g"] = np.asarray(chain["g"], dtype=np.float64)
        for k in _CHAIN_ARRAYS + _LOSS_ARRAYS + ("friction_velocity",):
            if k in chain:
                arrays[k] = np.asarray(chain[k], dtype=np.float64)
        if cart is not None:
            arrays["cart"] = np.asarray([cart["mass"], cart["damping"]], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise _damaged(path, f"the metadata's chain is not numbers: {exc}") from None
    return Results(_checked(path, arrays), metadata, path)


def _csv_problem(path: Path, body, first_lineno: int, columns) -> InputError:
    """The first line of a CSV body that does not hold one number per column, named."""
    for lineno, line in enumerate(body, start=first_lineno):
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) != len(columns):
            return _damaged(path, f"line {lineno}: expected {len(columns)} values, got {len(cells)} (truncated?)")
        for j, cell in enumerate(cells):
            if not is_float(cell):
                return _damaged(path, f"line {lineno}, column {j + 1} ({columns[j]}): expected a number, "
                                      f"got {cell[:40]!r}")
    return _damaged(path, "the CSV samples cannot be read as numbers")

