"""Linearisation about an equilibrium: normal modes, state-space matrices for control, and
pictures and animations of a mode.

Every derivative comes from the core: the Jacobian of the equations of motion
(:meth:`Chain.jacobian`, exact, from the variational equations), the mass matrix, and the
accelerations under unit joint torques. This module only does linear algebra on them.

About an equilibrium ``theta_eq`` (each angle 0 or pi for a free chain: hanging, inverted or
mixed) the small motion ``theta = theta_eq + q`` obeys ``M q'' + K q = 0`` with ``M`` the mass
matrix and ``K = -M J_theta`` the (symmetric) stiffness, ``J_theta`` the block
``d theta_ddot / d theta`` of the Jacobian. The generalized eigenproblem ``K v = lambda M v``
gives the modes: ``lambda > 0`` an oscillation at ``omega = sqrt(lambda)`` rad/s, ``lambda < 0``
an unstable direction growing like ``exp(sigma t)`` with ``sigma = sqrt(-lambda)`` 1/s.

On a cart the coordinates are ``q = (x, theta_1..theta_N)``, the cart first, as the core orders
them (mass matrix (N+1)^2, Jacobian (2N+2)^2 in ``(x, theta, v, omega)``): the cart's free
translation is a neutral mode (``lambda = 0``). Damping and friction do not change ``M`` or
``K``, so the normal modes are the undamped ones; the damped motion's exponents are the
eigenvalues of the full Jacobian (:attr:`NormalModes.exponents`, ``(A, B)`` from
:func:`linearize`), where Coulomb friction, regularised as ``f tanh(w / v_s)``, acts as a
viscous damping ``f / v_s`` (its slope at rest).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional, Sequence, Tuple, Union, overload

import numpy as np
import numpy.typing as npt

from ._chain import Chain, as_state
from .errors import InputError

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["NormalModes", "normal_modes", "linearize", "check_equilibrium", "animate_mode", "plot_modes"]

PathLike = Union[str, "os.PathLike[str]"]
#: An equilibrium's accelerations must vanish to this fraction of g / (shortest link): they are
#: of order 1e-16 g/l from round-off (sin(pi) != 0) and 1e-3 g/l a milliradian away.
EQUILIBRIUM_TOLERANCE = 1e-9


@dataclass(frozen=True)
class NormalModes:
    """The linear modes of a chain about an equilibrium ``theta_eq`` (N,).

    ``eigenvalues`` (D,), rad^2/s^2, ascending: ``lambda_k = omega_k^2`` for an oscillation,
    negative for an unstable direction (so unstable modes come first, the most unstable first,
    then the oscillations from the slowest); D = N, or N + 1 on a cart, whose free translation
    is a neutral mode (``lambda = 0``). ``shapes`` (D, D): column k is mode k's vector of the
    coordinates (the angles; on a cart ``(x, theta)``, x in metres), scaled so its largest entry
    has magnitude 1 and its first non-zero entry is positive; the columns are orthogonal in the
    mass matrix (``shapes.T @ M @ shapes`` diagonal). These are the undamped modes (damping does
    not enter ``M`` or ``K``); ``exponents`` (2D,) are the eigenvalues of the full linearisation
    ``A`` (1/s, with damping and friction), sorted by real part, largest first (a complex pair
    with its positive imaginary part first).
    """

    theta_eq: npt.NDArray[np.float64]
    eigenvalues: npt.NDArray[np.float64]
    shapes: npt.NDArray[np.float64]
    mass_matrix: npt.NDArray[np.float64]
    exponents: Optional[npt.NDArray[np.complex128]] = None

    @property
    def n(self) -> int:
        return int(self.eigenvalues.size)

    @property
    def cart(self) -> bool:
        """whether the first coordinate is a cart's position (D = N + 1)"""
        return self.eigenvalues.size == self.theta_eq.size + 1

    @property
    def stable(self) -> npt.NDArray[np.bool_]:
        """(D,) bool: True for an oscillating mode (lambda > 0)."""
        return self.eigenvalues > 0

    @property
    def frequencies(self) -> npt.NDArray[np.float64]:
        """(D,) angular frequencies sqrt(lambda) in rad/s; 0 for unstable (and neutral) modes."""
        return np.sqrt(np.clip(self.eigenvalues, 0.0, None))

    @property
    def growth_rates(self) -> npt.NDArray[np.float64]:
        """(D,) growth rates sqrt(-lambda) in 1/s of the unstable modes; 0 for the oscillations."""
        return np.sqrt(np.clip(-self.eigenvalues, 0.0, None))

    @property
    def periods(self) -> npt.NDArray[np.float64]:
        """(D,) periods 2 pi / omega in s; inf for unstable (and neutral) modes."""
        with np.errstate(divide="ignore"):
            return np.where(self.stable, 2 * np.pi / np.where(self.stable, self.frequencies, 1.0), np.inf)

    @property
    def n_unstable(self) -> int:
        return int(np.sum(self.eigenvalues < 0))

    def describe(self, k: int) -> str:
        """``"omega = 2.40 rad/s (period 2.62 s)"`` or ``"unstable: grows as exp(5.79 t)"``."""
        lam = self.eigenvalues[k]
        if lam > 0:
            return f"omega = {self.frequencies[k]:.3g} rad/s (period {self.periods[k]:.3g} s)"
        if lam < 0:
            return f"unstable: grows as exp({self.growth_rates[k]:.3g} t)"
        return "neutral (lambda = 0)"

    def __repr__(self) -> str:
        parts = ", ".join(self.describe(k) for k in range(self.n))
        return f"NormalModes(theta_eq={np.round(self.theta_eq, 6).tolist()}, {parts})"


