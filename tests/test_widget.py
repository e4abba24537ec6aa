"""The notebook widgets: mp.widget (the viewer's engine running live in a cell) and mp.show /
Solution.show (a computed solution played in a cell).

Python side: the setup the browser gets is the chain's own (compared against its attributes),
the drive maps onto the page's setup, every bad value is refused with the package's own class and
message (on construction and on assignment, leaving the widget as it was), a chain longer than
the viewer shows and Python functions are refused saying what to do instead, the player's frames
are the solution's states at up to 60 frames per simulated second, and the browser module is
built from the viewer's own files by a checked inliner.

In a real browser: JupyterLab started headless by the test (its settings in a temporary
directory), a notebook executed through its UI in Debian's chromium with Playwright: the
widget's canvas animates, Python's reads of ``w.t`` increase, a value the browser's core refuses
is shown in the widget and reported in ``w.error``, and ``sol.show()`` animates. Skipped without
chromium, Playwright or JupyterLab, failed instead with MULTIPENDULUM_REQUIRE_BROWSER=1 (CI).
"""
import importlib.util
import io
import json
import os
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp

anywidget = pytest.importorskip("anywidget", reason="the widget extra is not installed (pip install -e '.[test]')")

from multipendulum import _notebook, notebook  # noqa: E402
from multipendulum._notebook import BundleError, bundle  # noqa: E402
from test_viewer import CHROMIUM, CHROMIUM_ARGS, _browser_missing  # noqa: E402  (tests/test_viewer.py)

ROOT = Path(__file__).resolve().parents[1]
LIMIT = int(mp._core.LIMITS["viewer_max_links"])


# ----------------------------------------------------------------------------------------------
# The live widget, Python side


def test_the_browser_gets_the_chains_own_setup():
    chain = mp.Chain.rods([1.0, 0.7, 0.4], [1.0, 2.0, 0.5], g=9.5, damping=[0.1, 0.0, 0.2], friction=0.05,
                          friction_velocity=0.01)
    w = mp.widget(chain, [0.1, 0.2, 0.3], [1.0, 0.0, -1.0], method="gauss6", dt=0.01, speed=2.0)
    c = w._chain
    for name in ("lengths", "masses", "com", "inertia"):
        assert c[name] == getattr(chain, name).tolist(), name
    assert c["friction_velocity"] == chain.friction_velocity
    assert c["look"] == "rods"
    assert (c["pivot"], c["torque"], c["cart"]) == (None, None, None)
    assert w.g == chain.g and w.damping == chain.damping.tolist() and w.friction == chain.friction.tolist()
    assert (w.theta0, w.omega0) == ([0.1, 0.2, 0.3], [1.0, 0.0, -1.0])
    assert (w.method, w.dt, w.speed, w.playing) == ("gauss6", 0.01, 2.0, False)
    assert (w.rtol, w.atol) == (mp.DEFAULTS["rtol"], mp.DEFAULTS["atol"])
    assert w.chain == chain
    assert w._wasm == (_notebook.WEB / "multipendulum.wasm").read_bytes()
    # Until the browser reports: the start state, its energy the core's.
    assert (w.t, w.theta, w.omega, w.error) == (0.0, [0.1, 0.2, 0.3], [1.0, 0.0, -1.0], "")
    assert w.energy == pytest.approx(chain.energy([0.1, 0.2, 0.3], [1.0, 0.0, -1.0]), rel=1e-15)
    assert w.kinetic + w.potential == pytest.approx(w.energy, rel=1e-14)
    # Point masses (or any other chain) are drawn with their bobs.
    general = mp.Chain([1, 1], [1, 2], com=[0.5, 1.0], inertia=[0.1, 0.0])
    w = mp.widget(general, [0.5, 0.0])
    assert w._chain["look"] == "points" and w._chain["com"] == [0.5, 1.0] and w._chain["inertia"] == [0.1, 0.0]
    assert w.omega0 == [0.0, 0.0]


