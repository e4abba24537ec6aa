"""Flip-map pictures and `multipendulum fractal`: the energy bound drawn where the closed form
puts it, each kind of pixel in its own colour, the command's outputs and its refusals."""
import sys
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp
from multipendulum.cli import main
from multipendulum.fractal import BOUND_COLOR, CMAP, FORBIDDEN_COLOR, NEVER_COLOR, plot_flip_map
sys.path.insert(0, str(Path(__file__).resolve().parent))
from pictures import pixel, render  # noqa: E402  (tests/pictures.py)

DOUBLE = mp.Chain([1.0, 1.0], [1.0, 1.0])
RODS = mp.Chain.rods([1.0, 1.0], [1.0, 1.0])
GRID = np.radians(-180 + 360 / 48 * (np.arange(48) + 0.5))  # pixel centres, as the command uses

SCENARIO = """
name = "Test double"
[chain]
lengths = [1.0, 1.0]
masses = [1.0, 1.0]
[initial]
unit = "degrees"
theta = [120.0, -10.0]
[simulation]
t_end = 3.0
"""


@pytest.fixture(scope="module")
def maps():
    return {"points": mp.flip_map(DOUBLE, GRID, GRID, t_max=4.0), "rods": mp.flip_map(RODS, GRID, GRID, t_max=4.0)}


def _bound_lines(fig):
    from matplotlib.colors import to_rgba

    ax = fig.axes[0]
    out = []
    for coll in ax.collections:
        colors = coll.get_edgecolor() if hasattr(coll, "get_edgecolor") else []
        if len(colors) and np.allclose(colors[0], to_rgba(BOUND_COLOR)) and coll.get_facecolor().size == 0:
            for path in coll.get_paths():
                out.append(path.vertices)
    return out


@pytest.mark.parametrize("kind, bound", [
    ("points", lambda t1, t2: 2 * np.cos(t1) + np.cos(t2) - 1),   # E = E_flip for equal point masses
    ("rods", lambda t1, t2: 3 * np.cos(t1) + np.cos(t2) - 2),     # and for equal uniform rods
])
def test_the_energy_bound_is_drawn_where_the_closed_form_puts_it(maps, kind, bound):
    chain = DOUBLE if kind == "points" else RODS
    fig = plot_flip_map(maps[kind], chain=chain)
    lines = _bound_lines(fig)
    assert lines, "no energy-bound curve drawn"
    pts = np.radians(np.concatenate(lines))
    assert len(pts) > 100
    np.testing.assert_allclose(bound(pts[:, 0], pts[:, 1]), 0.0, atol=2e-4)
    # it goes all round the forbidden region: from theta_2 = -180 to 180 degrees
    assert np.degrees(pts[:, 1]).min() < -170 and np.degrees(pts[:, 1]).max() > 170


def test_without_the_chain_the_bound_is_traced_from_the_mask(maps):
    fig = plot_flip_map(maps["points"])
    pts = np.radians(np.concatenate(_bound_lines(fig)))
    # within a grid spacing of the true curve
    assert np.max(np.abs(2 * np.cos(pts[:, 0]) + np.cos(pts[:, 1]) - 1)) < 2 * (GRID[1] - GRID[0]) * 2.3


