"""The `multipendulum` command: every example runs through it, animate/plot work on results files,
every bad scenario exits non-zero with its message and writes nothing."""
import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp
from multipendulum.cli import ProgressBar, main
from multipendulum.results import load_results

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("*.toml"))
PLOTS = ["angles.png", "energy.png", "phase.png", "tip.png"]


def _gif_frame_count(path):
    from PIL import Image

    with Image.open(path) as im:
        return im.n_frames


@pytest.mark.parametrize("subcommand", [[], ["run"], ["animate"], ["plot"], ["demo"], ["fractal"], ["serve"]], ids=lambda s: s[0] if s else "top")
def test_help_everywhere(capsys, subcommand):
    assert main(subcommand + ["--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: multipendulum")
    if not subcommand:
        for name in ("run", "animate", "plot", "demo", "fractal", "serve"):
            assert name in out


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"multipendulum {mp.__version__}"


def test_no_command_is_a_usage_error(capsys):
    assert main([]) == 2
    assert "usage:" in capsys.readouterr().err


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_every_example_runs_through_the_cli(tmp_path, capsys, path):
    out = tmp_path / "out"
    assert main(["run", str(path), "-o", str(out), "--t-end", "0.5"]) == 0
    text = capsys.readouterr().out
    assert "N = " in text and "steps" in text and "wall time" in text
    from multipendulum.scenario import load_scenario

    scenario = load_scenario(path)
    # Losses, a moving pivot or a pushed cart: the energy balance's residual, and the work terms.
    balance = scenario.pivot is not None or scenario.cart is not None or "damping" in scenario.chain \
        or "friction" in scenario.chain
    assert ("max energy-balance residual" in text and "work done by t = 0.5 s:" in text) == balance, text
    assert ("max energy error" in text) != balance
    files = sorted(os.listdir(out))
    assert files == sorted(["results.npz", scenario.outputs.animation] + PLOTS)
    results = load_results(out / "results.npz")
    assert results.t[-1] == 0.5 and results.n == scenario.n
    assert results.metadata["scenario"]["overrides"] == {"t_end": 0.5}
    assert _gif_frame_count(out / scenario.outputs.animation) == int(0.5 * scenario.outputs.fps) + 1


def test_run_default_output_dir_and_csv(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    scenario = ROOT / "examples" / "triple.toml"
    assert main(["run", str(scenario), "--t-end", "0.2", "--format", "csv", "--no-animation", "--no-plots"]) == 0
    assert os.listdir(tmp_path / "out" / "triple") == ["results.csv"]
    results = load_results(tmp_path / "out" / "triple" / "results.csv")
    assert results.n == 3 and results.method == "gauss6"
    assert "wrote out/triple/results.csv" in capsys.readouterr().out


def test_animate_and_plot_subcommands(tmp_path, capsys):
    scenario = ROOT / "examples" / "driven_rod.toml"
    assert main(["run", str(scenario), "-o", str(tmp_path), "--t-end", "1.0", "--no-animation", "--no-plots", "-q"]) == 0
    assert capsys.readouterr().out == ""
    results = tmp_path / "results.npz"
    assert main(["animate", str(results), "-o", str(tmp_path / "x.gif"), "--fps", "10", "--speed", "2",
                 "--trail", "0.5", "--dpi", "30"]) == 0
    assert _gif_frame_count(tmp_path / "x.gif") == 6
    assert main(["animate", str(results), "-o", str(tmp_path / "x.mp4"), "--fps", "10"]) == 0
    assert (tmp_path / "x.mp4").stat().st_size > 1000
    assert main(["plot", str(results), "-o", str(tmp_path / "plots"), "--kinds", "energy", "tip"]) == 0
    assert sorted(os.listdir(tmp_path / "plots")) == ["energy.png", "tip.png"]
    out = capsys.readouterr().out
    assert "x.gif (6 frames)" in out and "energy.png" in out


def test_animate_missing_results_file(tmp_path, capsys):
    assert main(["animate", str(tmp_path / "nope.npz"), "-o", str(tmp_path / "a.gif")]) == 1
    assert "nope.npz: no such file" in capsys.readouterr().err
    assert os.listdir(tmp_path) == []


def test_demo_shows_its_scenario(capsys):
    assert main(["demo", "--show-scenario"]) == 0
    text = capsys.readouterr().out
    assert 'name = "Chaotic double pendulum"' in text and "[chain]" in text


GOOD = """
[chain]
lengths = [1.0, 1.0]
masses = [1.0, 1.0]
[initial]
unit = "degrees"
theta = [120.0, 10.0]
[simulation]
t_end = 0.2
"""

BAD = [
    ("unknown key", GOOD.replace("masses", "mass"), "key 'chain.mass': unknown key; did you mean 'masses'?"),
    ("wrong type", GOOD.replace("t_end = 0.2", 't_end = "soon"'),
     "key 'simulation.t_end': expected a number > 0, got a string 'soon'"),
    ("missing field", GOOD.replace('unit = "degrees"\n', ""),
     "key 'initial.unit': missing; expected \"degrees\" or \"radians\""),
    ("negative length", GOOD.replace("lengths = [1.0, 1.0]", "lengths = [1.0, -1]"),
     "key 'chain.lengths[1]': must be > 0, got -1"),
    ("bad method", GOOD + 'method = "euler"\n', "key 'simulation.method': expected one of"),
    ("bad toml", GOOD + "[[[\n", "not valid TOML"),
    ("singular chain", GOOD.replace("masses = [1.0, 1.0]", "masses = [1.0, 0.0]"),
     "key 'chain': link 1 leaves the mass matrix singular"),
]


@pytest.mark.parametrize("what,text,message", BAD, ids=[b[0] for b in BAD])
def test_bad_scenario_exits_nonzero_and_writes_nothing(tmp_path, capsys, what, text, message):
    scenario = tmp_path / "bad.toml"
    scenario.write_text(text)
    out = tmp_path / "out"
    assert main(["run", str(scenario), "-o", str(out)]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith(f"multipendulum: error: {scenario}: ")
    assert message in captured.err
    assert not out.exists()
    assert os.listdir(tmp_path) == ["bad.toml"]


def test_missing_scenario_file(tmp_path, capsys):
    assert main(["run", str(tmp_path / "none.toml"), "-o", str(tmp_path / "out")]) == 1
    assert "cannot read scenario file" in capsys.readouterr().err
    assert os.listdir(tmp_path) == []


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_progress_bar_only_on_a_terminal_after_the_delay():
    tty = _Tty()
    bar = ProgressBar("simulate", stream=tty, delay=0.0)
    bar(0.5)
    bar(1.0)
    bar.close()
    text = tty.getvalue()
    assert "\rsimulate [" in text and "100.0%" in text and text.endswith("\n")

    slow = _Tty()
    bar = ProgressBar("simulate", stream=slow, delay=60.0)  # a run shorter than the delay shows nothing
    bar(0.5)
    bar.close()
    assert slow.getvalue() == ""

    for stream, quiet in ((io.StringIO(), False), (_Tty(), True)):
        bar = ProgressBar("simulate", stream=stream, quiet=quiet, delay=0.0)
        bar(0.5)
        bar.close()
        assert stream.getvalue() == ""


def test_the_installed_command_runs_the_demo(tmp_path):
    exe = Path(sys.executable).with_name("multipendulum")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "multipendulum.cli"]
    proc = subprocess.run(cmd + ["demo"], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                          env=dict(os.environ, MPLBACKEND="Agg"))
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""  # not a terminal: no progress bar
    out = tmp_path / "out" / "demo"
    assert sorted(os.listdir(out)) == sorted(["results.npz", "double_pendulum.gif"] + PLOTS)
    assert "Chaotic double pendulum: N = 2, method dop853" in proc.stdout
    results = load_results(out / "results.npz")
    assert results.t[-1] == 10.0 and np.isfinite(results.theta).all()
    assert _gif_frame_count(out / "double_pendulum.gif") == 301


def test_failed_integration_exits_nonzero_and_writes_nothing(tmp_path, capsys):
    scenario = tmp_path / "blowup.toml"
    scenario.write_text(GOOD.replace("t_end = 0.2", 't_end = 100.0\nmethod = "rk4"\ndt = 0.9')
                        .replace("theta = [120.0, 10.0]", "theta = [170.0, 170.0]\nomega = [3000.0, -3000.0]"))
    out = tmp_path / "out"
    assert main(["run", str(scenario), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("multipendulum: error: integration failed at t = ") and err.rstrip().endswith("nothing written")
    assert not out.exists()


def test_the_summary_of_a_lossy_driven_run_gives_the_balance_and_its_terms(tmp_path, capsys):
    from multipendulum.scenario import load_scenario

    path = tmp_path / "pushed.toml"
    path.write_text(GOOD.replace("masses = [1.0, 1.0]", "masses = [1.0, 1.0]\ndamping = [0.1, 0.0]") + """
[torque]
kind = "constant"
convention = "joint"
value = [0.2, 0.0]
[cart]
mass = 1.0
damping = 0.5
force = { kind = "sinusoid", amplitude = 2.0, frequency = 3.0 }
""")
    assert main(["run", str(path), "-o", str(tmp_path / "out"), "--no-animation", "--no-plots"]) == 0
    lines = capsys.readouterr().out.splitlines()
    sol = load_scenario(path).run()
    residual = next(line for line in lines if "energy-balance residual" in line)
    assert residual == (f"  max energy-balance residual {sol.stats.energy_error:.3g} "
                        "(|E - E0 - W_torque - W_cart + D| / S, E in the lab frame; S: well depth + max kinetic energy)")
    work = next(line for line in lines if line.startswith("  work done by"))
    assert work == (f"  work done by t = 0.2 s: torque {sol.work.torque[-1]:.4g} J, cart force {sol.work.cart[-1]:.4g} J, "
                    f"dissipated {sol.work.dissipated[-1]:.4g} J")
    assert sol.work.dissipated[-1] > 0 and sol.work.cart[-1] != 0
    results = load_results(tmp_path / "out" / "results.npz")
    np.testing.assert_array_equal(results.cart_x, sol.cart_x)
    np.testing.assert_array_equal(results.work.dissipated, sol.work.dissipated)


def test_a_torque_alone_keeps_the_plain_energy_error_line(tmp_path, capsys):
    assert main(["run", str(ROOT / "examples" / "seed000_driven_chain.toml"), "-o", str(tmp_path / "out"),
                 "--t-end", "0.1", "--no-animation", "--no-plots"]) == 0
    text = capsys.readouterr().out
    assert "max energy error" in text and "(|E - E0 - W| / S;" in text and "work done by" not in text


#: Bad losses, pivots and carts (issue 13): each exits 1 naming the key, and nothing is written.
BAD_BASE = [
    ("negative damping", GOOD.replace("masses = [1.0, 1.0]", "masses = [1.0, 1.0]\ndamping = [0.1, -1.0]"),
     "key 'chain.damping[1]': must be >= 0, got -1.0"),
    ("nan damping", GOOD.replace("masses = [1.0, 1.0]", "masses = [1.0, 1.0]\ndamping = nan"),
     "key 'chain.damping': must be finite, got nan"),
    ("negative friction", GOOD.replace("masses = [1.0, 1.0]", "masses = [1.0, 1.0]\nfriction = [-0.2, 0.0]"),
     "key 'chain.friction[0]': must be >= 0, got -0.2"),
    ("infinite friction", GOOD.replace("masses = [1.0, 1.0]", "masses = [1.0, 1.0]\nfriction = inf"),
     "key 'chain.friction': must be finite, got inf"),
    ("zero friction_velocity", GOOD.replace("masses = [1.0, 1.0]", "masses = [1.0, 1.0]\nfriction_velocity = 0.0"),
     "key 'chain.friction_velocity': must be > 0, got 0.0"),
    ("negative friction_velocity",
     GOOD.replace("masses = [1.0, 1.0]", "masses = [1.0, 1.0]\nfriction_velocity = -1e-3"),
     "key 'chain.friction_velocity': must be > 0, got -0.001"),
    ("zero cart mass", GOOD + "[cart]\nmass = 0.0\n", "key 'cart.mass': must be > 0, got 0.0"),
    ("negative cart mass", GOOD + "[cart]\nmass = -1\n", "key 'cart.mass': must be > 0, got -1"),
    ("nan cart mass", GOOD + "[cart]\nmass = nan\n", "key 'cart.mass': must be finite, got nan"),
    ("negative cart damping", GOOD + "[cart]\nmass = 1\ndamping = -0.5\n", "key 'cart.damping': must be >= 0"),
    ("infinite cart damping", GOOD + "[cart]\nmass = 1\ndamping = inf\n", "key 'cart.damping': must be finite"),
    ("pivot table of 1 point", GOOD + '[pivot]\ny = { kind = "table", t = [0.0], values = [0.0] }\n',
     ("key 'pivot.y': ", "at least 2 samples, got 1")),
    ("pivot csv of 1 row", GOOD + '[pivot]\nx = { kind = "table", file = "x.csv" }\n',
     "key 'pivot.x.file': x.csv: expected at least 2 rows of numbers, got 1"),
    ("unknown pivot key", GOOD + "[pivot]\nx = 0.1\nphase = 2.0\n",
     "key 'pivot.phase': unknown key; expected one of: x, y"),
    ("unknown pivot axis key", GOOD + '[pivot.y]\nkind = "sinusoid"\namplitude = 0.1\nfrequency = 9\namp = 1\n',
     "key 'pivot.y.amp': unknown key"),
    ("unknown cart key", GOOD + "[cart]\nmass = 1.0\nvelocity = 2.0\n",
     "key 'cart.velocity': unknown key; expected one of: mass, damping, x0, v0, force"),
    ("unknown cart force key", GOOD + '[cart]\nmass = 1.0\n[cart.force]\nkind = "sinusoid"\namplitude = 1\n'
     "frequency = 1\nperiod = 3\n", "key 'cart.force.period': unknown key"),
    ("pivot with a cart", GOOD + "[pivot]\ny = 0.1\n[cart]\nmass = 1.0\n", "key 'pivot': cannot be given with [cart]"),
]


@pytest.mark.parametrize("what,text,message", BAD_BASE, ids=[b[0] for b in BAD_BASE])
def test_bad_losses_pivots_and_carts_exit_1_naming_the_key_and_write_nothing(tmp_path, capsys, what, text, message):
    scenario = tmp_path / "bad.toml"
    scenario.write_text(text)
    (tmp_path / "x.csv").write_text("t,x\n0,0.1\n")
    out = tmp_path / "out"
    assert main(["run", str(scenario), "-o", str(out)]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith(f"multipendulum: error: {scenario}: key '")
    for fragment in (message,) if isinstance(message, str) else message:
        assert fragment in captured.err, captured.err
    assert len(captured.err.strip().splitlines()) == 1 and "Traceback" not in captured.err
    assert not out.exists()
    assert sorted(os.listdir(tmp_path)) == ["bad.toml", "x.csv"]
