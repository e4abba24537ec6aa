"""Sweeps beyond one process: initial-condition grids split into chunks, one Dask task per chunk.

Each task calls the Rust ensemble kernel (:func:`multipendulum.flip_times`) on its chunk; the
kernel releases the GIL and runs on all the worker's cores, so the threads of the local scheduler
and the processes of a ``dask.distributed`` cluster both keep every core busy. Nothing here
schedules work itself: Dask does. A trajectory's flip time does not depend on which chunk,
worker or thread computes it, so a sweep equals the single-process result bit for bit.

``scheduler`` (every function here):

- ``None`` or ``"threads"``: Dask's local threaded scheduler, in this process (nothing to start),
  on a thread pool that is waited for before the call returns or raises;
- ``"sync"``: one task after another in this thread (for debugging);
- ``"processes"``: Dask's local process pool;
- an address such as ``"tcp://10.0.0.5:8786"``: a running ``dask.distributed`` scheduler
  (a client is opened for the call and closed after it);
- a ``distributed.Client``: used as is.

``zarr``: a directory path. The result is then written chunk by chunk into a Zarr store by the
tasks themselves and never gathered into one process, so a 4096 x 4096 map never has to fit in
memory; the function returns the (lazy, on-disk) Zarr array instead of a NumPy array. With a
distributed cluster the path must be on a file system every worker sees. An existing path is
replaced only when it is an empty directory or a store written here before (anything else is
refused, never wiped), and a run that fails or is interrupted removes its store.

``progress``: True for a bar on stderr (tqdm's when installed), or a callable given the fraction
of tasks done (see :mod:`multipendulum._progress`); on a ``dask.distributed`` cluster it counts
the chunks as their results arrive.

Limits: a result gathered into this process (no ``zarr``) is checked against the memory the
core allows before any task starts, and so are the chunks that run at once on the local
schedulers; the advice is to write to Zarr or use smaller chunks. A trajectory's length is
bounded as for :func:`multipendulum.flip_times` (10^9 steps); the number of trajectories is not:
that is what a cluster is for.

Dask, ``distributed`` (for addresses) and Zarr are optional: ``pip install 'multipendulum[dask]'``.
"""
from __future__ import annotations

import contextlib
import functools
import importlib.util
import math
import os
from types import ModuleType
from typing import TYPE_CHECKING, Any, Callable, Dict, Iterator, List, Mapping, Optional, Tuple, Union, cast

import numpy as np
import numpy.typing as npt

import multipendulum._core as _core
from ._base import Pivot
from ._chain import Chain, as_state
from ._convert import Integer
from ._progress import check as _check_progress
from ._progress import reporter
from ._torque import TorqueLike
from .chaos import (FlipMap, FlipVolume, IndicatorMap, Vary, Vary3, _check_varied, _check_vary, _grid, _grid_axes, _grid_of,
                    certified_flip_times, certified_indicator, check_certify, flip_threshold, flip_times, indicator_fn)
from .errors import InputError

if TYPE_CHECKING:
    from distributed import Client
    from zarr import Array as ZarrArray
    from zarr import Group as ZarrGroup

    from ._files import PathLike

#: Where the tasks run (see the module docstring): None, a scheduler's name or address, or a
#: ``distributed.Client``.
Scheduler = Union[None, str, "Client"]
#: ``progress=``: None or False (none), True (a bar on stderr) or a callable given the fraction done.
Progress = Union[None, bool, Callable[[float], object]]

__all__ = ["sweep", "sweep_flip_map", "open_flip_map", "sweep_flip_volume", "open_flip_volume", "sweep_indicator_map",
           "open_indicator_map", "DEFAULT_CHUNK_SIZE"]

#: Trajectories per task when ``chunks`` is not given: large enough that the Rust kernel's own
#: parallelism pays off inside a task, small enough to spread a 256 x 256 map over many workers.
DEFAULT_CHUNK_SIZE = 16384
_LOCAL = {"sync": "sync", "synchronous": "sync", "processes": "processes"}
_INSTALL = "pip install 'multipendulum[dask]'  (dask[array], distributed, zarr)"


def _dask() -> Tuple[ModuleType, ModuleType]:
    try:
        import dask
        import dask.array as da
    except ImportError as exc:
        raise ImportError(f"multipendulum sweeps need Dask, which is not installed: {_INSTALL}") from exc
    return dask, da


@contextlib.contextmanager
def _scheduler(scheduler: Scheduler) -> Iterator[Dict[str, Any]]:
    """Keyword arguments for ``dask.compute``. Opens (and closes) a client for an address. Local
    threads run in a pool of our own, which is waited for on the way out, so that when a task
    fails no other task is still writing when the caller cleans up."""
    if scheduler is None or scheduler == "threads":
        from concurrent.futures import ThreadPoolExecutor

        pool = ThreadPoolExecutor(max_workers=os.cpu_count() or 1, thread_name_prefix="multipendulum-sweep")
        try:
            yield {"scheduler": "threads", "pool": pool}
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
        return
    if isinstance(scheduler, str):
        if scheduler in _LOCAL:
            yield {"scheduler": _LOCAL[scheduler]}
            return
        if ":" not in scheduler:
            raise InputError(
                "scheduler must be None, 'threads', 'sync', 'processes', a dask.distributed address "
                f"such as 'tcp://host:8786', or a distributed.Client; got {scheduler!r}")
        try:
            from distributed import Client
        except ImportError as exc:
            raise ImportError(
                f"a scheduler address needs dask.distributed, which is not installed: {_INSTALL}") from exc
        try:
            client = Client(scheduler, set_as_default=False, timeout="20s")
        except OSError as exc:
            raise OSError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from exc
        try:
            yield {"scheduler": client}
        finally:
            client.close()
        return
    if type(scheduler).__name__ == "Client" and type(scheduler).__module__.startswith("distributed"):
        yield {"scheduler": scheduler}
        return
    raise InputError("scheduler must be None, a name, an address or a distributed.Client, "
                     f"got {type(scheduler).__name__}")


