"""Certified flip maps (issue 14): every cell computed at dt and at dt/2, the cells whose flip
decision or time (beyond a stated tolerance) moves with the step marked uncertain, counted and
drawn, on the map, the Dask sweep, the Zarr store, the picture and the command line."""
import sys
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp
from multipendulum.cli import main
from multipendulum.fractal import UNCERTAIN_COLOR, plot_flip_map

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pictures import render  # noqa: E402  (tests/pictures.py)

TRIPLE = mp.Chain([1.0, 1.0, 1.0], [1.0, 1.0, 1.0])
GRID = np.linspace(-np.pi, np.pi, 41)


def test_a_certified_map_marks_exactly_the_cells_that_change_at_half_the_step():
    fm = mp.flip_map(TRIPLE, GRID, GRID, t_max=15.0, dt=0.02, certify=True)
    plain = mp.flip_map(TRIPLE, GRID, GRID, t_max=15.0, dt=0.02)
    np.testing.assert_array_equal(fm.times, plain.times)  # the times are still those at dt
    assert plain.uncertain is None and plain.time_tolerance is None
    assert fm.time_tolerance == 0.02  # one step, by default
    th0 = np.stack([*np.meshgrid(GRID, GRID), np.zeros((41, 41))], -1)
    fine = mp.flip_times(TRIPLE, th0, t_max=15.0, dt=0.01)
    with np.errstate(invalid="ignore"):  # inf - inf where neither flips: not a difference
        differ = (np.isfinite(fm.times) != np.isfinite(fine)) | (np.abs(fm.times - fine) > 0.02)
    np.testing.assert_array_equal(fm.uncertain, differ)
    # What can never flip is never uncertain; chaos leaves some cells uncertain over 15 s.
    assert not fm.uncertain[~fm.allowed].any()
    assert 0 < fm.uncertain.mean() < 0.5
    # A tighter tolerance marks a superset.
    tight = mp.flip_map(TRIPLE, GRID, GRID, t_max=15.0, dt=0.02, certify=True, time_tolerance=1e-6)
    assert tight.time_tolerance == 1e-6 and (tight.uncertain >= fm.uncertain).all() \
        and tight.uncertain.sum() > fm.uncertain.sum()


def test_uncertainty_grows_with_the_time_chaos_has_to_amplify_the_step_error():
    short = mp.flip_map(TRIPLE, GRID, GRID, t_max=2.0, dt=0.02, certify=True)
    long = mp.flip_map(TRIPLE, GRID, GRID, t_max=20.0, dt=0.02, certify=True)
    # Flips within 2 s follow regular motion: rk4's error at 0.02 s moves them by far less than
    # a step. Over 20 s the chaotic cells' decisions depend on the step.
    assert short.uncertain.mean() < 0.01 < long.uncertain.mean()


def test_a_certified_sweep_is_the_certified_map_bit_for_bit_on_disk_too(tmp_path):
    pytest.importorskip("dask.array")
    pytest.importorskip("zarr")
    x = GRID[::2]
    ref = mp.flip_map(TRIPLE, x, x, t_max=10.0, dt=0.02, certify=True, time_tolerance=0.005)
    got = mp.sweep_flip_map(TRIPLE, x, x, t_max=10.0, dt=0.02, certify=True, time_tolerance=0.005, chunks=(7, 9))
    np.testing.assert_array_equal(got.times, ref.times)
    np.testing.assert_array_equal(got.uncertain, ref.uncertain)
    assert got.time_tolerance == 0.005 and ref.uncertain.any()
    mp.sweep_flip_map(TRIPLE, x, x, t_max=10.0, dt=0.02, certify=True, time_tolerance=0.005, chunks=8,
                      zarr=tmp_path / "c.zarr")
    again = mp.open_flip_map(tmp_path / "c.zarr")
    np.testing.assert_array_equal(again.uncertain[:], ref.uncertain)
    assert again.time_tolerance == 0.005
    plain = mp.sweep_flip_map(TRIPLE, x, x, t_max=10.0, dt=0.02, chunks=8, zarr=tmp_path / "p.zarr")
    assert plain.uncertain is None and mp.open_flip_map(tmp_path / "p.zarr").uncertain is None


