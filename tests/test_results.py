"""Results files: round trips (NPZ and CSV give back the same arrays, bit for bit), metadata that
reproduces the run, and atomic writes (an error while writing leaves no file and no debris)."""
import json
import os

import numpy as np
import pytest

import multipendulum as mp
from multipendulum.results import Results, load_results, save_results
from multipendulum.scenario import loads_scenario

SCENARIO = """
name = "round trip"
[chain]
lengths = [1.0, 0.7, 0.5]
masses = [1.0, 2.0, 0.5]
com = [0.6, 0.35, 0.5]
inertia = [0.01, 0.02, 0.0]
[initial]
unit = "radians"
theta = [1.0, -0.5, 2.0]
omega = [0.0, 0.3, 0.0]
[simulation]
t_end = 1.0
sample_dt = 0.05
[torque]
kind = "table"
convention = "generalized"
file = "u.csv"
"""
TABLE = "t,u1,u2,u3\n0,0.5,0,-0.1\n0.5,1.0,0.2,0\n1,0,0,0.3\n"
ARRAYS = ("t", "theta", "omega", "p", "energy", "work", "energy_error", "positions")


@pytest.fixture(scope="module")
def run():
    scenario = loads_scenario(SCENARIO, files={"u.csv": TABLE})
    return scenario, scenario.run()


def _assert_same(results, sol):
    # (np.asarray: the work is a multipendulum.Work, the net work as an array with its parts.)
    for name in ARRAYS:
        got, want = np.asarray(getattr(results, name)), np.asarray(getattr(sol, name))
        assert got.dtype == np.float64 and got.shape == want.shape, name
        np.testing.assert_array_equal(got, want, err_msg=name)
    for part in ("torque", "pivot", "cart", "dissipated"):
        np.testing.assert_array_equal(getattr(results.work, part), getattr(sol.work, part), err_msg=part)
    np.testing.assert_array_equal(results.pivot, sol.pivot)
    for name in ("cart_x", "cart_v"):
        if getattr(sol, name) is None:
            assert getattr(results, name) is None, name
        else:
            np.testing.assert_array_equal(getattr(results, name), getattr(sol, name), err_msg=name)
    for name in ("lengths", "masses", "com", "inertia", "damping", "friction"):
        np.testing.assert_array_equal(getattr(results, name), np.asarray(getattr(sol.chain, name)), err_msg=name)
    assert results.g == sol.chain.g and results.friction_velocity == sol.chain.friction_velocity
    assert results.cart == sol.chain.cart


@pytest.mark.parametrize("fmt", ["npz", "csv"])
def test_round_trip_gives_the_same_arrays(tmp_path, run, fmt):
    scenario, sol = run
    path = save_results(sol, tmp_path / f"r.{fmt}", scenario=scenario)
    results = load_results(path)
    assert isinstance(results, Results)
    _assert_same(results, sol)
    meta = results.metadata
    assert meta["version"] == mp.__version__
    assert meta["method"] == sol.method == results.method
    assert meta["stats"]["steps"] == sol.stats.steps
    assert meta["stats"]["energy_error"] == sol.stats.energy_error
    assert meta["scenario"]["text"] == SCENARIO
    assert meta["scenario"]["files"] == {"u.csv": TABLE}
    assert results.stats.steps == sol.stats.steps


def test_format_follows_suffix_or_argument(tmp_path, run):
    _, sol = run
    save_results(sol, tmp_path / "a.csv")
    assert (tmp_path / "a.csv").read_text().startswith("# multipendulum-results")
    save_results(sol, tmp_path / "b.dat", format="npz")
    assert (tmp_path / "b.dat").read_bytes()[:2] == b"PK"
    _assert_same(load_results(tmp_path / "b.dat"), sol)
    with pytest.raises(mp.InputError, match="format must be one of npz, csv"):
        save_results(sol, tmp_path / "c.npz", format="hdf5")
    assert not (tmp_path / "c.npz").exists()


def test_loaded_results_save_again_unchanged(tmp_path, run):
    scenario, sol = run
    first = load_results(save_results(sol, tmp_path / "1.npz", scenario=scenario))
    second = load_results(save_results(first, tmp_path / "2.csv"))
    _assert_same(second, sol)
    assert second.metadata["scenario"] == first.metadata["scenario"]


def test_stored_scenario_reproduces_the_run(tmp_path, run):
    scenario, sol = run
    results = load_results(save_results(sol, tmp_path / "r.npz", scenario=scenario))
    again = results.scenario().run()
    for name in ("t", "theta", "omega", "energy", "work"):
        np.testing.assert_array_equal(getattr(again, name), getattr(sol, name), err_msg=name)