class _LocalProgress:
    """Reports the fraction of a local schedule's tasks finished (Dask's scheduler callbacks run
    in the scheduling thread, for the threaded, synchronous and process schedulers alike)."""

    def __init__(self, report: Callable[[float], object]) -> None:
        from dask.callbacks import Callback

        outer = self

        class _Hook(Callback):
            def _start_state(self, dsk: Mapping[Any, Any], state: Dict[str, Any]) -> None:
                outer.total = max(1, len(state["ready"]) + len(state["waiting"]) + len(state.get("running", ())))
                outer.done = 0

            def _posttask(self, key: object, result: object, dsk: Mapping[Any, Any], state: Dict[str, Any],
                          worker_id: object) -> None:
                outer.done += 1
                outer.report(min(outer.done / outer.total, 1.0))

        self.report, self.total, self.done = report, 1, 0
        self.hook = _Hook()


def _compute(dask: ModuleType, how: Dict[str, Any], report: Optional[Callable[[float], object]],
             *collections: Any) -> Tuple[Any, ...]:
    """``dask.compute(*collections, **how)``, reporting progress to ``report`` (or not, if None)."""
    if report is None:
        return dask.compute(*collections, **how)
    scheduler = how["scheduler"]
    if isinstance(scheduler, str):
        with _LocalProgress(report).hook:
            return dask.compute(*collections, **how)
    from distributed import as_completed, futures_of

    persisted = scheduler.persist(list(collections))
    futures = futures_of(persisted)
    for done, _ in enumerate(as_completed(futures, loop=scheduler.loop), start=1):
        report(done / max(1, len(futures)))
    return dask.compute(*persisted, scheduler=scheduler)


def _check_chunks(rows: int, cols: int, n: int, n_chunks: int) -> None:
    """The chunks that run at once in this process (one per core with local threads): their
    initial states, energies and flip times, before they are made."""
    at_once = min(n_chunks, os.cpu_count() or 1)
    _core.check_memory(float(rows) * cols * (2 * n + 3) * 8.0 * at_once,
                       f"{at_once} chunks of {rows} x {cols} initial states at once",
                       "use smaller chunks (chunks=rows or (rows, columns))")


