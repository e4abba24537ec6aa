"""Feedback on long work: the progress helper (multipendulum._progress), progress=True and
callables in Python calls, and the command line's bars with the time remaining."""
import io
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp
from multipendulum import _progress
from multipendulum.cli import main

DOUBLE = mp.Chain([1.0, 1.0], [1.0, 1.0])
ROOT = Path(__file__).resolve().parents[1]


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_progress_true_is_tqdm_when_installed_else_the_packages_own_bar(monkeypatch):
    tqdm = pytest.importorskip("tqdm")
    bar = _progress.make(True, "work")
    try:
        assert isinstance(bar.bar, tqdm.tqdm)
    finally:
        bar.close()
    monkeypatch.setattr(_progress, "_tqdm", lambda: None)  # as if tqdm were not installed
    stream = io.StringIO()  # not a terminal: progress=True asked for it, so it is shown anyway
    bar = _progress.make(True, "work", stream=stream)
    assert isinstance(bar, _progress.TextBar)
    bar.delay = 0.0
    bar(0.25)
    time.sleep(0.12)
    bar(1.0)
    bar.close()
    text = stream.getvalue()
    assert "\rwork [" in text and "100.0%" in text and text.endswith("\n")
    assert _progress.make(None) is None and _progress.make(False) is None


def test_a_callable_passes_through_and_anything_else_is_refused():
    seen = []
    with _progress.reporter(seen.append, "x") as report:
        report(0.5)
    assert seen == [0.5, 1.0]  # completed on success
    seen.clear()
    with pytest.raises(RuntimeError):
        with _progress.reporter(seen.append) as report:
            report(0.3)
            raise RuntimeError
    assert seen == [0.3]  # not completed on failure
    with _progress.reporter(None) as report:
        assert report is None
    for bad in ("yes", 3, [1]):
        with pytest.raises(mp.InputError, match="progress must be True, False, None or a callable"):
            with _progress.reporter(bad):
                pass


def test_the_text_bar_shows_the_time_remaining():
    tty = _Tty()
    bar = _progress.TextBar("map", stream=tty, delay=0.0)
    bar(0.0)
    time.sleep(0.2)
    bar(0.5)
    bar.close()
    last = tty.getvalue().split("\r")[-1]
    assert "50.0%" in last and "s left" in last, last
    assert _progress.format_seconds(4.25) == "4.2 s" and _progress.format_seconds(185) == "3 min 05 s"
    assert _progress.format_seconds(7380) == "2 h 03 min"


def test_steps_count_pieces_from_many_threads_once_each():
    seen = []
    steps = _progress.Steps(seen.append, total=400)
    threads = [threading.Thread(target=lambda: [steps.add() for _ in range(100)]) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert steps.done == 400 and seen[-1] == 1.0
    assert seen == sorted(seen) and len(seen) == 400
    part = _progress.scaled(seen.append, 0.5, 0.75)
    part(0.5)
    assert seen[-1] == 0.625
    assert _progress.scaled(None, 0, 1) is None


@pytest.mark.parametrize("scheduler", [None, "sync"])
def test_sweeps_report_their_progress(scheduler):
    pytest.importorskip("dask.array")
    x = np.linspace(-3, 3, 24)
    seen = []
    fm = mp.sweep_flip_map(DOUBLE, x, x, t_max=1.0, chunks=4, scheduler=scheduler, progress=seen.append)
    np.testing.assert_array_equal(fm.times, mp.flip_map(DOUBLE, x, x, t_max=1.0).times)
    assert len(seen) >= 6 and seen == sorted(seen) and seen[-1] == 1.0 and 0 < seen[0] < 1
    seen.clear()
    th0 = np.random.default_rng(0).uniform(-3, 3, (60, 2))
    mp.sweep(DOUBLE, th0, t_max=1.0, chunks=10, scheduler=scheduler, progress=seen.append)
    assert len(seen) >= 6 and seen[-1] == 1.0
    with pytest.raises(mp.InputError, match="progress must be"):
        mp.sweep(DOUBLE, th0, progress="yes")


def test_scenario_run_and_animate_take_progress_true(tmp_path, capsys):
    from multipendulum.scenario import loads_scenario

    scenario = loads_scenario("""
[chain]
lengths = [1.0, 1.0]
masses = [1.0, 1.0]
[initial]
unit = "degrees"
theta = [120.0, 10.0]
[simulation]
t_end = 0.5
""")
    sol = scenario.run(progress=True)  # was: "progress must be callable"
    assert sol.t[-1] == 0.5
    seen = []
    scenario.run(progress=seen.append)
    assert seen[-1] == 1.0
    mp.animate(sol, tmp_path / "a.gif", fps=10, dpi=20, progress=True)
    assert "100%" in capsys.readouterr().err


def test_the_fractal_command_shows_progress_with_the_time_remaining(tmp_path, monkeypatch):
    import multipendulum.cli as cli

    tty = _Tty()
    monkeypatch.setattr(cli, "ProgressBar", lambda label, quiet=False: _progress.TextBar(
        label, stream=tty, delay=0.0, quiet=quiet))
    scenario = tmp_path / "double.toml"
    scenario.write_text((ROOT / "python" / "multipendulum" / "data" / "default.toml").read_text())
    out = tmp_path / "map.png"
    assert main(["fractal", str(scenario), "-o", str(out), "--size", "200", "--t-max", "2", "--dpi", "40"]) == 0
    shown = tty.getvalue().split("\r")
    assert any(s.startswith("flip map [") and "s left" in s for s in shown), shown
    assert "100.0%" in shown[-1] and tty.getvalue().endswith("\n")
    assert out.exists()
