"""A double inverted pendulum on a cart, balanced by LQR on the cart's force alone, with its GIF.

Two uniform rods stand upright (both angles pi: angles are measured from the downward
vertical) on a cart that slides along a horizontal rail; the only actuator is the horizontal
force on the cart. The core linearises the chain on its cart about the upright equilibrium
(:func:`multipendulum.linearize`: ``x' = A x + B F`` with the state
``x = (x_cart, theta - pi, v, omega)``, the cart first, and ``B`` the accelerations caused by a
unit force). The continuous algebraic Riccati equation gives the gain ``K`` that minimises the
integral of ``x'Qx + r F^2``; the feedback ``F = -K x`` then drives the full nonlinear chain
through ``mp.simulate(..., cart_force=lambda t, state: ...)``, ``state = (x, theta_1, theta_2,
v, omega_1, omega_2)``. The lower rod starts 0.1 rad off upright: the cart darts under it,
catches both rods within a few seconds and comes back to x = 0 (8 s are simulated; the GIF
plays them at twice real time). Without the controller the same push topples the chain
within half a second.

    python examples/cart_double_inverted.py            # writes cart_double_inverted.gif here
    python examples/cart_double_inverted.py out/       # ... into out/
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.linalg import solve_continuous_are

import multipendulum as mp

#: Two 0.5 m rods of 0.5 kg and 0.25 kg on a 1 kg cart (a cart damping of 0.1 N s/m).
CHAIN = mp.Chain.rods([0.5, 0.5], [0.5, 0.25], cart=mp.Cart(1.0, damping=0.1))
UPRIGHT = np.array([np.pi, np.pi])
#: The lower rod's initial tilt from upright (rad).
PUSH = 0.1


@dataclass
class CartBalance:
    gain: np.ndarray          # K (1, 6): F = -K (x, theta - pi, v, omega)
    closed_loop: np.ndarray   # eigenvalues of A - B K (all with negative real part)
    controlled: mp.Solution
    free: mp.Solution

    @staticmethod
    def deviation(sol: mp.Solution) -> np.ndarray:
        """Largest |theta_i - pi| at each output time (rad)."""
        return np.max(np.abs(sol.theta - np.pi), axis=1)


def lqr_gain(A: np.ndarray, B: np.ndarray, Q: np.ndarray, r: float) -> np.ndarray:
    R = np.array([[r]])
    P = solve_continuous_are(A, B, Q, R)
    return np.linalg.solve(R, B.T @ P)


def balance(push: float = PUSH, t_end: float = 8.0) -> CartBalance:
    """Tip the lower rod by ``push`` rad and simulate ``t_end`` seconds with and without LQR."""
    A, B = mp.linearize(CHAIN, UPRIGHT)  # on a cart the input is the cart force: B is (6, 1)
    Q = np.diag([10.0, 100.0, 100.0, 1.0, 10.0, 10.0])  # x, theta_1, theta_2, v, omega_1, omega_2
    K = lqr_gain(A, B, Q, r=0.1)
    state_eq = np.concatenate([[0.0], UPRIGHT, [0.0, 0.0, 0.0]])

    def force(t: float, state: np.ndarray) -> float:
        return float(-(K @ (state - state_eq))[0])

    theta0 = UPRIGHT + np.array([push, 0.0])
    t_eval = np.linspace(0.0, t_end, int(round(100 * t_end)) + 1)
    controlled = mp.simulate(CHAIN, theta0, [0.0, 0.0], t_end, cart_force=force, t_eval=t_eval)
    free = mp.simulate(CHAIN, theta0, [0.0, 0.0], min(t_end, 2.0), t_eval=t_eval[t_eval <= 2.0])
    return CartBalance(K, np.linalg.eigvals(A - B @ K), controlled, free)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    outdir = Path(argv[0]) if argv else Path(".")
    res = balance()
    dev = CartBalance.deviation(res.controlled)
    free = CartBalance.deviation(res.free)
    x = res.controlled.cart_x
    assert x is not None
    # Small and short, so it is written in a few seconds: 41 frames of 160 x 160 at twice real time.
    gif = mp.animate(res.controlled, outdir / "cart_double_inverted.gif", fps=10, speed=2.0, dpi=40, size=4.0,
                     trail=1.0, title="double inverted pendulum on a cart, LQR on the cart force")
    print(f"double inverted pendulum on a cart, pushed {PUSH:g} rad, LQR on the cart force")
    print(f"  gain K = {np.array2string(res.gain[0], precision=3, separator=', ')}")
    print(f"  with control:    max deviation {dev.max():.3g} rad, final deviation {dev[-1]:.2e} rad, "
          f"cart travel {np.ptp(x):.3g} m, final x {x[-1]:+.2e} m")
    print(f"  without control: max deviation {free.max():.3g} rad within {res.free.t[-1]:g} s")
    print(f"  animation: {gif}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