def _positive_int(value: object, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise InputError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def _check_zarr_path(zarr: Optional[PathLike]) -> Optional[str]:
    if zarr is None:
        return None
    if importlib.util.find_spec("zarr") is None:
        raise ImportError(f"writing to Zarr needs the zarr package, which is not installed: {_INSTALL}")
    return os.fspath(zarr)


_KINDS = ("multipendulum.sweep", "multipendulum.flip_map", "multipendulum.flip_volume", "multipendulum.indicator_map")


@contextlib.contextmanager
def _fresh_store(path: str, kind: str, attrs: Dict[str, Any]) -> Iterator[ZarrGroup]:
    """A new Zarr group at ``path`` for this run, removed again if the run fails or is interrupted.
    An existing path is replaced only when it is an empty directory or a store written here
    before: anything else is refused rather than wiped."""
    import shutil

    import zarr as _zarr

    if os.path.lexists(path):
        ours = False
        if os.path.isdir(path) and not os.listdir(path):
            ours = True
        else:
            try:
                ours = _zarr.open_group(path, mode="r").attrs.get("kind") in _KINDS
            except Exception:  # not a Zarr group at all
                ours = False
        if not ours:
            raise InputError(f"zarr path {path!r} exists and is not a store written by multipendulum; "
                             "remove it or choose another path")
    group = _zarr.open_group(path, mode="w")  # a fresh store: no stale chunks from an earlier run
    group.attrs.update(dict(attrs, kind=kind))
    try:
        yield group
    except BaseException:
        shutil.rmtree(path, ignore_errors=True)
        raise


def _times_block(theta: npt.NDArray[np.float64], omega: npt.NDArray[np.float64], chain: Chain, t_max: float,
                 dt: float, link: Optional[Integer], torque: Optional[TorqueLike],
                 pivot: Optional[Pivot]) -> npt.NDArray[np.float64]:
    # One task: a contiguous block of initial states, shape (rows, ..., N) -> (rows, ...).
    return flip_times(chain, theta, omega, t_max=t_max, dt=dt, link=link, torque=torque, pivot=pivot)


def sweep(chain: Chain, theta0: npt.ArrayLike, omega0: Optional[npt.ArrayLike] = None, t_max: float = 10.0,
          dt: float = 0.01, link: Optional[Integer] = None, torque: Optional[TorqueLike] = None,
          chunks: Optional[Integer] = None, scheduler: Scheduler = None, zarr: Optional[PathLike] = None,
          progress: Progress = None, *, pivot: Optional[Pivot] = None) -> Union[npt.NDArray[np.float64], ZarrArray]:
    """:func:`multipendulum.flip_times` over a large batch of initial states, on Dask.

    ``theta0`` (and ``omega0``, default rest) of shape (B, ..., N) is split along its first axis
    into chunks of ``chunks`` rows (default: about :data:`DEFAULT_CHUNK_SIZE` trajectories per
    chunk); each chunk is one task. Returns the flip times, shape (B, ...), ``inf`` where link
    ``link`` (None: any link) never went over the top by ``t_max``: a NumPy array, or the Zarr
    array written at ``zarr`` when given. ``torque`` and ``pivot`` (:class:`multipendulum.Pivot`)
    must pickle to reach other processes (the built-ins and arrays do). See the module docstring for ``scheduler`` and ``progress``.

    >>> import numpy as np, multipendulum as mp
    >>> chain = mp.Chain([1, 1], [1, 1])
    >>> th0 = np.random.default_rng(0).uniform(-3, 3, (100, 2))
    >>> bool(np.array_equal(mp.sweep(chain, th0, t_max=2.0, chunks=30), mp.flip_times(chain, th0, t_max=2.0)))
    True
    """
    dask, da = _dask()
    _check_progress(progress)
    if not isinstance(chain, Chain):
        raise InputError(f"chain must be a multipendulum.Chain, got {type(chain).__name__}")
    th0 = as_state(theta0, "theta0", chain.n)
    om0 = np.zeros_like(th0) if omega0 is None else as_state(omega0, "omega0", chain.n)
    if th0.shape != om0.shape:
        raise InputError(f"theta0 and omega0 must have the same shape, got {th0.shape} and {om0.shape}")
    if th0.ndim < 2:
        raise InputError(f"theta0 must have a batch axis, shape (B, ..., {chain.n}), got {th0.shape}")
    path = _check_zarr_path(zarr)
    # Check t_max, dt, link, torque and pivot here, on no states, rather than in every task.
    flip_times(chain, th0.reshape(-1, chain.n)[:0], t_max=t_max, dt=dt, link=link, torque=torque, pivot=pivot)
    per_row = max(1, math.prod(th0.shape[1:-1]))
    rows = max(1, DEFAULT_CHUNK_SIZE // per_row) if chunks is None else _positive_int(chunks, "chunks")
    block = (rows,) + th0.shape[1:]
    _check_chunks(rows, per_row, chain.n, -(-th0.shape[0] // rows))
    th = da.from_array(th0, chunks=block)
    om = da.from_array(om0, chunks=block)
    times = da.map_blocks(_times_block, th, om, chain, float(t_max), float(dt), link, torque, pivot,
                          drop_axis=th.ndim - 1, dtype=np.float64, meta=np.empty((0,) * (th.ndim - 1)))
    if path is None:
        with _scheduler(scheduler) as how, reporter(progress, "sweep") as report:
            (out,) = _compute(dask, how, report, times)
        return out
    import zarr as _zarr

    attrs = {"t_max": float(t_max), "dt": float(dt), "link": None if link is None else int(link),
             "chain": chain.to_dict()}
    # The store outside the scheduler: on failure every task has stopped before it is removed.
    with _fresh_store(path, "multipendulum.sweep", attrs), _scheduler(scheduler) as how, \
            reporter(progress, "sweep") as report:
        _compute(dask, how, report, da.to_zarr(times, path, component="times", compute=False))
    return cast("ZarrArray", _zarr.open_group(path, mode="r")["times"])


# ----------------------------------------------------------------------------------------------
# Flip-time maps: the initial grid is built inside each task, never as a whole


def _map_times_block(yb: npt.NDArray[np.float64], xb: npt.NDArray[np.float64], chain: Chain,
                     vary: Tuple[str, int, str, int], th_base: npt.NDArray[np.float64],
                     om_base: npt.NDArray[np.float64], t_max: float, dt: float, link: Optional[Integer],
                     torque: Optional[TorqueLike], pivot: Optional[Pivot]) -> npt.NDArray[np.float64]:
    theta0, omega0 = _grid(yb, xb, vary, th_base, om_base)
    return flip_times(chain, theta0, omega0, t_max=t_max, dt=dt, link=link, torque=torque, pivot=pivot)


def _map_certified_block(yb: npt.NDArray[np.float64], xb: npt.NDArray[np.float64], chain: Chain,
                         vary: Tuple[str, int, str, int], th_base: npt.NDArray[np.float64],
                         om_base: npt.NDArray[np.float64], t_max: float, dt: float, link: Optional[Integer],
                         torque: Optional[TorqueLike], pivot: Optional[Pivot],
                         time_tolerance: Optional[float]) -> npt.NDArray[np.float64]:
    # A certified block's times and uncertain flags (as 0 or 1) along a last axis of 2.
    theta0, omega0 = _grid(yb, xb, vary, th_base, om_base)
    times, uncertain, _ = certified_flip_times(chain, theta0, omega0, t_max=t_max, dt=dt, link=link, torque=torque,
                                               time_tolerance=time_tolerance, pivot=pivot)
    return np.stack([times, uncertain.astype(np.float64)], axis=-1)


def _map_allowed_block(yb: npt.NDArray[np.float64], xb: npt.NDArray[np.float64], chain: Chain,
                       vary: Tuple[str, int, str, int], th_base: npt.NDArray[np.float64],
                       om_base: npt.NDArray[np.float64], threshold: float) -> npt.NDArray[np.bool_]:
    theta0, omega0 = _grid(yb, xb, vary, th_base, om_base)
    return np.asarray(chain.energy(theta0, omega0) >= threshold)


def _map_arrays(da: ModuleType, Y: Any, X: Any, name: str, plain: Callable[..., Any],
                certified: Optional[Callable[..., Any]]) -> List[Tuple[str, Any]]:
    """A 2-D map's Dask arrays: ``name`` from ``plain``'s blocks, or, certified, ``name`` and
    ``uncertain`` as the two slices of ``certified``'s blocks (one task runs both steps)."""
    if certified is None:
        return [(name, da.blockwise(plain, "ij", Y, "i", X, "j", dtype=np.float64, meta=np.empty((0, 0))))]
    both = da.blockwise(certified, "ijk", Y, "i", X, "j", new_axes={"k": 2}, dtype=np.float64,
                        meta=np.empty((0, 0, 0)))
    return [(name, both[..., 0]), ("uncertain", both[..., 1] != 0.0)]


def _chunk_shape(chunks: Union[None, Integer, Tuple[Integer, Integer]], ny: int, nx: int) -> Tuple[int, int]:
    if chunks is None:
        cols = nx
        rows = max(1, DEFAULT_CHUNK_SIZE // max(1, nx))
        return min(rows, ny), cols
    if isinstance(chunks, (int, np.integer)) and not isinstance(chunks, bool):
        return _positive_int(chunks, "chunks"), nx
    try:
        rows, cols = chunks  # type: ignore[misc,assignment]  # (a bool fails here, as an InputError)
    except (TypeError, ValueError):
        raise InputError(f"chunks must be rows or (rows, columns), got {chunks!r}") from None
    return _positive_int(rows, "chunks[0]"), _positive_int(cols, "chunks[1]")


def _map_grid(chain: Chain, x: npt.ArrayLike, y: npt.ArrayLike, base_theta: Optional[npt.ArrayLike],
              base_omega: Optional[npt.ArrayLike], vary: Vary, zarr: Optional[PathLike]
              ) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64],
                         npt.NDArray[np.float64], Tuple[str, int, str, int], Optional[str]]:
    """A map sweep's grid arguments, checked: ``(x, y, base_theta, base_omega, vary, zarr path)``."""
    if not isinstance(chain, Chain):
        raise InputError(f"chain must be a multipendulum.Chain, got {type(chain).__name__}")
    xs, ys = _grid_axes(x=x, y=y)
    n = chain.n
    th_base = np.zeros(n) if base_theta is None else as_state(base_theta, "base_theta", n)
    om_base = np.zeros(n) if base_omega is None else as_state(base_omega, "base_omega", n)
    if th_base.ndim != 1 or om_base.ndim != 1:
        raise InputError(f"base_theta and base_omega must have shape ({n},)")
    return xs, ys, th_base, om_base, _check_vary(vary, n), _check_zarr_path(zarr)


def sweep_flip_map(chain: Chain, x: npt.ArrayLike, y: npt.ArrayLike, t_max: float = 10.0, dt: float = 0.01,
                   vary: Vary = ("theta", 0, "theta", 1), base_theta: Optional[npt.ArrayLike] = None,
                   base_omega: Optional[npt.ArrayLike] = None, link: Optional[Integer] = None,
                   torque: Optional[TorqueLike] = None, certify: bool = False,
                   time_tolerance: Optional[float] = None, chunks: Union[None, Integer, Tuple[Integer, Integer]] = None,
                   scheduler: Scheduler = None, zarr: Optional[PathLike] = None,
                   progress: Progress = None, *, pivot: Optional[Pivot] = None) -> FlipMap:
    """:func:`multipendulum.flip_map` on Dask, for grids too large for one process.

    Same arguments and the same result (bit for bit) as ``flip_map``, a certified one too
    (``certify``, ``time_tolerance``: its store gets an array ``uncertain`` and the attribute
    ``time_tolerance``); in addition ``chunks``,
    ``scheduler`` and ``zarr`` as for :func:`sweep`. ``chunks`` is a number of rows (of ``y``)
    or ``(rows, columns)``; by default whole rows, about :data:`DEFAULT_CHUNK_SIZE` points per
    chunk. Each task builds its own part of the initial grid from ``x`` and ``y``, so the
    (len(y), len(x), N) array of initial states never exists anywhere.

    With ``zarr``, the store gets arrays ``times`` and ``allowed`` (written chunk by chunk by
    the tasks) plus ``x`` and ``y`` and the attributes ``t_max`` and ``threshold``; the returned
    map's ``times`` and ``allowed`` are then the on-disk Zarr arrays (index them to read a part).
    :func:`open_flip_map` opens such a store again. Without ``zarr`` the whole map is gathered
    here: refused before any task starts when it would not fit in memory (advice: ``zarr``).
    ``progress`` as for :func:`sweep`.
    """
    dask, da = _dask()
    _check_progress(progress)
    x, y, th_base, om_base, vary, path = _map_grid(chain, x, y, base_theta, base_omega, vary, zarr)
    n = chain.n
    threshold = flip_threshold(chain, link, torque, pivot)
    # The arguments checked on no states (and a certified map's tolerance as the core takes it).
    certified = check_certify(certify, time_tolerance)
    if certified:
        tolerance: Optional[float] = certified_flip_times(chain, np.zeros((0, n)), t_max=t_max, dt=dt, link=link,
                                                          torque=torque, time_tolerance=time_tolerance,
                                                          pivot=pivot)[2]
    else:
        tolerance = None
        flip_times(chain, np.zeros((0, n)), t_max=t_max, dt=dt, link=link, torque=torque, pivot=pivot)
    rows, cols = _chunk_shape(chunks, y.size, x.size)
    rows, cols = min(rows, y.size), min(cols, x.size)
    _check_chunks(rows, cols, n, -(-y.size // rows) * -(-x.size // cols))
    if path is None:
        # Gathered here: the times (8 bytes) and flags (1) of every cell, and Dask's pieces of them
        # until they are joined; certified, the uncertain flags (1) and the blocks' stacked pairs (16).
        _core.check_memory(float(x.size) * y.size * (26.0 if certified else 9.0) * 2, f"gathering a flip map of {y.size} x {x.size} cells",
                           "pass zarr=PATH to write it chunk by chunk instead (multipendulum fractal --zarr)")
    Y = da.from_array(y, chunks=rows)
    X = da.from_array(x, chunks=cols)
    block: Dict[str, Any] = dict(chain=chain, vary=vary, th_base=th_base, om_base=om_base, t_max=float(t_max), dt=float(dt),
                 link=link, torque=torque, pivot=pivot)
    energy = functools.partial(_map_allowed_block, chain=chain, vary=vary, th_base=th_base, om_base=om_base,
                               threshold=threshold)
    arrays = _map_arrays(da, Y, X, "times", functools.partial(_map_times_block, **block),
                         functools.partial(_map_certified_block, time_tolerance=time_tolerance, **block)
                         if certified else None)
    arrays.insert(1, ("allowed", da.blockwise(energy, "ij", Y, "i", X, "j", dtype=bool,
                                              meta=np.empty((0, 0), dtype=bool))))
    if path is None:
        with _scheduler(scheduler) as how, reporter(progress, "flip map") as report:
            got = _compute(dask, how, report, *(arr for _, arr in arrays))
        return FlipMap(x, y, got[0], got[1], float(t_max), threshold, got[2] if certified else None, tolerance)
    attrs = {"t_max": float(t_max), "dt": float(dt), "threshold": threshold, "vary": list(vary),
             "base_theta": th_base.tolist(), "base_omega": om_base.tolist(),
             "link": None if link is None else int(link), "chain": chain.to_dict(), "time_tolerance": tolerance}
    with _fresh_store(path, "multipendulum.flip_map", attrs), _scheduler(scheduler) as how, \
            reporter(progress, "flip map") as report:
        stores = [da.to_zarr(arr, path, component=name, compute=False) for name, arr in arrays]
        stores += [da.to_zarr(da.from_array(v, chunks=v.size), path, component=name, compute=False)
                   for name, v in (("x", x), ("y", y))]
        _compute(dask, how, report, *stores)
    return open_flip_map(path)


def _open_store(path: PathLike, kind: str, what: str) -> ZarrGroup:
    """The Zarr group at ``path``, refused unless this package wrote it as ``kind``."""
    try:
        import zarr as _zarr
    except ImportError as exc:
        raise ImportError(f"reading a Zarr store needs the zarr package, which is not installed: {_INSTALL}") from exc
    path = os.fspath(path)
    try:
        group = _zarr.open_group(path, mode="r")
    except Exception as exc:  # zarr raises several kinds for a missing or foreign store
        raise InputError(f"{path}: not a Zarr store ({exc})") from exc
    if group.attrs.get("kind") != kind:
        raise InputError(f"{path}: not {what} written by multipendulum")
    return group


def open_flip_map(path: PathLike) -> FlipMap:
    """A flip-time map written by :func:`sweep_flip_map` (or ``multipendulum fractal --zarr``):
    ``x``, ``y`` read into memory; ``times`` and ``allowed`` left on disk as Zarr arrays."""
    group = _open_store(path, "multipendulum.flip_map", "a flip-time map")
    # The store's members are arrays and its attributes numbers, as sweep_flip_map wrote them; a
    # certified map's also its flags and tolerance.
    tolerance = group.attrs.get("time_tolerance")
    return FlipMap(np.asarray(cast("ZarrArray", group["x"])[:]), np.asarray(cast("ZarrArray", group["y"])[:]),
                   cast("ZarrArray", group["times"]), cast("ZarrArray", group["allowed"]),
                   float(cast(float, group.attrs["t_max"])), float(cast(float, group.attrs["threshold"])),
                   cast("ZarrArray", group["uncertain"]) if tolerance is not None else None,
                   None if tolerance is None else float(cast(float, tolerance)))


# ----------------------------------------------------------------------------------------------
# 3-D flip maps: a third varied value, the grid chunked along all three axes


def _volume_block(zb: npt.NDArray[np.float64], yb: npt.NDArray[np.float64], xb: npt.NDArray[np.float64],
                  chain: Chain, vary: Tuple[str, int, str, int, str, int], th_base: npt.NDArray[np.float64],
                  om_base: npt.NDArray[np.float64], t_max: float, dt: float, link: Optional[Integer],
                  torque: Optional[TorqueLike], pivot: Optional[Pivot], certify: bool, time_tolerance: Optional[float],
                  threshold: float) -> npt.NDArray[np.float64]:
    # A block's times, energy flags and (certified) uncertain flags, as floats along a last axis of 3.
    theta0, omega0 = _grid_of((zb, yb, xb), vary[4:] + vary[2:4] + vary[:2], th_base, om_base)
    if certify:
        times, uncertain, _ = certified_flip_times(chain, theta0, omega0, t_max=t_max, dt=dt, link=link,
                                                   torque=torque, time_tolerance=time_tolerance, pivot=pivot)
    else:
        times = flip_times(chain, theta0, omega0, t_max=t_max, dt=dt, link=link, torque=torque, pivot=pivot)
        uncertain = np.zeros(times.shape, dtype=bool)
    allowed = np.asarray(chain.energy(theta0, omega0) >= threshold)
    return np.stack([times, allowed.astype(np.float64), uncertain.astype(np.float64)], axis=-1)


def sweep_flip_volume(chain: Chain, x: npt.ArrayLike, y: npt.ArrayLike, z: npt.ArrayLike, t_max: float = 10.0,
                      dt: float = 0.01, vary: Vary3 = ("theta", 0, "theta", 1, "theta", 2),
                      base_theta: Optional[npt.ArrayLike] = None, base_omega: Optional[npt.ArrayLike] = None,
                      link: Optional[Integer] = None, torque: Optional[TorqueLike] = None, certify: bool = False,
                      time_tolerance: Optional[float] = None,
                      chunks: Union[None, Integer, Tuple[Integer, Integer, Integer]] = None,
                      scheduler: Scheduler = None, zarr: Optional[PathLike] = None,
                      progress: Progress = None, *, pivot: Optional[Pivot] = None) -> FlipVolume:
    """:func:`multipendulum.flip_volume` on Dask, for 3-D grids too large for one process.

    Same arguments and the same result, bit for bit, as ``flip_volume``; in addition ``chunks``
    (``(kz, ky, kx)`` cells per task, or a number of z-slices; by default whole slices, about
    :data:`DEFAULT_CHUNK_SIZE` cells per chunk), ``scheduler`` and ``zarr`` as for
    :func:`sweep_flip_map`. Each task builds its own part of the grid.

    With ``zarr``, the store gets the arrays ``times``, ``allowed`` (and, certified,
    ``uncertain``), each written chunk by chunk by the tasks, plus ``x``, ``y``, ``z`` and the
    attributes ``t_max``, ``dt``, ``threshold``, ``vary``, ``base_theta``, ``base_omega``,
    ``link``, ``chain`` and ``time_tolerance``; the returned volume's arrays are then the
    on-disk Zarr arrays, and :func:`open_flip_volume` opens the store again. Without ``zarr`` the
    whole volume is gathered here: refused before any task starts when it would not fit in memory.
    """
    dask, da = _dask()
    _check_progress(progress)
    if not isinstance(chain, Chain):
        raise InputError(f"chain must be a multipendulum.Chain, got {type(chain).__name__}")
    n = chain.n
    xs, ys, zs = _grid_axes(x=x, y=y, z=z)
    th_base = np.zeros(n) if base_theta is None else as_state(base_theta, "base_theta", n)
    om_base = np.zeros(n) if base_omega is None else as_state(base_omega, "base_omega", n)
    if th_base.ndim != 1 or om_base.ndim != 1:
        raise InputError(f"base_theta and base_omega must have shape ({n},)")
    vary3 = cast("Tuple[str, int, str, int, str, int]", _check_varied(vary, n, 3))
    path = _check_zarr_path(zarr)
    threshold = flip_threshold(chain, link, torque, pivot)
    certified = check_certify(certify, time_tolerance)
    if certified:
        tolerance: Optional[float] = certified_flip_times(chain, np.zeros((0, n)), t_max=t_max, dt=dt, link=link,
                                                          torque=torque, time_tolerance=time_tolerance,
                                                          pivot=pivot)[2]
    else:
        tolerance = None
        flip_times(chain, np.zeros((0, n)), t_max=t_max, dt=dt, link=link, torque=torque, pivot=pivot)
    kz: int
    if chunks is None:
        plane = ys.size * xs.size
        kz, ky, kx = max(1, DEFAULT_CHUNK_SIZE // plane), max(1, DEFAULT_CHUNK_SIZE // xs.size), xs.size
    elif isinstance(chunks, (int, np.integer)) and not isinstance(chunks, bool):
        kz, ky, kx = _positive_int(chunks, "chunks"), ys.size, xs.size
    else:
        try:
            given = tuple(chunks)  # type: ignore[arg-type]
            if len(given) != 3:
                raise ValueError
        except (TypeError, ValueError):
            raise InputError(f"chunks must be z-slices or (kz, ky, kx), got {chunks!r}") from None
        kz, ky, kx = (_positive_int(v, f"chunks[{i}]") for i, v in enumerate(given))
    kz, ky, kx = min(kz, zs.size), min(ky, ys.size), min(kx, xs.size)
    count = -(-zs.size // kz) * -(-ys.size // ky) * -(-xs.size // kx)
    _check_chunks(kz * ky, kx, n, count)
    cells = float(xs.size) * ys.size * zs.size
    if path is None:
        # Gathered here: times (8 bytes) and flags (1 + 1) of every cell, and the blocks' stacked
        # triples (24) until they are split.
        _core.check_memory(cells * 34.0 * 2, f"gathering a flip volume of {zs.size} x {ys.size} x {xs.size} cells",
                           "pass zarr=PATH to write it chunk by chunk instead")
    Z, Y, X = da.from_array(zs, chunks=kz), da.from_array(ys, chunks=ky), da.from_array(xs, chunks=kx)
    kernel = functools.partial(_volume_block, chain=chain, vary=vary3, th_base=th_base, om_base=om_base,
                               t_max=float(t_max), dt=float(dt), link=link, torque=torque, pivot=pivot,
                               certify=certified,
                               time_tolerance=time_tolerance, threshold=threshold)
    both = da.blockwise(kernel, "kijl", Z, "k", Y, "i", X, "j", new_axes={"l": 3}, dtype=np.float64,
                        meta=np.empty((0, 0, 0, 0)))
    arrays: List[Tuple[str, Any]] = [("times", both[..., 0]), ("allowed", both[..., 1] != 0.0)]
    if certified:
        arrays.append(("uncertain", both[..., 2] != 0.0))
    if path is None:
        with _scheduler(scheduler) as how, reporter(progress, "flip volume") as report:
            got = _compute(dask, how, report, *(arr for _, arr in arrays))
        return FlipVolume(xs, ys, zs, got[0], got[1], float(t_max), threshold, vary3,
                          got[2] if certified else None, tolerance)
    attrs = {"t_max": float(t_max), "dt": float(dt), "threshold": threshold, "vary": list(vary3),
             "base_theta": th_base.tolist(), "base_omega": om_base.tolist(),
             "link": None if link is None else int(link), "chain": chain.to_dict(), "time_tolerance": tolerance}
    with _fresh_store(path, "multipendulum.flip_volume", attrs), _scheduler(scheduler) as how, \
            reporter(progress, "flip volume") as report:
        stores = [da.to_zarr(arr, path, component=name, compute=False) for name, arr in arrays]
        stores += [da.to_zarr(da.from_array(v, chunks=v.size), path, component=name, compute=False)
                   for name, v in (("x", xs), ("y", ys), ("z", zs))]
        _compute(dask, how, report, *stores)
    return open_flip_volume(path)


def open_flip_volume(path: PathLike) -> FlipVolume:
    """A 3-D flip map written by :func:`sweep_flip_volume` (or ``multipendulum fractal --z ...
    --zarr``): ``x``, ``y``, ``z`` read into memory; ``times``, ``allowed`` (and ``uncertain``)
    left on disk as Zarr arrays, read a slice at a time by ``FlipVolume.slice``."""
    group = _open_store(path, "multipendulum.flip_volume", "a 3-D flip map")
    tolerance = group.attrs.get("time_tolerance")
    read = lambda name: np.asarray(cast("ZarrArray", group[name])[:])  # noqa: E731
    vary = tuple(cast(list, group.attrs["vary"]))
    return FlipVolume(read("x"), read("y"), read("z"), cast("ZarrArray", group["times"]),
                      cast("ZarrArray", group["allowed"]), float(cast(float, group.attrs["t_max"])),
                      float(cast(float, group.attrs["threshold"])),
                      cast("Tuple[str, int, str, int, str, int]", vary),
                      cast("ZarrArray", group["uncertain"]) if tolerance is not None else None,
                      None if tolerance is None else float(cast(float, tolerance)))


# ----------------------------------------------------------------------------------------------
# Chaos-indicator maps: as flip-time maps, each task building its own part of the grid


def _map_indicator_block(yb: npt.NDArray[np.float64], xb: npt.NDArray[np.float64], chain: Chain,
                         vary: Tuple[str, int, str, int], th_base: npt.NDArray[np.float64],
                         om_base: npt.NDArray[np.float64], t_end: float, indicator: str, k: Optional[Integer],
                         dt: float, torque: Optional[TorqueLike], pivot: Optional[Pivot]) -> npt.NDArray[np.float64]:
    theta0, omega0 = _grid(yb, xb, vary, th_base, om_base)
    return cast("npt.NDArray[np.float64]",  # a batch: the values at t_end, shape (rows, columns)
                indicator_fn(chain, theta0, omega0, t_end, indicator, k=k, dt=dt, torque=torque, pivot=pivot))


def _map_certified_indicator_block(yb: npt.NDArray[np.float64], xb: npt.NDArray[np.float64], chain: Chain,
                                   vary: Tuple[str, int, str, int], th_base: npt.NDArray[np.float64],
                                   om_base: npt.NDArray[np.float64], t_end: float, indicator: str,
                                   k: Optional[Integer], dt: float, torque: Optional[TorqueLike],
                                   pivot: Optional[Pivot], threshold: Optional[float]) -> npt.NDArray[np.float64]:
    # A certified block's values and uncertain flags (as 0 or 1) along a last axis of 2.
    theta0, omega0 = _grid(yb, xb, vary, th_base, om_base)
    values, uncertain, _ = certified_indicator(chain, theta0, omega0, t_end, indicator, k=k, dt=dt, torque=torque,
                                               threshold=threshold, pivot=pivot)
    return np.stack([values, uncertain.astype(np.float64)], axis=-1)


def sweep_indicator_map(chain: Chain, x: npt.ArrayLike, y: npt.ArrayLike, t_end: float = 50.0,
                        indicator: str = "megno", k: Optional[Integer] = None, dt: float = 0.005,
                        vary: Vary = ("theta", 0, "theta", 1), base_theta: Optional[npt.ArrayLike] = None,
                        base_omega: Optional[npt.ArrayLike] = None, torque: Optional[TorqueLike] = None,
                        certify: bool = False, threshold: Optional[float] = None,
                        chunks: Union[None, Integer, Tuple[Integer, Integer]] = None, scheduler: Scheduler = None,
                        zarr: Optional[PathLike] = None, progress: Progress = None, *,
                        pivot: Optional[Pivot] = None) -> IndicatorMap:
    """:func:`multipendulum.indicator_map` on Dask, for grids too large for one process.

    Same arguments and the same result (bit for bit: each cell's value does not depend on what
    is computed with it) as ``indicator_map``, a certified one too (``certify``, ``threshold``:
    its store gets an array ``uncertain`` and the attribute ``threshold``); in addition
    ``chunks``, ``scheduler`` and ``zarr`` as for :func:`sweep_flip_map`. Each task builds its own part of the initial grid from ``x``
    and ``y`` and calls :func:`multipendulum.indicator` on it.

    The arguments (``indicator``, ``k``, ``t_end``, ``dt``, ``torque``) are checked before any task
    starts, by the indicator of the base state alone (one trajectory's work).

    With ``zarr``, the store gets the array ``values`` (written chunk by chunk by the tasks) plus
    ``x`` and ``y`` and the attributes ``indicator``, ``k``, ``t_end``, ``dt``, ``vary``,
    ``base_theta``, ``base_omega`` and ``chain``; the returned map's ``values`` is then the on-disk
    Zarr array (index it to read a part). :func:`open_indicator_map` opens such a store again.
    Without ``zarr`` the whole map is gathered here: refused before any task starts when it
    would not fit in memory (advice: ``zarr``). ``progress`` as for :func:`sweep`.

    >>> import numpy as np, multipendulum as mp
    >>> from multipendulum.sweeps import sweep_indicator_map
    >>> chain, x = mp.Chain([1, 1], [1, 1]), np.linspace(-2.5, 2.5, 6)
    >>> m = sweep_indicator_map(chain, x, x, t_end=5.0, chunks=(4, 3))
    >>> bool(np.array_equal(m.values, mp.indicator_map(chain, x, x, t_end=5.0).values))
    True
    """
    dask, da = _dask()
    _check_progress(progress)
    x, y, th_base, om_base, vary, path = _map_grid(chain, x, y, base_theta, base_omega, vary, zarr)
    n = chain.n
    # Checks, here rather than in every task: the core refuses an empty batch after checking the
    # arguments, so one state (the base state, as a batch of one: no history) is run instead.
    certified = check_certify(certify, threshold, "threshold")
    used: Optional[float] = None
    if certified:
        # (and the threshold as the core takes it)
        used = certified_indicator(chain, th_base[None], om_base[None], t_end, indicator, k=k, dt=dt, torque=torque,
                                   threshold=threshold, pivot=pivot)[2]
    else:
        indicator_fn(chain, th_base[None], om_base[None], t_end, indicator, k=k, dt=dt, torque=torque, pivot=pivot)
    rows, cols = _chunk_shape(chunks, y.size, x.size)
    rows, cols = min(rows, y.size), min(cols, x.size)
    _check_chunks(rows, cols, n, -(-y.size // rows) * -(-x.size // cols))
    if path is None:
        # Gathered here: the value (8 bytes) of every cell, and Dask's pieces of them until joined;
        # certified, the uncertain flags (1) and the blocks' stacked pairs (16).
        _core.check_memory(float(x.size) * y.size * (25.0 if certified else 8.0) * 2,
                           f"gathering an indicator map of {y.size} x {x.size} cells",
                           "pass zarr=PATH to write it chunk by chunk instead (multipendulum atlas --zarr)")
    Y = da.from_array(y, chunks=rows)
    X = da.from_array(x, chunks=cols)
    block: Dict[str, Any] = dict(chain=chain, vary=vary, th_base=th_base, om_base=om_base, t_end=float(t_end),
                                 indicator=indicator, k=k, dt=float(dt), torque=torque, pivot=pivot)
    arrays = _map_arrays(da, Y, X, "values", functools.partial(_map_indicator_block, **block),
                         functools.partial(_map_certified_indicator_block, threshold=threshold, **block)
                         if certified else None)
    label = f"{indicator} map"
    k_ = None if k is None else int(k)
    if path is None:
        with _scheduler(scheduler) as how, reporter(progress, label) as report:
            got = _compute(dask, how, report, *(arr for _, arr in arrays))
        return IndicatorMap(x, y, got[0], indicator, float(t_end), k_, got[1] if certified else None, used)
    attrs = {"indicator": indicator, "k": k_, "t_end": float(t_end), "dt": float(dt),
             "vary": list(vary), "base_theta": th_base.tolist(), "base_omega": om_base.tolist(),
             "chain": chain.to_dict(), "threshold": used}
    with _fresh_store(path, "multipendulum.indicator_map", attrs), _scheduler(scheduler) as how, \
            reporter(progress, label) as report:
        stores = [da.to_zarr(arr, path, component=name, compute=False) for name, arr in arrays]
        stores += [da.to_zarr(da.from_array(v, chunks=v.size), path, component=name, compute=False)
                   for name, v in (("x", x), ("y", y))]
        _compute(dask, how, report, *stores)
    return open_indicator_map(path)


def open_indicator_map(path: PathLike) -> IndicatorMap:
    """A chaos-indicator map written by :func:`sweep_indicator_map` (or ``multipendulum atlas
    --zarr``): ``x``, ``y`` read into memory; ``values`` left on disk as a Zarr array. The store's
    attributes (``k``, ``dt``, ``vary``, the chain...) are in ``zarr.open_group(path).attrs``."""
    group = _open_store(path, "multipendulum.indicator_map", "a chaos-indicator map")
    k = group.attrs.get("k")
    # A certified map's flags and threshold too (stores of earlier versions have no threshold).
    threshold = group.attrs.get("threshold")
    return IndicatorMap(np.asarray(cast("ZarrArray", group["x"])[:]), np.asarray(cast("ZarrArray", group["y"])[:]),
                        cast("ZarrArray", group["values"]), str(group.attrs["indicator"]),
                        float(cast(float, group.attrs["t_end"])), None if k is None else int(cast(int, k)),
                        cast("ZarrArray", group["uncertain"]) if threshold is not None else None,
                        None if threshold is None else float(cast(float, threshold)))