def test_the_drive_is_the_pages_setup():
    chain = mp.Chain([1.0, 1.0], [1.0, 1.0])
    w = mp.widget(chain, [0.1, 0.2], joint_torque=mp.Sinusoid([0.0, 0.5], 3.0, phase=[0.0, 1.0]),
                  pivot=mp.Pivot(x=0.1, y=mp.Sinusoid(amplitude=0.02, frequency=50.0)))
    assert w._chain["torque"] == {"convention": "joint", "kind": "sinusoid", "amplitude": [0.0, 0.5],
                                  "frequency": [3.0, 3.0], "phase": [0.0, 1.0], "offset": [0.0, 0.0]}
    assert w._chain["pivot"] == {"x": 0.1, "y": {"kind": "sinusoid", "amplitude": 0.02, "frequency": 50.0,
                                                 "phase": 0.0, "offset": 0.0}}
    table = mp.Table([0.0, 1.0, 2.0], [[0.0, 1.0], [1.0, 0.0], [0.0, 0.0]], kind="cubic")
    w = mp.widget(chain, [0.1, 0.2], torque=table, pivot=mp.Pivot(y=mp.Table([0, 1, 2], [0.0, 0.1, 0.0], kind="cubic")))
    assert w._chain["torque"] == {"convention": "generalized", "kind": "table", "t": [0.0, 1.0, 2.0],
                                  "values": [[0.0, 1.0], [1.0, 0.0], [0.0, 0.0]], "interpolation": "cubic"}
    assert w._chain["pivot"]["y"] == {"kind": "table", "t": [0.0, 1.0, 2.0], "values": [0.0, 0.1, 0.0],
                                      "interpolation": "cubic"}
    w = mp.widget(chain, [0.1, 0.2], torque=[1.0, -1.0])
    assert w._chain["torque"] == {"convention": "generalized", "kind": "constant", "value": [1.0, -1.0]}
    cartpole = mp.Chain.rods([0.6], [0.1], cart=mp.Cart(1.0, damping=0.2))
    w = mp.widget(cartpole, [3.0], cart_x0=0.5, cart_v0=-1.0, cart_force=mp.Table([0, 1], [2.0, 0.0]))
    assert w._chain["cart"] == {"mass": 1.0, "damping": 0.2,
                                "force": {"kind": "table", "t": [0.0, 1.0], "values": [2.0, 0.0], "interpolation": "linear"}}
    assert (w.cart_x0, w.cart_v0, w.base) == (0.5, -1.0, [0.5, 0.0])
    assert w.energy == pytest.approx(cartpole.energy([3.0], [0.0], cart_v=-1.0), rel=1e-15)


def _widget():
    return mp.widget(mp.Chain([1.0, 1.0], [1.0, 1.0]), [2.0, 2.5])


def test_the_reported_state_is_read_only_in_python():
    import traitlets

    w = _widget()
    assert set(w._setup.start) == set(notebook.STATE)
    for name in notebook.STATE:
        with pytest.raises(traitlets.TraitError, match=f'The "{name}" trait is read-only'):
            setattr(w, name, getattr(w, name))


# (name, value, message): the package's own messages (mp.simulate's, the core's), nothing restated.
BAD_VALUES = [
    ("g", float("nan"), "g must be finite, got NaN"),
    ("g", "heavy", "g must be a number, got str 'heavy'"),
    ("damping", [-1.0, 0.0], "damping[0] must be >= 0 and finite, got -1"),
    ("friction", [0.0, 0.0, 0.0], "friction must be a number or have 2 entries (one per joint), got shape (3,)"),
    ("theta0", [1.0, 2.0, 3.0], "theta0 must have shape (2,) or (..., 2) (one entry per link), got shape (3,)"),
    ("theta0", [[1.0, 2.0]], "theta0 must have shape (2,): a widget runs one chain (batches are mp.simulate's), got shape (1, 2)"),
    ("omega0", [float("inf"), 0.0], "omega0[0] must be finite, got inf"),
    ("method", "rk5", 'method must be one of rk4, dop853, gauss4, gauss6, got "rk5"'),
    ("method", "rk4", "method rk4 takes a fixed step: give dt"),
    ("dt", -0.01, "dt must be > 0 and finite, got -0.01"),
    ("rtol", 1e-20, "rtol must be >= 1e-15 and finite, got 1e-20"),
    ("cart_x0", 1.0, "cart_x0, cart_v0 and cart_force need a chain with a cart (mp.Chain(..., cart=mp.Cart(mass)))"),
    ("speed", 0.0, "speed must be > 0 and finite (simulated seconds per second), got 0"),
    ("speed", float("inf"), "speed must be > 0 and finite (simulated seconds per second), got inf"),
    ("playing", "yes", "playing must be True or False, got 'yes'"),
    ("height", 10, "height must be a whole number of pixels from 80 to 4000, got 10"),
]


@pytest.mark.parametrize("name, value, message", BAD_VALUES, ids=[f"{n}={v!r}" for n, v, _ in BAD_VALUES])
def test_bad_values_are_refused_on_assignment_and_nothing_changes(name, value, message):
    w = _widget()
    before = {k: getattr(w, k) for k in notebook.PARAMETERS + ("speed", "playing", "height", "_restart")}
    with pytest.raises(mp.InputError) as info:
        setattr(w, name, value)
    assert str(info.value) == message
    assert {k: getattr(w, k) for k in before} == before


