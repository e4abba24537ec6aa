"""Chaos-indicator maps beyond one call: mp.sweep_indicator_map (Dask, Zarr) cell for cell equal to
mp.indicator_map, their pictures (each indicator on its own scale, regular and chaotic orbits in
different colours) and `multipendulum atlas` (its outputs, `--indicator flip` as `fractal`, its
refusals)."""
import re
import sys
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp
from multipendulum.cli import main
from multipendulum.fractal import CMAP, INDICATOR_STYLES, LOG_FLOOR, plot_indicator_map
from multipendulum.sweeps import open_indicator_map, sweep_indicator_map
sys.path.insert(0, str(Path(__file__).resolve().parent))
from pictures import pixel, render  # noqa: E402  (tests/pictures.py)

DOUBLE = mp.Chain([1.0, 1.0], [1.0, 1.0])
X = np.linspace(-2.8, 2.8, 8)
Y = np.linspace(-2.5, 2.9, 7)

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


def _scenario(tmp_path):
    path = tmp_path / "double.toml"
    path.write_text(SCENARIO)
    return path


def _cells(size, lo=-180.0, hi=180.0):
    """The grid `fractal` and `atlas` use: pixel centres, in radians."""
    return np.radians(lo + (hi - lo) / size * (np.arange(size) + 0.5))


# ----------------------------------------------------------------------------------------------
# sweep_indicator_map


@pytest.mark.parametrize("indicator, k", [("megno", None), ("gali", 3), ("sali", None), ("lyapunov", None)])
def test_sweep_indicator_map_equals_indicator_map_cell_for_cell(indicator, k):
    pytest.importorskip("dask.array")
    ref = mp.indicator_map(DOUBLE, X, Y, t_end=3.0, indicator=indicator, k=k)
    for chunks, scheduler in (((3, 5), None), (2, "sync")):
        m = sweep_indicator_map(DOUBLE, X, Y, t_end=3.0, indicator=indicator, k=k, chunks=chunks, scheduler=scheduler)
        assert isinstance(m, mp.IndicatorMap) and isinstance(m.values, np.ndarray)
        np.testing.assert_array_equal(m.values, ref.values)  # bit for bit
        np.testing.assert_array_equal(m.x, X)
        np.testing.assert_array_equal(m.y, Y)
        assert (m.indicator, m.t_end) == (indicator, 3.0)


def test_sweep_indicator_map_with_omega_a_base_state_and_a_torque():
    pytest.importorskip("dask.array")
    kw = dict(t_end=2.0, indicator="fli", vary=("theta", 1, "omega", 0), base_theta=[0.4, 0.0],
              base_omega=[0.0, 0.3], torque=mp.Sinusoid([0.5, 0.0], [2.0, 0.0]))
    ref = mp.indicator_map(DOUBLE, X, Y, **kw)
    np.testing.assert_array_equal(sweep_indicator_map(DOUBLE, X, Y, chunks=(4, 3), **kw).values, ref.values)


