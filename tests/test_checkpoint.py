"""Checkpoints and restart: a run resumed from its checkpoint archive returns bit-for-bit the
arrays of the uninterrupted run (Python API and CLI, after SIGKILL, SIGINT and SIGTERM); damaged
or foreign archives are refused with InputError / a clean CLI error."""
import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp
from multipendulum.cli import main
from multipendulum.results import load_results

FIELDS = ("t", "theta", "omega", "p", "energy", "work")
COUNTERS = ("steps", "rejected", "evaluations", "iterations", "energy_error")


def assert_same_run(a, b):
    for k in FIELDS:
        assert np.array_equal(getattr(a, k), getattr(b, k)), k
    for k in COUNTERS:
        assert getattr(a.stats, k) == getattr(b.stats, k), k


@pytest.fixture
def chain():
    return mp.Chain(lengths=[1.0, 0.8, 0.6], masses=[1.0, 1.5, 0.7])


RUNS = {
    "rk4": dict(method="rk4", dt=0.002),
    "gauss6": dict(method="gauss6", dt=0.005),
    "dop853": dict(method="dop853", rtol=1e-9, atol=1e-11),
}


@pytest.mark.parametrize("sampled", [False, True], ids=["every-step", "t_eval"])
@pytest.mark.parametrize("name", list(RUNS))
def test_resume_from_a_mid_run_checkpoint_is_bit_for_bit(tmp_path, chain, name, sampled):
    kwargs = dict(RUNS[name], torque=mp.Sinusoid([0.4, 0.0, -0.2], [2.0, 1.0, 3.0]))
    if sampled:
        kwargs["t_eval"] = np.linspace(0.0, 4.0, 333)  # not on the step grid: interpolated rows
    theta0, omega0 = [2.0, 2.5, 1.0], [0.0, 0.3, -0.5]
    full = mp.simulate(chain, theta0, omega0, 4.0, **kwargs)
    every = full.stats.steps * 3 // 5  # the last checkpoint falls at 60% of the run
    path = tmp_path / "run.ckpt"
    with_ckpt = mp.simulate(chain, theta0, omega0, 4.0, checkpoint=path, checkpoint_every=every, **kwargs)
    assert_same_run(with_ckpt, full)  # taking checkpoints does not change the run
    archive = mp.load_checkpoint(path)
    assert archive.metadata["state"]["steps"] == every
    assert 0.4 * 4.0 < archive.t < 0.8 * 4.0
    resumed = mp.resume(path, checkpoint=False)
    assert_same_run(resumed, full)
    assert resumed.method == name


def test_resume_keeps_checkpointing_and_a_finished_archive_resumes_to_the_same_end(tmp_path, chain):
    path = tmp_path / "run.ckpt"
    full = mp.simulate(chain, [1.0, 2.0, 3.0], [0, 0, 0], 2.0, method="gauss6", dt=0.01, checkpoint=path,
                       checkpoint_every=70)
    assert mp.load_checkpoint(path).metadata["state"]["steps"] == 140
    os.utime(path, (0, 0))
    again = mp.resume(path)  # from step 140 to 200, checkpointing every 70 steps as before
    assert_same_run(again, full)
    assert os.stat(path).st_mtime == 0  # step 210 never comes: the archive was not rewritten
    path2 = tmp_path / "every-50.ckpt"
    mp.simulate(chain, [1.0, 2.0, 3.0], [0, 0, 0], 2.0, method="gauss6", dt=0.01, checkpoint=path2,
                checkpoint_every=50)
    ck = mp.load_checkpoint(path2)
    assert ck.t == 2.0 and ck.metadata["state"]["steps"] == 200  # the last step is on a multiple of 50
    assert_same_run(mp.resume(path2), full)


