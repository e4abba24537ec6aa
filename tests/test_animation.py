"""Animations and plots: files exist, have the expected frames, are not blank, play in real time,
and draw the right thing (pivot fixed, rods connected, energy on a log scale)."""
import os

import numpy as np
import pytest

import multipendulum as mp
from multipendulum.animation import _Painter, frame_times
from multipendulum.results import load_results, save_results, series



@pytest.fixture(scope="module")
def sol():
    chain = mp.Chain(lengths=[1.0, 1.0], masses=[1.0, 2.0])
    return mp.simulate(chain, [2.0, 2.6], [0.0, 0.0], 2.0, t_eval=np.linspace(0, 2.0, 201))


def _gif_frames(path):
    from PIL import Image, ImageSequence

    with Image.open(path) as im:
        frames = [np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(im)]
        durations = [f.info["duration"] for f in ImageSequence.Iterator(im)]
    return np.stack(frames), durations


def _assert_not_blank(frames):
    # Each frame has content, and the frames differ from one another (the pendulum moves).
    assert all(f.std() > 10 for f in frames)
    assert frames.astype(float).var(axis=0).mean() > 1.0


def test_frame_times_are_real_time():
    t = frame_times(0.0, 2.0, fps=30, speed=1.0)
    assert len(t) == 61 and t[-1] == pytest.approx(2.0)
    assert len(frame_times(0.0, 2.0, fps=10, speed=2.0)) == 11
    assert len(frame_times(0.0, 1.99, fps=10, speed=1.0)) == 20


def test_gif(tmp_path, sol):
    path = mp.animate(sol, tmp_path / "a.gif", fps=20, dpi=40)
    frames, durations = _gif_frames(path)
    assert len(frames) == len(frame_times(0.0, 2.0, 20, 1.0)) == 41
    assert frames.shape[1:] == (192, 192, 3)  # 5 in at 40 dpi, rounded to a multiple of 16
    _assert_not_blank(frames)
    assert sum(durations) == pytest.approx(1000 * len(frames) / 20, abs=10)  # real-time playback
    assert (frames[:, 2, 2] == 255).all()  # a white background, not grey
    assert os.listdir(tmp_path) == ["a.gif"]


def test_gif_durations_stay_real_time_when_fps_does_not_divide(tmp_path, sol):
    _, durations = _gif_frames(mp.animate(sol, tmp_path / "a.gif", fps=30, dpi=30, speed=2.0))
    assert len(durations) == 31
    assert set(durations) <= {30, 40}
    assert sum(durations) == pytest.approx(1000 * 31 / 30, abs=10)


def test_mp4(tmp_path, sol):
    import imageio_ffmpeg

    path = mp.animate(sol, tmp_path / "a.mp4", fps=15, dpi=40)
    count, seconds = imageio_ffmpeg.count_frames_and_secs(str(path))
    assert count == len(frame_times(0.0, 2.0, 15, 1.0)) == 31
    assert seconds == pytest.approx(31 / 15, abs=0.1)
    reader = imageio_ffmpeg.read_frames(str(path))
    try:
        w, h = next(reader)["size"]
        frames = np.stack([np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in reader])
    finally:
        reader.close()
    assert len(frames) == 31
    _assert_not_blank(frames)


def test_animate_results_file_and_speed(tmp_path, sol):
    results = load_results(save_results(sol, tmp_path / "r.npz"))
    frames, _ = _gif_frames(mp.animate(results, tmp_path / "b.gif", fps=10, speed=0.5, trail=0, dpi=30))
    assert len(frames) == 41  # 2 s at half speed, 10 frames per second of playback
    _assert_not_blank(frames)


def test_bad_animation_arguments_write_nothing(tmp_path, sol):
    with pytest.raises(mp.InputError, match=r"must end in \.gif or \.mp4"):
        mp.animate(sol, tmp_path / "a.avi")
    with pytest.raises(mp.InputError, match="fps must be > 0"):
        mp.animate(sol, tmp_path / "a.gif", fps=0)
    with pytest.raises(mp.InputError, match="trail must be >= 0"):
        mp.animate(sol, tmp_path / "a.gif", trail=-1)
    assert os.listdir(tmp_path) == []


def _pixel(painter, xy):
    """Data coordinates -> (row, col) in the frame array."""
    x, y = painter.ax.transData.transform(xy)
    return int(round(painter.pixels - y)), int(round(x))


