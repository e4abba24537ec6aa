"""Linearisation about equilibria: normal modes against closed forms and against the nonlinear
integrator, the control matrix B, LQR balancing of an inverted chain, pictures of the modes."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest

import multipendulum as mp

ROOT = Path(__file__).resolve().parents[1]
G = 9.81
DOUBLE = mp.Chain([1.0, 1.0], [1.0, 1.0], g=G)


def _example(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_equal_double_pendulum_hanging_modes_are_2_plus_minus_sqrt2():
    modes = mp.normal_modes(DOUBLE, [0.0, 0.0])
    np.testing.assert_allclose(modes.frequencies**2, G * np.array([2 - np.sqrt(2), 2 + np.sqrt(2)]), rtol=1e-12)
    assert modes.n_unstable == 0 and modes.stable.all() and np.all(modes.growth_rates == 0)
    # shapes (1, sqrt 2) in phase and (1, -sqrt 2) in opposition, scaled to a largest entry of 1
    np.testing.assert_allclose(modes.shapes[:, 0], [1 / np.sqrt(2), 1.0], atol=1e-12)
    np.testing.assert_allclose(modes.shapes[:, 1], [1 / np.sqrt(2), -1.0], atol=1e-12)
    np.testing.assert_allclose(modes.periods, 2 * np.pi / modes.frequencies, rtol=1e-15)


def test_inverted_double_pendulum_has_two_unstable_directions_with_the_same_rates():
    modes = mp.normal_modes(DOUBLE, [np.pi, -np.pi])
    assert modes.n_unstable == 2 and not modes.stable.any()
    np.testing.assert_allclose(modes.growth_rates**2, G * np.array([2 + np.sqrt(2), 2 - np.sqrt(2)]), rtol=1e-12)
    assert np.all(modes.frequencies == 0) and np.all(np.isinf(modes.periods))


def test_mixed_equilibrium_has_one_unstable_direction():
    # Link 1 down, link 2 up. With unit lengths and masses, K = diag(2g, -g) and
    # M = [[2, -1], [-1, 1]]: det(K - lambda M) = lambda^2 - 2 g^2, so lambda = -+ sqrt(2) g.
    modes = mp.normal_modes(DOUBLE, [0.0, np.pi])
    assert modes.n_unstable == 1
    np.testing.assert_allclose(modes.eigenvalues, [-np.sqrt(2) * G, np.sqrt(2) * G], rtol=1e-12)
    assert modes.describe(0).startswith("unstable: grows as exp(3.72 t)")
    assert modes.describe(1).startswith("omega = 3.72 rad/s")


def test_modes_are_mass_orthogonal_and_solve_the_generalized_eigenproblem_for_a_general_chain():
    chain = mp.Chain([1.0, 0.7, 0.5, 0.9], [1.0, 2.0, 0.5, 0.3], com=[0.6, 0.3, 0.5, 0.2],
                     inertia=[0.05, 0.1, 0.0, 0.02])
    eq = [0.0, np.pi, 0.0, 0.0]
    modes = mp.normal_modes(chain, eq)
    M = chain.mass_matrix(eq)
    np.testing.assert_allclose(M, modes.mass_matrix)
    gram = modes.shapes.T @ M @ modes.shapes
    assert np.max(np.abs(gram - np.diag(np.diag(gram)))) < 1e-12 * np.max(np.abs(gram))
    # M^-1 K v = lambda v, where -M^-1 K is the core's d(theta_ddot)/d(theta) block
    jtheta = chain.jacobian(eq, np.zeros(4))[4:, :4]
    for k in range(4):
        v = modes.shapes[:, k]
        np.testing.assert_allclose(-jtheta @ v, modes.eigenvalues[k] * v, atol=1e-10 * np.abs(modes.eigenvalues).max())
    assert np.all(np.diff(modes.eigenvalues) >= 0)
    assert np.all(np.max(np.abs(modes.shapes), axis=0) == 1.0)


def test_a_small_motion_along_a_mode_keeps_its_shape_and_frequency():
    # Independent of the linear algebra: the full nonlinear integrator, started along the fast
    # mode of a triple pendulum of rods at 1e-4 rad, swings in that shape at that frequency.
    chain = mp.Chain.rods([1.0, 0.8, 0.6], [1.0, 0.8, 0.6])
    modes = mp.normal_modes(chain, [0, 0, 0])
    k = 2
    amp = 1e-4
    w = modes.frequencies[k]
    t = np.linspace(0, 2 * modes.periods[k], 401)
    sol = mp.simulate(chain, amp * modes.shapes[:, k], [0, 0, 0], t[-1], t_eval=t)
    expected = amp * np.outer(np.cos(w * t), modes.shapes[:, k])
    assert np.max(np.abs(sol.theta - expected)) < 1e-3 * amp


def test_equilibria_are_checked():
    with pytest.raises(mp.InputError,
                       match=r"theta_eq = \[0\.3, 0\. \] is not an equilibrium: theta_ddot\[0\] = -5\.33"):
        mp.normal_modes(DOUBLE, [0.3, 0.0])
    with pytest.raises(mp.InputError, match=r"not an equilibrium.*e\.g\. \(pi, 0\)"):
        mp.linearize(DOUBLE, [3.14159, 0.0])  # a few microradians off is not an equilibrium
    with pytest.raises(mp.InputError, match=r"theta_eq must have shape \(2,\) or \(\.\.\., 2\)"):
        mp.normal_modes(DOUBLE, [0.0, 0.0, 0.0])
    with pytest.raises(mp.InputError, match="inputs must be 'joint' or 'generalized'"):
        mp.linearize(DOUBLE, [0.0, 0.0], inputs="motor")
    # 2 pi and -pi are the same equilibria as 0 and pi
    np.testing.assert_allclose(mp.normal_modes(DOUBLE, [2 * np.pi, -np.pi]).eigenvalues,
                               mp.normal_modes(DOUBLE, [0.0, np.pi]).eigenvalues, rtol=1e-12)


def test_linearize_gives_the_joint_and_generalized_input_matrices():
    chain = mp.Chain.rods([1.0, 0.7, 0.5], [1.0, 2.0, 0.5])
    eq = np.array([np.pi, np.pi, 0.0])
    A, B = mp.linearize(chain, eq)
    _, Bg = mp.linearize(chain, eq, inputs="generalized")
    np.testing.assert_array_equal(A, chain.jacobian(eq, np.zeros(3)))
    assert A.shape == (6, 6) and B.shape == (6, 3)
    assert np.all(B[:3] == 0) and np.all(Bg[:3] == 0)
    # Generalized inputs act through the inverse mass matrix ...
    np.testing.assert_allclose(Bg[3:], np.linalg.inv(chain.mass_matrix(eq)), rtol=1e-10, atol=1e-12)
    # ... and a joint motor u_j is tau_j = u_j, tau_{j-1} = -u_j.
    S = np.eye(3) - np.eye(3, k=1)
    np.testing.assert_allclose(B[3:], Bg[3:] @ S, rtol=1e-10, atol=1e-12)
    # The linear model predicts the nonlinear response to a small torque at rest.
    u = np.array([0.01, -0.02, 0.005])
    acc = chain.accelerations(eq, np.zeros(3), joint_torque=u)
    np.testing.assert_allclose(acc, B[3:] @ u, rtol=1e-9, atol=1e-15)


def test_lqr_balances_the_inverted_double_pendulum_which_falls_without_it():
    lqr = _example("lqr_inverted")
    res = lqr.balance(n=2, push=0.05, t_end=10.0)
    assert np.all(res.closed_loop.real < 0)
    dev = lqr.Balance.deviation(res.controlled)
    t = res.controlled.t
    assert dev[0] == pytest.approx(0.05)
    assert dev.max() < 0.06                    # it never gets far from upright
    assert np.all(dev[t >= 4.0] < 1e-3)        # and is within 1e-3 rad of it from 4 s on
    assert dev[-1] < 1e-6
    free = lqr.Balance.deviation(res.free)
    assert free.max() > 1.0 and free[np.searchsorted(t, 2.0)] > 0.5  # uncontrolled, it falls within 2 s


def test_lqr_example_balances_a_triple_pendulum_and_prints_its_result(capsys):
    lqr = _example("lqr_inverted")
    assert lqr.main(["3"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("3-link inverted pendulum")
    final = float(out.split("final deviation ")[1].split(" rad")[0])
    assert final < 1e-6


def test_mode_pictures_and_animation(tmp_path):
    fig = mp.plot_modes(DOUBLE, [0.0, np.pi])
    assert [ax.get_title() for ax in fig.axes] == ["mode 1: unstable, $\\sigma$ = 3.72 1/s\nshape (+0.29, +1.00)",
                                                   "mode 2: $\\omega$ = 3.72 rad/s\nshape (+1.00, +0.59)"]
    assert "mixed (down, up)" in fig._suptitle.get_text()
    png = mp.plot_modes(mp.Chain([1, 1, 1], [1, 1, 1]), [0, 0, 0], tmp_path / "modes.png", dpi=50)
    assert png.read_bytes()[:4] == b"\x89PNG"
    gif = mp.animate_mode(DOUBLE, [0.0, 0.0], 1, tmp_path / "mode.gif", amplitude=0.1, fps=10, dpi=30, size=3)
    from PIL import Image

    with Image.open(gif) as im:
        frames = im.n_frames
    period = 2 * np.pi / np.sqrt(G * (2 + np.sqrt(2)))
    assert frames == int(np.floor(3 * period * 10 + 1e-9)) + 1  # three periods at 10 frames per second
    with pytest.raises(mp.InputError, match=r"mode must be an index in \[0, 2\), got 2"):
        mp.animate_mode(DOUBLE, [0.0, 0.0], 2, tmp_path / "x.gif")


def test_damping_enters_the_linearisation_but_not_the_undamped_modes():
    # One link, a joint damper b: theta'' = -(m g c / I_p) q - (b / I_p) omega about hanging.
    b = 0.3
    chain = mp.Chain([1.0], [2.0], damping=b)
    A, B = mp.linearize(chain, [0.0])
    I_p = 2.0
    np.testing.assert_allclose(A, [[0.0, 1.0], [-2.0 * G / I_p, -b / I_p]], rtol=1e-12)
    np.testing.assert_allclose(B, [[0.0], [1.0 / I_p]], rtol=1e-12)
    modes = mp.normal_modes(chain, [0.0])
    np.testing.assert_allclose(modes.eigenvalues, [G], rtol=1e-12)  # as without the damper
    zeta = b / (2 * I_p * np.sqrt(G))
    expected = np.sqrt(G) * (-zeta + np.array([1j, -1j]) * np.sqrt(1 - zeta**2))
    np.testing.assert_allclose(modes.exponents, expected, rtol=1e-12)
    assert not modes.cart


def test_friction_enters_the_linearisation_as_its_slope_at_rest():
    # Regularised Coulomb friction u = -f tanh(w / v_s) is, to first order at rest, a damper
    # of f / v_s; with a damper b too: theta'' = -(m g c / I_p) q - ((b + f / v_s) / I_p) omega.
    b, f, v_s = 0.1, 0.05, 0.01
    chain = mp.Chain([1.0], [2.0], damping=b, friction=f, friction_velocity=v_s)
    A, B = mp.linearize(chain, [0.0])
    I_p = 2.0
    np.testing.assert_allclose(A, [[0.0, 1.0], [-2.0 * G / I_p, -(b + f / v_s) / I_p]], rtol=1e-12)
    np.testing.assert_allclose(B, [[0.0], [1.0 / I_p]], rtol=1e-12)
    # Two links: the relative rate of joint 2 is omega_2 - omega_1, so its slope couples both.
    two = mp.Chain([1.0, 1.0], [1.0, 1.0], friction=[0.0, f], friction_velocity=v_s)
    A2, _ = mp.linearize(two, [0.0, 0.0])
    Minv = np.linalg.inv(two.mass_matrix([0.0, 0.0]))
    c = f / v_s
    np.testing.assert_allclose(A2[2:, 2:], -Minv @ np.array([[c, -c], [-c, c]]), rtol=1e-12, atol=1e-12)


def test_modes_of_a_chain_on_a_cart_are_drawn_and_animated_with_the_cart(tmp_path):
    chain = mp.Chain.rods([1.0, 1.0], [1.0, 1.0], cart=mp.Cart(2.0))
    modes = mp.normal_modes(chain, [0.0, 0.0])
    assert modes.cart and modes.n == 3 and modes.shapes.shape == (3, 3)
    assert modes.eigenvalues[0] == 0.0 and modes.describe(0) == "neutral (lambda = 0)"
    np.testing.assert_allclose(modes.shapes[:, 0], [1.0, 0.0, 0.0], atol=1e-12)
    M = chain.mass_matrix([0.0, 0.0])
    gram = modes.shapes.T @ M @ modes.shapes
    assert np.max(np.abs(gram - np.diag(np.diag(gram)))) < 1e-12 * np.max(np.abs(gram))
    fig = mp.plot_modes(chain, [0.0, 0.0], modes=[1])
    ax = fig.axes[0]
    # the displaced chains start at the cart, which moves with the mode (x first in the shape)
    starts = {round(float(line.get_xdata()[0]), 9) for line in ax.get_lines() if len(line.get_xdata()) == 3}
    assert len(starts) > 2 and modes.shapes[0, 1] != 0
    gif = mp.animate_mode(chain, [0.0, 0.0], 1, tmp_path / "cart_mode.gif", amplitude=0.05, fps=5, dpi=30, size=3)
    assert gif.exists()
