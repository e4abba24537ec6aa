"""Certified chaos-indicator maps (issue 14): every cell computed at dt and at dt/2, the cells
that fall on different sides of the regular/chaotic threshold at the two steps marked
uncertain, counted and drawn, on the map, the Dask sweep, the Zarr store, the picture and the
command line; the threshold the core's rule of thumb unless given."""
import sys
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp
from multipendulum.cli import main
from multipendulum.fractal import UNCERTAIN_COLOR, plot_indicator_map

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pictures import render  # noqa: E402  (tests/pictures.py)

DOUBLE = mp.Chain([1.0, 1.0], [1.0, 1.0])
GRID = np.linspace(-np.pi, np.pi, 40)


def _grid_states(x, y):
    tx, ty = np.meshgrid(x, y)
    return np.stack([tx, ty], -1)


def test_a_certified_map_marks_exactly_the_cells_whose_side_of_the_threshold_changes():
    im = mp.indicator_map(DOUBLE, GRID, GRID, t_end=40.0, dt=0.02, certify=True)
    plain = mp.indicator_map(DOUBLE, GRID, GRID, t_end=40.0, dt=0.02)
    np.testing.assert_array_equal(im.values, plain.values)  # the values are still those at dt
    assert plain.uncertain is None and plain.threshold is None
    assert im.threshold == mp.CHAOS_RULES["megno"][1] == 4.0
    th0 = _grid_states(GRID, GRID)
    fine = mp.megno(DOUBLE, th0, np.zeros_like(th0), t_end=40.0, dt=0.01)
    np.testing.assert_array_equal(im.uncertain, (im.values > 4.0) != (fine > 4.0))
    # Chaos leaves some cells uncertain over 40 s at this coarse step, and most of them certain.
    assert 0 < im.uncertain.mean() < 0.1
    # SALI's side is below its threshold; a stated one replaces the rule.
    sali = mp.indicator_map(DOUBLE, GRID[::4], GRID[::4], t_end=40.0, dt=0.02, indicator="sali", certify=True,
                            threshold=1e-4)
    fine = mp.sali(DOUBLE, _grid_states(GRID[::4], GRID[::4]), np.zeros((10, 10, 2)), t_end=40.0, dt=0.01)
    assert sali.threshold == 1e-4
    np.testing.assert_array_equal(sali.uncertain, (sali.values < 1e-4) != (fine < 1e-4))


def test_a_smaller_step_leaves_fewer_cells_uncertain():
    coarse = mp.indicator_map(DOUBLE, GRID, GRID, t_end=40.0, dt=0.04, certify=True)
    fine = mp.indicator_map(DOUBLE, GRID, GRID, t_end=40.0, dt=0.01, certify=True)
    assert fine.uncertain.sum() < coarse.uncertain.sum()


def test_the_certified_batch_is_the_function_the_map_uses():
    th0 = np.array([[0.3, 0.2], [2.0, 2.5], [1.0, -0.5]])
    values, uncertain, threshold = mp.certified_indicator(DOUBLE, th0, np.zeros_like(th0), 30.0, "fli", dt=0.01,
                                                          threshold=10.0)
    np.testing.assert_array_equal(values, mp.fli(DOUBLE, th0, np.zeros_like(th0), 30.0, dt=0.01))
    fine = mp.fli(DOUBLE, th0, np.zeros_like(th0), 30.0, dt=0.005)
    np.testing.assert_array_equal(uncertain, (values > 10.0) != (fine > 10.0))
    assert threshold == 10.0 and uncertain.dtype == bool