@pytest.mark.parametrize("kwargs, message", [
    ({"g": -1.0}, None),  # a chain's g may be negative (gravity upwards): accepted
    ({"method": "rk4"}, "method rk4 takes a fixed step: give dt"),
    ({"theta0": [1.0]}, "theta0 must have shape (2,) or (..., 2) (one entry per link), got shape (1,)"),
    ({"speed": -1}, "speed must be > 0 and finite (simulated seconds per second), got -1"),
    ({"torque": [1.0, float("nan")]}, "torque[1] must be finite, got nan"),
    ({"pivot": mp.Pivot(x=mp.Table([0, 1], [0, 1]))},
     'pivot x: a pivot Table must be kind="cubic" (the motion needs two derivatives), got "linear"'),
])
def test_bad_values_are_refused_on_construction(kwargs, message):
    chain = mp.Chain([1.0, 1.0], [1.0, 1.0], g=kwargs.pop("g", 9.81))
    args = {"theta0": kwargs.pop("theta0", [2.0, 2.5])}
    if message is None:
        assert mp.widget(chain, **args, **kwargs).g == chain.g
        return
    with pytest.raises(mp.InputError) as info:
        mp.widget(chain, **args, **kwargs)
    assert str(info.value) == message


def test_a_change_restarts_the_run_from_its_start_state():
    w = _widget()
    w.set_trait("t", 3.5)  # as a report from the browser would
    w.set_trait("theta", [0.3, 0.4])
    w.g = 1.62
    assert (w.t, w.theta, w.chain.g, w.g) == (0.0, [2.0, 2.5], 1.62, 1.62)
    assert w.energy == pytest.approx(w.chain.energy([2.0, 2.5], [0.0, 0.0]), rel=1e-15)
    w.theta0 = np.array([0.1, -0.1])  # arrays are taken, and stored as plain floats for the browser
    assert w.theta0 == [0.1, -0.1] and type(w.theta0[0]) is float and w.theta == [0.1, -0.1]
    w.damping = 0.5
    assert w.damping == [0.5, 0.5] and w.chain.damping.tolist() == [0.5, 0.5]
    with pytest.raises(mp.InputError, match="^method rk4 takes a fixed step: give dt$"):
        w.method = "rk4"  # dt is None: one at a time, dt first (dop853 takes it as its first step)
    w.set(method="rk4", dt=0.005)  # or both at once
    assert (w.method, w.dt) == ("rk4", 0.005)
    with pytest.raises(mp.InputError, match="^dt must be > 0 and finite, got 0$"):
        w.set(g=5.0, dt=0.0)
    assert (w.g, w.dt) == (1.62, 0.005)
    with pytest.raises(mp.InputError, match="^set takes theta0, omega0, .*; got speed$"):
        w.set(speed=2.0)
    restarts = w._restart
    w.set_trait("t", 1.0)
    w.restart()
    assert (w._restart, w.t) == (restarts + 1, 0.0)


def test_a_chain_longer_than_the_viewer_shows_is_refused():
    n = LIMIT + 1
    chain = mp.Chain(np.full(n, 0.1), np.ones(n))
    message = (f"mp.widget shows chains of up to {LIMIT} links (the browser viewer's limit), this one has {n}: "
               "run it with mp.simulate and write a video with mp.animate(sol, path)")
    with pytest.raises(mp.InputError) as info:
        mp.widget(chain, np.zeros(n))
    assert str(info.value) == message
    sol = mp.simulate(chain, np.full(n, 0.1), np.zeros(n), 0.01, method="rk4", dt=0.005)
    with pytest.raises(mp.InputError) as info:
        sol.show()
    assert str(info.value) == message.replace("mp.widget", "show")
    # At the limit it is shown.
    mp.widget(mp.Chain(np.full(LIMIT, 0.1), np.ones(LIMIT)), np.zeros(LIMIT))