def check_equilibrium(chain: Chain, theta_eq: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """``theta_eq`` as a float array (N,), after checking that the chain rests there
    (all accelerations zero at omega = 0, and on a cart at cart velocity 0 with no force: any
    cart position is then an equilibrium); :class:`InputError` otherwise."""
    if not isinstance(chain, Chain):
        raise InputError(f"chain must be a multipendulum.Chain, got {type(chain).__name__}")
    th = as_state(theta_eq, "theta_eq", chain.n)
    if th.ndim != 1:
        raise InputError(f"theta_eq must have shape ({chain.n},), got {th.shape}")
    acc = chain.accelerations(th, np.zeros(chain.n))
    scale = max(chain.g, 0.0) / float(np.min(chain.lengths))
    # On a cart the core's accelerations are (x_ddot, theta_ddot): x_ddot in m/s^2 is scaled by
    # the chain's reach, so it is held to the same measure as the angles.
    cart = chain.cart is not None
    weights = np.ones(acc.size)
    if cart:
        weights[0] = 1.0 / float(np.sum(chain.lengths))
    worst = int(np.argmax(np.abs(acc * weights)))
    if abs(acc[worst]) * weights[worst] > EQUILIBRIUM_TOLERANCE * scale:
        nearest = np.round(th / np.pi) * np.pi
        hint = ", ".join("pi" if round(v / np.pi) % 2 else "0" for v in nearest)
        what = ("x_ddot = {:.3g} m/s^2" if cart and worst == 0 else
                f"theta_ddot[{worst - cart}] = {{:.3g}} rad/s^2").format(acc[worst])
        raise InputError(
            f"theta_eq = {np.array2string(th, precision=6, separator=', ')} is not an equilibrium: "
            f"{what} at rest (expected 0); a free chain rests "
            f"where every angle is 0 or pi (mod 2 pi), e.g. ({hint})")
    return th


def _stiffness(chain: Chain, th: npt.NDArray[np.float64]) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64],
                                                                     npt.NDArray[np.float64]]:
    """``(M, K, A)``: the mass matrix, the stiffness and the core's Jacobian at rest, all in the
    core's coordinates (``(x, theta)`` on a cart)."""
    d = chain.dof
    jac = chain.jacobian(th, np.zeros(chain.n))
    M = chain.mass_matrix(th)
    K = -M @ jac[d:, :d]
    return M, 0.5 * (K + K.T), jac  # K symmetric in exact arithmetic (the Hessian of the potential)


