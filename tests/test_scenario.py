"""Scenario files: every example loads and runs; every kind of bad file is refused with a message
naming the key, the value and what was expected."""
import math
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp
from multipendulum.scenario import ScenarioError, default_scenario_path, load_scenario, loads_scenario

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("*.toml"))

GOOD = """
name = "test"
[chain]
lengths = [1.0, 1.0, 1.0]
masses = [1.0, 1.0, 1.0]
[initial]
unit = "degrees"
theta = [90.0, 45.0, 0.0]
[simulation]
t_end = 0.5
"""


def test_examples_are_there():
    names = {p.stem for p in EXAMPLES}
    assert {"seed000_driven_chain", "seed001_compound_double", "triple", "chain50", "driven_rod"} <= names
    assert {"damped_double", "kapitza", "kapitza_slow", "shaken_horizontal"} <= names


@pytest.mark.parametrize("path", EXAMPLES + [default_scenario_path()], ids=lambda p: p.stem)
def test_example_loads_and_runs(path):
    scenario = load_scenario(path)
    chain = scenario.build_chain()
    assert chain.n == scenario.n == len(scenario.theta0) == len(scenario.omega0)
    short = scenario.replace(t_end=0.05)
    sol = short.run()
    assert sol.t[0] == 0.0 and sol.t[-1] == pytest.approx(0.05)
    assert np.all(np.isfinite(sol.theta))
    assert short.overrides == {"t_end": 0.05}


def test_examples_say_what_they_are():
    by_name = {p.stem: load_scenario(p) for p in EXAMPLES}
    seed000 = by_name["seed000_driven_chain"]
    assert seed000.chain["kind"] == "points" and "com" not in seed000.chain
    assert seed000.torque.kind == "sinusoid" and seed000.torque.convention == "generalized"
    seed001 = by_name["seed001_compound_double"]
    rods = mp.Chain.rods(seed001.chain["lengths"], seed001.chain["masses"])
    np.testing.assert_allclose(seed001.build_chain().com, rods.com, rtol=1e-14)
    np.testing.assert_allclose(seed001.build_chain().inertia, rods.inertia, rtol=1e-14)
    assert seed001.method == "rk4" and seed001.dt == 0.001 and seed001.form == "hamiltonian"
    assert seed001.replace(t_end=0.01).run().form == "hamiltonian"
    assert by_name["triple"].n == 3
    chain50 = by_name["chain50"]
    assert chain50.n == 50
    np.testing.assert_allclose(chain50.theta0[[0, -1]], np.radians([90.0, 45.0]))
    assert np.all(np.diff(chain50.theta0) < 0)  # a curve, not a straight line
    rod = by_name["driven_rod"]
    assert rod.chain["kind"] == "rods" and rod.torque.kind == "table" and rod.torque.convention == "joint"
    assert rod.files["driven_rod.csv"].startswith("#")


def _by_name(name):
    return load_scenario(ROOT / "examples" / f"{name}.toml")


def test_the_damped_double_pendulum_loses_its_energy_to_its_joints():
    scenario = _by_name("damped_double")
    assert scenario.chain["damping"] == [0.08, 0.05] and scenario.pivot is None and scenario.cart is None
    sol = scenario.run()
    energy, lost = sol.energy, sol.work.dissipated
    scale = 9.81 * float(np.sum(np.asarray(sol.chain.masses) * np.asarray(sol.chain.com)))
    assert np.all(np.diff(energy) < 1e-9 * scale)                # never gains energy
    assert np.all(np.diff(lost) >= 0) and lost[-1] > 0.8 * (energy[0] - energy.min())
    assert energy[-1] < energy[0] - 20.0                        # most of its 28 J above the bottom is gone
    np.testing.assert_allclose(energy[0] - energy[-1], lost[-1], rtol=1e-8)   # the balance, closed
    assert sol.stats.energy_error < 1e-8
    assert not sol.work.torque.any() and not sol.work.pivot.any() and not sol.work.cart.any()