def test_python_functions_are_refused():
    chain = mp.Chain([1.0, 1.0], [1.0, 1.0])
    tail = "or run mp.simulate with the function and play the solution with sol.show()"
    cases = [
        ({"torque": lambda t: [0.0, 0.0]}, "give torque as numbers (one per link), mp.Sinusoid or mp.Table, "),
        ({"joint_torque": lambda t, th, om: -om}, "give joint_torque as numbers (one per link), mp.Sinusoid or mp.Table, "),
        ({"pivot": mp.Pivot(y=lambda t: (0.0, 0.0, 0.0))}, 'give each pivot axis as a number, mp.Sinusoid or mp.Table(kind="cubic"), '),
    ]
    for kwargs, middle in cases:
        with pytest.raises(mp.InputError) as info:
            mp.widget(chain, [0.1, 0.2], **kwargs)
        assert str(info.value) == ("mp.widget runs the chain in the browser, where a Python function cannot be called: "
                                   + middle + tail)
    with pytest.raises(mp.InputError) as info:
        mp.widget(mp.Chain([1.0], [1.0], cart=mp.Cart(1.0)), [0.1], cart_force=lambda t, s: -s[0])
    assert "give cart_force as a number, mp.Sinusoid or mp.Table, " in str(info.value)


def test_without_anywidget_the_import_error_says_what_to_install():
    code = ("import sys; sys.modules['anywidget'] = None\n"
            "import multipendulum as mp\n"
            "sol = mp.simulate(mp.Chain([1], [1]), [1.0], [0.0], 0.1)\n"
            "for f in (lambda: mp.widget, lambda: mp.show, sol.show):\n"
            "    try:\n        f()\n    except ImportError as e:\n        print(e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    expected = ("multipendulum's notebook widgets (mp.widget, mp.show, Solution.show) need anywidget: "
                "pip install 'multipendulum[widget]'")
    assert out.splitlines() == [expected] * 3


# ----------------------------------------------------------------------------------------------
# The player, Python side


def test_show_sends_the_solutions_states_at_60_frames_per_second():
    chain = mp.Chain([1.0, 0.5], [1.0, 2.0])
    grid = np.arange(241) / 120  # outputs every 1/120 s: every other one is a frame
    sol = mp.simulate(chain, [2.0, 2.5], [0.0, 0.0], t_end=2.0, t_eval=grid)
    p = sol.show()
    assert isinstance(p, _notebook.Player) and isinstance(mp.show(sol), _notebook.Player)
    f = p.frames
    assert f["t"].dtype == np.float64 and f["positions"].dtype == np.float32 and f["base"].dtype == np.float32
    np.testing.assert_allclose(f["t"], np.arange(121) / 60, rtol=0, atol=1e-12)
    assert f["positions"].shape == (121, 2, 2) and f["base"].shape == (121, 2)
    # At the output times the frames are the solution's own states (to float32).
    np.testing.assert_allclose(f["positions"], sol.positions[::2].astype(np.float32), rtol=0, atol=2e-7)
    assert not f["base"].any()
    assert p._chain == {"lengths": [1.0, 0.5], "masses": [1.0, 2.0], "kind": "points", "cart": False, "x0": 0.0, "reach": 0.0}
    assert (p.playing, p.loop, p.speed, p.time, p._note) == (True, True, 1.0, 0.0, "")
    # Fewer frames per second on request; in between outputs the angles are interpolated.
    f = mp.show(sol, fps=25, playing=False).frames
    np.testing.assert_allclose(f["t"], np.append(np.arange(50) / 25, 2.0), rtol=0, atol=1e-12)
    theta = np.stack([np.interp(f["t"], sol.t, sol.theta[:, i]) for i in range(2)], axis=1)
    np.testing.assert_allclose(f["positions"], chain.positions(theta), rtol=0, atol=2e-7)


def test_show_draws_the_base_a_cart_and_rods():
    cartpole = mp.Chain.rods([0.6], [0.1], cart=mp.Cart(1.0))
    sol = mp.simulate(cartpole, [3.0], [0.0], t_end=1.0, cart_v0=0.5, cart_force=mp.Sinusoid(2.0, 5.0))
    p = sol.show()
    f = p.frames
    np.testing.assert_allclose(f["base"][:, 0], np.interp(f["t"], sol.t, sol.cart_x), rtol=0, atol=1e-6)
    assert not f["base"][:, 1].any()
    assert p._chain["kind"] == "rods" and p._chain["cart"] is True
    kapitza = mp.Pivot(y=mp.Sinusoid(amplitude=0.05, frequency=20.0))
    sol = mp.simulate(mp.Chain([1.0], [1.0]), [3.0], [0.0], t_end=1.0, pivot=kapitza)
    p = sol.show()
    base = p.frames["base"].astype(float)
    assert p._chain["reach"] == pytest.approx(np.hypot(base[:, 0], base[:, 1]).max(), rel=1e-6)
    assert 0.045 < p._chain["reach"] <= 0.05