def _block(mask):
    """Indices (i, j) of a cell whose 3 x 3 neighbourhood is all in mask (away from edges)."""
    inner = mask[1:-1, 1:-1].copy()
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            inner &= mask[1 + di:mask.shape[0] - 1 + di, 1 + dj:mask.shape[1] - 1 + dj]
    i, j = np.argwhere(inner)[len(np.argwhere(inner)) // 2]
    return i + 1, j + 1


def test_each_kind_of_pixel_has_its_own_colour(maps):
    import matplotlib
    from matplotlib.colors import LogNorm, to_rgb

    fm = maps["points"]
    fig = plot_flip_map(fm, chain=DOUBLE, dpi=100)
    rgb = render(fig)
    deg = np.degrees(GRID)
    flipped = np.isfinite(fm.times)
    never = ~flipped & fm.allowed
    # A flip: the colour map's colour for its time (log scale, t_max / 100 .. t_max).
    i, j = _block(flipped & (fm.times > 0.1))
    want = matplotlib.colormaps[CMAP](LogNorm(0.04, 4.0)(fm.times[i, j]))[:3]
    np.testing.assert_allclose(pixel(fig, rgb, deg[j], deg[i]), want, atol=0.02)
    # Could flip but did not: white.
    i, j = _block(never)
    np.testing.assert_allclose(pixel(fig, rgb, deg[j], deg[i]), to_rgb(NEVER_COLOR), atol=0.02)
    # Forbidden by energy: the grey (or its hatching), never white and never a colour-map colour.
    samples = np.array([pixel(fig, rgb, x, y) for x in (-20, -10, 0, 10, 20) for y in (-40, 0, 40)])
    grey = np.isclose(samples, to_rgb(FORBIDDEN_COLOR), atol=0.03).all(axis=1)
    assert grey.mean() > 0.5
    assert np.all(np.ptp(samples, axis=1) < 0.03)  # neutral: equal red, green and blue
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels[0].startswith("no flip by t = 4 s (") and "no flip possible" in labels[1]
    assert "energy bound" in labels[2] and f"{fm.threshold:.4g} J" in labels[2]
    assert fig.axes[0].get_xlabel().endswith("(degrees)") and "first flip (s)" in fig.axes[1].get_ylabel()


def test_the_picture_is_written_atomically_as_png(tmp_path, maps):
    path = plot_flip_map(maps["rods"], tmp_path / "sub" / "map.png", chain=RODS, dpi=60)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in path.parent.iterdir()] == ["map.png"]