@pytest.mark.parametrize("kwargs, message", [
    (dict(certify="yes"), "certify must be True or False, got 'yes'"),
    (dict(time_tolerance=0.1), "time_tolerance applies to a certified map: pass certify=True with it"),
    (dict(certify=True, time_tolerance=-1.0), "time_tolerance must be >= 0 and finite, got -1"),
    (dict(certify=True, time_tolerance=float("nan")), "time_tolerance must be >= 0 and finite, got NaN"),
])
def test_bad_certification_arguments_are_refused(kwargs, message):
    for fn in (mp.flip_map, mp.sweep_flip_map):
        with pytest.raises(mp.InputError) as e:
            fn(TRIPLE, GRID[:3], GRID[:3], t_max=1.0, **kwargs)
        assert message in str(e.value)


def test_the_picture_draws_and_counts_the_uncertain_cells():
    fm = mp.flip_map(TRIPLE, GRID, GRID, t_max=15.0, dt=0.02, certify=True)
    fig = plot_flip_map(fm, chain=TRIPLE, dpi=60)
    rgb = render(fig)
    from matplotlib.colors import to_rgb

    magenta = np.all(np.abs(rgb - np.array(to_rgb(UNCERTAIN_COLOR))) < 0.02, axis=-1).sum()
    assert magenta > 200
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert f"uncertain: changes at dt / 2 (by > 0.02 s) ({100 * fm.uncertain.mean():.1f}%)" in labels
    plain = render(plot_flip_map(mp.flip_map(TRIPLE, GRID, GRID, t_max=15.0, dt=0.02), chain=TRIPLE, dpi=60))
    assert np.all(np.abs(plain - np.array(to_rgb(UNCERTAIN_COLOR))) < 0.02, axis=-1).sum() < magenta / 20


TRIPLE_SCENARIO = """
name = "Test triple"
[chain]
lengths = [1.0, 1.0, 1.0]
masses = [1.0, 1.0, 1.0]
[initial]
unit = "radians"
theta = [0.0, 0.0, 0.0]
[simulation]
t_end = 12.0
"""


def test_fractal_certify_counts_the_uncertain_cells(tmp_path, capsys):
    scenario = tmp_path / "triple.toml"
    scenario.write_text(TRIPLE_SCENARIO)
    out = tmp_path / "map.png"
    assert main(["fractal", str(scenario), "-o", str(out), "--size", "30", "--dpi", "60", "--dt", "0.02",
                 "--certify"]) == 0
    text = capsys.readouterr().out
    assert "(certified: again at dt/2)" in text and out.read_bytes()[:4] == b"\x89PNG"
    x = np.radians(-180 + 12 * (np.arange(30) + 0.5))
    fm = mp.flip_map(TRIPLE, x, x, t_max=12.0, dt=0.02, certify=True)
    k = int(fm.uncertain.sum())
    assert k > 0
    assert (f"uncertain: {k} of 900 cells ({100 * k / 900:.1f}%) change their flip decision, or their time by "
            "more than 0.02 s, at dt/2 = 0.01 s") in text


@pytest.mark.parametrize("args, message", [
    (["fractal", "--time-tolerance", "0.1"], "--time-tolerance applies to a certified map: add --certify"),
    (["fractal", "--certify", "--time-tolerance", "-1"], "time_tolerance must be >= 0 and finite, got -1"),
    (["atlas", "--certify", "--indicator", "fli"], "--certify with --indicator fli needs --threshold VALUE"),
    (["atlas", "--threshold", "3"], "--threshold applies to a certified map: add --certify"),
    (["atlas", "--indicator", "flip", "--certify", "--threshold", "3"],
     "--threshold is for the indicators' certified maps; a flip map takes --time-tolerance"),
])
def test_the_commands_refuse_bad_certification_options(tmp_path, capsys, args, message):
    scenario = tmp_path / "triple.toml"
    scenario.write_text(TRIPLE_SCENARIO)
    out = tmp_path / "map.png"
    assert main([args[0], str(scenario), "-o", str(out), "--size", "8", "-q"] + args[1:]) == 1
    assert message in capsys.readouterr().err
    assert not out.exists()