def test_zarr_output_is_written_chunk_by_chunk_and_reads_back(tmp_path):
    pytest.importorskip("dask.array")
    zarr = pytest.importorskip("zarr")
    ref = mp.indicator_map(DOUBLE, X, Y, t_end=3.0, indicator="gali", k=3)
    seen = []
    store = tmp_path / "atlas.zarr"
    m = sweep_indicator_map(DOUBLE, X, Y, t_end=3.0, indicator="gali", k=3, chunks=(3, 5), zarr=store,
                            progress=seen.append)
    assert not isinstance(m.values, np.ndarray)  # the store's array, on disk
    assert tuple(m.values.chunks) == (3, 5) and m.values.shape == (7, 8)
    np.testing.assert_array_equal(m.values[:], ref.values)
    assert seen and seen[-1] == 1.0 and all(b >= a for a, b in zip(seen, seen[1:]))
    attrs = zarr.open_group(str(store), mode="r").attrs
    assert attrs["kind"] == "multipendulum.indicator_map"
    assert (attrs["indicator"], attrs["k"], attrs["t_end"], attrs["dt"]) == ("gali", 3, 3.0, 0.005)
    assert list(attrs["vary"]) == ["theta", 0, "theta", 1] and mp.Chain.from_dict(dict(attrs["chain"])) == DOUBLE
    again = open_indicator_map(store)
    np.testing.assert_array_equal(again.values[:], ref.values)
    np.testing.assert_array_equal(again.x, X)
    assert (again.indicator, again.t_end) == ("gali", 3.0)
    # A store written here before is replaced; a flip map's store is not an indicator map.
    sweep_indicator_map(DOUBLE, X, Y, t_end=1.0, chunks=4, zarr=store)
    assert open_indicator_map(store).t_end == 1.0
    mp.sweep_flip_map(DOUBLE, X, Y, t_max=1.0, zarr=tmp_path / "flip.zarr")
    with pytest.raises(mp.InputError, match="not a chaos-indicator map written by multipendulum"):
        open_indicator_map(tmp_path / "flip.zarr")


def test_bad_requests_are_refused_by_name_before_any_task(tmp_path, monkeypatch):
    pytest.importorskip("dask.array")
    pytest.importorskip("zarr")
    import multipendulum.sweeps as sweeps

    def no_task(*args, **kwargs):
        raise AssertionError("a task ran")

    monkeypatch.setattr(sweeps, "_map_indicator_block", no_task)
    cases = [
        (dict(indicator="lyap"), "indicator must be one of megno, fli, ofli, sali, gali, lyapunov, got 'lyap'"),
        (dict(indicator="gali"), "gali needs its order k"),
        (dict(indicator="gali", k=5), r"GALI's order k must be between 2 and 2N = 4, got 5"),
        (dict(k=2), "k is GALI's order; megno takes none"),
        (dict(dt=-0.1), "dt must be > 0"),
        (dict(t_end=float("inf")), "t_end must be > 0 and finite"),
        (dict(chunks=0), "chunks must be a positive integer, got 0"),
        (dict(chunks=(2, 0)), r"chunks\[1\] must be a positive integer, got 0"),
        (dict(vary=("theta", 0, "theta", 0)), "vary must name two different quantities"),
        (dict(base_theta=[0.0]), "base_theta"),
        (dict(scheduler="nowhere"), "scheduler must be None"),
    ]
    for kwargs, message in cases:
        with pytest.raises(mp.InputError, match=message):
            sweep_indicator_map(DOUBLE, X, Y, **dict(dict(t_end=1.0), **kwargs))
    with pytest.raises(mp.InputError, match="x must be a non-empty array of finite numbers"):
        sweep_indicator_map(DOUBLE, [0.1, np.nan], Y, t_end=1.0)
    with pytest.raises(mp.InputError, match="chain must be a multipendulum.Chain"):
        sweep_indicator_map("double", X, Y, t_end=1.0)
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    with pytest.raises(mp.InputError, match="exists and is not a store written by multipendulum"):
        sweep_indicator_map(DOUBLE, X, Y, t_end=1.0, zarr=foreign)
    assert (foreign / "notes.txt").read_text() == "keep me"


def test_a_map_too_large_to_gather_is_refused_before_any_task(monkeypatch):
    pytest.importorskip("dask.array")
    import multipendulum.sweeps as sweeps

    monkeypatch.setattr(sweeps, "_map_indicator_block", lambda *a, **k: pytest.fail("a task ran"))
    big = np.zeros(200_000)
    with pytest.raises(mp.InputError, match=r"gathering an indicator map of 200000 x 200000 cells.*zarr=PATH"):
        sweep_indicator_map(DOUBLE, big, big, t_end=1.0, chunks=(1, 1000))


# ----------------------------------------------------------------------------------------------
# plot_indicator_map