def test_fractal_command_writes_the_map_and_summarises_it(tmp_path, capsys):
    scenario = tmp_path / "double.toml"
    scenario.write_text(SCENARIO)
    out = tmp_path / "map.png"
    assert main(["fractal", str(scenario), "-o", str(out), "--size", "40", "--dpi", "60"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("Test double: flip-time map of 40 x 40 initial states, N = 2, t_max = 3 s")
    assert "no flip possible (energy below E_flip = -9.81 J)" in text and f"wrote {out}" in text
    assert out.read_bytes()[:4] == b"\x89PNG"
    # The percentages printed are the map's.
    x = np.radians(-180 + 9 * (np.arange(40) + 0.5))
    fm = mp.flip_map(DOUBLE, x, x, t_max=3.0, base_omega=[0, 0])
    assert f"flipped {100 * np.isfinite(fm.times).mean():.1f}%" in text


def test_fractal_command_writes_zarr_through_dask(tmp_path, capsys):
    pytest.importorskip("dask.array")
    pytest.importorskip("zarr")
    scenario = tmp_path / "double.toml"
    scenario.write_text(SCENARIO)
    args = ["fractal", str(scenario), "-o", str(tmp_path / "m.png"), "--size", "24", "--t-max", "2",
            "--x", "theta2", "--y", "omega1", "--y-range", "-300", "300", "--zarr", str(tmp_path / "m.zarr"),
            "--chunks", "5", "--dask", "threads", "--link", "2", "-q"]
    assert main(args) == 0
    assert capsys.readouterr().out == ""
    fm = mp.open_flip_map(tmp_path / "m.zarr")
    x = np.radians(-180 + 15 * (np.arange(24) + 0.5))
    y = np.radians(-300 + 25 * (np.arange(24) + 0.5))
    ref = mp.flip_map(DOUBLE, x, y, t_max=2.0, vary=("theta", 1, "omega", 0),
                      base_theta=np.radians([120.0, -10.0]), link=1)
    np.testing.assert_array_equal(fm.times[:], ref.times)
    np.testing.assert_array_equal(fm.allowed[:], ref.allowed)
    assert tuple(fm.times.chunks)[0] == 5


def test_fractal_command_maps_a_scenarios_shaken_pivot(tmp_path, capsys):
    pytest.importorskip("dask.array")
    pytest.importorskip("zarr")
    scenario = tmp_path / "shaken.toml"
    scenario.write_text(SCENARIO + '[pivot]\nx = { kind = "sinusoid", amplitude = 0.1, frequency = 6.0 }\n')
    args = ["fractal", str(scenario), "-o", str(tmp_path / "m.png"), "--size", "12", "--t-max", "2",
            "--zarr", str(tmp_path / "m.zarr"), "--dask", "threads"]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "no energy bound (the pivot moves)" in text and "no flip possible" not in text
    fm = mp.open_flip_map(tmp_path / "m.zarr")
    x = np.radians(-180 + 30 * (np.arange(12) + 0.5))
    shaken = mp.Pivot(x=mp.Sinusoid(amplitude=0.1, frequency=6.0))
    ref = mp.flip_map(DOUBLE, x, x, t_max=2.0, base_omega=[0, 0], pivot=shaken)
    np.testing.assert_array_equal(fm.times[:], ref.times)
    assert (ref.times != mp.flip_map(DOUBLE, x, x, t_max=2.0).times).any()  # the pivot was applied


@pytest.mark.parametrize("extra, message", [
    (["--x", "theta3"], "--x must be theta1..theta2 or omega1..omega2, got 'theta3'"),
    (["--y", "theta1"], "--x and --y must differ"),
    (["--size", "1"], "--size must be at least 2"),
    (["--link", "3"], "--link must be between 1 and 2, got 3"),
    (["--t-max", "-1"], "t_max must be > 0 and finite, got -1"),
    (["--x-range", "10", "-10"], "a range must have HI > LO"),
    (["--dask", "nowhere"], "scheduler must be None, 'threads'"),
])
def test_fractal_command_refuses_bad_options(tmp_path, capsys, extra, message):
    scenario = tmp_path / "double.toml"
    scenario.write_text(SCENARIO)
    out = tmp_path / "map.png"
    assert main(["fractal", str(scenario), "-o", str(out), "--size", "8", "-q"] + extra) == 1
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_fractal_command_needs_a_png(tmp_path, capsys):
    scenario = tmp_path / "double.toml"
    scenario.write_text(SCENARIO)
    assert main(["fractal", str(scenario), "-o", str(tmp_path / "map.jpg")]) == 1
    assert "-o must end in .png" in capsys.readouterr().err


def test_fractal_help_lists_every_option(capsys):
    assert main(["fractal", "--help"]) == 0
    out = capsys.readouterr().out
    for option in ("--size", "--t-max", "--dt", "--x", "--y", "--x-range", "--y-range", "--link", "--linear",
                   "--dask", "--chunks", "--zarr", "--dpi", "SCENARIO"):
        assert option in out


def test_the_python_snippets_in_docs_chaos_run_as_written(tmp_path, monkeypatch):
    import re

    pytest.importorskip("distributed")
    pytest.importorskip("zarr")
    pytest.importorskip("scipy")
    text = (Path(__file__).resolve().parents[1] / "docs" / "chaos.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) >= 6
    monkeypatch.chdir(tmp_path)
    ns = {"__name__": "docs_chaos"}
    for block in blocks:
        exec(compile(block, "docs/chaos.md", "exec"), ns)
    for name in ("flip_map.png", "flip_map.zarr", "modes.png", "falling_mode.gif"):
        assert (tmp_path / name).exists(), name
    # what the comments in the snippets say
    assert ns["fm"].times.shape == (128, 128) and ns["fm"].threshold == pytest.approx(-9.81)
    np.testing.assert_allclose(ns["modes"].frequencies ** 2 / 9.81, [2 - np.sqrt(2), 2 + np.sqrt(2)], rtol=1e-12)
    assert ns["mixed"].n_unstable == 1 and ns["mixed"].growth_rates[0] == pytest.approx(np.sqrt(np.sqrt(2) * 9.81))
    assert np.abs(ns["sol"].theta[-1] - ns["upright"]).max() < 1e-9