def test_checkpoints_are_refused_where_the_state_cannot_be_saved(tmp_path, chain):
    path = tmp_path / "x.ckpt"
    run = lambda **kw: mp.simulate(chain, kw.pop("theta0", [1.0, 0, 0]), kw.pop("omega0", [0.0, 0, 0]), 1.0,
                                   method="rk4", dt=0.01, **kw)
    with pytest.raises(mp.InputError, match="Python torque function cannot be saved"):
        run(checkpoint=path, torque=lambda t: [0.0, 0.0, 0.0])
    with pytest.raises(mp.InputError, match="single runs"):
        run(checkpoint=path, theta0=np.ones((2, 3)), omega0=np.zeros((2, 3)))
    with pytest.raises(mp.InputError, match="cannot be combined with events"):
        run(checkpoint=path, events=[mp.Flip()])
    with pytest.raises(mp.InputError, match="need checkpoint=FILE"):
        run(checkpoint_every=10)
    for bad in (0, -3, 2.5, True):
        with pytest.raises(mp.InputError, match="checkpoint_every must be a positive integer"):
            run(checkpoint=path, checkpoint_every=bad)
    for bad in (0, -1.0, float("nan"), "soon"):
        with pytest.raises(mp.InputError, match="checkpoint_seconds must be"):
            run(checkpoint=path, checkpoint_seconds=bad)
    assert not path.exists()


# ----------------------------------------------------------------------------------------------
# Damaged and foreign archives


@pytest.fixture
def archive(tmp_path, chain):
    path = tmp_path / "good.ckpt"
    mp.simulate(chain, [1.0, 2.0, 3.0], [0, 0, 0], 1.0, method="rk4", dt=0.01, checkpoint=path,
                checkpoint_every=60)
    return path


def _rewrite(src, dst, drop=(), meta=None, arrays=None):
    with np.load(src, allow_pickle=False) as d:
        members = {k: d[k] for k in d.files if k not in drop}
    if meta is not None:
        m = json.loads(str(members["metadata"][()]))
        meta(m)
        members["metadata"] = np.asarray(json.dumps(m))
    members.update(arrays or {})
    with open(dst, "wb") as f:
        np.savez(f, **members)
    return dst


