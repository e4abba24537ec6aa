"""The cart-pole: its linearisation against the textbook closed form (Barto, Sutton & Anderson
1983; Florian 2007, "Correct equations for the dynamics of the cart-pole system"), with damping
against the linearised Lagrangian written out here, LQR on the cart force balancing it from
0.1 rad, and the double inverted pendulum on a cart example (LQR, GIF)."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import solve_continuous_are

import multipendulum as mp

ROOT = Path(__file__).resolve().parents[1]
G = 9.81


def _example(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def textbook_cartpole(M, m, L, g=G):
    """A, B of the frictionless cart-pole about upright, from Florian's (Barto's) equations:

        theta_ddot = (g sin th + cos th (-F - m l th_dot^2 sin th) / (M + m)) / (l (4/3 - m cos^2 th / (M + m)))
        x_ddot     = (F + m l (th_dot^2 sin th - theta_ddot cos th)) / (M + m)

    with l = L / 2 the pole's half-length (a uniform rod, I = m L^2 / 12) and th their angle:
    from the upward vertical, positive when the pole leans towards +x (its centre of mass at
    x + l sin th, l cos th). Linearised at th = th_dot = 0, F = 0.

    This package measures theta from the downward vertical, counter-clockwise (the centre of
    mass at x + l sin theta, -l cos theta): upright is theta = pi, and th = pi - theta (a pole
    leaning towards +x has theta < pi). So d/dtheta = -d/dth and theta_ddot = -th_ddot; the
    state is (x, theta, v, omega), the input F."""
    mu = M + m
    l = L / 2
    D = l * (4.0 / 3.0 - m / mu)
    # Barto's linearisation: th_ddot = (g th - F / mu) / D, x_ddot = (F - m l th_ddot) / mu.
    dthdd_dth, dthdd_dF = g / D, -1.0 / (mu * D)
    dxdd_dth, dxdd_dF = -m * l * dthdd_dth / mu, (1.0 - m * l * dthdd_dF) / mu
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    A[2, 1] = -dxdd_dth       # d x_ddot / d theta = -d x_ddot / d th
    A[3, 1] = dthdd_dth       # d theta_ddot / d theta = (-1)(-1) d th_ddot / d th
    B = np.array([[0.0], [0.0], [dxdd_dF], [-dthdd_dF]])
    return A, B


@pytest.mark.parametrize("M, m, L, g", [(1.0, 0.1, 1.0, 9.81), (0.7, 2.5, 0.4, 9.81), (3.0, 0.3, 2.2, 1.62)])
def test_cartpole_linearisation_is_the_textbook_one(M, m, L, g):
    chain = mp.Chain.rods([L], [m], g=g, cart=mp.Cart(M))
    A, B = mp.linearize(chain, [np.pi])
    A_ref, B_ref = textbook_cartpole(M, m, L, g)
    assert A.shape == (4, 4) and B.shape == (4, 1)
    np.testing.assert_allclose(A, A_ref, rtol=1e-10, atol=1e-10 * np.abs(A_ref).max())
    np.testing.assert_allclose(B, B_ref, rtol=1e-10, atol=1e-10 * np.abs(B_ref).max())
    # -pi and 3 pi are the same upright equilibrium
    np.testing.assert_allclose(mp.linearize(chain, [-np.pi])[0], A_ref, rtol=1e-10, atol=1e-10 * np.abs(A_ref).max())
    # Its modes: the cart's translation (neutral) and the fall, growing as exp(sqrt(g / D) t).
    modes = mp.normal_modes(chain, [np.pi])
    assert modes.cart and modes.n == 2 and modes.n_unstable == 1
    D = L / 2 * (4 / 3 - m / (M + m))
    np.testing.assert_allclose(modes.eigenvalues, [-g / D, 0.0], rtol=1e-12, atol=0)
    np.testing.assert_allclose(modes.shapes[:, 1], [1.0, 0.0], atol=1e-12)  # the translation moves only x
    np.testing.assert_allclose(np.sort(modes.exponents.real), [-np.sqrt(g / D), 0, 0, np.sqrt(g / D)],
                               rtol=1e-9, atol=1e-9)


def test_damped_cartpole_linearisation_is_the_linearised_lagrangian():
    # Cart mass M, damping c (force -c v); a pole of mass m, com l, inertia I about its com,
    # viscous joint damping b (torque -b omega: the cart does not turn). Kinetic energy
    # 1/2 (M + m) v^2 + m l v omega cos theta + 1/2 (I + m l^2) omega^2, potential -m g l cos theta;
    # at theta = pi: M0 q'' + C q' + K0 q = (F, 0), q = (x, theta - pi).
    M, m, L, c, b = 1.3, 0.4, 0.8, 0.25, 0.03
    l, I = L / 2, m * L**2 / 12
    chain = mp.Chain.rods([L], [m], damping=b, cart=mp.Cart(M, damping=c))
    M0 = np.array([[M + m, -m * l], [-m * l, I + m * l**2]])
    K0 = np.diag([0.0, -m * G * l])
    C0 = np.diag([c, b])
    Minv = np.linalg.inv(M0)
    A_ref = np.block([[np.zeros((2, 2)), np.eye(2)], [-Minv @ K0, -Minv @ C0]])
    B_ref = np.vstack([np.zeros((2, 1)), Minv[:, :1]])
    A, B = mp.linearize(chain, [np.pi], inputs="cart")
    np.testing.assert_allclose(A, A_ref, rtol=1e-10, atol=1e-10 * np.abs(A_ref).max())
    np.testing.assert_allclose(B, B_ref, rtol=1e-10, atol=1e-10 * np.abs(B_ref).max())
    # A motor between the cart and the pole acts on theta only: B = M0^-1 (0, 1).
    _, Bj = mp.linearize(chain, [np.pi], inputs="joint")
    np.testing.assert_allclose(Bj[2:, 0], Minv[:, 1], rtol=1e-10)
    # Hanging, the damped motion's exponents are the roots of det(M0 s^2 + C0 s + K0) = 0
    # (M0, K0 at theta = 0); the undamped modes are those of M0, K0 alone.
    M0[0, 1] = M0[1, 0] = m * l
    K0 = np.diag([0.0, m * G * l])
    det = np.polynomial.Polynomial  # det of the 2 x 2 polynomial matrix, coefficients in s
    entry = [[det([K0[i, j], C0[i, j], M0[i, j]]) for j in range(2)] for i in range(2)]
    roots = (entry[0][0] * entry[1][1] - entry[0][1] * entry[1][0]).roots()
    modes = mp.normal_modes(chain, [0.0])
    key = lambda z: (round(z.real, 9), round(z.imag, 9))  # noqa: E731
    np.testing.assert_allclose(sorted(modes.exponents, key=key), sorted(roots, key=key), rtol=1e-9, atol=1e-12)
    assert np.all(modes.exponents.real <= 0) and np.sum(np.abs(modes.exponents) < 1e-12) == 1  # the free translation
    lam = np.linalg.eigvals(np.linalg.solve(M0, K0))
    np.testing.assert_allclose(np.sort(modes.eigenvalues), np.sort(lam.real), rtol=1e-12, atol=1e-12)


def test_the_linear_model_predicts_small_forces_and_tilts_of_the_nonlinear_cartpole():
    chain = mp.Chain.rods([1.0], [0.2], cart=mp.Cart(1.0, damping=0.1), damping=0.01)
    A, B = mp.linearize(chain, [np.pi])
    dq, dw, F = 1e-6, np.array([2e-6, -1e-6]), 3e-6
    acc = chain.accelerations([np.pi + dq], [dw[1]], cart_v=dw[0], cart_force=F)
    lin = A[2:] @ np.array([0.0, dq, dw[0], dw[1]]) + B[2:, 0] * F
    np.testing.assert_allclose(acc, lin, rtol=1e-5, atol=1e-20)


def test_inputs_are_checked():
    cartpole = mp.Chain.rods([1.0], [0.1], cart=mp.Cart(1.0))
    with pytest.raises(mp.InputError, match=r"inputs='cart' needs a chain with a cart"):
        mp.linearize(mp.Chain([1.0], [1.0]), [np.pi], inputs="cart")
    with pytest.raises(mp.InputError, match=r"inputs must be 'joint' or 'generalized' \(torques\) or 'cart'"):
        mp.linearize(cartpole, [np.pi], inputs="force")
    with pytest.raises(mp.InputError, match=r"theta_eq = \[3\.\] is not an equilibrium: theta_ddot\[0\] = "):
        mp.linearize(cartpole, [3.0])
    with pytest.raises(mp.InputError, match=r"theta_eq must have shape \(1,\)"):
        mp.linearize(cartpole, [0.0, np.pi])  # the angles only: any cart position is an equilibrium


def _lqr(A, B, Q, r):
    P = solve_continuous_are(A, B, Q, np.array([[r]]))
    return (B.T @ P) / r


def test_lqr_on_the_cart_force_balances_the_cartpole_from_a_tenth_of_a_radian():
    chain = mp.Chain.rods([1.0], [0.2], cart=mp.Cart(1.0))
    A, B = mp.linearize(chain, [np.pi])
    K = _lqr(A, B, np.diag([1.0, 10.0, 1.0, 1.0]), 0.1)
    assert np.all(np.linalg.eigvals(A - B @ K).real < 0)
    s_eq = np.array([0.0, np.pi, 0.0, 0.0])
    seen = []

    def force(t, s):
        seen.append(np.array(s, dtype=float))
        return float(-(K @ (s - s_eq))[0])

    t = np.linspace(0.0, 10.0, 1001)
    sol = mp.simulate(chain, [np.pi + 0.1], [0.0], 10.0, cart_force=force, t_eval=t)
    tilt = np.abs(sol.theta[:, 0] - np.pi)
    assert tilt[0] == pytest.approx(0.1)
    assert tilt.max() < 0.15                         # it never gets far from upright
    assert tilt[-1] < 1e-3 and np.all(tilt[t >= 8.0] < 1e-3)
    assert abs(sol.cart_x[-1]) < 1e-2 and abs(sol.cart_v[-1]) < 1e-2  # and the cart comes back to x = 0
    assert np.ptp(sol.cart_x) > 0.05                 # it had to move to catch the pole
    # the feedback saw the core's state (x, theta, v, omega), cart first
    assert seen[0].shape == (4,) and seen[0][1] == pytest.approx(np.pi + 0.1) and seen[0][0] == 0.0
    # the force's work is what changed the energy (balance residual to the integrator's tolerance)
    assert np.max(sol.energy_error) < 1e-8 and np.any(sol.work.cart != 0)
    # Without the controller the same tilt topples it.
    free = mp.simulate(chain, [np.pi + 0.1], [0.0], 3.0)
    assert np.max(np.abs(free.theta[:, 0] - np.pi)) > 1.0


def test_cart_double_inverted_example_balances_and_writes_its_gif(tmp_path, capsys):
    example = _example("cart_double_inverted")
    assert example.main([str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("double inverted pendulum on a cart, pushed 0.1 rad")
    gif = tmp_path / "cart_double_inverted.gif"
    from PIL import Image

    with Image.open(gif) as im:
        assert im.n_frames == 41 and im.size == (160, 160)
    final = float(out.split("final deviation ")[1].split(" rad")[0])
    assert final < 1e-4
    res = example.balance()
    dev = example.CartBalance.deviation(res.controlled)
    assert res.gain.shape == (1, 6) and np.all(res.closed_loop.real < 0)
    assert dev[0] == pytest.approx(0.1) and dev.max() < 0.15
    assert np.all(dev[res.controlled.t >= 6.0] < 1e-3)
    assert abs(res.controlled.cart_x[-1]) < 1e-3
    assert example.CartBalance.deviation(res.free).max() > 1.0  # uncontrolled, it falls
