"""Balance an inverted double (or triple) pendulum with joint-motor torques (LQR).

The chain is linearised about the upright equilibrium (every angle pi) by the core:
``x' = A x + B u`` with ``x = (theta - pi, omega)`` and ``u`` the motor torques at the joints
(:func:`multipendulum.linearize`). The continuous algebraic Riccati equation gives the gain ``K``
that minimises the integral of ``x'Qx + u'Ru``; the feedback ``u = -K x`` is then applied to the
full nonlinear chain through the engine's torque interface (``joint_torque=`` a function of
``(t, theta, omega)``), and the run is compared with the same push and no control.

    python examples/lqr_inverted.py           # double pendulum
    python examples/lqr_inverted.py 3         # triple pendulum
"""
from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_continuous_are

import multipendulum as mp


@dataclass
class Balance:
    chain: mp.Chain
    gain: np.ndarray          # K (N, 2N): u = -K (theta - theta_eq, omega)
    closed_loop: np.ndarray   # eigenvalues of A - B K (all with negative real part)
    controlled: mp.Solution
    free: mp.Solution

    @staticmethod
    def deviation(sol: mp.Solution) -> np.ndarray:
        """Largest |theta_i - pi| at each output time (rad)."""
        return np.max(np.abs(sol.theta - np.pi), axis=1)


def lqr_gain(A: np.ndarray, B: np.ndarray, q_angle=100.0, q_rate=10.0, r=1.0) -> np.ndarray:
    n = B.shape[1]
    Q = np.diag([q_angle] * n + [q_rate] * n)
    R = r * np.eye(n)
    P = solve_continuous_are(A, B, Q, R)
    return np.linalg.solve(R, B.T @ P)


def balance(n: int = 2, push: float = 0.05, t_end: float = 10.0) -> Balance:
    """Push link 1 of an upright n-link chain (1 m, 1 kg point masses) by ``push`` rad and
    simulate ``t_end`` seconds with the LQR feedback and without it."""
    chain = mp.Chain(lengths=[1.0] * n, masses=[1.0] * n)
    upright = np.full(n, np.pi)
    A, B = mp.linearize(chain, upright, inputs="joint")
    K = lqr_gain(A, B)

    def motor(t, theta, omega):
        return -K @ np.concatenate([theta - upright, omega])

    theta0 = upright + push * np.eye(n)[0]
    t_eval = np.linspace(0.0, t_end, 1001)
    controlled = mp.simulate(chain, theta0, np.zeros(n), t_end, joint_torque=motor, t_eval=t_eval)
    free = mp.simulate(chain, theta0, np.zeros(n), t_end, t_eval=t_eval)
    return Balance(chain, K, np.linalg.eigvals(A - B @ K), controlled, free)


def _eigenvalues(ev: np.ndarray) -> str:
    """"-20.57, -2.05 ± 0.21i": one entry per real eigenvalue or complex pair."""
    out = []
    for z in sorted(ev, key=lambda z: (z.real, abs(z.imag))):
        if abs(z.imag) < 1e-9:
            out.append(f"{z.real:.2f}")
        elif z.imag > 0:
            out.append(f"{z.real:.2f} ± {z.imag:.2f}i")
    return ", ".join(out)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    n = int(argv[0]) if argv else 2
    res = balance(n)
    dev = Balance.deviation(res.controlled)
    free = Balance.deviation(res.free)
    fall = res.free.t[np.argmax(free > 0.5)]
    print(f"{n}-link inverted pendulum, pushed 0.05 rad, LQR on the joint motors")
    print(f"  closed-loop eigenvalues (1/s): {_eigenvalues(res.closed_loop)}")
    print(f"  with control:    max deviation {dev.max():.3g} rad, final deviation {dev[-1]:.2e} rad")
    print(f"  without control: deviation passes 0.5 rad at t = {fall:.2f} s (max {free.max():.3g} rad)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
