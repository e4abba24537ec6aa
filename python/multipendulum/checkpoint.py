"""Checkpoint archives: the complete state of a run, so that it can stop and continue.

A run given ``checkpoint="run.ckpt"`` (:func:`multipendulum.simulate`, ``multipendulum run
--checkpoint``) rewrites that one file now and then, and once more when it is interrupted
(Ctrl-C, or SIGTERM under the CLI). :func:`resume` continues from it; the resumed run takes
exactly the floating-point path the uninterrupted run would have taken, so its arrays are
bit-for-bit the same (same multipendulum version, same machine).

The archive is an NPZ file (``np.savez``, no pickles) holding ``metadata``, a JSON string
(``format`` "multipendulum-checkpoint", ``format_version``, the package ``version``, the
simulate arguments, the counters, the scenario when the run came from one), the chain's
``lengths``, ``masses``, ``com``, ``inertia``, ``g``, the initial ``theta0``/``omega0``,
``t_eval``, and ``state``: the core's run state serialised whole (bytes, as a uint8 array:
the run driver's time, raw ODE state ``[theta, omega or p, work]``, counters and the
integrator's typed memory, the initial state and the output rows so far), so no part of it can
be left out by a hand-written list. It is written atomically (a temporary file beside it, fsynced, renamed over it), so
a kill at any moment leaves the previous archive or the new one, never half of one.

Resuming is :func:`multipendulum.resume` (in :mod:`multipendulum._simulate`, above this
module). Not checkpointable, and refused with a clear message: batch runs, a torque given as a Python
function, and events (their tracker's state is not saved).
"""
from __future__ import annotations

import datetime as _dt
import json
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Dict, Optional, Tuple

import numpy as np
import numpy.typing as npt

from ._torque import torque_object
from .errors import InputError

if TYPE_CHECKING:
    from ._chain import Chain
    from ._convert import Integer
    from ._files import PathLike

__all__ = ["load_checkpoint", "Archive", "Writer", "FORMAT", "FORMAT_VERSION"]

FORMAT = "multipendulum-checkpoint"
FORMAT_VERSION = 2
#: Seconds of wall time between checkpoints when neither a step count nor a time is given.
DEFAULT_SECONDS = 60.0
_CHAIN = ("lengths", "masses", "com", "inertia", "g")
_MEMBERS = ("metadata",) + _CHAIN + ("theta0", "omega0", "t_eval", "state")
_COUNTERS = ("steps",)
_RUN_KEYS = ("method", "form", "t_end", "dt", "rtol", "atol", "adaptive", "max_steps", "torque", "joint",
             "has_t_eval")


def _version() -> str:
    from ._core import __version__

    return str(__version__)


class Archive:
    """A loaded checkpoint archive (see the module docstring): ``metadata`` (dict), ``arrays``
    (dict of float64 arrays), ``t`` the time reached, ``t_end``, ``method``, ``path``, and
    ``scenario_info`` / ``cli`` when ``multipendulum run`` wrote it."""

    def __init__(self, metadata: Dict[str, Any], arrays: Dict[str, npt.NDArray[Any]],
                 path: Optional[Path] = None) -> None:
        self.metadata, self.arrays, self.path = metadata, arrays, path

    @property
    def t(self) -> float:
        return float(self.metadata["state"]["t"])

    @property
    def t_end(self) -> float:
        return float(self.metadata["run"]["t_end"])

    @property
    def method(self) -> str:
        return str(self.metadata["run"]["method"])

    @property
    def info(self) -> Dict[str, Any]:
        """What the writer asked to keep (``checkpoint_info``): the CLI keeps the scenario there."""
        return self.metadata.get("info") or {}

    def state(self) -> bytes:
        """The run's state as the core serialised it (and takes it back)."""
        return self.arrays["state"].tobytes()

    def chain(self) -> Chain:
        from ._chain import Chain

        a = self.arrays
        chain = Chain(lengths=a["lengths"], masses=a["masses"], com=a["com"], inertia=a["inertia"],
                      g=float(a["g"]))
        # Losses and a cart (the model beyond the seeds) are kept in the metadata.
        extra = self.metadata.get("chain")
        return Chain.from_dict({**chain.to_dict(), **extra}) if extra else chain

    def __repr__(self) -> str:
        where = f" {str(self.path)!r}" if self.path else ""
        return f"<checkpoint{where}: {self.method}, t = {self.t:g} of {self.t_end:g} s>"


# ----------------------------------------------------------------------------------------------
# Writing


class Writer:
    """Called by the core with each checkpoint; writes the archive atomically. Keeps the fixed
    part (chain, arguments, t_eval) and adds the state, the counters and the wall time so far."""

    def __init__(self, path: PathLike, chain: Chain, theta0: npt.ArrayLike, omega0: npt.ArrayLike,
                 t_eval: Optional[npt.ArrayLike], run: Dict[str, Any], every_steps: Optional[int],
                 every_seconds: Optional[float], info: Optional[Dict[str, Any]] = None,
                 wall_before: float = 0.0) -> None:
        self.path = Path(path)
        self.fixed = {
            "lengths": chain.lengths, "masses": chain.masses, "com": chain.com, "inertia": chain.inertia,
            "g": np.asarray(chain.g, dtype=np.float64),
            "theta0": np.asarray(theta0, dtype=np.float64), "omega0": np.asarray(omega0, dtype=np.float64),
            "t_eval": np.zeros(0) if t_eval is None else np.asarray(t_eval, dtype=np.float64),
        }
        self.meta = {
            "format": FORMAT, "format_version": FORMAT_VERSION, "version": _version(), "run": run,
            "checkpoint": {"every_steps": every_steps, "every_seconds": every_seconds},
            "info": info,
        }
        extra = {k: v for k, v in chain.to_dict().items() if k not in _CHAIN}
        if extra:
            self.meta["chain"] = extra
        self.every_steps, self.every_seconds = every_steps, every_seconds
        self.wall_before = wall_before
        self.start = time.perf_counter()
        self.saved = 0

    def __call__(self, state: bytes, t: float, steps: int) -> None:
        from ._files import atomic_path

        meta = dict(self.meta)
        meta["created"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        meta["wall_time"] = self.wall_before + (time.perf_counter() - self.start)
        meta["state"] = {"t": float(t), "steps": int(steps)}
        arrays: Dict[str, Any] = dict(self.fixed)
        arrays["state"] = np.frombuffer(state, dtype=np.uint8)
        with atomic_path(self.path) as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, metadata=np.asarray(json.dumps(meta)), **arrays)
        self.saved += 1