def test_a_long_run_is_shown_at_fewer_frames_and_says_so():
    sol = mp.simulate(mp.Chain([1.0], [1.0]), [1.0], [0.0], t_end=3600.0, method="rk4", dt=0.05)
    p = sol.show()
    most = min(_notebook.MAX_VALUES // 4, 100_000)
    assert p.frames["t"].size <= most + 1
    assert p._note.startswith("3600 s shown at 27.8 frames per simulated second")


@pytest.mark.parametrize("kwargs, message", [
    ({"fps": 120}, "fps must be > 0 and at most 60 (frames per simulated second), got 120"),
    ({"fps": 0}, "fps must be > 0 and at most 60 (frames per simulated second), got 0"),
    ({"speed": 0}, "speed must be > 0 and finite (simulated seconds per second), got 0"),
    ({"loop": 1}, "loop must be True or False, got 1"),
    ({"height": 1e9}, "height must be a whole number of pixels from 80 to 4000, got 1000000000.0"),
])
def test_show_refuses_bad_options(kwargs, message):
    sol = mp.simulate(mp.Chain([1.0], [1.0]), [1.0], [0.0], t_end=0.5)
    with pytest.raises(mp.InputError) as info:
        sol.show(**kwargs)
    assert str(info.value) == message


def test_show_refuses_a_batch_and_other_objects():
    sol = mp.simulate(mp.Chain([1.0], [1.0]), [[1.0], [2.0]], [[0.0], [0.0]], t_end=0.5, t_eval=[0.0, 0.5])
    with pytest.raises(mp.InputError) as info:
        sol.show()
    # The package's one refusal of batches (results.check_single), said for show.
    assert str(info.value) == (
        "show takes one run, but this Solution is a batch of 2 runs (theta shape (2, 2, 1)); pick one trajectory b "
        "by simulating it alone, mp.simulate(chain, theta0[b], omega0[b], ...), which gives the batch's row b (to "
        "round-off, or to dop853's tolerance, where the batch ran in SIMD lanes)")
    with pytest.raises(mp.InputError) as info:
        mp.show([1, 2, 3])
    assert str(info.value) == "show takes a multipendulum Solution or loaded Results, got list"


def test_show_plays_loaded_results(tmp_path):
    sol = mp.simulate(mp.Chain([1.0, 1.0], [1.0, 1.0]), [2.0, 2.5], [0.0, 0.0], t_end=1.0)
    path = mp.save_results(sol, tmp_path / "run.npz")
    a, b = mp.show(sol).frames, mp.show(mp.load_results(path)).frames
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])


# ----------------------------------------------------------------------------------------------
# The browser module


def _web(tmp_path, files):
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    return tmp_path


@pytest.mark.parametrize("files, message", [
    ({"a.js": 'import b from "./b.js";\n'}, "a.js:1: cannot inline 'import b from \"./b.js\";'"),
    ({"a.js": 'import { x as y } from "./b.js";\n', "b.js": "export const x = 1;\n"},
     "a.js:1: the bundler takes plain names only (no `as`), got x as y"),
    ({"a.js": 'import {\n  x } from "./b.js";\n', "b.js": "export const x = 1;\n"}, "a.js:1: cannot inline 'import {'"),
    ({"a.js": 'const m = await import("./b.js");\n', "b.js": ""}, "a.js: a dynamic import() cannot be inlined"),
    ({"a.js": 'import { y } from "./b.js";\n', "b.js": "export const x = 1;\n"}, "a.js imports y from b.js, which does not export it"),
    ({"a.js": 'import { x } from "./b.js";\nconst x = 2;\n', "b.js": "export const x = 1;\n"},
     "a.js and b.js both declare x at the top level"),
    ({"a.js": 'import { x } from "./b.js";\n', "b.js": "export const x = 1;\nexport default x;\n"},
     "b.js: cannot inline 'export default'"),
    ({"a.js": 'import { x } from "./b.js";\n', "b.js": 'import { y } from "./a.js";\nexport const x = 1;\n'},
     "import cycle: a.js -> b.js -> a.js"),
    ({"a.js": 'import { x } from "./c.js";\n'}, "a.js imports c.js, which is not in"),
])
def test_the_inliner_refuses_what_it_does_not_understand(tmp_path, files, message):
    with pytest.raises(BundleError) as info:
        bundle("a.js", _web(tmp_path, files))
    assert str(info.value).startswith(message)