def test_a_certified_sweep_is_the_certified_map_bit_for_bit_on_disk_too(tmp_path):
    pytest.importorskip("dask.array")
    pytest.importorskip("zarr")
    x = GRID[::2]
    ref = mp.indicator_map(DOUBLE, x, x, t_end=40.0, dt=0.04, certify=True)
    got = mp.sweep_indicator_map(DOUBLE, x, x, t_end=40.0, dt=0.04, certify=True, chunks=(7, 9))
    np.testing.assert_array_equal(got.values, ref.values)
    np.testing.assert_array_equal(got.uncertain, ref.uncertain)
    assert got.threshold == 4.0 and ref.uncertain.any()
    mp.sweep_indicator_map(DOUBLE, x, x, t_end=40.0, dt=0.04, certify=True, chunks=8, zarr=tmp_path / "c.zarr")
    again = mp.open_indicator_map(tmp_path / "c.zarr")
    np.testing.assert_array_equal(again.uncertain[:], ref.uncertain)
    assert again.threshold == 4.0
    plain = mp.sweep_indicator_map(DOUBLE, x, x, t_end=5.0, dt=0.04, chunks=8, zarr=tmp_path / "p.zarr")
    assert plain.uncertain is None and mp.open_indicator_map(tmp_path / "p.zarr").uncertain is None


@pytest.mark.parametrize("kwargs, message", [
    (dict(certify="yes"), "certify must be True or False, got 'yes'"),
    (dict(threshold=3.0), "threshold applies to a certified map: pass certify=True with it"),
    (dict(certify=True, indicator="fli"),
     "a certified fli map needs a threshold: the value above which a cell counts as chaotic (megno, sali and gali "
     "have their own)"),
    (dict(certify=True, threshold=float("nan")), "threshold must be finite, got NaN"),
    (dict(certify=True, threshold="high"), "threshold must be a number, got str 'high'"),
])
def test_bad_certification_arguments_are_refused(kwargs, message):
    for fn in (mp.indicator_map, mp.sweep_indicator_map):
        with pytest.raises(mp.InputError) as e:
            fn(DOUBLE, GRID[:3], GRID[:3], t_end=1.0, **kwargs)
        assert message in str(e.value)


def test_the_picture_draws_and_counts_the_uncertain_cells():
    im = mp.indicator_map(DOUBLE, GRID, GRID, t_end=40.0, dt=0.04, certify=True)
    assert im.uncertain.sum() > 20
    fig = plot_indicator_map(im, chain=DOUBLE, dpi=60)
    rgb = render(fig)
    from matplotlib.colors import to_rgb

    magenta = np.all(np.abs(rgb - np.array(to_rgb(UNCERTAIN_COLOR))) < 0.02, axis=-1).sum()
    assert magenta > 100
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert f"uncertain: MEGNO > 4 changes at dt / 2 ({100 * im.uncertain.mean():.1f}%)" in labels
    plain = render(plot_indicator_map(mp.indicator_map(DOUBLE, GRID, GRID, t_end=40.0, dt=0.04), chain=DOUBLE,
                                      dpi=60))
    assert np.all(np.abs(plain - np.array(to_rgb(UNCERTAIN_COLOR))) < 0.02, axis=-1).sum() < magenta / 20


DOUBLE_SCENARIO = """
name = "Test double"
[chain]
lengths = [1.0, 1.0]
masses = [1.0, 1.0]
[initial]
unit = "radians"
theta = [0.0, 0.0]
[simulation]
t_end = 40.0
"""


def test_atlas_certify_counts_the_uncertain_cells(tmp_path, capsys):
    scenario = tmp_path / "double.toml"
    scenario.write_text(DOUBLE_SCENARIO)
    out = tmp_path / "map.png"
    assert main(["atlas", str(scenario), "-o", str(out), "--size", "40", "--dpi", "60", "--dt", "0.02",
                 "--certify"]) == 0
    text = capsys.readouterr().out
    assert out.exists() and "(certified: again at dt/2)" in text
    x = np.radians(-180 + 9 * (np.arange(40) + 0.5))
    im = mp.indicator_map(DOUBLE, x, x, t_end=40.0, dt=0.02, certify=True)
    k = int(im.uncertain.sum())
    assert k > 0
    assert f"certified: {100 * k / 1600:.2f}% of cells uncertain ({k} of 1600: MEGNO > 4 changes at dt/2)" in text
    assert main(["atlas", str(scenario), "-o", str(tmp_path / "f.png"), "--size", "8", "--dt", "0.02", "-q",
                 "--indicator", "fli", "--certify", "--threshold", "12"]) == 0