def test_kapitza_stands_upright_on_a_fast_pivot_and_falls_on_a_slow_one():
    fast, slow = _by_name("kapitza"), _by_name("kapitza_slow")
    rod = fast.build_chain()
    m, c, length = rod.masses[0], rod.com[0], rod.lengths[0]
    i_pivot = rod.inertia[0] + m * c ** 2
    threshold = 2 * 9.81 * i_pivot / (m * c)                     # a^2 Omega^2 needed upright
    for scenario, stable in ((fast, True), (slow, False)):
        y = scenario.pivot["y"]
        assert y.kind == "sinusoid" and "x" not in scenario.pivot
        drive = (y.params["amplitude"] * y.params["frequency"]) ** 2
        assert (drive > 2 * threshold) if stable else (drive < 0.5 * threshold)
        assert abs(scenario.theta0[0] - math.pi) < 0.15 and scenario.chain["lengths"] == [length]
        sol = scenario.run()
        off = np.abs(sol.theta[:, 0] - math.pi)
        if stable:
            assert off.max() < 0.3, off.max()                   # within 0.3 rad of upright throughout
        else:
            assert off.max() > 1.5, off.max()                   # leaves upright: falls below horizontal
        np.testing.assert_allclose(sol.pivot[:, 1], y.params["amplitude"] * np.cos(y.params["frequency"] * sol.t),
                                   atol=1e-12)
        assert np.ptp(sol.work.pivot) > 0 and sol.stats.energy_error < 1e-8


def test_a_sideways_shaken_pendulum_is_pumped_up_by_its_pivot():
    scenario = _by_name("shaken_horizontal")
    sol = scenario.run()
    assert scenario.theta0[0] == 0.0 and np.all(scenario.omega0 == 0.0)
    assert np.abs(sol.theta[:, 0]).max() > 0.5                  # from rest to swings of over 0.5 rad
    assert sol.work.pivot[-1] > 1.0 and sol.work.dissipated[-1] > 0
    assert not sol.pivot[:, 1].any() and np.ptp(sol.pivot[:, 0]) == pytest.approx(0.1, rel=1e-3)
    assert sol.stats.energy_error < 1e-8


PIVOTED = """
[chain]
kind = "rods"
lengths = [0.5, 0.3]
masses = [0.1, 0.1]
damping = 0.01
friction = [0.0, 0.002]
friction_velocity = 0.05
[initial]
unit = "radians"
theta = [3.0, 3.1]
[simulation]
t_end = 0.3
"""


def test_run_is_simulate_with_the_pivot_and_the_cart():
    pivot = loads_scenario(PIVOTED + """
[pivot]
x = { kind = "table", t = [0.0, 0.1, 0.2, 0.3], values = [0.0, 0.01, -0.01, 0.0] }
y = { kind = "sinusoid", amplitude = 0.02, frequency = 250.0, offset = 0.5 }
""")
    chain = mp.Chain.rods([0.5, 0.3], [0.1, 0.1], damping=0.01, friction=[0.0, 0.002], friction_velocity=0.05)
    ref = mp.simulate(chain, [3.0, 3.1], [0.0, 0.0], 0.3, t_eval=pivot.t_eval(),
                      pivot=mp.Pivot(x=mp.Table([0.0, 0.1, 0.2, 0.3], [0.0, 0.01, -0.01, 0.0], kind="cubic"),
                                     y=mp.Sinusoid(0.02, 250.0, offset=0.5)))
    sol = pivot.run()
    for name in ("theta", "omega", "energy", "pivot"):
        np.testing.assert_array_equal(getattr(sol, name), getattr(ref, name), err_msg=name)
    np.testing.assert_array_equal(sol.work.pivot, ref.work.pivot)
    assert sol.pivot[0, 1] == 0.5

    cart = loads_scenario(PIVOTED + """
[cart]
mass = 2.0
damping = 0.3
x0 = -0.2
v0 = 0.4
[cart.force]
kind = "sinusoid"
amplitude = 1.5
frequency = 4.0
""")
    chain = mp.Chain.rods([0.5, 0.3], [0.1, 0.1], damping=0.01, friction=[0.0, 0.002], friction_velocity=0.05,
                          cart=mp.Cart(2.0, 0.3))
    assert cart.build_chain().cart == mp.Cart(2.0, 0.3)
    ref = mp.simulate(chain, [3.0, 3.1], [0.0, 0.0], 0.3, t_eval=cart.t_eval(), cart_x0=-0.2, cart_v0=0.4,
                      cart_force=mp.Sinusoid(1.5, 4.0))
    sol = cart.run()
    for name in ("theta", "omega", "cart_x", "cart_v", "energy"):
        np.testing.assert_array_equal(getattr(sol, name), getattr(ref, name), err_msg=name)
    np.testing.assert_array_equal(sol.work.cart, ref.work.cart)
    assert sol.cart_x[0] == -0.2 and sol.cart_v[0] == 0.4
    # A number is a constant: a fixed offset of the pivot, a constant push on the cart.
    offset = loads_scenario(PIVOTED + "[pivot]\nx = 0.25\n")
    assert offset.build_base()["pivot"] == mp.Pivot(x=0.25, y=0.0)
    np.testing.assert_array_equal(offset.run().pivot, np.tile([0.25, 0.0], (31, 1)))
    pushed = loads_scenario(PIVOTED + "[cart]\nmass = 1.0\nforce = 2.5\n")
    assert pushed.build_base() == {"cart_x0": 0.0, "cart_v0": 0.0, "cart_force": 2.5}


