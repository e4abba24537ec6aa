"""Sweeps on Dask: chunked flip times and flip maps equal the single-process results bit for bit,
on the local schedulers, on a two-process dask.distributed cluster and through Zarr."""
import importlib.util
import signal
import sys
import time

import numpy as np
import pytest

import multipendulum as mp

pytest.importorskip("dask.array")

DOUBLE = mp.Chain(lengths=[1.0, 1.0], masses=[1.0, 1.0])
RODS3 = mp.Chain.rods(lengths=[1.0, 0.8, 0.6], masses=[1.0, 0.8, 0.6])


@pytest.mark.parametrize("scheduler", [None, "threads", "sync"])
def test_sweep_equals_flip_times_for_any_chunking(scheduler):
    rng = np.random.default_rng(7)
    th0 = rng.uniform(-3, 3, (37, 5, 3))  # a 2-D batch; 37 rows do not divide into chunks of 8
    om0 = rng.uniform(-1, 1, (37, 5, 3))
    single = mp.flip_times(RODS3, th0, om0, t_max=3.0, dt=0.01)
    out = mp.sweep(RODS3, th0, om0, t_max=3.0, dt=0.01, chunks=8, scheduler=scheduler)
    assert out.shape == (37, 5)
    assert np.isfinite(single).any() and np.isinf(single).any()  # the comparison covers both kinds
    np.testing.assert_array_equal(out, single)


def test_sweep_passes_link_and_torque_through():
    th0 = np.random.default_rng(1).uniform(-3, 3, (40, 2))
    drive = mp.Sinusoid([2.0, 0.0], [3.0, 0.0])
    for kw in ({"link": 0}, {"link": 1}, {"torque": drive}):
        np.testing.assert_array_equal(mp.sweep(DOUBLE, th0, t_max=3.0, chunks=9, **kw),
                                      mp.flip_times(DOUBLE, th0, t_max=3.0, **kw))
    # and they matter: link 0 alone flips less often than any link
    assert np.isinf(mp.sweep(DOUBLE, th0, t_max=3.0, link=0)).sum() > np.isinf(mp.sweep(DOUBLE, th0, t_max=3.0)).sum()


def test_sweep_flip_map_equals_flip_map_exactly_with_two_dimensional_chunks():
    x = np.linspace(-np.pi, np.pi, 41)
    y = np.linspace(-np.pi, np.pi, 29)
    ref = mp.flip_map(DOUBLE, x, y, t_max=4.0)
    fm = mp.sweep_flip_map(DOUBLE, x, y, t_max=4.0, chunks=(6, 16))
    np.testing.assert_array_equal(fm.times, ref.times)
    np.testing.assert_array_equal(fm.allowed, ref.allowed)
    assert (fm.threshold, fm.t_max) == (ref.threshold, ref.t_max)
    np.testing.assert_array_equal(fm.x, x)
    np.testing.assert_array_equal(fm.y, y)


def test_sweep_flip_map_with_omega_and_a_base_state():
    x = np.linspace(-1, 1, 15)
    y = np.linspace(-8, 8, 13)
    kw = dict(t_max=3.0, vary=("theta", 1, "omega", 0), base_theta=[0.5, 0.0], base_omega=[0.0, 1.0])
    ref = mp.flip_map(DOUBLE, x, y, **kw)
    fm = mp.sweep_flip_map(DOUBLE, x, y, chunks=4, **kw)
    np.testing.assert_array_equal(fm.times, ref.times)
    np.testing.assert_array_equal(fm.allowed, ref.allowed)
    assert not ref.allowed.all() and ref.allowed.any()


def test_zarr_output_is_written_chunk_by_chunk_and_reads_back(tmp_path):
    zarr = pytest.importorskip("zarr")
    x = np.linspace(-np.pi, np.pi, 33)
    ref = mp.flip_map(DOUBLE, x, x, t_max=3.0)
    fm = mp.sweep_flip_map(DOUBLE, x, x, t_max=3.0, chunks=(8, 11), zarr=tmp_path / "map.zarr")
    assert not isinstance(fm.times, np.ndarray)  # left on disk
    assert tuple(fm.times.chunks) == (8, 11)
    np.testing.assert_array_equal(fm.times[:], ref.times)
    np.testing.assert_array_equal(fm.allowed[:], ref.allowed)
    again = mp.open_flip_map(tmp_path / "map.zarr")
    np.testing.assert_array_equal(again.times[:], ref.times)
    assert again.threshold == ref.threshold and again.t_max == 3.0
    # a second run into the same store replaces it (no stale chunks from a bigger first run)
    small = mp.sweep_flip_map(DOUBLE, x[:5], x[:4], t_max=3.0, zarr=tmp_path / "map.zarr")
    assert small.times.shape == (4, 5)
    # plain sweeps write one array
    th0 = np.random.default_rng(2).uniform(-3, 3, (50, 2))
    arr = mp.sweep(DOUBLE, th0, t_max=2.0, chunks=20, zarr=tmp_path / "t.zarr")
    assert isinstance(arr, zarr.Array) and tuple(arr.chunks) == (20,)
    np.testing.assert_array_equal(arr[:], mp.flip_times(DOUBLE, th0, t_max=2.0))


