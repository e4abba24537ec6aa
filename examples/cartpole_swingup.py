"""Swing a pole up on a cart and balance it there: energy shaping, then LQR, through the
``multipendulum/CartPole-v0`` Gymnasium environment (``task="swingup"``, its defaults: one
uniform rod 1.0 m, 0.1 kg on a 1.0 kg cart, 10 N force limit, 20 ms steps, track +-2.4 m).

Two controllers, switched on the pole's angle from upright:

- **Swing-up** (Astrom & Furuta 2000, "Swinging up a pendulum by energy control"): the pole's
  energy in the cart's frame, ``E`` (:meth:`multipendulum.Chain.energy` at cart velocity 0, so the
  package's own energy), is driven to its value upright at rest, ``E_up``, by a cart acceleration

      a = sat(k_E (E - E_up) / E_ref * sign(omega cos theta)) - k_x x - k_v v

  (``E_ref = E_up - E_hang``; the pump term is limited to ``a_max``; the PD term keeps the cart
  near the centre). The pole's energy changes as ``dE/dt = -m l_c a omega cos theta`` under a
  cart acceleration ``a``, so the first term always pumps the energy towards ``E_up``. The
  acceleration is turned into the cart force by the package's equations of motion: ``x_ddot``
  is affine in the force, ``x_ddot = a0 + b F``, and ``a0``, ``b`` come from
  :meth:`multipendulum.Chain.accelerations` (no cart-pole equations are written here).
- **Balance** (LQR): the chain is linearised about upright by
  :func:`multipendulum.modes.linearize` (``inputs="cart"``: the state ``(x, theta - pi, v,
  omega)``, the input the cart force), the gain ``K`` from the continuous-time Riccati equation
  (``scipy.linalg.solve_continuous_are``), and ``F = -K s``. It takes over when every pole is
  within ``catch`` rad of upright with the LQR's force within the limit, and hands back to the
  swing-up if one falls beyond ``release``.

The environment's defaults are enough, so no keyword is changed: from the hanging start the
pump reaches the upright energy in about three swings (the force at the 10 N limit for a few
steps), the LQR catches the pole about 0.4 rad from upright 4.1 to 4.3 s in, with at most about
4.5 N, and holds it (within 1e-2 rad over the episode's last 200 steps, 4e-4 rad at its end,
the cart back within 5 mm of the centre); the cart stays within about 1.15 m of the centre
(the track is +-2.4 m); the default 500-step episode (10 s) leaves more than 260 steps upright.

The swing-up part is for one pole (``n=1``); with ``n >= 2`` poles the controller is the LQR
alone (the same code builds the gain for any N): with the default weights it holds two poles
from the balance task's start (every value within +-0.05 of upright), not three.

Needs scipy (``pip install scipy``; imported where the gain is computed).

    python examples/cartpole_swingup.py              # 3 seeds, 500 steps (10 s) each
    python examples/cartpole_swingup.py 5 1000       # 5 seeds, 1000 steps
"""
from __future__ import annotations

import sys
from typing import Any, Callable, Dict, Optional, cast

import gymnasium as gym
import numpy as np

from multipendulum.envs import PendulumEnv  # importing multipendulum.envs registers the ids
from multipendulum.modes import linearize

ENV_ID = "multipendulum/CartPole-v0"
#: "Upright": every pole within this of theta = pi (rad) ...
UPRIGHT = 0.05
#: ... and every rate within this (rad/s).
STILL = 0.5


def wrap(a: Any) -> Any:
    """Angles into [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def base(env: gym.Env) -> PendulumEnv:
    """The environment under gym.make's wrappers (its ``task`` and ``state``)."""
    return cast(PendulumEnv, env.unwrapped)


def lqr_gain(env: gym.Env, q_x: float = 1.0, q_theta: float = 100.0, q_v: float = 1.0,
             q_omega: float = 1.0, r: float = 0.1) -> np.ndarray:
    """K (1, 2N+2) of ``F = -K (x, theta - pi, v, omega)`` for the environment's chain, upright."""
    from scipy.linalg import solve_continuous_are  # type: ignore[import-untyped]

    chain = base(env).task.chain
    n = chain.n
    A, B = linearize(chain, np.full(n, np.pi), inputs="cart")
    Q = np.diag([q_x] + [q_theta] * n + [q_v] + [q_omega] * n)
    R = np.array([[r]])
    P = solve_continuous_are(A, B, Q, R)
    return np.linalg.solve(R, B.T @ P)