def test_the_inliner_puts_each_file_once_before_its_importers(tmp_path):
    root = _web(tmp_path, {
        "a.js": 'import { b } from "./b.js";\nimport { c } from "./c.js";\nexport default () => b + c;\n',
        "b.js": 'import { c } from "./c.js";\nexport const b = c + 1;\n',
        "c.js": "export function c() { return import.meta.url; }\n",
    })
    out = bundle("a.js", root)
    assert [m for m in re.findall(r"^// ---- (\S+)", out, re.M)] == ["c.js", "b.js", "a.js"]
    assert "export const" not in out and "export function" not in out and "export default" in out
    assert not re.search(r"^\s*import\b(?!\.)", out, re.M)


@pytest.mark.parametrize("entry", ["widget.js", "player.js"])
def test_the_widgets_modules_are_the_viewers_own_code(entry):
    out = bundle(entry)
    names = re.findall(r"^// ---- (\S+)", out, re.M)
    assert names == (["engine.js", "draw.js", "cell.js", "widget.js"] if entry == "widget.js"
                     else ["draw.js", "cell.js", "player.js"])
    for name in names[:-1]:  # the inlined files' code, unchanged but for their exports
        source = (_notebook.WEB / name).read_text()
        assert re.sub(r"^export\s+", "", source, flags=re.M).strip() in out
    assert out.count("export default") == 1
    node = shutil.which("node")
    if node:  # it parses as a module
        path = ROOT / "tests" / f".bundle-{entry}.mjs"
        try:
            path.write_text(out)
            proc = subprocess.run([node, "--check", str(path)], capture_output=True, text=True)
            assert proc.returncode == 0, proc.stderr
        finally:
            path.unlink(missing_ok=True)


def test_the_docs_pages_examples_run_in_order():
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "widget.md").read_text(), flags=re.S)
    assert len(blocks) >= 3
    namespace: dict = {}
    for i, block in enumerate(blocks):
        exec(compile(block, f"docs/widget.md python block {i}", "exec"), namespace)


# ----------------------------------------------------------------------------------------------
# In JupyterLab, in chromium