def normal_modes(chain: Chain, theta_eq: npt.ArrayLike) -> NormalModes:
    """Normal modes about the equilibrium ``theta_eq`` (see the module docstring).

    Raises :class:`InputError` when ``theta_eq`` is not an equilibrium.

    >>> import numpy as np, multipendulum as mp
    >>> modes = mp.normal_modes(mp.Chain([1, 1], [1, 1], g=9.81), [0, 0])
    >>> np.allclose(modes.frequencies**2, 9.81 * np.array([2 - np.sqrt(2), 2 + np.sqrt(2)]))
    True
    >>> mp.normal_modes(mp.Chain([1, 1], [1, 1]), [0, np.pi]).n_unstable
    1
    """
    th = check_equilibrium(chain, theta_eq)
    M, K, jac = _stiffness(chain, th)
    # K v = lambda M v through the Cholesky factor: L^-1 K L^-T is symmetric, so eigh applies and
    # the eigenvalues come out real and the shapes M-orthogonal.
    L = np.linalg.cholesky(M)
    Linv = np.linalg.inv(L)
    lam, W = np.linalg.eigh(Linv @ K @ Linv.T)
    # A neutral direction (a cart's translation) comes out as +-1e-17: call it 0, not unstable.
    lam = np.where(np.abs(lam) <= 1e-12 * np.max(np.abs(lam), initial=0.0), 0.0, lam)
    V = Linv.T @ W
    V = V / np.max(np.abs(V), axis=0)
    for k in range(V.shape[1]):
        first = np.flatnonzero(np.abs(V[:, k]) > 1e-12)[0]
        if V[first, k] < 0:
            V[:, k] = -V[:, k]
    order = np.argsort(lam, kind="stable")
    exponents = np.linalg.eigvals(jac).astype(np.complex128)
    # Largest real part first (equal to round-off counts as equal, so a complex pair stays
    # together), then the positive imaginary part first.
    scale = float(np.max(np.abs(exponents), initial=0.0)) or 1.0
    exponents = exponents[np.lexsort((-exponents.imag, -np.round(exponents.real / scale, 10)))]
    return NormalModes(th, lam[order], np.ascontiguousarray(V[:, order]), M, exponents)


def linearize(chain: Chain, theta_eq: npt.ArrayLike,
              inputs: Optional[str] = None) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """State-space matrices ``(A, B)`` of the chain about an equilibrium: ``x' = A x + B u``.

    The state is the core's: ``x = (theta - theta_eq, omega)`` (2N,), on a cart
    ``x = (x_cart, theta - theta_eq, v, omega)`` (2N+2,), the cart first (any cart position is an
    equilibrium, so ``A``'s x column is zero). ``A`` is the core's exact Jacobian at rest, with
    the chain's joint damping, friction (its slope at rest, ``f / v_s``) and the cart's damping.
    ``B`` has zeros in its top half and, below, the accelerations caused by a unit input
    (exact: the accelerations are linear in the inputs); the input ``u``:

    - ``inputs="cart"`` (the default on a cart): the horizontal force on the cart (N), ``B``
      (2N+2, 1);
    - ``"joint"`` (the default otherwise): joint-motor torques ``u_i`` between link i-1 and
      link i (what a motor at each joint applies), ``B`` (2N, N) (on a cart (2N+2, N));
    - ``"generalized"``: torques conjugate to the absolute angles.

    Raises :class:`InputError` when ``theta_eq`` is not an equilibrium, or for ``"cart"``
    without a cart.

    >>> import numpy as np, multipendulum as mp
    >>> cartpole = mp.Chain.rods([1.0], [0.1], cart=mp.Cart(1.0))
    >>> A, B = mp.linearize(cartpole, [np.pi])
    >>> A.shape, B.shape
    ((4, 4), (4, 1))
    """
    cart = chain.cart is not None if isinstance(chain, Chain) else False
    if inputs is None:
        inputs = "cart" if cart else "joint"
    if inputs not in ("joint", "generalized", "cart"):
        raise InputError(f"inputs must be 'joint' or 'generalized' (torques) or 'cart' (the cart's force), "
                         f"got {inputs!r}")
    th = check_equilibrium(chain, theta_eq)
    if inputs == "cart" and not cart:
        raise InputError("inputs='cart' needs a chain with a cart (mp.Chain(..., cart=mp.Cart(mass))); "
                         "this chain's inputs are torques: 'joint' or 'generalized'")
    n, d = chain.n, chain.dof
    zero = np.zeros(n)
    A = chain.jacobian(th, zero)
    rest = chain.accelerations(th, zero)
    if inputs == "cart":
        B = np.zeros((2 * d, 1))
        B[d:, 0] = chain.accelerations(th, zero, cart_force=1.0) - rest
        return A, B
    B = np.zeros((2 * d, n))
    key = "joint_torque" if inputs == "joint" else "torque"
    for j in range(n):
        B[d:, j] = chain.accelerations(th, zero, **{key: np.eye(n)[j]}) - rest
    return A, B


# ----------------------------------------------------------------------------------------------
# Pictures