def test_pivot_and_force_tables_from_csv_files():
    files = {"y.csv": "# the pivot's height\nt,y\n0,0\n0.1,0.01\n0.2,0\n0.3,0.01\n",
             "f.csv": "t,F\n0,0\n0.3,3\n"}
    pivot = loads_scenario(PIVOTED + '[pivot]\ny = { kind = "table", file = "y.csv" }\n', files=files)
    y = pivot.build_base()["pivot"].y
    assert isinstance(y, mp.Table) and y.kind == "cubic"
    np.testing.assert_array_equal(np.asarray(y.values), [0, 0.01, 0, 0.01])
    assert pivot.files == {"y.csv": files["y.csv"]}
    cart = loads_scenario(PIVOTED + '[cart]\nmass = 1.0\nforce = { kind = "table", file = "f.csv" }\n', files=files)
    force = cart.build_base()["cart_force"]
    assert isinstance(force, mp.Table) and force.kind == "linear"
    np.testing.assert_array_equal(np.asarray(force.t), [0, 0.3])
    assert np.all(np.isfinite(cart.run().cart_x))
    bad = {"y.csv": "t,y\n0,0\n0.1,x\n"}
    with pytest.raises(ScenarioError, match=r"^key 'pivot\.y\.file': y\.csv line 3, column 2 \('y', y\): "
                                            r"expected a number, got 'x'$"):
        loads_scenario(PIVOTED + '[pivot]\ny = { kind = "table", file = "y.csv" }\n', files=bad)
    with pytest.raises(ScenarioError, match=r"^key 'cart\.force\.file': f\.csv line 1: expected 2 columns "
                                            r"\(t, then force in N\), got 3$"):
        loads_scenario(PIVOTED + '[cart]\nmass = 1.0\nforce = { kind = "table", file = "f.csv" }\n',
                       files={"f.csv": "0,1,2\n1,2,3\n"})


def test_degrees_and_radians_mean_the_same_run():
    deg = loads_scenario(GOOD)
    rad = loads_scenario(GOOD.replace('"degrees"', '"radians"').replace("[90.0, 45.0, 0.0]",
                                                                        f"[{math.pi / 2!r}, {math.pi / 4!r}, 0.0]"))
    np.testing.assert_allclose(deg.theta0, [math.pi / 2, math.pi / 4, 0.0], rtol=1e-15)
    np.testing.assert_allclose(rad.theta0, deg.theta0, rtol=1e-15)


def test_run_is_simulate_with_the_scenario_arguments():
    text = GOOD + """
[torque]
kind = "sinusoid"
convention = "joint"
amplitude = [0.5, 0.0, 0.2]
frequency = 2.0
"""
    scenario = loads_scenario(text)
    sol = scenario.run()
    chain = mp.Chain(lengths=[1, 1, 1], masses=[1, 1, 1])
    ref = mp.simulate(chain, np.radians([90.0, 45.0, 0.0]), [0, 0, 0], 0.5, t_eval=np.linspace(0, 0.5, 51),
                      joint_torque=mp.Sinusoid([0.5, 0.0, 0.2], [2.0, 2.0, 2.0]))
    np.testing.assert_array_equal(sol.t, ref.t)
    np.testing.assert_array_equal(sol.theta, ref.theta)
    np.testing.assert_array_equal(sol.work, ref.work)