def test_zarr_never_wipes_a_foreign_directory_and_a_failed_run_leaves_no_store(tmp_path, monkeypatch):
    pytest.importorskip("zarr")
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    x = np.linspace(-1, 1, 8)
    with pytest.raises(mp.InputError, match="exists and is not a store written by multipendulum"):
        mp.sweep_flip_map(DOUBLE, x, x, t_max=1.0, zarr=foreign)
    with pytest.raises(mp.InputError, match="exists and is not a store written by multipendulum"):
        mp.sweep(DOUBLE, np.zeros((3, 2)), t_max=1.0, zarr=foreign)
    assert (foreign / "notes.txt").read_text() == "keep me"

    import multipendulum.sweeps as sweep_module

    real = sweep_module.flip_times

    def failing(chain, theta, *args, **kwargs):
        if np.size(theta) and np.asarray(theta)[..., 0].max() > 0.5:  # one chunk of the grid fails
            raise mp.IntegrationError("boom")
        if np.size(theta):
            time.sleep(0.3)  # while the others are still running, and write after the failure
        return real(chain, theta, *args, **kwargs)

    monkeypatch.setattr(sweep_module, "flip_times", failing)
    with pytest.raises(mp.IntegrationError, match="boom"):
        mp.sweep_flip_map(DOUBLE, x, x, t_max=1.0, chunks=(4, 4), zarr=tmp_path / "half.zarr")
    time.sleep(0.5)  # any task still running would have written by now
    assert not (tmp_path / "half.zarr").exists()


def test_a_two_process_distributed_cluster_gives_the_single_process_map_exactly(tmp_path):
    distributed = pytest.importorskip("distributed")
    x = np.linspace(-np.pi, np.pi, 64)
    ref = mp.flip_map(DOUBLE, x, x, t_max=3.0)
    # A cluster that cannot start or a lost worker must fail the test, not hang it.
    previous = signal.signal(signal.SIGALRM, _timeout) if hasattr(signal, "SIGALRM") else None
    if previous is not None:
        signal.alarm(120)
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=None, worker_dashboard_address=None)
    try:
        address = cluster.scheduler_address
        seen = []  # progress on a cluster: the chunks counted as their results arrive
        fm = mp.sweep_flip_map(DOUBLE, x, x, t_max=3.0, chunks=8, scheduler=address, progress=seen.append)
        assert len(seen) >= 8 and seen == sorted(seen) and seen[-1] == 1.0
        np.testing.assert_array_equal(fm.times, ref.times)
        np.testing.assert_array_equal(fm.allowed, ref.allowed)
        # Both worker processes did some of the work.
        with distributed.Client(address, set_as_default=False) as client:
            done = client.run(lambda dask_worker: len(dask_worker.data) + dask_worker.state.executed_count)
            assert len(done) == 2 and all(count > 0 for count in done.values())
            # A client object works too, and so does writing to Zarr from the workers.
            if importlib.util.find_spec("zarr") is not None:
                fz = mp.sweep_flip_map(DOUBLE, x, x, t_max=3.0, chunks=16, scheduler=client,
                                       zarr=tmp_path / "d.zarr")
                np.testing.assert_array_equal(fz.times[:], ref.times)
    finally:
        cluster.close()
        if previous is not None:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, previous)


def _timeout(signum, frame):
    raise TimeoutError("the two-worker Dask cluster did not finish within 120 s")


def test_bad_sweep_input():
    th0 = np.zeros((4, 2))
    with pytest.raises(mp.InputError, match="scheduler must be None, 'threads', 'sync', 'processes', a dask"):
        mp.sweep(DOUBLE, th0, scheduler="thread")
    with pytest.raises(mp.InputError, match="chunks must be a positive integer, got 0"):
        mp.sweep(DOUBLE, th0, chunks=0)
    with pytest.raises(mp.InputError, match=r"theta0 must have a batch axis, shape \(B, \.\.\., 2\), got \(2,\)"):
        mp.sweep(DOUBLE, [0.1, 0.2])
    with pytest.raises(mp.InputError, match=r"vary must name \('theta'\|'omega', link index < 2\) twice"):
        mp.sweep_flip_map(DOUBLE, [0, 1], [0, 1], vary=("theta", 0, "p", 1))
    with pytest.raises(mp.InputError, match="vary must name two different quantities"):
        mp.sweep_flip_map(DOUBLE, [0, 1], [0, 1], vary=("theta", 0, "theta", 0))
    with pytest.raises(mp.InputError, match=r"link must be an integer in \[0, 2\) or None"):
        mp.sweep_flip_map(DOUBLE, [0, 1], [0, 1], link=5)
    with pytest.raises(mp.InputError, match="t_max must be > 0 and finite, got -1"):
        mp.sweep(DOUBLE, th0, t_max=-1.0)  # refused before any task runs
    with pytest.raises(mp.InputError, match="dt must be > 0 and finite, got 0"):
        mp.sweep_flip_map(DOUBLE, [0, 1], [0, 1], dt=0.0)
    with pytest.raises(mp.InputError, match="not a Zarr store|not a flip-time map"):
        mp.open_flip_map("/nonexistent/map.zarr")


def test_missing_dask_is_a_clear_import_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "dask", None)
    monkeypatch.setitem(sys.modules, "dask.array", None)
    with pytest.raises(ImportError, match=r"need Dask, which is not installed: pip install 'multipendulum\[dask\]'"):
        mp.sweep(DOUBLE, np.zeros((3, 2)))
