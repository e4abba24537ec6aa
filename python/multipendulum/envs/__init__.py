"""Gymnasium environments on the core: ``pip install 'multipendulum[gym]'``, then

>>> import gymnasium as gym
>>> import multipendulum.envs                      # registers the ids below
>>> env = gym.make("multipendulum/Acrobot-v0", n=3)
>>> obs, info = env.reset(seed=0)
>>> obs.shape                                      # cos, sin of 3 angles and 3 rates
(9,)
>>> envs = gym.make_vec("multipendulum/CartPole-v0", num_envs=8, n=2)
>>> envs.reset(seed=0)[0].shape
(8, 8)

Ids (every keyword of the task classes is a ``gym.make`` / ``gym.make_vec`` keyword):

- ``multipendulum/Acrobot-v0``: :class:`~multipendulum.envs.tasks.Acrobot`, an N-link chain
  (default 2 rods) with motors on chosen joints (default the last: the acrobot; ``"first"``:
  the pendubot), continuous or discrete actions, swung up. 500 steps per episode.
- ``multipendulum/CartPole-v0``: :class:`~multipendulum.envs.tasks.CartPole`, N poles on a
  cart, a continuous force, balance or swing-up. 500 steps per episode.
- ``multipendulum/AcrobotCompat-v0``: :mod:`~multipendulum.envs.compat`, gymnasium's
  ``Acrobot-v1`` transitions exactly, stepped by the core. 500 steps per episode.

Each environment steps its chain by ``substeps`` steps of ``method`` per action (default rk4,
``ceil(dt / 0.01)`` substeps), holding the action constant over the step, and reports the
energy balance's residual in ``info["energy_error"]`` (with ``info["energy"]`` and ``info["t"]``).
``gym.make_vec(id, num_envs=B)`` returns this package's own vector environment, which steps
all B in one call into the core, in parallel; see ``docs/envs.md``.
"""
from __future__ import annotations

from typing import Any, Dict, Tuple

try:
    import gymnasium as gym
except ImportError as e:  # pragma: no cover - exercised in a venv without the extra
    raise ImportError("multipendulum.envs needs gymnasium: pip install 'multipendulum[gym]'") from e

from ._engine import MAX_STEP
from ._env import PendulumEnv, PendulumVectorEnv
from .compat import AcrobotCompatEnv, AcrobotCompatVectorEnv
from .tasks import Acrobot, CartPole

#: The steps of an episode of every registered id (``max_episode_steps``; a vector env's default).
EPISODE_STEPS = 500


def _split(kwargs: dict) -> tuple:
    render_mode = kwargs.pop("render_mode", None)
    return render_mode, kwargs


def acrobot(**kwargs: Any) -> PendulumEnv:
    render_mode, kw = _split(kwargs)
    return PendulumEnv(Acrobot(**kw), render_mode=render_mode)


def cartpole(**kwargs: Any) -> PendulumEnv:
    render_mode, kw = _split(kwargs)
    return PendulumEnv(CartPole(**kw), render_mode=render_mode)


def _vector(task_class: Any, num_envs: int = 1, max_episode_steps: Any = EPISODE_STEPS, render_mode: Any = None,
            autoreset_mode: Any = gym.vector.AutoresetMode.NEXT_STEP, **kwargs: Any) -> PendulumVectorEnv:
    return PendulumVectorEnv(task_class(**kwargs), num_envs=num_envs, max_episode_steps=max_episode_steps,
                             render_mode=render_mode, autoreset_mode=autoreset_mode)


def acrobot_vector(**kwargs: Any) -> PendulumVectorEnv:
    return _vector(Acrobot, **kwargs)


def cartpole_vector(**kwargs: Any) -> PendulumVectorEnv:
    return _vector(CartPole, **kwargs)


def _register() -> None:
    ids: Dict[str, Tuple[Any, Any]] = {
        "multipendulum/Acrobot-v0": (acrobot, acrobot_vector),
        "multipendulum/CartPole-v0": (cartpole, cartpole_vector),
        "multipendulum/AcrobotCompat-v0": (AcrobotCompatEnv, AcrobotCompatVectorEnv),
    }
    for env_id, (single, vector) in ids.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=single, vector_entry_point=vector,
                         max_episode_steps=EPISODE_STEPS)


_register()

__all__ = ["Acrobot", "CartPole", "AcrobotCompatEnv", "AcrobotCompatVectorEnv", "PendulumEnv", "PendulumVectorEnv",
           "MAX_STEP", "EPISODE_STEPS"]
