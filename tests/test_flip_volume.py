"""3-D flip maps (issue 14): three varied initial values (the triple pendulum's three angles by
default), in memory or on Dask written chunk by chunk to Zarr, certified like the 2-D maps,
drawn as slices; the command line's `fractal --z`."""
import sys
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp
from multipendulum.cli import main
from multipendulum.fractal import UNCERTAIN_COLOR, plot_flip_volume

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pictures import render  # noqa: E402  (tests/pictures.py)

TRIPLE = mp.Chain([1.0, 1.0, 1.0], [1.0, 1.0, 1.0])
G = np.linspace(-np.pi, np.pi, 12)
Z = np.radians([-150.0, 0.0, 60.0, 170.0])


def test_a_volume_is_its_slices_each_a_flip_map_with_the_third_value_fixed():
    fv = mp.flip_volume(TRIPLE, G, G, Z, t_max=6.0, dt=0.02)
    assert fv.times.shape == fv.allowed.shape == (4, 12, 12)
    assert fv.vary == ("theta", 0, "theta", 1, "theta", 2) and fv.uncertain is None
    for k, z in enumerate(Z):
        fm = mp.flip_map(TRIPLE, G, G, t_max=6.0, dt=0.02, base_theta=[0.0, 0.0, z])
        np.testing.assert_array_equal(fv.times[k], fm.times)
        np.testing.assert_array_equal(fv.slice(k).allowed, fm.allowed)
    # The cells are the initial states they say: theta = (x[j], y[i], z[k]).
    i, j, k = 3, 7, 2
    alone = mp.flip_times(TRIPLE, [G[j], G[i], Z[k]], t_max=6.0, dt=0.02)
    assert fv.times[k, i, j] == alone
    assert fv.allowed[k, i, j] == (TRIPLE.energy([G[j], G[i], Z[k]], [0, 0, 0]) >= fv.threshold)
    assert np.isfinite(fv.times).any() and (~fv.allowed).any()


def test_other_quantities_and_a_certified_volume():
    vary = ("omega", 2, "theta", 0, "theta", 1)
    rates = np.radians(np.linspace(-400, 400, 6))
    fv = mp.flip_volume(TRIPLE, rates, G[:5], G[4:7], t_max=4.0, dt=0.02, vary=vary, certify=True)
    assert fv.times.shape == (3, 5, 6) and fv.time_tolerance == 0.02
    th0 = np.zeros((3, 5, 6, 3))
    om0 = np.zeros((3, 5, 6, 3))
    th0[..., 0] = G[:5][None, :, None]
    th0[..., 1] = G[4:7][:, None, None]
    om0[..., 2] = rates[None, None, :]
    times, uncertain, _ = mp.certified_flip_times(TRIPLE, th0, om0, t_max=4.0, dt=0.02)
    np.testing.assert_array_equal(fv.times, times)
    np.testing.assert_array_equal(fv.uncertain, uncertain)


def test_the_dask_sweep_is_the_volume_bit_for_bit_and_streams_to_zarr(tmp_path):
    pytest.importorskip("dask.array")
    pytest.importorskip("zarr")
    ref = mp.flip_volume(TRIPLE, G, G, Z, t_max=8.0, dt=0.02, certify=True)
    got = mp.sweep_flip_volume(TRIPLE, G, G, Z, t_max=8.0, dt=0.02, certify=True, chunks=(3, 5, 7))
    for name in ("times", "allowed", "uncertain"):
        np.testing.assert_array_equal(getattr(got, name), getattr(ref, name))
    assert ref.uncertain.any()
    mp.sweep_flip_volume(TRIPLE, G, G, Z, t_max=8.0, dt=0.02, chunks=(1, 4, 12), zarr=tmp_path / "v.zarr")
    import zarr

    store = zarr.open_group(str(tmp_path / "v.zarr"), mode="r")
    assert store["times"].chunks == (1, 4, 12) and store.attrs["vary"] == ["theta", 0, "theta", 1, "theta", 2]
    again = mp.open_flip_volume(tmp_path / "v.zarr")
    np.testing.assert_array_equal(again.z, Z)
    for k in range(Z.size):
        np.testing.assert_array_equal(again.slice(k).times, ref.times[k])
        np.testing.assert_array_equal(again.slice(k).allowed, ref.allowed[k])
    assert again.uncertain is None and again.time_tolerance is None


@pytest.mark.parametrize("kwargs, message", [
    (dict(vary=("theta", 0, "theta", 1)), "vary must be (kind_x, link_x, kind_y, link_y, kind_z, link_z), got"),
    (dict(vary=("theta", 0, "theta", 1, "theta", 0)), "vary must name three different quantities"),
    (dict(vary=("theta", 0, "theta", 1, "phi", 2)),
     "vary must name ('theta'|'omega', link index < 3) three times"),
    (dict(z=[]), "z must be a non-empty array of finite numbers"),
    (dict(z=[0.1, float("nan")]), "z must be a non-empty array of finite numbers"),
    (dict(z="up"), "z must be an array of numbers, got str 'up'"),
])
def test_bad_volumes_are_refused(kwargs, message):
    args = dict(x=G[:3], y=G[:3], z=Z[:2])
    args.update(kwargs)
    for fn in (mp.flip_volume, mp.sweep_flip_volume):
        with pytest.raises(mp.InputError) as e:
            fn(TRIPLE, t_max=1.0, **args)
        assert message in str(e.value), (fn.__name__, str(e.value))
    with pytest.raises(mp.InputError, match=r"chunks\[1\] must be a positive integer, got 0"):
        mp.sweep_flip_volume(TRIPLE, G[:3], G[:3], Z[:2], t_max=1.0, chunks=(1, 0, 2))
    fv = mp.flip_volume(TRIPLE, G[:3], G[:3], Z[:2], t_max=1.0)
    with pytest.raises(mp.InputError, match=r"k must be an index of z \(length 2\), got 2"):
        fv.slice(2)
    with pytest.raises(mp.InputError, match=r"slices must be indices of z \(0 <= k < 2\), got 5"):
        plot_flip_volume(fv, slices=[0, 5])