def cadence(every_steps: Optional[Integer], every_seconds: Optional[float]) -> Tuple[Optional[int], Optional[float]]:
    """Checked ``(every_steps, every_seconds)`` as the core takes them; neither given: every
    :data:`DEFAULT_SECONDS` seconds."""
    if every_steps is not None and (isinstance(every_steps, bool) or not isinstance(every_steps, (int, np.integer))
                                    or every_steps <= 0):
        raise InputError(f"checkpoint_every must be a positive integer (steps), got {every_steps!r}")
    if every_seconds is not None:
        try:
            every_seconds = float(every_seconds)
        except (TypeError, ValueError):
            raise InputError(f"checkpoint_seconds must be a number > 0, got {every_seconds!r}") from None
        if not (math.isfinite(every_seconds) and every_seconds > 0):
            raise InputError(f"checkpoint_seconds must be > 0 and finite, got {every_seconds!r}")
    if every_steps is None and every_seconds is None:
        every_seconds = DEFAULT_SECONDS
    return (None if every_steps is None else int(every_steps)), every_seconds


# ----------------------------------------------------------------------------------------------
# Reading


def load_checkpoint(path: PathLike, any_version: bool = False) -> Archive:
    """Read and check a checkpoint archive. Raises :class:`InputError` naming the problem: no
    such file, not an archive (truncated, corrupt), a missing member, another format version,
    or (unless ``any_version``) another multipendulum version, whose arithmetic may differ.

    >>> import multipendulum as mp, tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "run.ckpt")
    >>> chain = mp.Chain(lengths=[1, 1], masses=[1, 1])
    >>> sol = mp.simulate(chain, [2.0, 2.5], [0, 0], t_end=1.0, method="rk4", dt=0.01,
    ...                   checkpoint=path, checkpoint_every=50)
    >>> mp.load_checkpoint(path).t
    1.0
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{str(path)!r}: no such checkpoint file")
    name = repr(str(path))
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in _MEMBERS if k not in data.files]
            if missing:
                raise InputError(f"{name} is not a multipendulum checkpoint: missing {', '.join(missing)}")
            arrays = {k: np.asarray(data[k]) for k in _MEMBERS if k != "metadata"}
            text = str(data["metadata"][()])
    except InputError:
        raise
    except Exception as exc:  # zipfile, EOF, CRC, format errors: all mean the file is damaged
        raise InputError(f"{name} is not a readable checkpoint archive (truncated or corrupt?): {exc}") from None
    try:
        meta = json.loads(text)
    except ValueError as exc:
        raise InputError(f"{name}: the checkpoint's metadata is not valid JSON: {exc}") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise InputError(f"{name} is not a multipendulum checkpoint (format {meta.get('format') if isinstance(meta, dict) else None!r})")
    if meta.get("format_version") != FORMAT_VERSION:
        raise InputError(f"{name}: checkpoint format version {meta.get('format_version')!r}; "
                         f"this multipendulum reads version {FORMAT_VERSION}")
    if not any_version and meta.get("version") != _version():
        raise InputError(f"{name} was written by multipendulum {meta.get('version')!r}, this is {_version()!r}: "
                         "a resumed run is bit-for-bit only with the same version "
                         "(pass any_version=True to continue anyway)")
    for key, fields in (("run", _RUN_KEYS), ("state", _COUNTERS + ("t",)), ("checkpoint", ("every_steps", "every_seconds"))):
        part = meta.get(key)
        if not isinstance(part, dict):
            raise InputError(f"{name}: the checkpoint's metadata has no {key!r} table")
        absent = [f for f in fields if f not in part]
        if absent:
            raise InputError(f"{name}: the checkpoint's metadata {key!r} lacks {', '.join(absent)}")
    for k in _COUNTERS:
        v = meta["state"][k]
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise InputError(f"{name}: state.{k} must be an integer >= 0, got {v!r}")
    v = meta["state"]["t"]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InputError(f"{name}: state.t must be a finite number, got {v!r}")
    for k, a in arrays.items():
        want = np.uint8 if k == "state" else np.float64
        if a.dtype != want or a.ndim != (0 if k == "g" else 1):
            raise InputError(f"{name}: member {k} must be a {np.dtype(want).name} {'scalar' if k == 'g' else 'vector'}, "
                             f"got {a.dtype} of shape {a.shape}")
    import multipendulum._core as _core

    try:
        t, steps = _core.checkpoint_time(arrays["state"].tobytes())
    except InputError as exc:
        raise InputError(f"{name}: {exc}") from None
    if (t, steps) != (float(meta["state"]["t"]), meta["state"]["steps"]):
        raise InputError(f"{name}: the run state is at t = {t} after {steps} steps, the metadata says "
                         f"t = {meta['state']['t']} after {meta['state']['steps']}")
    return Archive(meta, arrays, path)