def _dark(frame, row, col, radius=1):
    patch = frame[max(row - radius, 0): row + radius + 1, max(col - radius, 0): col + radius + 1]
    return patch.min() < 90


@pytest.mark.parametrize("masses", [[1.0, 2.0], [1.0, 1.0, 1.0, 1.0, 1.0]])
def test_pivot_fixed_and_rods_connected(masses):
    n = len(masses)
    chain = mp.Chain(lengths=[1.0] * n, masses=masses)
    sol = mp.simulate(chain, np.linspace(2.0, 2.6, n), np.zeros(n), 3.0, t_eval=np.linspace(0, 3.0, 301))
    view = series(sol)
    painter = _Painter(view, dpi=60, size=5.0, title=None, speed=1.0)
    times = frame_times(0.0, 3.0, 5, 1.0)
    joints = chain.positions(np.array([np.interp(times, sol.t, sol.theta[:, i]) for i in range(n)]).T)
    for k, t in enumerate(times):
        frame = painter.frame(k, t, joints[k], trail=1.0)
        assert _dark(frame, *_pixel(painter, (0.0, 0.0))), f"pivot not drawn at the origin at t = {t}"
        chain_xy = np.vstack([[0.0, 0.0], joints[k]])
        for i in range(n):
            a, b = chain_xy[i], chain_xy[i + 1]
            for s in np.linspace(0.0, 1.0, 9):  # every point along each rod is drawn
                assert _dark(frame, *_pixel(painter, a + s * (b - a))), f"rod {i + 1} broken at t = {t}"
        # And far from the chain the picture is background.
        far = -np.sign(joints[k][-1]) * 0.9 * n
        row, col = _pixel(painter, far)
        assert frame[row, col].min() > 200


def test_bob_sizes_follow_mass(sol):
    painter = _Painter(series(sol), dpi=80, size=5.0, title=None, speed=1.0)
    assert painter.bob_sizes[1] == pytest.approx(2 * painter.bob_sizes[0])  # area proportional to mass


def test_plots_written(tmp_path, sol):
    paths = mp.plot(sol, tmp_path)
    assert [p.name for p in paths] == ["angles.png", "energy.png", "phase.png", "tip.png"]
    from PIL import Image

    for p in paths:
        with Image.open(p) as im:
            assert im.size[0] > 300 and np.asarray(im.convert("L")).std() > 5
    assert sorted(os.listdir(tmp_path)) == sorted(p.name for p in paths)


def test_plot_figures_and_log_energy(sol):
    import matplotlib.pyplot as plt

    figs = mp.plot(sol, kinds=("energy", "phase"))
    try:
        energy, phase = figs
        assert energy.axes[0].get_yscale() == "log"
        assert len(phase.axes) == 2  # first and last link
        lines = energy.axes[0].get_lines()
        assert lines and np.all(lines[0].get_ydata() > 0)
    finally:
        for f in figs:
            plt.close(f)


def test_plot_rejects_unknown_kind(tmp_path, sol):
    with pytest.raises(mp.InputError, match="unknown plot kind 'energie'"):
        mp.plot(sol, tmp_path, kinds=("energie",))
    assert os.listdir(tmp_path) == []


# ---------------------------------------------------------------------------------------------
# Settings that would not fit are refused before anything is drawn


@pytest.mark.parametrize("kwargs, fragment", [
    (dict(fps=100000), "has 2e+05 frames, more than 100000; lower fps, raise speed"),
    (dict(speed=1e-6), "has 6e+07 frames, more than 100000"),
    (dict(dpi=100000), "frames of 5e+05 x 5e+05 pixels (dpi = 100000, 5 inches) are larger than 8192 x 8192"),
    (dict(fps=30000, dpi=400), "draws 2.4e+11 pixels, more than 3e+10"),
    (dict(fps=45000), "write .mp4 (its frames are streamed, not kept)"),   # every GIF frame is kept
    (dict(fps=float("inf")), "fps must be finite, got inf"),
    (dict(trail=float("nan")), "trail must be finite, got nan"),
])
def test_animations_that_would_not_fit_are_refused_at_once(tmp_path, sol, kwargs, fragment):
    import time

    start = time.perf_counter()
    with pytest.raises(mp.InputError) as info:
        mp.animate(sol, tmp_path / "a.gif", **kwargs)
    assert fragment in str(info.value), str(info.value)
    assert time.perf_counter() - start < 2.0  # refused, not attempted
    assert os.listdir(tmp_path) == []


