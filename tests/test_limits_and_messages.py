"""Limits enforced before the work starts on every Python path (the command line, scenario
sampling, flip maps and sweeps), and messages that name the file, the key and the value in the
file's own units."""
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp
from multipendulum.cli import main
from multipendulum.scenario import ScenarioError, loads_scenario

ROOT = Path(__file__).resolve().parents[1]
DOUBLE = mp.Chain([1.0, 1.0], [1.0, 1.0])

BASE = """
[chain]
lengths = [1.0, 1.0]
masses = [1.0, 1.0]
[initial]
unit = "degrees"
theta = [120.0, 10.0]
[simulation]
t_end = 1.0
"""


def _edit(old, new, base=BASE):
    assert old in base
    return base.replace(old, new)


def _fresh_process(code: str, timeout: float = 120):
    """Run ``code`` in a new interpreter (its peak memory is its own) and return its stdout."""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout,
                          cwd=ROOT, env=dict(os.environ, MPLBACKEND="Agg"))
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


# ---------------------------------------------------------------------------------------------
# Limits before the work starts


@pytest.mark.parametrize("t_end", ["5e6", "1e12"])
def test_a_huge_t_end_on_the_command_line_is_refused_at_once_with_advice(tmp_path, t_end):
    scenario = tmp_path / "base.toml"
    scenario.write_text(BASE)
    out = tmp_path / "out"
    # In a fresh process, so that its peak memory (ru_maxrss) says what the refusal cost.
    report = _fresh_process(f"""
import resource, sys, time, io, contextlib
from multipendulum.cli import main
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
err = io.StringIO()
start = time.perf_counter()
with contextlib.redirect_stderr(err):
    code = main(["run", {str(scenario)!r}, "-o", {str(out)!r}, "--t-end", {t_end!r}])
print(code, time.perf_counter() - start, (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024)
print(err.getvalue())
""")
    first, message = report.split("\n", 1)
    code, seconds, grown_mib = first.split()
    assert int(code) == 1
    assert float(seconds) < 2.0 and float(grown_mib) < 50, report  # nothing was allocated for it
    assert message.startswith(f"multipendulum: error: {scenario}: key 'simulation.sample_dt': storing "
                              f"{float(t_end) / 0.01 + 1:.4g} samples of 2 links needs "), message
    assert ("raise simulation.sample_dt (now 0.01 s between samples) or shorten the run "
            f"(--t-end {float(t_end):g} on the command line)") in message
    assert "Traceback" not in message and not out.exists()


@pytest.mark.parametrize("text, key, fragment", [
    (_edit("t_end = 1.0", "t_end = 1.0\nsample_dt = 1e-12"), "simulation.sample_dt",
     "storing 1e+12 samples of 2 links needs "),
    (_edit("t_end = 1.0", 't_end = 1e30\nmethod = "rk4"\ndt = 1.0\nsample_dt = 1e29'), "simulation.dt",
     "rk4 with dt = 1 s takes 1e+30 steps to reach t_end = 1e+30 s, more than the 1e+08 steps a run may take"),
    (_edit("t_end = 1.0", 't_end = 1e12\nmethod = "gauss6"\ndt = 1e-12'), "simulation.dt",
     "gauss6 with dt = 1e-12 s takes 1e+24 steps"),
])
def test_scenarios_that_would_not_fit_are_refused_before_the_run(text, key, fragment):
    scenario = loads_scenario(text)  # the viewer and flip maps may still take its chain
    start = time.perf_counter()
    with pytest.raises(ScenarioError) as info:
        scenario.run()
    assert time.perf_counter() - start < 2.0
    assert info.value.key == key and fragment in str(info.value), str(info.value)
    assert "1.845e19" not in str(info.value)  # never a saturated 2^64 step count


def test_a_replaced_t_end_is_checked_again():
    scenario = loads_scenario(BASE)
    longer = scenario.replace(t_end=1e12)
    for check in (longer.check_limits, longer.t_eval, longer.simulate_kwargs, longer.run):
        with pytest.raises(ScenarioError, match=r"key 'simulation\.sample_dt': storing 1e\+14 samples"):
            check()
    for bad in (float("inf"), float("nan")):
        with pytest.raises(ScenarioError, match=r"key 'simulation\.t_end': must be finite, got (inf|nan)"):
            scenario.replace(t_end=bad)