def test_damaged_archives_raise_input_error_naming_the_problem(tmp_path, archive):
    data = archive.read_bytes()
    cases = {
        "truncated.ckpt": (data[: len(data) // 2], "not a readable checkpoint archive"),
        "garbage.ckpt": (b"\x00" * 300, "not a readable checkpoint archive"),
    }
    for name, (content, message) in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(mp.InputError, match=message):
            mp.resume(tmp_path / name)
    flipped = bytearray(data)
    i = data.index(b"state.npy")  # a byte inside a stored member: the CRC check fails
    flipped[i + 200] ^= 0xFF
    (tmp_path / "flipped.ckpt").write_bytes(bytes(flipped))
    with pytest.raises(mp.InputError, match="truncated or corrupt"):
        mp.load_checkpoint(tmp_path / "flipped.ckpt")
    with pytest.raises(mp.InputError, match="no such checkpoint file"):
        mp.resume(tmp_path / "absent.ckpt")
    with pytest.raises(mp.InputError, match="missing t_eval, state"):
        mp.resume(_rewrite(archive, tmp_path / "m.ckpt", drop=("t_eval", "state")))
    with pytest.raises(mp.InputError, match="format version 99; this multipendulum reads version 2"):
        mp.resume(_rewrite(archive, tmp_path / "v.ckpt", meta=lambda m: m.update(format_version=99)))
    with pytest.raises(mp.InputError, match="not a multipendulum checkpoint"):
        mp.resume(_rewrite(archive, tmp_path / "f.ckpt", meta=lambda m: m.update(format="something-else")))
    with pytest.raises(mp.InputError, match="state.steps must be an integer >= 0, got -1"):
        mp.resume(_rewrite(archive, tmp_path / "s.ckpt", meta=lambda m: m["state"].update(steps=-1)))
    with pytest.raises(mp.InputError, match="lacks t_end"):
        mp.resume(_rewrite(archive, tmp_path / "r.ckpt", meta=lambda m: m["run"].pop("t_end")))
    with pytest.raises(mp.InputError, match="member theta0 must be a float64 vector"):
        mp.resume(_rewrite(archive, tmp_path / "i.ckpt", arrays={"theta0": np.arange(3)}))
    with pytest.raises(mp.InputError, match="member state must be a uint8 vector"):
        mp.resume(_rewrite(archive, tmp_path / "u.ckpt", arrays={"state": np.ones(5)}))
    # The core's serialised run state, damaged or cut: the core refuses it, naming the file.
    state = np.load(archive)["state"]
    with pytest.raises(mp.InputError, match="c.ckpt.*run state cannot be read"):
        mp.resume(_rewrite(archive, tmp_path / "c.ckpt", arrays={"state": state[: state.size // 2]}))
    with pytest.raises(mp.InputError, match="not of this format"):
        mp.resume(_rewrite(archive, tmp_path / "x.ckpt", arrays={"state": state[::-1].copy()}))
    # The metadata and the run state disagree.
    with pytest.raises(mp.InputError, match="the run state is at t = .* the metadata says t = 0.3"):
        mp.resume(_rewrite(archive, tmp_path / "t.ckpt", meta=lambda m: m["state"].update(t=0.3)))
    # Consistent on its face, but not this run's (a chain of two links): the core refuses it.
    two = {"lengths": np.ones(2), "masses": np.ones(2), "com": np.ones(2), "inertia": np.zeros(2),
           "theta0": np.ones(2), "omega0": np.zeros(2)}
    with pytest.raises(mp.InputError, match="its state has 6 values, this run's 4"):
        mp.resume(_rewrite(archive, tmp_path / "y.ckpt", arrays=two))


def test_another_package_version_is_refused_unless_asked(tmp_path, archive):
    other = _rewrite(archive, tmp_path / "o.ckpt", meta=lambda m: m.update(version="0.0.1-other"))
    with pytest.raises(mp.InputError, match="written by multipendulum '0.0.1-other'.*bit-for-bit only with the same"):
        mp.resume(other)
    plain = mp.simulate(mp.Chain(lengths=[1.0, 0.8, 0.6], masses=[1.0, 1.5, 0.7]), [1.0, 2.0, 3.0], [0, 0, 0], 1.0,
                        method="rk4", dt=0.01)
    assert_same_run(mp.resume(other, any_version=True, checkpoint=False), plain)


# ----------------------------------------------------------------------------------------------
# The CLI: kill a run, resume it, compare with an uninterrupted one

SCENARIO = """
name = "Checkpointed chain"

[chain]
lengths = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]
masses = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]

[initial]
unit = "degrees"
theta = [90.0, 100.0, 110.0, 120.0, 130.0, 140.0, 150.0, 160.0]

[simulation]
t_end = 25.0
method = "rk4"
dt = 0.00005

[torque]
kind = "sinusoid"
convention = "joint"
amplitude = 0.5
frequency = 2.0

[output]
animation = false
plots = false
"""


@pytest.fixture(scope="module")
def long_run(tmp_path_factory):
    """The scenario (about 1.5 s of integration) and its uninterrupted results."""
    d = tmp_path_factory.mktemp("long")
    (d / "long.toml").write_text(SCENARIO)
    assert main(["run", str(d / "long.toml"), "-o", str(d / "reference"), "-q"]) == 0
    return d / "long.toml", load_results(d / "reference" / "results.npz")


def _start(scenario, out, ckpt):
    cmd = [sys.executable, "-m", "multipendulum", "run", str(scenario), "-o", str(out), "-q",
           "--checkpoint", str(ckpt), "--checkpoint-every", "20000"]
    # SIGINT as a terminal delivers it, even when these tests run where it is ignored (a shell's
    # background job), which the child would inherit.
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 60
    while not ckpt.exists():  # appears only complete (atomic rename)
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "no checkpoint appeared"
        time.sleep(0.005)
    return proc


@pytest.mark.parametrize("sig, code", [(signal.SIGKILL, -signal.SIGKILL), (signal.SIGINT, 130),
                                       (signal.SIGTERM, 143)], ids=["SIGKILL", "SIGINT", "SIGTERM"])
def test_cli_run_killed_then_resumed_equals_the_uninterrupted_run(tmp_path, long_run, sig, code):
    scenario, reference = long_run
    ckpt, out = tmp_path / "run.ckpt", tmp_path / "out"
    proc = _start(scenario, out, ckpt)
    time.sleep(0.2)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    if sig != signal.SIGKILL:
        assert "checkpoint" in err and f"resume {ckpt}" in err, err
    assert not (out / "results.npz").exists()
    stopped = mp.load_checkpoint(ckpt)  # a complete archive, whatever the moment of the kill
    assert 0 < stopped.t < 25.0
    if sig != signal.SIGKILL:  # a stopped run cleans up; a killed one may leave a temporary file, never a half archive
        assert not list(tmp_path.glob(".run.ckpt.*"))
    assert main(["resume", str(ckpt), "-q"]) == 0  # into the run's own output directory
    resumed = load_results(out / "results.npz")
    for k in FIELDS:
        assert np.array_equal(getattr(resumed, k), getattr(reference, k)), k
    assert resumed.metadata["scenario"]["text"] == reference.metadata["scenario"]["text"]


def test_cli_resume_refuses_bad_archives_cleanly(tmp_path, capsys, archive):
    (tmp_path / "bad.ckpt").write_bytes(archive.read_bytes()[:100])
    assert main(["resume", str(tmp_path / "bad.ckpt")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("multipendulum: error:") and "truncated or corrupt" in err
    assert main(["resume", str(archive)]) == 1  # written by mp.simulate: no scenario to write outputs for
    assert "continue it in Python with mp.resume" in capsys.readouterr().err
    assert main(["resume", str(tmp_path / "none.ckpt")]) == 1
    assert "no such checkpoint file" in capsys.readouterr().err


def test_checkpoint_seconds_are_polled_every_64_steps(tmp_path, chain):
    path = tmp_path / "clock.ckpt"
    kwargs = dict(method="rk4", dt=0.01)
    full = mp.simulate(chain, [1.0, 2.0, 3.0], [0, 0, 0], 3.0, checkpoint=path, checkpoint_seconds=1e-9, **kwargs)
    archive = mp.load_checkpoint(path)
    assert archive.metadata["state"]["steps"] == 256  # the last multiple of 64 within 300 steps
    assert archive.metadata["checkpoint"] == {"every_steps": None, "every_seconds": 1e-9}
    assert_same_run(mp.resume(path, checkpoint=False), full)


@pytest.mark.parametrize("torque", [
    dict(torque=[0.2, -0.1, 0.05]),
    dict(joint_torque=mp.Table([0.0, 0.5, 1.0, 2.0], [[0, 0, 0], [1, 0.5, 0], [0, 0, 1], [0.2, 0.2, 0.2]],
                               kind="cubic")),
], ids=["constant", "joint-table"])
def test_built_in_torques_are_saved_and_rebuilt(tmp_path, chain, torque):
    path = tmp_path / "torque.ckpt"
    full = mp.simulate(chain, [1.0, 2.0, 3.0], [0, 0, 0], 2.0, method="rk4", dt=0.01, **torque)
    mp.simulate(chain, [1.0, 2.0, 3.0], [0, 0, 0], 2.0, method="rk4", dt=0.01, checkpoint=path,
                checkpoint_every=130, **torque)
    resumed = mp.resume(path)
    assert_same_run(resumed, full)
    assert np.any(resumed.work != 0)  # the torque acted, and its work integral went on from the archive
    assert resumed.trustworthy_until(horizon=2.0) == full.trustworthy_until(horizon=2.0)