def test_the_same_frames_stream_to_mp4_within_the_limits(sol):
    from multipendulum.animation import plan

    # 90001 frames of 400 x 400: too many to keep for a GIF, but an MP4 streams them.
    assert plan(0.0, 2.0, 45000, 1.0, 80, format=".mp4") == (90001, 400)
    with pytest.raises(mp.InputError, match="needs [0-9.]+ GiB"):
        plan(0.0, 2.0, 45000, 1.0, 80, format=".gif")


def test_the_cli_refuses_animation_settings_before_it_writes_any_results(tmp_path, capsys):
    from multipendulum.cli import main

    scenario = tmp_path / "s.toml"
    scenario.write_text("""
[chain]
lengths = [1.0, 1.0]
masses = [1.0, 1.0]
[initial]
unit = "degrees"
theta = [120.0, 10.0]
[simulation]
t_end = 10.0
[output]
fps = 100000
""")
    out = tmp_path / "out"
    assert main(["run", str(scenario), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"multipendulum: error: {scenario}: key 'output.fps': an animation of 10 s of the run at "
                          "output.fps = 100000 and output.speed = 1 has 1e+06 frames, more than 100000; lower "
                          "output.fps, raise output.speed"), err
    assert "--t-end" not in err and "simulation.t_end = 10 s" in err
    assert not out.exists()
    # with --no-animation the same scenario runs and writes its results
    assert main(["run", str(scenario), "-o", str(out), "--no-animation", "--no-plots", "--t-end", "2", "-q"]) == 0
    results = out / "results.npz"
    # `animate` takes the stored scenario's fps (here 100000) unless told otherwise
    for options, fragment in ((["--fps", "10", "--dpi", "100000"], "lower --dpi"), ([], "lower --fps"),
                              (["--fps", "30", "--speed", "1e-9"], "raise --speed")):
        assert main(["animate", str(results), "-o", str(tmp_path / "a.gif")] + options) == 1
        err = capsys.readouterr().err
        assert fragment in err and "Traceback" not in err, err
    assert not (tmp_path / "a.gif").exists()


def test_long_titles_are_wrapped_inside_the_frame_and_the_plots(sol):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    import matplotlib.pyplot as plt

    name = "A rather long scenario name that describes the driven triple pendulum experiment in great detail"
    painter = _Painter(series(sol), dpi=60, size=5.0, title=name + " (dop853)", speed=1.0)
    figures = [(painter.fig, painter.canvas.get_renderer())]
    plots = mp.plot(sol, title=name)
    try:
        for fig in plots:
            canvas = FigureCanvasAgg(fig)
            canvas.draw()
            figures.append((fig, canvas.get_renderer()))
        for fig, renderer in figures:
            box = fig.bbox
            texts = [t for t in fig.findobj(lambda a: hasattr(a, "get_text") and hasattr(a, "get_window_extent"))
                     if "rather long" in str(a_text := t.get_text()) or "\u2026" in a_text]
            assert texts, "the title is missing"
            for t in texts:
                ext = t.get_window_extent(renderer)
                assert ext.x0 >= box.x0 - 1 and ext.x1 <= box.x1 + 1, (t.get_text(), ext, box)
                assert ext.y1 <= box.y1 + 1
    finally:
        for fig in plots:
            plt.close(fig)


# ---------------------------------------------------------------------------------------------
# A moving pivot and a cart are drawn where the run put them


@pytest.fixture(scope="module")
def cart_sol():
    chain = mp.Chain.rods([1.0, 0.8], [1.0, 0.5], cart=mp.Cart(1.0, damping=0.2), damping=0.05)
    return mp.simulate(chain, [2.4, 2.0], [0.0, 0.0], 3.0, cart_force=mp.Sinusoid(4.0, 2.0),
                       t_eval=np.linspace(0, 3.0, 31))


@pytest.fixture(scope="module")
def pivot_sol():
    chain = mp.Chain([1.0], [1.0], damping=0.1)
    pivot = mp.Pivot(x=mp.Sinusoid(0.6, 2.5), y=mp.Sinusoid(0.3, 5.0, phase=1.0))
    return mp.simulate(chain, [0.5], [0.0], 2.0, pivot=pivot, t_eval=np.linspace(0, 2.0, 21))


def _draw_at_samples(sol):
    """A painter and the frames drawn at the run's own sample times (frame k = sample k)."""
    from multipendulum.animation import _frame_positions
    from multipendulum.plotting import base_motion

    view = base_motion(sol, series(sol))
    painter = _Painter(view, dpi=60, size=5.0, title=None, speed=1.0)
    joints, bases = _frame_positions(view, sol.t)
    return painter, joints, bases


def test_the_cart_block_sits_at_the_runs_cart_position_in_every_frame(cart_sol):
    sol = cart_sol
    assert np.ptp(sol.cart_x) > 0.3  # the cart travels
    painter, joints, bases = _draw_at_samples(sol)
    np.testing.assert_allclose(bases, sol.pivot, rtol=0, atol=1e-12)
    np.testing.assert_allclose(joints, sol.positions, rtol=0, atol=1e-12)
    w, h = painter.cart_size
    for k, t in enumerate(sol.t):
        frame = painter.frame(k, t, joints[k], trail=0.5, base=bases[k])
        # the patch, and the pixels: the block's fill around its centre, rods from its centre
        assert painter.cart.get_x() + 0.5 * painter.cart.get_width() == pytest.approx(sol.cart_x[k], abs=1e-12)
        assert painter.cart.get_y() + 0.5 * painter.cart.get_height() == pytest.approx(0.0, abs=1e-12)
        for dx in (-0.35 * w, 0.35 * w):
            row, col = _pixel(painter, (sol.cart_x[k] + dx, -0.3 * h))
            assert frame[row, col].max() < 235, f"no cart at x = {sol.cart_x[k]:.3f} at t = {t}"
        assert _dark(frame, *_pixel(painter, (sol.cart_x[k], 0.0)))
        chain_xy = np.vstack([bases[k], joints[k]])
        for i in range(2):
            for s in np.linspace(0.1, 1.0, 6):
                assert _dark(frame, *_pixel(painter, chain_xy[i] + s * (chain_xy[i + 1] - chain_xy[i])))
        # far from the cart (half a block beyond it, at the rail's height but above it) is background
        row, col = _pixel(painter, (sol.cart_x[k] + (1 if joints[k][-1][0] < sol.cart_x[k] else -1) * 1.2 * w, 0.6 * h))
        assert frame[row, col].min() > 200
    # the axes hold the whole travel, with the chain's reach either side
    lo, hi = painter.ax.get_xlim()
    assert lo <= sol.cart_x.min() - 1.8 and hi >= sol.cart_x.max() + 1.8


def test_the_pivot_marker_follows_the_moving_pivot(pivot_sol):
    sol = pivot_sol
    painter, joints, bases = _draw_at_samples(sol)
    assert painter.cart is None
    np.testing.assert_allclose(bases, sol.pivot, rtol=0, atol=1e-12)
    np.testing.assert_allclose(joints, sol.positions, rtol=0, atol=1e-12)
    for k, t in enumerate(sol.t):
        frame = painter.frame(k, t, joints[k], trail=0.5, base=bases[k])
        x, y = painter.pivot.get_data()
        assert (x[0], y[0]) == pytest.approx(tuple(sol.pivot[k]), abs=1e-12)
        assert _dark(frame, *_pixel(painter, sol.pivot[k])), f"pivot not drawn at {sol.pivot[k]} at t = {t}"
        for s in np.linspace(0.1, 1.0, 6):
            assert _dark(frame, *_pixel(painter, sol.pivot[k] + s * (joints[k][0] - sol.pivot[k])))
    # between samples the pivot is the run's Pivot evaluated by the core, not an interpolation
    from multipendulum.animation import _frame_positions
    from multipendulum.plotting import base_motion

    mid = 0.5 * (sol.t[:-1] + sol.t[1:])
    _, between = _frame_positions(base_motion(sol, series(sol)), mid)
    expected = np.stack([0.6 * np.sin(2.5 * mid), 0.3 * np.sin(5.0 * mid + 1.0)], axis=1)
    np.testing.assert_allclose(between, expected, rtol=0, atol=1e-12)
    ylo, yhi = painter.ax.get_ylim()
    assert ylo <= -0.3 - 1.1 and yhi >= 0.3 + 1.1


def test_a_results_file_of_a_cart_run_animates_with_its_moving_base(tmp_path, cart_sol):
    from multipendulum.animation import _frame_positions
    from multipendulum.plotting import base_motion

    results = load_results(save_results(cart_sol, tmp_path / "r.npz"))
    view = base_motion(results, series(results))
    assert view.moving
    np.testing.assert_allclose(view.pivot, cart_sol.pivot, rtol=0, atol=1e-12)  # recovered from the positions
    joints, _ = _frame_positions(view, cart_sol.t)
    np.testing.assert_allclose(joints, cart_sol.positions, rtol=0, atol=1e-12)
    frames, _ = _gif_frames(mp.animate(results, tmp_path / "c.gif", fps=5, dpi=30))
    assert len(frames) == 16
    _assert_not_blank(frames)


def test_a_fixed_pivot_is_drawn_as_before(sol):
    from multipendulum.plotting import base_motion

    view = base_motion(sol, series(sol))
    assert not view.moving and view.cart_x is None and view.work == {}
    painter = _Painter(view, dpi=60, size=5.0, title=None, speed=1.0)
    assert painter.ax.get_xlim() == pytest.approx((-2.2, 2.2)) and painter.ax.get_ylim() == pytest.approx((-2.2, 2.2))


def test_the_energy_plot_of_a_lossy_run_shows_the_balance_and_its_terms(cart_sol, pivot_sol):
    import matplotlib.pyplot as plt

    for run, names in ((cart_sol, {"$W_{cart}$ (cart force)": cart_sol.work.cart,
                                   "$-D$ (dissipated)": -cart_sol.work.dissipated}),
                       (pivot_sol, {"$W_{pivot}$ (moving pivot)": pivot_sol.work.pivot,
                                    "$-D$ (dissipated)": -pivot_sol.work.dissipated})):
        (fig,) = mp.plot(run, kinds=("energy",))
        try:
            balance, residual = fig.axes
            lines = {line.get_label(): line for line in balance.get_lines()}
            assert set(lines) == {"$E - E_0$"} | set(names)  # only the terms that are not zero
            np.testing.assert_array_equal(lines["$E - E_0$"].get_ydata(), run.energy - run.energy[0])
            for label, values in names.items():
                np.testing.assert_array_equal(lines[label].get_ydata(), values)
            # the terms add up to E - E0, to the run's residual
            total = sum(names.values())
            assert np.max(np.abs(total - (run.energy - run.energy[0]))) < 1e-6 * np.max(np.abs(total))
            assert residual.get_yscale() == "log"
            (err,) = residual.get_lines()
            positive = run.energy_error > 0
            np.testing.assert_array_equal(err.get_ydata(), run.energy_error[positive])
            assert fig._suptitle.get_text().startswith("Energy balance")
        finally:
            plt.close(fig)


def test_the_energy_plot_of_a_conservative_run_is_unchanged(sol):
    import matplotlib.pyplot as plt

    (fig,) = mp.plot(sol, kinds=("energy",))
    try:
        (ax,) = fig.axes
        assert ax.get_yscale() == "log" and len(ax.get_lines()) == 1
        assert fig._suptitle.get_text().startswith("Energy error")
    finally:
        plt.close(fig)


def test_the_tip_plot_holds_the_pivots_motion_and_marks_the_rail(cart_sol, pivot_sol):
    import matplotlib.pyplot as plt

    figs = mp.plot(cart_sol, kinds=("tip",)) + mp.plot(pivot_sol, kinds=("tip",))
    try:
        for fig, run in zip(figs, (cart_sol, pivot_sol)):
            ax = fig.axes[0]
            (xlo, xhi), (ylo, yhi) = ax.get_xlim(), ax.get_ylim()
            pts = np.concatenate([run.positions[:, -1], run.pivot])
            assert xlo < pts[:, 0].min() and xhi > pts[:, 0].max() and ylo < pts[:, 1].min() and yhi > pts[:, 1].max()
            labels = [line.get_label() for line in ax.get_lines()]
            assert ("rail" in labels) == (run is cart_sol)
            assert "pivot (at start)" in labels
    finally:
        for fig in figs:
            plt.close(fig)