@pytest.mark.parametrize("value, message", [("inf", "--t-end must be finite, got inf"),
                                            ("-1", "--t-end must be > 0, got -1")])
def test_the_command_line_names_its_own_options(tmp_path, capsys, value, message):
    scenario = tmp_path / "base.toml"
    scenario.write_text(BASE)
    assert main(["run", str(scenario), "-o", str(tmp_path / "out"), f"--t-end={value}"]) == 1
    assert capsys.readouterr().err == f"multipendulum: error: {message}\n"


def test_fractal_maps_that_would_not_fit_or_finish_are_refused_with_the_commands_advice(tmp_path, capsys):
    scenario = tmp_path / "base.toml"
    scenario.write_text(BASE)
    out = tmp_path / "map.png"
    cases = [
        (["--size", "100000"], "a flip-time map of 100000 x 100000 initial states needs",
         "use a smaller --size, or --zarr PATH"),
        (["--size", "4096", "--t-max", "1e6"], "is up to 1.68e+15 rk4 steps, more than the 1e+12",
         "--dask ADDRESS"),
        (["--dpi", "1e6"], "(--dpi = 1e+06) is larger than 16384 a side", "lower --dpi"),
    ]
    for extra, what, advice in cases:
        start = time.perf_counter()
        assert main(["fractal", str(scenario), "-o", str(out), "-q"] + extra) == 1
        err = capsys.readouterr().err
        assert what in err and advice in err, err
        assert time.perf_counter() - start < 5.0 and not out.exists()


def test_a_sweep_too_large_to_gather_is_refused_before_any_task_runs(monkeypatch):
    pytest.importorskip("dask.array")
    import multipendulum.sweeps as sweeps

    def no_task(chain, theta0, *args, **kwargs):
        if np.size(theta0):  # the argument checks run on no states; a task has some
            raise AssertionError("a task started")
        return mp.flip_times(chain, theta0, *args, **kwargs)

    monkeypatch.setattr(sweeps, "flip_times", no_task)
    if hasattr(signal, "SIGALRM"):  # a refusal is immediate; scheduling 10^10 cells would not be
        previous = signal.signal(signal.SIGALRM, _too_slow)
        signal.alarm(30)
    try:
        _refused_sweeps()
    finally:
        if hasattr(signal, "SIGALRM"):
            signal.alarm(0)
            signal.signal(signal.SIGALRM, previous)


def _too_slow(signum, frame):
    raise TimeoutError("not refused within 30 s: the sweep was scheduled")


def _refused_sweeps():
    x = np.linspace(-3, 3, 100_000)
    with pytest.raises(mp.InputError, match=r"^gathering a flip map of 100000 x 100000 cells needs [0-9.]+ GiB "
                                            r".*pass zarr=PATH to write it chunk by chunk"):
        mp.sweep_flip_map(DOUBLE, x, x, t_max=1.0)
    with pytest.raises(mp.InputError, match=r"chunks of 100000 x 100000 initial states at once needs .*smaller chunks"):
        mp.sweep_flip_map(DOUBLE, x, x, t_max=1.0, chunks=(100_000, 100_000), zarr="never-written.zarr")
    assert not os.path.exists("never-written.zarr")


def test_plots_refuse_a_resolution_that_would_not_fit(tmp_path):
    sol = mp.simulate(DOUBLE, [1.0, 1.0], [0, 0], 0.2)
    with pytest.raises(mp.InputError, match=r"plots at dpi = 1e\+06 would be 7000000 x 4200000 pixels"):
        mp.plot(sol, tmp_path, dpi=1e6)
    assert os.listdir(tmp_path) == []


# ---------------------------------------------------------------------------------------------
# Messages: the file, the key, the value in the file's own units, numbers written compactly