class SwingUp:
    """``obs -> action`` for the cart-pole environment ``env``: energy pump, then LQR.

    ``mode`` is ``"swing"`` or ``"balance"``, ``switches`` counts the hand-overs. The action is
    the cart force divided by the environment's ``max_force``, clipped to [-1, 1]."""

    def __init__(self, env: gym.Env, k_energy: float = 20.0, a_max: float = 6.0, k_x: float = 1.0,
                 k_v: float = 2.0, catch: float = 0.4, release: float = 0.8, **lqr: float) -> None:
        task = base(env).task
        if task.chain.cart is None:
            raise ValueError(f"{ENV_ID} environment needed, got {task.name}")
        self.chain = task.chain
        self.n = task.n
        self.max_force = float(task.scale[0])
        self.K = lqr_gain(env, **lqr)
        self.k_energy, self.a_max, self.k_x, self.k_v = k_energy, a_max, k_x, k_v
        self.catch, self.release = catch, release
        up = np.full(self.n, np.pi)
        self.e_up = float(self.chain.energy(up, np.zeros(self.n)))
        self.e_ref = self.e_up - float(self.chain.energy(np.zeros(self.n), np.zeros(self.n)))
        self.swings = self.n == 1  # energy shaping is for one pole; more poles: LQR only
        self.mode = "swing" if self.swings else "balance"
        self.switches = 0

    def state(self, obs: np.ndarray) -> tuple:
        """obs ``(x, cos theta, sin theta, v, omega)`` -> x, theta (N), v, omega (N)."""
        n = self.n
        obs = np.asarray(obs, dtype=float)
        theta = np.arctan2(obs[1 + n:1 + 2 * n], obs[1:1 + n])
        return float(obs[0]), theta, float(obs[1 + 2 * n]), obs[2 + 2 * n:]

    def energy(self, theta: np.ndarray, omega: np.ndarray) -> float:
        """The poles' energy in the cart's frame (J)."""
        return float(self.chain.energy(theta, omega))

    def swing_force(self, x: float, theta: np.ndarray, v: float, omega: np.ndarray) -> float:
        pump = self.k_energy * (self.energy(theta, omega) - self.e_up) / self.e_ref
        s = omega[0] * np.cos(theta[0])
        direction = np.sign(s) if s != 0 else 1.0
        a = float(np.clip(pump * direction, -self.a_max, self.a_max)) - self.k_x * x - self.k_v * v
        # x_ddot = a0 + b F, from the core's equations of motion
        a0 = self.chain.accelerations(theta, omega, cart_v=v)[0]
        b = self.chain.accelerations(theta, omega, cart_v=v, cart_force=1.0)[0] - a0
        return (a - a0) / b

    def balance_force(self, x: float, theta: np.ndarray, v: float, omega: np.ndarray) -> float:
        s = np.concatenate([[x], wrap(theta - np.pi), [v], omega])
        return float(-(self.K @ s)[0])

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        x, theta, v, omega = self.state(obs)
        lean = float(np.max(np.abs(wrap(theta - np.pi))))
        if self.swings:
            # catch only where the LQR's force is within the limit: a pole arriving short of
            # the upright energy is left to swing once more rather than shoved up at full force
            catchable = lean < self.catch and abs(self.balance_force(x, theta, v, omega)) <= self.max_force
            new = "balance" if catchable else "swing" if lean > self.release else self.mode
            self.switches += new != self.mode
            self.mode = new
        f = self.balance_force(x, theta, v, omega) if self.mode == "balance" else self.swing_force(x, theta, v, omega)
        return np.array([np.clip(f / self.max_force, -1.0, 1.0)])


def controller(env: gym.Env, **kw: float) -> Callable[[np.ndarray], np.ndarray]:
    """A fresh :class:`SwingUp` for ``env`` (one per episode: it remembers its mode)."""
    return SwingUp(env, **kw)