@pytest.fixture(scope="module")
def megno_map():
    # theta_1 = theta_2 along the diagonal: near rest regular (MEGNO ~ 2 or below), high up chaotic.
    g = np.linspace(0.2, 2.6, 8)
    return mp.indicator_map(DOUBLE, g, g, t_end=6.0, indicator="megno")


def test_regular_and_chaotic_cells_are_drawn_in_the_colours_their_values_say(megno_map):
    import matplotlib
    from matplotlib.colors import Normalize

    m = megno_map
    regular, chaotic = (0, 0), (7, 7)
    assert m.values[regular] < 2.5 < 4.0 < m.values[chaotic]
    fig = plot_indicator_map(m, chain=DOUBLE, dpi=100)
    rgb = render(fig)
    deg = np.degrees(m.x)
    colours = {}
    for name, (i, j) in (("regular", regular), ("chaotic", chaotic)):
        colours[name] = pixel(fig, rgb, deg[j], deg[i])
        want = matplotlib.colormaps[CMAP](Normalize(0.0, 8.0)(min(m.values[i, j], 8.0)))[:3]
        np.testing.assert_allclose(colours[name], want, atol=0.02)
    assert np.abs(colours["regular"] - colours["chaotic"]).sum() > 0.5
    # MEGNO's scale: linear, 0 to 8, with 2 marked "regular" on the colour bar.
    image = fig.axes[0].images[0]
    assert (image.norm.vmin, image.norm.vmax) == (0.0, 8.0)
    assert "2 regular" in [t.get_text() for t in fig.axes[1].get_yticklabels()]
    # The title names the indicator, t_end and the chain; the axes are labelled as a flip map's.
    heading = fig._suptitle.get_text()
    assert "MEGNO at t = 6 s" in heading and "double pendulum" in heading and "l = 1, 1 m" in heading
    assert fig.axes[0].get_xlabel() == r"$\theta_{1}$ at release (degrees)"
    assert fig.axes[0].get_ylabel() == r"$\theta_{2}$ at release (degrees)"


def test_each_indicator_has_its_scale_sali_and_gali_logarithmic_with_a_floor():
    from matplotlib.colors import LogNorm

    assert set(INDICATOR_STYLES) == set(mp.INDICATORS)
    g = np.linspace(0.2, 2.6, 6)
    for name, k in (("sali", None), ("gali", 3)):
        m = mp.indicator_map(DOUBLE, g, g, t_end=4.0, indicator=name, k=k)
        values = m.values.copy()
        values[0, 1] = 0.0  # drawn at the floor, not lost
        fig = plot_indicator_map(mp.IndicatorMap(m.x, m.y, values, name, m.t_end), k=k, dpi=60)
        image = fig.axes[0].images[0]
        assert isinstance(image.norm, LogNorm) and image.norm.vmin == LOG_FLOOR
        assert image.get_array()[0, 1] == LOG_FLOOR and not np.ma.getmaskarray(image.get_array())[0, 1]
        assert image.get_cmap().name.endswith("_r")  # chaotic (small) at the bright end
        if k is not None:
            assert "GALI_3 at t = 4 s" in fig._suptitle.get_text()
    lyap = mp.indicator_map(DOUBLE, g, g, t_end=4.0, indicator="lyapunov")
    fig = plot_indicator_map(lyap, dpi=60)
    norm = fig.axes[0].images[0].norm
    assert (norm.vmin, norm.vmax) == (lyap.values.min(), lyap.values.max())
    assert "(1/s)" in fig.axes[1].get_ylabel()