NOTEBOOK_CELLS = [
    # 0: the widget, playing at once
    "import multipendulum as mp\n"
    "chain = mp.Chain([1.0, 1.0], [1.0, 1.0])\n"
    "w = mp.widget(chain, theta0=[2.0, 2.5], height=300)\n"
    "display(w)\n"
    "w.playing = True",
    # 1: Python reads the state the browser reports (run again later)
    'print(f"T={w.t:.6f} E={w.energy:.9f} ERR={w.error!r}")',
    # 2: a computed solution, played
    "sol = mp.simulate(chain, [2.0, 2.5], [0.0, 0.0], t_end=5.0)\n"
    "sol.show(height=300)",
    # 3: the drives the page's setup takes, accepted by the core in the browser
    "cartpole = mp.Chain.rods([0.6], [0.1], cart=mp.Cart(1.0, damping=0.1))\n"
    "w2 = mp.widget(cartpole, [3.0], cart_force=mp.Sinusoid(2.0, 5.0), joint_torque=mp.Table([0, 1], [[0.1], [0.0]]),\n"
    "               playing=True, height=150)\n"
    "shaken = mp.Pivot(x=0.05, y=mp.Table([5.0 * k for k in range(13)], [0.03 * (-1) ** k for k in range(13)], kind='cubic'))\n"
    "w3 = mp.widget(mp.Chain([1.0, 1.0], [1.0, 1.0], friction=0.01), [0.5, 0.5], method='gauss6', dt=0.005,\n"
    "               pivot=shaken, torque=mp.Sinusoid([0.1, 0.0], 2.0), playing=True, height=150)\n"
    "display(w2, w3)",
    # 4: their reports
    'print(f"DRIVES {w2.t:.4f} {w3.t:.4f} {w2.base[0]:.6f} {w3.base[0]!r} {w3.base[1]:.6f} {w2.error!r} {w3.error!r}")',
]


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """JupyterLab on a free port, headless, every bit of its state in a temporary directory; the
    server (and its kernels: its process group) killed at the end, however the test ends."""
    reason = _browser_missing()
    for module in ("jupyterlab", "ipykernel"):
        if reason is None and importlib.util.find_spec(module) is None:
            reason = f"{module} is not installed (pip install -e '.[test]')"
    if reason:
        if os.environ.get("MULTIPENDULUM_REQUIRE_BROWSER"):
            pytest.fail(f"browser tests required but {reason}")
        pytest.skip(reason)
    home = tmp_path_factory.mktemp("lab")
    root = home / "notebooks"
    root.mkdir()
    settings = home / "settings" / "@jupyterlab" / "apputils-extension"
    settings.mkdir(parents=True)
    # No news or update check (a toast over the notebook, and a request to the internet).
    (settings / "notification.jupyterlab-settings").write_text(json.dumps({"fetchNews": "false", "checkForUpdates": False}))
    env = dict(os.environ, JUPYTER_CONFIG_DIR=str(home / "config"), JUPYTER_DATA_DIR=str(home / "data"),
               JUPYTER_RUNTIME_DIR=str(home / "runtime"), JUPYTERLAB_SETTINGS_DIR=str(home / "settings"),
               JUPYTERLAB_WORKSPACES_DIR=str(home / "workspaces"), IPYTHONDIR=str(home / "ipython"),
               JUPYTER_PLATFORM_DIRS="1", PYTHONNOUSERSITE="1")
    token = secrets.token_hex(16)
    port = _free_port()
    log = open(home / "lab.log", "wb")
    # The kernel is the environment's own python3 (ipykernel's spec in sys.prefix/share/jupyter,
    # its `python` the server's interpreter), so it imports this package.
    proc = subprocess.Popen(
        [sys.executable, "-m", "jupyterlab", "--no-browser", f"--port={port}", "--ip=127.0.0.1",
         f"--IdentityProvider.token={token}", f"--ServerApp.root_dir={root}", "--ServerApp.port_retries=0",
         "--ServerApp.terminals_enabled=False", "--LabApp.check_for_updates_class=jupyterlab.NeverCheckForUpdate"]
        + (["--allow-root"] if hasattr(os, "geteuid") and os.geteuid() == 0 else []),
        cwd=root, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    direct = urllib.request.build_opener(urllib.request.ProxyHandler({}))  # never a proxy for 127.0.0.1
    try:
        deadline = time.monotonic() + 60
        while True:
            if proc.poll() is not None:
                raise AssertionError(f"JupyterLab exited with {proc.returncode}:\n{(home / 'lab.log').read_text()[-3000:]}")
            try:
                with direct.open(f"{url}/api/status?token={token}", timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                pass
            if time.monotonic() > deadline:
                raise AssertionError(f"JupyterLab did not answer within 60 s:\n{(home / 'lab.log').read_text()[-3000:]}")
            time.sleep(0.25)
        yield {"url": url, "token": token, "root": root, "log": home / "lab.log"}
    finally:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=15)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait(timeout=5)
        log.close()


def _write_notebook(path, cells):
    path.write_text(json.dumps({
        "cells": [{"cell_type": "code", "execution_count": None, "metadata": {}, "outputs": [], "source": src}
                  for src in cells],
        "metadata": {"kernelspec": {"name": "python3", "display_name": "Python 3", "language": "python"}},
        "nbformat": 4, "nbformat_minor": 5,
    }))


def _pixels(locator):
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(locator.screenshot())).convert("RGB")).astype(int)


def _animates(page, canvas, pause_ms=400):
    a = _pixels(canvas)
    page.wait_for_timeout(pause_ms)
    b = _pixels(canvas)
    return a.shape == b.shape and np.abs(a - b).sum(axis=-1).astype(bool).sum() > 50


def _output_text(cell):
    return cell.locator(".jp-OutputArea-output").all_inner_texts()


def _run_cell(page, cell):
    """Run one cell through the UI, as a user does: click into it, Ctrl+Enter (run in place)."""
    cell.locator(".jp-InputArea-editor").click()
    page.keyboard.press("Control+Enter")