def test_torque_kinds_and_conventions():
    const = loads_scenario(GOOD + '[torque]\nkind = "constant"\nconvention = "generalized"\nvalue = 0.25\n')
    kwargs = const.build_torque()
    assert list(kwargs) == ["torque"]
    np.testing.assert_array_equal(kwargs["torque"], [0.25, 0.25, 0.25])
    sin = loads_scenario(GOOD + '[torque]\nkind = "sinusoid"\nconvention = "joint"\namplitude = 1\nfrequency = 2\n')
    assert isinstance(sin.build_torque()["joint_torque"], mp.Sinusoid)
    table = loads_scenario(
        GOOD + '[torque]\nkind = "table"\nconvention = "generalized"\nfile = "u.csv"\n',
        files={"u.csv": "t,a,b,c\n0,1,2,3\n1,4,5,6\n"},
    )
    torque = table.build_torque()["torque"]
    assert isinstance(torque, mp.Table)
    np.testing.assert_array_equal(np.asarray(torque.values), [[1, 2, 3], [4, 5, 6]])
    assert table.files == {"u.csv": "t,a,b,c\n0,1,2,3\n1,4,5,6\n"}


def test_scenario_error_is_an_input_error():
    assert issubclass(ScenarioError, mp.InputError) and issubclass(ScenarioError, ValueError)


def _edit(old, new, base=GOOD):
    assert old in base
    return base.replace(old, new)