def test_overrides_are_recorded(tmp_path, run):
    scenario, _ = run
    short = scenario.replace(t_end=0.25)
    results = load_results(save_results(short.run(), tmp_path / "r.npz", scenario=short))
    assert results.metadata["scenario"]["overrides"] == {"t_end": 0.25}
    assert results.scenario().t_end == 0.25
    assert results.t[-1] == 0.25


def test_results_plain_solution_has_no_scenario(tmp_path):
    chain = mp.Chain(lengths=[1.0], masses=[1.0])
    sol = mp.simulate(chain, [0.5], [0.0], 0.2)
    results = load_results(save_results(sol, tmp_path / "r.npz"))
    assert results.metadata["scenario"] is None and results.scenario() is None
    assert results.chain == chain
    np.testing.assert_array_equal(results.positions, sol.positions)


class Boom(RuntimeError):
    pass


def test_failed_write_leaves_nothing(tmp_path, run, monkeypatch):
    _, sol = run

    def broken(f, **arrays):
        f.write(b"PK half a file")
        raise Boom()

    monkeypatch.setattr(np, "savez_compressed", broken)
    with pytest.raises(Boom):
        save_results(sol, tmp_path / "r.npz")
    assert os.listdir(tmp_path) == []


def test_failed_write_keeps_the_old_file(tmp_path, run, monkeypatch):
    _, sol = run
    path = save_results(sol, tmp_path / "r.npz")
    before = path.read_bytes()
    monkeypatch.setattr(np, "savez_compressed", lambda f, **a: (_ for _ in ()).throw(KeyboardInterrupt()))
    with pytest.raises(KeyboardInterrupt):
        save_results(sol, path)
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["r.npz"]


def test_written_file_has_normal_permissions(tmp_path, run):
    _, sol = run
    path = save_results(sol, tmp_path / "r.npz")
    mask = os.umask(0)
    os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask


def test_not_a_results_file(tmp_path):
    other = tmp_path / "other.npz"
    np.savez(other, x=np.arange(3))
    with pytest.raises(mp.InputError, match="not a multipendulum results file: missing metadata"):
        load_results(other)
    text = tmp_path / "other.csv"
    text.write_text("a,b\n1,2\n")
    with pytest.raises(mp.InputError, match="not a multipendulum results file"):
        load_results(text)


def test_npz_metadata_is_plain_json(tmp_path, run):
    scenario, sol = run
    path = save_results(sol, tmp_path / "r.npz", scenario=scenario)
    with np.load(path, allow_pickle=False) as data:
        meta = json.loads(str(data["metadata"]))
        assert set(ARRAYS) <= set(data.files)
        assert data["positions"].shape == (len(sol.t), 3, 2)
    assert meta["format"] == "multipendulum-results" and meta["format_version"] == 2


# ---------------------------------------------------------------------------------------------
# Damaged files: every kind is an InputError naming the file and the problem


