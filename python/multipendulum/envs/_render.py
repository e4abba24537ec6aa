"""Frames of an environment, drawn by the package's own animation painter (matplotlib, Agg):
``rgb_array`` returns them; ``human`` shows them in a matplotlib window where the backend has
one (else it says so once and draws nothing)."""
from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import numpy.typing as npt

from .._chain import Chain
from ..animation import _Painter

_DPI = 100.0
_SIZE = 5.0  # inches: 500 x 500 pixels


def _view(chain: Chain, span: float, name: str) -> Any:
    """What the painter reads of a run, for a picture that holds the chain wherever it goes:
    around a fixed pivot, or along the cart's track ``|x| <= span``."""
    cart = chain.cart is not None
    pivot = np.array([[-span, 0.0], [span, 0.0]]) if cart else np.zeros((2, 2))
    return SimpleNamespace(lengths=chain.lengths, masses=chain.masses, com=chain.com, name=name, method="",
                           t=np.array([0.0, 1.0]), energy_error=np.zeros(2), positions=np.zeros((2, chain.n, 2)),
                           pivot=pivot, cart_x=pivot[:, 0] if cart else None, moving=False)


class Renderer:
    def __init__(self, task: Any, fps: float) -> None:
        self.chain, self.n, self.cart, self.fps = task.chain, task.n, task.cart, fps
        span = float(getattr(task, "x_limit", 0.0))
        self.painter = _Painter(_view(task.chain, span, task.name.split("/")[-1]), _DPI, _SIZE, None, 1.0)
        self._window: Any = None
        self._no_window = False

    def frame(self, row: npt.NDArray[np.float64], t: float, err: float) -> npt.NDArray[np.uint8]:
        """The picture of a core state row ``(theta, omega, [x, v])`` at time t."""
        n = self.n
        base = (float(row[2 * n]), 0.0) if self.cart else (0.0, 0.0)
        joints = self.chain.positions(row[:n]) + np.asarray(base)
        return self.painter.frame(0, float(t), joints, 0.0, base, err=float(err))

    def show(self, frame: npt.NDArray[np.uint8]) -> None:
        import matplotlib
        import matplotlib.pyplot as plt

        if self._no_window:
            return
        if matplotlib.get_backend().lower() in ("agg", "pdf", "ps", "svg", "cairo", "template") \
                or matplotlib.get_backend().lower().startswith("module://matplotlib_inline"):
            import gymnasium as gym

            gym.logger.warn(f"render_mode='human' needs a window; matplotlib's backend here is "
                            f"{matplotlib.get_backend()!r}, which has none: use render_mode='rgb_array'")
            self._no_window = True
            return
        if self._window is None:
            fig, ax = plt.subplots(figsize=(_SIZE, _SIZE))
            ax.set_axis_off()
            self._window = (fig, ax.imshow(frame))
        else:
            self._window[1].set_data(frame)
        plt.pause(1.0 / self.fps)

    def close(self) -> None:
        if self._window is not None:
            import matplotlib.pyplot as plt

            plt.close(self._window[0])
            self._window = None


__all__ = ["Renderer"]