BAD = [
    # (what, text, key, message fragment)
    ("unknown key", _edit("lengths =", "lenghts ="), "chain.lenghts", "unknown key; did you mean 'lengths'?"),
    ("unknown top", GOOD + "\n[outputs]\nfps = 3\n", "outputs", "did you mean 'output'?"),
    ("unknown section key", _edit("t_end = 0.5", "t_end = 0.5\nstep = 0.1"), "simulation.step", "unknown key"),
    ("wrong type", _edit("[1.0, 1.0, 1.0]\nmasses", '"long"\nmasses'), "chain.lengths",
     "expected a number or an array of numbers (one per link), got a string 'long'"),
    ("wrong element type", _edit("masses = [1.0, 1.0, 1.0]", 'masses = [1.0, "1", 1.0]'), "chain.masses[1]",
     "expected a number >= 0, got a string '1'"),
    ("missing field", _edit("masses = [1.0, 1.0, 1.0]\n", ""), "chain.masses", "missing; expected link masses"),
    ("missing section", _edit("[simulation]\nt_end = 0.5\n", ""), "simulation", "missing"),
    ("negative length", _edit("lengths = [1.0, 1.0, 1.0]", "lengths = [1.0, 1.0, -1]"), "chain.lengths[2]",
     "must be > 0, got -1"),
    ("zero length", _edit("lengths = [1.0, 1.0, 1.0]", "lengths = [0, 1.0, 1.0]"), "chain.lengths[0]",
     "must be > 0, got 0"),
    ("negative mass", _edit("masses = [1.0, 1.0, 1.0]", "masses = [1.0, -2.5, 1.0]"), "chain.masses[1]",
     "must be >= 0, got -2.5"),
    ("nan", _edit("masses = [1.0, 1.0, 1.0]", "masses = [1.0, nan, 1.0]"), "chain.masses[1]", "must be finite"),
    ("count", _edit("masses = [1.0, 1.0, 1.0]", "masses = [1.0, 1.0]"), "chain.masses",
     "expected 3 values (one per link), got 2"),
    ("singular", _edit("masses = [1.0, 1.0, 1.0]", "masses = [1.0, 1.0, 0.0]"), "chain", "singular"),
    ("rods with com", _edit("[chain]", '[chain]\nkind = "rods"\ncom = [0.5, 0.5, 0.5]'), "chain.com",
     'cannot be given with kind = "rods"'),
    ("kind", _edit("[chain]", '[chain]\nkind = "rod"'), "chain.kind",
     'expected one of "points", "rods", got \'rod\' (did you mean "rods"?)'),
    ("unit missing", _edit('unit = "degrees"\n', ""), "initial.unit", 'missing; expected "degrees" or "radians"'),
    ("unit", _edit('"degrees"', '"deg"'), "initial.unit", 'got \'deg\' (did you mean "degrees"?)'),
    ("t_end", _edit("t_end = 0.5", "t_end = -1.0"), "simulation.t_end", "must be > 0, got -1.0"),
    ("t_end type", _edit("t_end = 0.5", 't_end = "10 s"'), "simulation.t_end", "expected a number > 0, got a string"),
    ("method", _edit("t_end = 0.5", 't_end = 0.5\nmethod = "rk5"'), "simulation.method",
     'expected one of "rk4", "dop853", "gauss4", "gauss6", got \'rk5\''),
    ("fixed step without dt", _edit("t_end = 0.5", 't_end = 0.5\nmethod = "gauss6"'), "simulation.dt",
     'missing; method "gauss6" takes fixed steps'),
    ("form", _edit("t_end = 0.5", 't_end = 0.5\nform = "newtonian"'), "simulation.form",
     'expected one of "lagrangian", "hamiltonian"'),
    ("form with gauss", _edit("t_end = 0.5", 't_end = 0.5\nmethod = "gauss4"\ndt = 0.01\nform = "lagrangian"'),
     "simulation.form", 'only applies to "rk4" and "dop853"'),
    ("torque kind", GOOD + '[torque]\nkind = "square"\nconvention = "joint"\n', "torque.kind",
     'expected one of "constant", "sinusoid", "table"'),
    ("torque convention", GOOD + '[torque]\nkind = "constant"\nvalue = 1.0\n', "torque.convention",
     'missing; expected "generalized"'),
    ("torque key of another kind", GOOD + '[torque]\nkind = "constant"\nconvention = "joint"\nvalue = 1.0\n'
     "amplitude = 2.0\n", "torque.amplitude", "unknown key"),
    ("table file", GOOD + '[torque]\nkind = "table"\nconvention = "joint"\nfile = "nowhere.csv"\n', "torque.file",
     "cannot read"),
    ("animation suffix", GOOD + '[output]\nanimation = "movie.avi"\n', "output.animation",
     "expected a file name ending in .gif or .mp4, or false, got 'movie.avi'"),
    ("plot kind", GOOD + '[output]\nplots = ["angles", "energie"]\n', "output.plots[1]",
     '(did you mean "energy"?)'),
    ("ramp key", _edit("theta = [90.0, 45.0, 0.0]", "theta = { from = 1, too = 2 }"), "initial.theta.too",
     "did you mean 'to'?"),
    # losses, a moving pivot, a cart (issue 13)
    ("negative damping", _edit("[chain]", "[chain]\ndamping = [0.1, -0.5, 0.0]"), "chain.damping[1]",
     "must be >= 0, got -0.5"),
    ("nan damping", _edit("[chain]", "[chain]\ndamping = nan"), "chain.damping", "must be finite, got nan"),
    ("infinite friction", _edit("[chain]", "[chain]\nfriction = [0.0, inf, 0.0]"), "chain.friction[1]",
     "must be finite, got inf"),
    ("negative friction", _edit("[chain]", "[chain]\nfriction = -1"), "chain.friction", "must be >= 0, got -1"),
    ("damping count", _edit("[chain]", "[chain]\ndamping = [0.1, 0.1]"), "chain.damping",
     "expected 3 values (one per link), got 2"),
    ("zero friction_velocity", _edit("[chain]", "[chain]\nfriction_velocity = 0"), "chain.friction_velocity",
     "must be > 0, got 0"),
    ("friction_velocity type", _edit("[chain]", "[chain]\nfriction_velocity = [0.1]"), "chain.friction_velocity",
     "expected a number > 0, got an array [0.1]"),
    ("pivot key", GOOD + "[pivot]\nz = 1.0\n", "pivot.z", "unknown key; expected one of: x, y"),
    ("pivot type", GOOD + '[pivot]\ny = "shake"\n', "pivot.y",
     'expected a number (m) or a table {kind = "sinusoid" or "table", ...}, got a string \'shake\''),
    ("pivot kind", GOOD + '[pivot]\ny = { kind = "sine", amplitude = 0.1, frequency = 2 }\n', "pivot.y.kind",
     'expected one of "sinusoid", "table", got \'sine\''),
    ("pivot sinusoid key", GOOD + '[pivot]\ny = { kind = "sinusoid", amplitude = 0.1, frequency = 2, freq = 1 }\n',
     "pivot.y.freq", "unknown key; did you mean 'frequency'?"),
    ("pivot frequency", GOOD + '[pivot]\ny = { kind = "sinusoid", amplitude = 0.1 }\n', "pivot.y.frequency",
     "missing; expected the angular frequency in rad/s"),
    ("pivot amplitude nan", GOOD + '[pivot]\nx = { kind = "sinusoid", amplitude = nan, frequency = 2 }\n',
     "pivot.x.amplitude", "must be finite"),
    ("pivot one point", GOOD + '[pivot]\ny = { kind = "table", t = [0.0], values = [0.1] }\n', "pivot.y",
     "at least 2 samples, got 1"),
    ("pivot times", GOOD + '[pivot]\ny = { kind = "table", t = [0.0, 1.0, 1.0], values = [0, 1, 2] }\n',
     "pivot.y", "strictly increasing"),
    ("pivot table count", GOOD + '[pivot]\ny = { kind = "table", t = [0.0, 1.0], values = [0.1] }\n',
     "pivot.y.values", "expected 2 values (one per time in t), got 1"),
    ("pivot table linear", GOOD + '[pivot]\ny = { kind = "table", t = [0, 1], values = [0, 1], '
     'interpolation = "linear" }\n', "pivot.y.interpolation", "unknown key; expected one of: kind, t, values, file"),
    ("pivot table both", GOOD + '[pivot]\ny = { kind = "table", file = "y.csv", t = [0, 1] }\n', "pivot.y.t",
     "cannot be given with file"),
    ("pivot spline overflow", GOOD + '[pivot]\ny = { kind = "table", t = [0, 1e-300, 1], values = [0, 1e300, 0] }\n',
     "pivot.y", "values[0] and values[1]: the cubic spline through 0 at t = 0 and 1e+300 at t = 1e-300 overflows"),
    ("pivot with cart", GOOD + "[pivot]\ny = 0.1\n[cart]\nmass = 1.0\n", "pivot",
     "cannot be given with [cart]"),
    ("cart mass missing", GOOD + "[cart]\ndamping = 0.1\n", "cart.mass", "missing; expected the cart's mass in kg"),
    ("cart mass zero", GOOD + "[cart]\nmass = 0\n", "cart.mass", "must be > 0, got 0"),
    ("cart mass negative", GOOD + "[cart]\nmass = -2.0\n", "cart.mass", "must be > 0, got -2.0"),
    ("cart mass inf", GOOD + "[cart]\nmass = inf\n", "cart.mass", "must be finite, got inf"),
    ("cart damping", GOOD + "[cart]\nmass = 1.0\ndamping = -0.1\n", "cart.damping", "must be >= 0, got -0.1"),
    ("cart damping nan", GOOD + "[cart]\nmass = 1.0\ndamping = nan\n", "cart.damping", "must be finite"),
    ("cart key", GOOD + "[cart]\nmass = 1.0\nx_0 = 1.0\n", "cart.x_0", "unknown key; did you mean 'x0'?"),
    ("cart force type", GOOD + '[cart]\nmass = 1.0\nforce = [1.0, 2.0]\n', "cart.force",
     "expected a number (N) or a table"),
    ("cart force one point", GOOD + '[cart]\nmass = 1.0\nforce = { kind = "table", t = [0], values = [1] }\n',
     "cart.force", "at least 2 samples, got 1"),
    ("cart force interpolation", GOOD + '[cart]\nmass = 1.0\nforce = { kind = "table", t = [0, 1], '
     'values = [0, 1], interpolation = "spline" }\n', "cart.force.interpolation",
     'expected one of "linear", "cubic", got \'spline\''),
    ("cart force file", GOOD + '[cart]\nmass = 1.0\nforce = { kind = "table", file = "nowhere.csv" }\n',
     "cart.force.file", "cannot read"),
]