def _wait(page, predicate, what, timeout=30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        page.wait_for_timeout(100)
    raise AssertionError(f"timed out waiting for {what}")


def _drive_the_notebook(page, lab):
    """Run the notebook through JupyterLab's UI and check what it shows and what Python reads."""
    page.goto(f"{lab['url']}/lab/tree/widget.ipynb?token={lab['token']}")
    page.wait_for_selector(".jp-Notebook .jp-Cell", timeout=60000)
    # The kernel is up when the status bar says so ("No Kernel | Idle" before it is).
    page.locator(".jp-StatusBar-Item", has_text=re.compile(r"^(?!No Kernel).+ \| Idle$")).wait_for(timeout=60000)
    cells = page.locator(".jp-Notebook .jp-Cell.jp-CodeCell")
    _wait(page, lambda: cells.count() == len(NOTEBOOK_CELLS), "the notebook's cells")
    # Run → Run All Cells, through the menu.
    page.locator(".lm-MenuBar-itemLabel", has_text="Run").first.click()
    page.locator(".lm-Menu-itemLabel", has_text="Run All Cells").first.click()

    canvas = cells.nth(0).locator("canvas.mp-view")
    canvas.wait_for(state="visible", timeout=30000)
    assert _wait(page, lambda: _animates(page, canvas), "the widget's canvas to animate")
    assert cells.nth(0).locator(".mp-play").inner_text() == "❚❚ Pause"

    def reading():
        texts = _output_text(cells.nth(1))
        m = re.search(r"T=([0-9.]+) E=(-?[0-9.]+) ERR='(.*)'", " ".join(texts))
        return m and (float(m.group(1)), float(m.group(2)), m.group(3))

    first = _wait(page, reading, "the first read of w.t")
    page.wait_for_timeout(1000)
    _run_cell(page, cells.nth(1))
    second = _wait(page, lambda: (r := reading()) and r != first and r, "the second read of w.t")
    assert second[0] > first[0] + 0.3, (first, second)
    assert second[2] == "" and first[2] == ""
    # The run conserves energy: the browser's energy is the start's to the integrator's accuracy.
    e0 = mp.Chain([1.0, 1.0], [1.0, 1.0]).energy([2.0, 2.5], [0.0, 0.0])
    assert abs(second[1] - e0) < 1e-6 * abs(e0)

    # The player animates too.
    player = cells.nth(2).locator("canvas.mp-view")
    player.wait_for(state="visible", timeout=30000)
    assert _wait(page, lambda: _animates(page, player), "the player's canvas to animate")
    assert "frames over 5.000 s" in cells.nth(2).locator(".mp-status").inner_text()

    # A cart pushed by a force and a joint torque, a pivot moved by a spline and a torque:
    # accepted by the core in the browser, running, the base moving.
    for k in (3, 4):
        cells.nth(3).locator("canvas.mp-view").nth(k - 3).wait_for(state="visible", timeout=30000)
    page.wait_for_timeout(500)
    _run_cell(page, cells.nth(4))

    def drives():
        m = re.search(r"DRIVES (\S+) (\S+) (\S+) (\S+) (\S+) '(.*)' '(.*)'", " ".join(_output_text(cells.nth(4))))
        return m and float(m.group(1)) > 0 and m.groups()

    t2, t3, cart_x, pivot_x, pivot_y, error2, error3 = _wait(page, drives, "the drives' reports")
    assert (error2, error3) == ("", "")
    assert float(t3) > 0 and float(cart_x) != 0 and pivot_x == "0.05" and float(pivot_y) != 0
    assert cells.nth(3).locator(".mp-message").evaluate_all("els => els.every((e) => e.hidden)")

    # A value only the browser sees (sent past Python's checks, as a buggy front end could)
    # is refused by the core there: shown in the widget, reported as w.error, run kept.
    page.locator(".jp-Notebook .jp-Cell").last.locator(".jp-InputArea-editor").click()
    page.keyboard.press("Escape")
    page.keyboard.press("b")  # a new cell below
    page.keyboard.press("Enter")
    page.keyboard.insert_text('w._send({"method": "update", "state": {"damping": [-1.0, 0.0]}, "buffer_paths": []})')
    page.keyboard.press("Control+Enter")
    message = cells.nth(0).locator(".mp-message")
    message.wait_for(state="visible", timeout=15000)
    assert message.inner_text() == "Not applied: damping[0] must be >= 0 and finite, got -1"
    page.wait_for_timeout(300)
    _run_cell(page, cells.nth(1))
    third = _wait(page, lambda: (r := reading()) and r[2] and r, "w.error")
    assert third[2] == "Not applied: damping[0] must be >= 0 and finite, got -1"
    assert third[0] > second[0]  # the old run goes on


def test_in_jupyterlab_the_widget_animates_and_python_reads_its_state(lab):
    from playwright.sync_api import sync_playwright

    _write_notebook(lab["root"] / "widget.ipynb", NOTEBOOK_CELLS)
    started = time.monotonic()
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 1400})
            errors = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            try:
                _drive_the_notebook(page, lab)
            except Exception as exc:  # say what the page showed
                shot = lab["root"].parent / "failure.png"
                page.screenshot(path=str(shot), full_page=True)
                outputs = page.locator(".jp-Notebook .jp-Cell").evaluate_all(
                    "cells => cells.map((c) => c.querySelector('.jp-OutputArea')?.innerText ?? '')")
                raise AssertionError(f"{exc}\nthe page: {shot}\ncell outputs: {outputs}\npage errors: {errors}") from exc
            assert not errors, errors
        finally:
            browser.close()
    assert time.monotonic() - started < 90