def test_the_picture_is_written_as_png_of_the_expected_size(tmp_path, megno_map):
    from PIL import Image

    path = plot_indicator_map(megno_map, tmp_path / "sub" / "megno.png", chain=DOUBLE, dpi=50)
    assert path == tmp_path / "sub" / "megno.png" and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in path.parent.iterdir()] == ["megno.png"]  # written atomically
    with Image.open(path) as im:
        assert im.size == (320, round(6.4 * 0.86 * 50))
    with pytest.raises(mp.InputError, match="dpi must be a finite number > 0"):
        plot_indicator_map(megno_map, tmp_path / "x.png", dpi=0)
    with pytest.raises(mp.InputError, match=r"must have shape \(len\(y\), len\(x\)\)"):
        plot_indicator_map(mp.IndicatorMap(megno_map.x, megno_map.y[:3], megno_map.values, "megno", 6.0))


# ----------------------------------------------------------------------------------------------
# multipendulum atlas


def test_atlas_writes_the_map_and_summarises_it(tmp_path, capsys):
    out = tmp_path / "megno.png"
    assert main(["atlas", str(_scenario(tmp_path)), "-o", str(out), "--size", "8", "--dpi", "50"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("Test double: MEGNO map of 8 x 8 initial states, N = 2, t_end = 3 s, dt = 0.005 s\n")
    assert f"wrote {out}" in text and out.read_bytes()[:4] == b"\x89PNG"
    # The numbers printed are the map's: the default grid, the scenario's t_end, mp.indicator_map's dt.
    x = _cells(8)
    m = mp.indicator_map(DOUBLE, x, x, t_end=3.0, base_theta=np.radians([120.0, -10.0]))
    v = m.values
    assert (f"MEGNO at t_end: min {v.min():.4g}, mean {v.mean():.4g}, max {v.max():.4g}; "
            f"{100 * (v > 4).mean():.1f}% with MEGNO > 4") in text


def test_atlas_gali_through_dask_into_zarr(tmp_path, capsys):
    pytest.importorskip("dask.array")
    pytest.importorskip("zarr")
    args = ["atlas", str(_scenario(tmp_path)), "-o", str(tmp_path / "g.png"), "--indicator", "gali", "--k", "3",
            "--size", "6", "--t-end", "2", "--x", "theta2", "--y", "omega1", "--y-range", "-300", "300",
            "--zarr", str(tmp_path / "g.zarr"), "--chunks", "4", "--dask", "threads", "--dpi", "40", "-q"]
    assert main(args) == 0
    assert capsys.readouterr().out == ""
    m = open_indicator_map(tmp_path / "g.zarr")
    ref = mp.indicator_map(DOUBLE, _cells(6), _cells(6, -300, 300), t_end=2.0, indicator="gali", k=3,
                           vary=("theta", 1, "omega", 0), base_theta=np.radians([120.0, -10.0]))
    np.testing.assert_array_equal(m.values[:], ref.values)
    assert tuple(m.values.chunks)[0] == 4 and (tmp_path / "g.png").exists()


def test_atlas_maps_a_scenarios_shaken_pivot(tmp_path, capsys):
    pytest.importorskip("dask.array")
    pytest.importorskip("zarr")
    path = tmp_path / "shaken.toml"
    path.write_text(SCENARIO + '[pivot]\ny = { kind = "sinusoid", amplitude = 0.04, frequency = 30.0 }\n')
    args = ["atlas", str(path), "-o", str(tmp_path / "m.png"), "--size", "6", "--t-end", "2",
            "--zarr", str(tmp_path / "m.zarr"), "--dask", "threads", "--dpi", "40", "-q"]
    assert main(args) == 0
    m = open_indicator_map(tmp_path / "m.zarr")
    shaken = mp.Pivot(y=mp.Sinusoid(amplitude=0.04, frequency=30.0))
    ref = mp.indicator_map(DOUBLE, _cells(6), _cells(6), t_end=2.0, base_theta=np.radians([120.0, -10.0]), pivot=shaken)
    np.testing.assert_array_equal(m.values[:], ref.values)
    still = mp.indicator_map(DOUBLE, _cells(6), _cells(6), t_end=2.0, base_theta=np.radians([120.0, -10.0]))
    assert (ref.values != still.values).any()  # the pivot was applied


def test_atlas_flip_is_the_fractal_command(tmp_path, capsys):
    scenario = _scenario(tmp_path)
    common = ["--size", "12", "--dpi", "50", "--link", "2", "--x", "theta2", "--y", "omega2"]
    assert main(["fractal", str(scenario), "-o", str(tmp_path / "fractal.png"), "--t-max", "2.5"] + common) == 0
    by_fractal = capsys.readouterr().out
    assert main(["atlas", str(scenario), "-o", str(tmp_path / "atlas.png"), "--indicator", "flip", "--t-end", "2.5"]
                + common) == 0
    by_atlas = capsys.readouterr().out

    def steady(text):  # the wall time is the machine's, the file name the test's
        return re.sub(r"wall time [0-9.e+-]+ s", "", text).replace("fractal.png", "atlas.png")

    assert by_atlas.startswith("Test double: flip-time map of 12 x 12 initial states, N = 2, t_max = 2.5 s, dt = 0.01 s")
    assert steady(by_atlas) == steady(by_fractal)
    assert (tmp_path / "atlas.png").read_bytes() == (tmp_path / "fractal.png").read_bytes()


def test_atlas_offers_the_core_indicators_and_flip(capsys):
    assert main(["atlas", "--help"]) == 0
    out = re.sub(r"\s+", " ", capsys.readouterr().out)
    assert f"one of {', '.join((*mp.INDICATORS, 'flip'))} (default megno)" in out
    for option in ("--indicator", "--k", "--t-end", "--dt", "--size", "--x", "--y", "--x-range", "--y-range",
                   "--dask", "--chunks", "--zarr", "--dpi", "--link", "--linear", "SCENARIO"):
        assert option in out


@pytest.mark.parametrize("extra, status, message", [
    (["--indicator", "lyap"], 2, "argument --indicator: invalid choice: 'lyap'"),
    (["--indicator", "gali"], 1, "--indicator gali needs --k K, its order, between 2 and 2N = 4; none given"),
    (["--indicator", "gali", "--k", "5"], 1, "--indicator gali needs --k K, its order, between 2 and 2N = 4; got 5"),
    (["--k", "2"], 1, "--k is GALI's order (--indicator gali); megno takes none"),
    (["--indicator", "flip", "--k", "2"], 1, "--k is GALI's order (--indicator gali); flip takes none"),
    (["--k", "x"], 2, "argument --k: invalid int value: 'x'"),
    (["--indicator", "sali", "--link", "1"], 1, "--link is for --indicator flip only"),
    (["--t-end", "-1"], 1, "--t-end must be > 0, got -1"),
    (["--dt", "0"], 1, "--dt must be > 0, got 0"),
    (["--x", "omega3"], 1, "--x must be theta1..theta2 or omega1..omega2, got 'omega3'"),
    (["--size", "1"], 1, "--size must be at least 2, got 1"),
    (["--x-range", "10", "-10"], 1, "a range must have HI > LO"),
    (["--size", "4096", "--t-end", "1e6"], 1, "more than the 1e+12 one machine is given"),
])
def test_atlas_refuses_bad_options_with_a_message_and_writes_nothing(tmp_path, capsys, extra, status, message):
    out = tmp_path / "map.png"
    assert main(["atlas", str(_scenario(tmp_path)), "-o", str(out), "--size", "8", "-q"] + extra) == status
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not out.exists()


def test_atlas_needs_a_png_and_a_scenario(tmp_path, capsys):
    assert main(["atlas", str(_scenario(tmp_path)), "-o", str(tmp_path / "map.jpg")]) == 1
    assert "-o must end in .png" in capsys.readouterr().err
    assert main(["atlas", str(tmp_path / "missing.toml"), "-o", str(tmp_path / "map.png")]) == 1
    assert "missing.toml" in capsys.readouterr().err