@pytest.mark.parametrize("what,text,key,fragment", BAD, ids=[b[0] for b in BAD])
def test_bad_scenarios_name_key_value_and_expectation(what, text, key, fragment):
    with pytest.raises(ScenarioError) as info:
        loads_scenario(text, base_dir=ROOT)
    err = info.value
    assert err.key == key
    assert str(err).startswith(f"key '{key}': ")
    assert fragment in str(err)


def test_the_seed_style_message():
    with pytest.raises(ScenarioError, match=r"^key 'chain\.lengths\[2\]': must be > 0, got -1$"):
        loads_scenario(_edit("lengths = [1.0, 1.0, 1.0]", "lengths = [1, 1, -1]"))


def test_table_csv_problems(tmp_path):
    base = GOOD + '[torque]\nkind = "table"\nconvention = "generalized"\nfile = "u.csv"\n'
    cases = {
        "t,a,b\n0,1,2\n1,3,4\n": "line 2: expected 4 columns (t, then one torque per link), got 3",
        "0,1,2,3\n0,1,2,3\n": "u.csv line 2, column 1 (t): times must increase, got 0 after 0 on line 1",
        "0,1,2,3\n1,x,2,3\n": "u.csv line 2, column 2 (link 1): expected a number, got 'x'",
        "0,1,2,3\n": "expected at least 2 rows",
    }
    for csv, fragment in cases.items():
        (tmp_path / "u.csv").write_text(csv)
        with pytest.raises(ScenarioError, match="key 'torque.file'") as info:
            loads_scenario(base, base_dir=tmp_path)
        assert fragment in str(info.value), (csv, str(info.value))