def test_the_picture_has_a_panel_per_slice_with_its_value_and_marks_the_uncertain():
    fv = mp.flip_volume(TRIPLE, G, G, np.radians(np.linspace(-160, 160, 11)), t_max=15.0, dt=0.04, certify=True)
    fig = plot_flip_volume(fv, chain=TRIPLE, dpi=50)
    panels = [ax for ax in fig.axes if ax.get_title()]
    # Nine of eleven slices, evenly spaced, the first and the last among them.
    assert [ax.get_title() for ax in panels][0] == "$\\theta_{3}$ = -160°"
    assert [ax.get_title() for ax in panels][-1] == "$\\theta_{3}$ = 160°"
    assert len(panels) == 9
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any(label.startswith("uncertain: changes at dt / 2") for label in labels)
    from matplotlib.colors import to_rgb

    rgb = render(fig)
    assert np.all(np.abs(rgb - np.array(to_rgb(UNCERTAIN_COLOR))) < 0.02, axis=-1).sum() > 20
    two = plot_flip_volume(fv, slices=[0, 10], dpi=50)
    assert len([ax for ax in two.axes if ax.get_title()]) == 2


TRIPLE_SCENARIO = """
name = "Test triple"
[chain]
lengths = [1.0, 1.0, 1.0]
masses = [1.0, 1.0, 1.0]
[initial]
unit = "radians"
theta = [0.0, 0.0, 0.0]
[simulation]
t_end = 6.0
"""


def test_fractal_z_draws_slices_and_counts_the_whole_volume(tmp_path, capsys):
    scenario = tmp_path / "triple.toml"
    scenario.write_text(TRIPLE_SCENARIO)
    out = tmp_path / "v.png"
    assert main(["fractal", str(scenario), "-o", str(out), "--size", "10", "--dpi", "50", "--dt", "0.02",
                 "--z", "theta3", "--z-size", "3", "--z-range", "-90", "90"]) == 0
    text = capsys.readouterr().out
    assert out.exists() and "3-D flip-time map of 10 x 10 x 3 initial states" in text
    x = np.radians(-180 + 36 * (np.arange(10) + 0.5))
    fv = mp.flip_volume(TRIPLE, x, x, np.radians([-60.0, 0.0, 60.0]), t_max=6.0, dt=0.02)
    flipped = np.isfinite(fv.times).mean()
    assert f"flipped {100 * flipped:.1f}%" in text
    pytest.importorskip("zarr")
    pytest.importorskip("dask.array")
    assert main(["fractal", str(scenario), "-o", str(tmp_path / "w.png"), "--size", "10", "--dpi", "50", "--dt",
                 "0.02", "--z", "theta3", "--z-size", "3", "--z-range", "-90", "90", "--zarr",
                 str(tmp_path / "v.zarr"), "-q"]) == 0
    np.testing.assert_array_equal(mp.open_flip_volume(tmp_path / "v.zarr").times[:], fv.times)


@pytest.mark.parametrize("args, message", [
    (["--z-size", "4"], "--z-size applies to a 3-D map: add --z QUANTITY"),
    (["--z", "theta1"], "--z must differ from --x and --y, got 'theta1'"),
    (["--z", "theta7"], "--z must be theta1..theta3 or omega1..omega3, got 'theta7'"),
    (["--z", "omega3", "--z-size", "0"], "--z-size must be at least 1, got 0"),
])
def test_fractal_refuses_bad_volumes(tmp_path, capsys, args, message):
    scenario = tmp_path / "triple.toml"
    scenario.write_text(TRIPLE_SCENARIO)
    out = tmp_path / "v.png"
    assert main(["fractal", str(scenario), "-o", str(out), "--size", "8", "-q"] + args) == 1
    assert message in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("bad, message", [
    ([0.1, float("nan")], "x must be a non-empty array of finite numbers"),
    ([0.1, float("inf")], "x must be a non-empty array of finite numbers"),
    ([], "x must be a non-empty array of finite numbers"),
    ("abc", "x must be an array of numbers, got str 'abc'"),
])
def test_every_map_refuses_a_bad_grid_by_its_name(bad, message):
    """NaN, inf, empty or non-numeric grids: the grid named, before any work (never an internal
    name such as theta0, nor a ValueError from NumPy)."""
    pytest.importorskip("dask.array")
    double = mp.Chain([1.0, 1.0], [1.0, 1.0])
    calls = [
        lambda: mp.flip_map(double, bad, [0.1, 0.2], t_max=1.0),
        lambda: mp.indicator_map(double, bad, [0.1, 0.2], t_end=1.0),
        lambda: mp.sweep_flip_map(double, bad, [0.1, 0.2], t_max=1.0),
        lambda: mp.sweep_indicator_map(double, bad, [0.1, 0.2], t_end=1.0),
        lambda: mp.flip_volume(TRIPLE, bad, [0.1], [0.2], t_max=1.0),
        lambda: mp.sweep_flip_volume(TRIPLE, bad, [0.1], [0.2], t_max=1.0),
    ]
    for call in calls:
        with pytest.raises(mp.InputError) as e:
            call()
        assert message in str(e.value)