def _damaged_files(tmp_path, good_npz, good_csv):
    """(name, bytes or writer, fragment of the message) for each kind of damage."""
    data = good_npz.read_bytes()
    text = good_csv.read_text()
    corrupt = bytearray(data)
    corrupt[len(corrupt) // 3: len(corrupt) // 3 + 64] = b"\0" * 64  # inside a compressed member
    lines = text.splitlines(keepends=True)
    return [
        ("empty.npz", b"", "the file is empty (0 bytes)"),
        ("empty.csv", b"", "the file is empty (0 bytes)"),
        ("head.npz", data[:10], "not a readable NPZ archive (truncated or corrupt?)"),
        ("half.npz", data[: len(data) // 2], "not a readable NPZ archive (truncated or corrupt?)"),
        ("tail.npz", data[:-30], "not a readable NPZ archive (truncated or corrupt?)"),
        ("corrupt.npz", bytes(corrupt), "not a readable NPZ archive (truncated or corrupt?)"),
        ("text.npz", b"t,theta_1\n0,1\n", "not an NPZ archive"),
        ("binary.csv", b"\xff\xfe\x00garbage", "neither an NPZ archive nor UTF-8 text"),
        ("cut.csv", "".join(lines[:-1]) + lines[-1][: len(lines[-1]) // 2], "(truncated?)"),
        ("header-only.csv", "".join(lines[:3]), "no samples after the header line"),
        ("word.csv", "".join(lines[:4]) + "x" + lines[4][1:], "line 5, column 1 (t): expected a number, got 'x"),
    ]


def test_damaged_results_files_are_input_errors_naming_the_file_and_the_problem(tmp_path, run):
    scenario, sol = run
    good_npz = save_results(sol, tmp_path / "good.npz", scenario=scenario)
    good_csv = save_results(sol, tmp_path / "good.csv", scenario=scenario)
    for name, content, fragment in _damaged_files(tmp_path, good_npz, good_csv):
        path = tmp_path / name
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
        with pytest.raises(mp.InputError) as info:
            load_results(path)
        message = str(info.value)
        assert repr(str(path)) in message and fragment in message, (name, message)
    with pytest.raises(mp.InputError, match="no such results file"):
        load_results(tmp_path / "missing.npz")
    with pytest.raises(mp.InputError, match="not a file"):
        load_results(tmp_path)


def test_results_whose_arrays_do_not_fit_together_are_refused(tmp_path, run):
    scenario, sol = run
    good = tmp_path / "good.npz"
    save_results(sol, good, scenario=scenario)
    with np.load(good) as data:
        arrays = {k: data[k] for k in data.files}
    cases = [
        ("omega", arrays["omega"][:-1], "omega must have shape"),
        ("positions", arrays["positions"][..., :1], "positions must have shape"),
        ("theta", arrays["theta"].astype(str), "member 'theta' must hold numbers"),
        ("t", arrays["t"][::-1].copy(), "t must be ascending"),
        ("energy", np.where(np.arange(arrays["energy"].size) == 3, np.nan, arrays["energy"]), "energy[3] is nan"),
        ("metadata", np.asarray("{not json"), "metadata is not valid JSON"),
        ("metadata", np.asarray('{"format": "something-else"}'), "format 'something-else'"),
    ]
    for k, (member, value, fragment) in enumerate(cases):
        path = tmp_path / f"bad{k}.npz"
        np.savez(path, **dict(arrays, **{member: value}))
        with pytest.raises(mp.InputError, match=None) as info:
            load_results(path)
        assert repr(str(path)) in str(info.value) and fragment in str(info.value), (member, str(info.value))


@pytest.mark.parametrize("command", ["plot", "animate"])
def test_the_cli_refuses_damaged_results_cleanly(tmp_path, capsys, run, command):
    from multipendulum.cli import main

    scenario, sol = run
    data = save_results(sol, tmp_path / "good.npz", scenario=scenario).read_bytes()
    for name, content in (("cut.npz", data[: len(data) // 2]), ("empty.npz", b"")):
        path = tmp_path / name
        path.write_bytes(content)
        out = tmp_path / ("plots" if command == "plot" else "a.gif")
        assert main([command, str(path), "-o", str(out)]) == 1
        err = capsys.readouterr().err
        assert err.startswith(f"multipendulum: error: {str(path)!r}: ") and "Traceback" not in err, err
        assert len(err.strip().splitlines()) == 1
        assert not out.exists()


# ---------------------------------------------------------------------------------------------
# A batch run is not one run: refused with a way to pick one


def test_a_batch_solution_is_refused_by_plot_animate_and_save_results(tmp_path):
    chain = mp.Chain([1.0, 1.0], [1.0, 1.0])
    batch = mp.simulate(chain, np.full((3, 2), 0.5), np.zeros((3, 2)), 0.5, t_eval=np.linspace(0, 0.5, 11))
    assert batch.theta.shape == (3, 11, 2)
    calls = {
        "mp.plot": lambda: mp.plot(batch, tmp_path / "plots"),
        "mp.animate": lambda: mp.animate(batch, tmp_path / "a.gif"),
        "save_results": lambda: save_results(batch, tmp_path / "r.npz"),
    }
    for what, call in calls.items():
        with pytest.raises(mp.InputError) as info:
            call()
        message = str(info.value)
        assert message.startswith(f"{what} takes one run, but this Solution is a batch of 3 runs "
                                  "(theta shape (3, 11, 2))"), message
        assert "mp.simulate(chain, theta0[b], omega0[b], ...)" in message
    assert os.listdir(tmp_path) == []
    # and the advice holds: the single run is the batch's row (which ran in lanes: to dop853's tolerance)
    single = mp.simulate(chain, [0.5, 0.5], [0, 0], 0.5, t_eval=np.linspace(0, 0.5, 11))
    np.testing.assert_allclose(single.theta, batch.theta[1], rtol=0, atol=1e-9)
    with pytest.raises(mp.InputError, match="takes a multipendulum Solution or loaded Results, got dict"):
        mp.plot({"t": [0.0]})


# ---------------------------------------------------------------------------------------------
# Losses, a moving pivot, a cart (issue 13): their series and parameters round-trip


BASE_RUNS = {
    "pivot": """
[chain]
kind = "rods"
lengths = [0.5, 0.4]
masses = [0.1, 0.2]
friction = [0.001, 0.0]
friction_velocity = 0.01
[initial]
unit = "degrees"
theta = [170.0, 175.0]
[simulation]
t_end = 0.5
sample_dt = 0.05
[pivot]
x = 0.1
y = { kind = "sinusoid", amplitude = 0.02, frequency = 300.0, phase = 1.5707963267948966 }
""",
    "cart": """
[chain]
lengths = [0.6]
masses = [0.2]
damping = 0.01
[initial]
unit = "radians"
theta = [0.3]
[simulation]
t_end = 0.5
sample_dt = 0.05
[cart]
mass = 1.0
damping = 0.2
x0 = 0.5
v0 = -0.1
force = { kind = "table", t = [0.0, 0.25, 0.5], values = [0.0, 2.0, -1.0], interpolation = "cubic" }
""",
}


@pytest.mark.parametrize("fmt", ["npz", "csv"])
@pytest.mark.parametrize("kind", sorted(BASE_RUNS))
def test_pivot_cart_and_work_parts_round_trip(tmp_path, kind, fmt):
    scenario = loads_scenario(BASE_RUNS[kind])
    sol = scenario.run()
    # What the run has, so the round trip below compares something.
    if kind == "cart":
        assert sol.cart_x is not None and np.ptp(sol.cart_x) > 0 and np.ptp(sol.work.cart) > 0
        assert sol.work.dissipated[-1] > 0
    else:
        assert sol.cart_x is None and np.ptp(sol.pivot[:, 1]) > 0 and np.all(sol.pivot[:, 0] == 0.1)
        assert np.ptp(sol.work.pivot) > 0
    results = load_results(save_results(sol, tmp_path / f"r.{fmt}", scenario=scenario))
    _assert_same(results, sol)
    np.testing.assert_array_equal(np.asarray(results.work), np.asarray(sol.work))
    chain = results.chain
    np.testing.assert_array_equal(chain.damping, sol.chain.damping)
    np.testing.assert_array_equal(chain.friction, sol.chain.friction)
    assert chain.friction_velocity == sol.chain.friction_velocity and chain.cart == sol.chain.cart
    # saved again from the loaded results: the same file contents
    again = load_results(save_results(results, tmp_path / f"again.{fmt}"))
    _assert_same(again, sol)
    # and its scenario reruns the same run
    np.testing.assert_array_equal(results.scenario().run().theta, sol.theta)


def test_format_1_files_still_load(tmp_path, run):
    """A file written before issue 13: no pivot, work parts or losses; read as a fixed pivot, all
    the work the torque's, no losses."""
    scenario, sol = run
    path = save_results(sol, tmp_path / "new.npz", scenario=scenario)
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["metadata"]))
    meta["format_version"] = 1
    arrays["metadata"] = np.asarray(json.dumps(meta))
    for k in ("pivot", "work_torque", "work_pivot", "work_cart", "dissipated", "damping", "friction",
              "friction_velocity"):
        del arrays[k]
    old = tmp_path / "old.npz"
    np.savez(old, **arrays)
    results = load_results(old)
    np.testing.assert_array_equal(results.work.torque, np.asarray(sol.work))
    assert not results.work.dissipated.any() and not results.pivot.any() and results.cart_x is None
    assert not results.chain.damping.any() and results.chain.cart is None
    np.testing.assert_array_equal(results.theta, sol.theta)
    # CSV of format 1: the columns end with the positions
    csv = save_results(sol, tmp_path / "new.csv", scenario=scenario).read_text().splitlines()
    n = sol.theta.shape[1]
    keep = 1 + 3 * n + 3 + 2 * n
    meta_line = csv[1].replace('"format_version": 2', '"format_version": 1')
    body = [",".join(line.split(",")[:keep]) for line in csv[2:]]
    (tmp_path / "old.csv").write_text("\n".join([csv[0], meta_line] + body) + "\n")
    results = load_results(tmp_path / "old.csv")
    np.testing.assert_array_equal(results.theta, sol.theta)
    np.testing.assert_array_equal(results.work.torque, np.asarray(sol.work))


def test_a_cart_file_missing_its_series_is_refused(tmp_path):
    sol = loads_scenario(BASE_RUNS["cart"]).run()
    path = save_results(sol, tmp_path / "r.npz")
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    del arrays["cart_v"]
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(mp.InputError, match="a run with a cart stores cart .* got only cart, cart_x"):
        load_results(tmp_path / "bad.npz")
    arrays["cart_v"] = arrays["cart_x"][:-1]
    np.savez(tmp_path / "bad2.npz", **arrays)
    with pytest.raises(mp.InputError, match=r"cart_v must have shape \(11,\)"):
        load_results(tmp_path / "bad2.npz")