def test_endless_or_huge_files_are_refused_not_read_for_ever(tmp_path):
    base = GOOD + '[torque]\nkind = "table"\nconvention = "generalized"\nfile = "/dev/zero"\n'
    with pytest.raises(ScenarioError, match=r"key 'torque.file'.*larger than 64 MiB"):
        loads_scenario(base, base_dir=tmp_path)
    with pytest.raises(ScenarioError, match="cannot read scenario file: larger than 64 MiB"):
        load_scenario("/dev/zero")
    (tmp_path / "latin1.csv").write_bytes(b"0,1,2,3\n1,\xe9,2,3\n")
    with pytest.raises(ScenarioError, match="is not UTF-8 text"):
        loads_scenario(base.replace("/dev/zero", "latin1.csv"), base_dir=tmp_path)


def test_the_parsers_own_limits_are_scenario_errors():
    # Found by the fuzz target: a 53-digit chain.n overflowed list sizes; the parser itself
    # refuses integers of over 4300 digits and deep nesting with raw exceptions.
    with pytest.raises(ScenarioError, match=r"key 'chain\.n': must be from 1 to 1000000, got 6{53}"):
        loads_scenario("[chain]\nn = " + "6" * 53 + "\nlengths = 0.02\nmasses = 1.0\n")
    with pytest.raises(ScenarioError, match="not a usable TOML file: Exceeds the limit"):
        loads_scenario("[chain]\nn = " + "9" * 5000 + "\n")
    with pytest.raises(ScenarioError, match="nested too deeply"):
        loads_scenario("a = " + "[" * 100_000 + "]" * 100_000)


def test_unreadable_files_and_bad_toml(tmp_path):
    with pytest.raises(ScenarioError, match="cannot read scenario file") as info:
        load_scenario(tmp_path / "missing.toml")
    assert info.value.key is None and info.value.path == tmp_path / "missing.toml"
    bad = tmp_path / "bad.toml"
    bad.write_text("[chain\nlengths = 1\n")
    with pytest.raises(ScenarioError, match="not valid TOML"):
        load_scenario(bad)


def test_scalars_broadcast_with_n():
    text = """
[chain]
n = 4
lengths = 0.25
masses = 0.5
[initial]
unit = "radians"
theta = { from = 0.0, to = 0.3 }
omega = 0.1
[simulation]
t_end = 1.0
"""
    s = loads_scenario(text)
    assert s.chain["lengths"] == [0.25] * 4 and s.chain["masses"] == [0.5] * 4
    np.testing.assert_allclose(s.theta0, [0.0, 0.1, 0.2, 0.3])
    np.testing.assert_allclose(s.omega0, [0.1] * 4)
    with pytest.raises(ScenarioError, match=r"key 'chain\.lengths': expected 4 values"):
        loads_scenario(text.replace("lengths = 0.25", "lengths = [1.0, 1.0]"))


def test_sample_times_end_at_t_end():
    s = loads_scenario(GOOD.replace("t_end = 0.5", "t_end = 0.123\nsample_dt = 0.05"))
    t = s.t_eval()
    assert t[0] == 0.0 and t[-1] == 0.123 and np.all(np.diff(t) <= 0.05 + 1e-15)


def test_the_documented_example_is_valid():
    text = (ROOT / "docs" / "cli.md").read_text()
    block = text.split("```toml\n", 1)[1].split("```", 1)[0]
    scenario = loads_scenario(block)
    assert scenario.n == 3 and scenario.torque.kind == "sinusoid"
    assert scenario.outputs.animation == "triple.gif"
    assert np.all(np.isfinite(scenario.replace(t_end=0.05).run().theta))


def test_the_documented_messages_are_the_real_ones():
    text = (ROOT / "docs" / "cli.md").read_text()
    with pytest.raises(ScenarioError) as info:
        loads_scenario(_edit("lengths =", "lenghts ="))
    assert f"mine.toml: {info.value}\n" in text