@pytest.mark.parametrize("text, key, message", [
    (_edit("theta = [120.0, 10.0]", "theta = [1e300, 10.0]"), "initial.theta[0]",
     "must be within +-5.73e+16 degrees (1e15 rad), got 1e+300"),
    (_edit('"degrees"', '"radians"', _edit("theta = [120.0, 10.0]", "theta = [1.0, -2e15]")), "initial.theta[1]",
     "must be within +-1e+15 radians (1e15 rad), got -2e+15"),
    (_edit("theta = [120.0, 10.0]", "theta = { from = 0.0, to = 1e17 }"), "initial.theta.to",
     "must be within +-5.73e+16 degrees"),
    (_edit("t_end = 1.0", "t_end = 1.0\nrtol = 1e-20"), "simulation.rtol", "must be >= 1e-15 (dop853's error estimate "
     "is round-off below it), got 1e-20"),
    (_edit("t_end = 1.0", "t_end = inf"), "simulation.t_end", "must be finite, got inf"),
    (_edit("t_end = 1.0", "t_end = 1.0\nsample_dt = inf"), "simulation.sample_dt", "must be finite, got inf"),
    (_edit("masses = [1.0, 1.0]", "masses = [1.0, 1.0]\ng = 1e308"), "chain",
     "g = 1e+308 with these masses and lengths overflows"),
])
def test_scenario_messages_name_the_key_and_the_value_as_the_file_wrote_it(tmp_path, capsys, text, key, message):
    with pytest.raises(ScenarioError) as info:
        loads_scenario(text)
    assert info.value.key == key and message in str(info.value), str(info.value)
    assert not re.search(r"\d{13,}|0\.0{6,}", str(info.value))  # no 300-digit numbers, no 0.000000000001
    path = tmp_path / "mine.toml"  # and the command line names the file
    path.write_text(text)
    assert main(["run", str(path), "-o", str(tmp_path / "out")]) == 1
    assert capsys.readouterr().err.startswith(f"multipendulum: error: {path}: key '{key}': ")


@pytest.mark.parametrize("csv, interpolation, message", [
    ("t,u1,u2\n0,1,2\n1,3,x\n", "linear", "u.csv line 3, column 3 ('u2', link 2): expected a number, got 'x'"),
    ("t,u1,u2\n0,1,2\n1,inf,2\n", "linear", "u.csv line 3, column 2 ('u1', link 1): must be finite, got 'inf'"),
    ("0,1,2\n1,1,2\n1,1,2\n", "linear", "u.csv line 3, column 1 (t): times must increase, got 1 after 1 on line 2"),
    ("0,1,-1.7e308\n1,1,1.7e308\n", "linear", "u.csv line 2, column 3 (link 2): the change from line 1 "
     "(-1.7e+308 to 1.7e+308) overflows"),
    ("0,0,1e300\n1e-300,0,-1e300\n1,0,1e300\n", "cubic", "u.csv lines 1-2, column 3 (link 2): the cubic spline through "
     "1e+300 at t = 0 and -1e+300 at t = 1e-300 overflows"),
])
def test_table_errors_name_their_row_and_column(csv, interpolation, message):
    text = BASE + f'[torque]\nkind = "table"\nconvention = "joint"\nfile = "u.csv"\ninterpolation = "{interpolation}"\n'
    with pytest.raises(ScenarioError) as info:
        loads_scenario(text, files={"u.csv": csv})
    assert message in str(info.value), str(info.value)


def test_a_table_torque_is_not_called_a_python_function_in_the_summary(tmp_path, capsys):
    path = ROOT / "examples" / "driven_rod.toml"  # a joint-motor torque read from a table
    assert main(["run", str(path), "-o", str(tmp_path), "--t-end", "0.5", "--no-animation", "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "Python torque function" not in out
    assert re.search(r"trustworthy (to 1e-2 rad )?until", out), out


def test_the_docs_dask_cluster_example_runs_as_a_script(tmp_path):
    pytest.importorskip("distributed")
    text = (ROOT / "docs" / "chaos.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    cluster = [b for b in blocks if "LocalCluster" in b]
    assert len(cluster) == 1
    script = tmp_path / "example.py"
    script.write_text(blocks[0] + "\n" + cluster[0] + "\nif __name__ == '__main__':\n    print('fm3', fm3.times.shape)\n")
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, MPLBACKEND="Agg"))
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "fm3 (128, 128)" in proc.stdout


def test_the_demo_output_in_docs_cli_is_the_real_one(tmp_path):
    text = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    block = text.split("```console\n$ multipendulum demo\n", 1)[1].split("```", 1)[0]
    proc = subprocess.run([sys.executable, "-m", "multipendulum.cli", "demo"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=300, env=dict(os.environ, MPLBACKEND="Agg"))
    assert proc.returncode == 0, proc.stderr

    def steady(lines):  # the wall time is the machine's; everything else is the run's
        return [re.sub(r"wall time [0-9.e+-]+ s", "wall time ... s", line) for line in lines.strip().splitlines()]

    assert steady(block) == steady(proc.stdout)