def run(seed: int = 0, steps: int = 500, task: str = "swingup", state: Optional[Any] = None,
        env_kwargs: Optional[Dict[str, Any]] = None, **kw: float) -> Dict[str, Any]:
    """One episode of ``steps`` steps from ``reset(seed=seed)`` (or from ``state``, the
    environment's ``(x, theta, v, omega)``). Returns the trajectory and what happened:

    ``states`` (steps+1, 2N+2) as ``env.unwrapped.state``; ``actions`` (steps,); ``modes``
    (steps,) the controller's mode at each step; ``steps`` actually taken; ``terminated``,
    ``truncated``; ``reached`` the first step with every pole upright (within ``UPRIGHT`` rad and
    ``STILL`` rad/s), or None; ``held`` the number of final steps all within ``UPRIGHT`` rad;
    ``max_lean_tail``, the largest lean over the last 200 steps; ``max_x``; ``saturated``, the
    fraction of steps at the force limit; ``energy_error``, the environment's last residual."""
    env = gym.make(ENV_ID, task=task, max_episode_steps=steps, **(env_kwargs or {}))
    try:
        obs, info = env.reset(seed=seed, options=None if state is None else {"state": state})
        ctrl = SwingUp(env, **kw)
        n = ctrl.n
        states, actions, modes = [base(env).state.copy()], [], []
        terminated = truncated = False
        while not (terminated or truncated):
            action = ctrl(obs)
            modes.append(ctrl.mode)
            obs, _, terminated, truncated, info = env.step(action)
            states.append(base(env).state.copy())
            actions.append(float(action[0]))
    finally:
        env.close()
    S = np.array(states)
    lean = np.max(np.abs(wrap(S[:, 1:1 + n] - np.pi)), axis=1)
    spin = np.max(np.abs(S[:, 2 + n:]), axis=1)
    upright = np.flatnonzero((lean < UPRIGHT) & (spin < STILL))
    inside = lean < UPRIGHT
    held = len(inside) - (np.flatnonzero(~inside)[-1] + 1) if (~inside).any() else len(inside)
    a = np.array(actions)
    return {"seed": seed, "states": S, "actions": a, "modes": modes, "steps": len(a), "dt": base(env).task.dt,
            "terminated": bool(terminated), "truncated": bool(truncated),
            "reached": int(upright[0]) if upright.size else None, "held": int(held),
            "max_lean_tail": float(lean[-200:].max()), "max_x": float(np.abs(S[:, 0]).max()),
            "saturated": float(np.mean(np.abs(a) >= 1.0)) if a.size else 0.0, "switches": ctrl.switches,
            "energy_error": float(info["energy_error"]), "K": ctrl.K}


def main(argv: Optional[list] = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    seeds = int(argv[0]) if argv else 3
    steps = int(argv[1]) if len(argv) > 1 else 500
    env = gym.make(ENV_ID, task="swingup")
    K = lqr_gain(env)
    env.close()
    print(f"{ENV_ID}, task='swingup' (defaults), {steps} steps of 20 ms; LQR gain K = {np.round(K[0], 2).tolist()}")
    ok = True
    for seed in range(seeds):
        r = run(seed, steps)
        t_up = None if r["reached"] is None else r["reached"] * r["dt"]
        good = r["reached"] is not None and r["held"] >= 200 and not r["terminated"]
        ok &= good
        print(f"  seed {seed}: " + (f"upright at t = {t_up:.2f} s, " if t_up is not None else "never upright, ")
              + f"held for the last {r['held']} steps (lean <= {r['max_lean_tail']:.1e} rad over the last 200), "
              f"|x| <= {r['max_x']:.2f} m, force at the limit {100 * r['saturated']:.0f}% of steps, "
              f"{'terminated' if r['terminated'] else 'no termination'}: {'ok' if good else 'FAILED'}")
    # The LQR alone, from a lean near upright, one and two poles (task="balance").
    for n, lean in ((1, 0.1), (2, 0.05)):
        state = [0.0] + [np.pi + lean] * n + [0.0] * (n + 1)
        r = run(0, 500, task="balance", state=state, env_kwargs={"n": n})
        good = not r["terminated"] and r["held"] >= 200
        ok &= good
        print(f"  LQR catch, n={n}, from {lean} rad: terminated={r['terminated']}, held the last {r['held']} steps, "
              f"final lean {np.max(np.abs(wrap(r['states'][-1, 1:1 + n] - np.pi))):.1e} rad, "
              f"|x| <= {r['max_x']:.2f} m: "
              f"{'ok' if good else 'FAILED'}")
    print("all ok" if ok else "some runs FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