def _mode_title(modes: NormalModes, k: int) -> str:
    lam = modes.eigenvalues[k]
    if lam > 0:
        return f"mode {k + 1}: $\\omega$ = {modes.frequencies[k]:.3g} rad/s"
    if lam < 0:
        return f"mode {k + 1}: unstable, $\\sigma$ = {modes.growth_rates[k]:.3g} 1/s"
    return f"mode {k + 1}: neutral"


def _equilibrium_name(theta_eq: npt.NDArray[np.float64]) -> str:
    up = [bool(round(v / np.pi) % 2) for v in theta_eq]
    if not any(up):
        return "hanging"
    if all(up):
        return "inverted"
    return "mixed (" + ", ".join("up" if u else "down" for u in up) + ")"


def _drawn(chain: Chain, nm: NormalModes, q: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """(N+1, 2) points (base, then joints) of the chain displaced by ``q`` (D,) from the
    equilibrium: on a cart ``q[0]`` moves the base along x."""
    base = np.array([q[0] if nm.cart else 0.0, 0.0])
    angles = nm.theta_eq + (q[1:] if nm.cart else q)
    return np.vstack([base, chain.positions(angles) + base])


# The figure without a path, the path with one.
@overload
def plot_modes(chain: Chain, theta_eq: npt.ArrayLike, path: None = None, amplitude: float = 0.35,
               modes: Optional[Sequence[int]] = None, dpi: float = 110, title: Optional[str] = None) -> Figure: ...
@overload
def plot_modes(chain: Chain, theta_eq: npt.ArrayLike, path: PathLike, amplitude: float = 0.35,
               modes: Optional[Sequence[int]] = None, dpi: float = 110, title: Optional[str] = None) -> Path: ...
@overload
def plot_modes(chain: Chain, theta_eq: npt.ArrayLike, path: Optional[PathLike] = None, amplitude: float = 0.35,
               modes: Optional[Sequence[int]] = None, dpi: float = 110,
               title: Optional[str] = None) -> Union[Figure, Path]: ...


def plot_modes(chain: Chain, theta_eq: npt.ArrayLike, path: Optional[PathLike] = None, amplitude: float = 0.35,
               modes: Optional[Sequence[int]] = None, dpi: float = 110,
               title: Optional[str] = None) -> Union[Figure, Path]:
    """Draw each normal mode about ``theta_eq``: the chain at rest (grey) and displaced by
    ``+amplitude`` and ``-amplitude`` (radians, largest link) along the mode's shape.

    ``modes``: which ones (indices; default all, at most 6). Writes a PNG (atomically) and returns
    its path when ``path`` is given, else returns the Matplotlib figure.
    """
    from matplotlib.figure import Figure

    from .results import atomic_path

    nm = normal_modes(chain, theta_eq)
    picks = list(range(min(nm.n, 6))) if modes is None else [int(k) for k in modes]
    for k in picks:
        if not 0 <= k < nm.n:
            raise InputError(f"modes must be indices in [0, {nm.n}), got {k}")
    if not (isinstance(amplitude, (int, float)) and math.isfinite(amplitude) and amplitude > 0):
        raise InputError(f"amplitude must be > 0 (radians), got {amplitude!r}")
    cols = len(picks)
    steps = np.linspace(-1.0, 1.0, 7)
    shapes = {k: [_drawn(chain, nm, s * amplitude * nm.shapes[:, k]) for s in steps] for k in picks}
    pts = np.concatenate([np.concatenate(v) for v in shapes.values()])
    reach = float(np.sum(chain.lengths))
    pad = 0.12 * reach
    half_w = max(float(np.max(np.abs(pts[:, 0]))) + pad, 0.35 * reach)
    y_lo, y_hi = min(float(pts[:, 1].min()), 0.0) - pad, max(float(pts[:, 1].max()), 0.0) + pad
    box_w = 2.4 * (2 * half_w) / (y_hi - y_lo)  # panel width in inches for a 2.4-inch-high equal-aspect panel
    fig = Figure(figsize=(max(cols * (max(box_w, 1.2) + 0.55) + 0.5, 6.4), 3.7), dpi=dpi)
    axes = fig.subplots(1, cols, squeeze=False)[0]
    colors = {-1.0: "tab:orange", 1.0: "tab:blue"}
    for ax, k in zip(axes, picks):
        rest = _drawn(chain, nm, np.zeros(nm.n))
        for s, xy in zip(steps, shapes[k]):
            if s in colors:
                ax.plot(xy[:, 0], xy[:, 1], "-o", color=colors[s], lw=1.8, ms=4, zorder=3,
                        label=f"{'+' if s > 0 else '-'}{amplitude:g} rad along the mode")
            elif s != 0:
                ax.plot(xy[:, 0], xy[:, 1], "-", color=colors[np.sign(s)], lw=0.8, alpha=0.35, zorder=2)
        ax.plot(rest[:, 0], rest[:, 1], "--o", color="0.45", lw=1.2, ms=3, zorder=4, label="equilibrium")
        if nm.cart:
            ax.axhline(0.0, color="0.35", lw=1.0, zorder=1)  # the cart's rail
        ax.plot([0], [0], "s" if nm.cart else "^", color="black", ms=7, zorder=5)
        ax.set_xlim(-half_w, half_w)
        ax.set_ylim(y_lo, y_hi)
        ax.set_aspect("equal")
        ax.grid(alpha=0.25)
        ax.tick_params(labelsize=7)
        shape = ", ".join(f"{v:+.2f}" for v in nm.shapes[:, k])
        ax.set_title(f"{_mode_title(nm, k)}\nshape ({shape})", fontsize=8.5)
        ax.set_xlabel("x (m)", fontsize=8)
    axes[0].set_ylabel("y (m)", fontsize=8)
    handles, labels = axes[0].get_legend_handles_labels()
    order = [labels.index(name) for name in sorted(set(labels), key=lambda t: (not t.startswith("eq"), t))]
    fig.legend([handles[i] for i in order], [labels[i] for i in order], loc="lower center", ncol=3, fontsize=7.5,
               frameon=False)
    fig.suptitle(title or f"Normal modes about the {_equilibrium_name(nm.theta_eq)} equilibrium", fontsize=10)
    fig.subplots_adjust(left=0.5 / fig.get_figwidth() + 0.04, right=0.98, bottom=0.17, top=0.8, wspace=0.3)
    if path is None:
        return fig
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or "png")
    return path


def animate_mode(chain: Chain, theta_eq: npt.ArrayLike, mode: int, path: PathLike, amplitude: float = 0.05,
                 t_end: Optional[float] = None, periods: float = 3.0, fps: float = 30, speed: float = 1.0,
                 trail: float = 0.0, dpi: float = 80, **kwargs: Any) -> Path:
    """Animate the motion started along one normal mode (GIF or MP4, by ``path``'s suffix).

    The chain starts at rest at ``theta_eq + amplitude * shapes[:, mode]`` (``amplitude`` in
    radians for the link that moves most; on a cart the shape's first entry is the cart's
    displacement, ``cart_x0``) and is simulated by :func:`multipendulum.simulate`
    (dop853), nonlinear terms and all: a small amplitude shows the mode swinging at its own
    frequency; an unstable mode shows the fall. ``t_end`` defaults to ``periods`` periods, or for
    an unstable mode to when the linear growth would reach 1 rad. Other keyword arguments go to
    :func:`multipendulum.animate`. Returns the path.
    """
    from ._simulate import simulate
    from .animation import animate

    nm = normal_modes(chain, theta_eq)
    if isinstance(mode, bool) or not isinstance(mode, (int, np.integer)) or not 0 <= mode < nm.n:
        raise InputError(f"mode must be an index in [0, {nm.n}), got {mode!r}")
    if not (isinstance(amplitude, (int, float)) and math.isfinite(amplitude) and amplitude > 0):
        raise InputError(f"amplitude must be > 0 (radians), got {amplitude!r}")
    if t_end is None:
        lam = nm.eigenvalues[mode]
        if lam > 0:
            t_end = periods * nm.periods[mode]
        elif lam < 0:
            t_end = math.acosh(max(1.0 / amplitude, 1.0) + 1.0) / nm.growth_rates[mode]
        else:
            t_end = 5.0
    q0 = amplitude * nm.shapes[:, mode]
    theta0 = nm.theta_eq + (q0[1:] if nm.cart else q0)
    samples = max(2, int(math.ceil(t_end * max(fps / speed, 100.0))) + 1)
    sol = simulate(chain, theta0, np.zeros(chain.n), t_end, t_eval=np.linspace(0.0, t_end, samples),
                   cart_x0=float(q0[0]) if nm.cart else 0.0)
    title = f"{_mode_title(nm, mode)} ({_equilibrium_name(nm.theta_eq)})".replace("$\\omega$", "ω") \
        .replace("$\\sigma$", "σ")
    return animate(sol, path, fps=fps, speed=speed, trail=trail, dpi=dpi, title=title, **kwargs)
