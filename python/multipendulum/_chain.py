"""The chain model: a thin layer over the Rust core that converts and reshapes arrays."""
from __future__ import annotations

from typing import Any, Dict, List, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

import multipendulum._core as _core
from ._base import Cart, ForceLike, Pivot, core_force, core_pivot, normalise_force, normalise_pivot
from ._convert import as_float, as_floats
from ._torque import TorqueLike, core_torque, normalise_torque
from .errors import InputError

#: The routes to the accelerations and the most links each takes (None: any), from the core.
ALGORITHMS = dict(_core.ALGORITHMS)
MAX_STATE = _core.LIMITS["max_angle"]  # the largest |angle| a state may hold (the core's limit)


def _finite_result(out: npt.NDArray[np.float64], what: str) -> npt.NDArray[np.float64]:
    """Finite inputs can still overflow (huge masses times huge rates): say so, never return NaN."""
    if not np.isfinite(out).all():
        raise InputError(f"the {what} overflow for these inputs (non-finite result): the chain's masses, "
                         "lengths, g, the state or the torque are too large together")
    return out


def check_chain(chain: object) -> None:
    if not isinstance(chain, Chain):
        raise InputError(f"chain must be a multipendulum.Chain, got {type(chain).__name__}")


def as_state(x: npt.ArrayLike, name: str, n: int) -> npt.NDArray[np.float64]:
    """float64, C-contiguous, last axis of length n (leading axes are a batch)."""
    a = as_floats(x, name)
    if a.ndim == 0 and n == 1:
        a = a.reshape(1)
    if a.ndim == 0 or a.shape[-1] != n:
        raise InputError(f"{name} must have shape ({n},) or (..., {n}) (one entry per link), got shape {a.shape}")
    # Angles as the core bounds them (model.rs MAX_STATE): differences of huge angles overflow to
    # NaN. Rates and momenta are not bounded: too large, they fail as an overflow or a blow-up.
    # This is on every call's path, so first one cheap test that any NaN or inf fails (min/max
    # carry a NaN through; neither they nor isfinite warn, where a sum would); details on failure.
    # Not a BLAS dot product: on a large batch OpenBLAS wakes its threads, which then spin for a
    # while on the cores the core's workers are about to use (a third off the flip lanes' rate).
    theta = "theta" in name
    if a.size == 0 or ((-MAX_STATE <= a.min() and a.max() <= MAX_STATE) if theta else np.isfinite(a).all()):
        return a
    for bad, what in ((~np.isfinite(a), "must be finite"),
                      (np.abs(a) > MAX_STATE if theta else np.zeros(a.shape, bool), f"must be within +-{MAX_STATE:.0e} rad")):
        if bad.any():
            idx = tuple(int(i) for i in np.argwhere(bad)[0])
            raise InputError(f"{name}[{', '.join(map(str, idx))}] {what}, got {a[idx]}")
    return a


def _per_joint(v: Optional[npt.ArrayLike], name: str, n: int) -> Optional[List[float]]:
    if v is None:
        return None
    a = as_floats(v, name)
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.shape != (n,):
        raise InputError(f"{name} must be a number or have {n} entries (one per joint), got shape {a.shape}")
    return a.tolist()


def _cart(cart: Optional[Cart]) -> Optional[Tuple[float, float]]:
    if cart is None:
        return None
    if not isinstance(cart, Cart):
        raise InputError(f"cart must be a multipendulum.Cart or None, got {type(cart).__name__}")
    return cart._spec()


class Chain:
    """A planar chain of N rigid links hanging from a pivot (fixed at the origin, moved by a
    prescribed motion in a run, or carried by a cart). SI units; the arrays have one entry per
    link, link 1 hanging from the pivot.

    Parameters:
        lengths: pivot-to-next-joint length of each link, > 0.
        masses: mass of each link, >= 0.
        com: distance of each link's centre of mass from its own pivot (default: ``lengths``,
            i.e. point masses at the link ends, seed 000).
        inertia: moment of inertia of each link about its centre of mass (default: 0).
        g: gravitational acceleration along -y.
        damping: viscous joint damping ``b_i >= 0`` (N m s/rad), a number or one per joint:
            joint torque ``u_i = -b_i w_i`` with ``w_i = omega_i - omega_{i-1}`` (joint 1 joins
            the base to link 1), acting ``+u_i`` on link i and ``-u_i`` on link i-1.
        friction: Coulomb joint friction ``f_i >= 0`` (N m), regularised
            ``u_i = -f_i tanh(w_i / friction_velocity)``: below ``friction_velocity`` it acts
            as a steep viscous damping ``f_i / v_s``; smaller values are closer to dry friction
            (a joint that sticks) and make the equations stiffer (smaller steps, or the
            implicit methods).
        friction_velocity: the friction's regularisation rate ``v_s`` (rad/s, > 0, default 1e-3).
        cart: a :class:`Cart`: the pivot rides on a cart sliding along x (coordinates
            ``(x, theta)``, the cart first in the mass matrix and the accelerations).

    Angles ``theta`` are absolute, from the downward vertical, counter-clockwise positive.
    Methods accept a state of shape (N,) or a batch (..., N) and return matching shapes.
    A chain whose mass matrix would be singular (e.g. a massless last point mass) is refused.

    >>> import multipendulum as mp
    >>> chain = mp.Chain(lengths=[1, 1], masses=[1, 1])
    >>> round(chain.energy([0, 0], [0, 0]), 2)   # hanging at rest: U = -g (2 l1 m + l2 m)
    -29.43
    """

    __slots__ = ("_c",)
    _c: _core.Chain

    def __init__(self, lengths: npt.ArrayLike, masses: npt.ArrayLike, com: Optional[npt.ArrayLike] = None,
                 inertia: Optional[npt.ArrayLike] = None, g: float = 9.81, damping: Optional[npt.ArrayLike] = None,
                 friction: Optional[npt.ArrayLike] = None, friction_velocity: float = 1e-3,
                 cart: Optional[Cart] = None) -> None:
        args: Dict[str, Any] = {}
        for name, v in (("lengths", lengths), ("masses", masses), ("com", com), ("inertia", inertia)):
            if v is None and name in ("com", "inertia"):
                args[name] = None
                continue
            a = as_floats(v, name)
            if a.ndim != 1:
                raise InputError(f"{name} must be a 1-D sequence of numbers, got shape {a.shape}")
            args[name] = a.tolist()
        n = len(args["lengths"])
        self._c = _core.Chain(args["lengths"], args["masses"], args["com"], args["inertia"], as_float(g, "g"),
                              damping=_per_joint(damping, "damping", n), friction=_per_joint(friction, "friction", n),
                              friction_velocity=as_float(friction_velocity, "friction_velocity"), cart=_cart(cart))

    @classmethod
    def rods(cls, lengths: npt.ArrayLike, masses: npt.ArrayLike, g: float = 9.81,
             damping: Optional[npt.ArrayLike] = None, friction: Optional[npt.ArrayLike] = None,
             friction_velocity: float = 1e-3, cart: Optional[Cart] = None) -> Chain:
        """Uniform rods (seed 001's arms): centre of mass mid-link, inertia m l^2 / 12; the
        other parameters as for :class:`Chain`."""
        lengths = as_floats(lengths, "lengths")
        masses = as_floats(masses, "masses")
        if lengths.shape != masses.shape:
            raise InputError(f"masses must have {lengths.size} entries (one per link), got {masses.size}")
        if lengths.ndim != 1:
            raise InputError(f"lengths must be a 1-D sequence of numbers, got shape {lengths.shape}")
        n = lengths.size
        return cls._wrap(_core.Chain.rods(lengths.tolist(), masses.tolist(), as_float(g, "g"),
                                          damping=_per_joint(damping, "damping", n),
                                          friction=_per_joint(friction, "friction", n),
                                          friction_velocity=as_float(friction_velocity, "friction_velocity"),
                                          cart=_cart(cart)))

    @classmethod
    def _wrap(cls, core_chain: _core.Chain) -> Chain:
        obj = cls.__new__(cls)
        obj._c = core_chain
        return obj

    @property
    def n(self) -> int:
        """number of links"""
        return self._c.n

    @property
    def lengths(self) -> npt.NDArray[np.float64]:
        return self._c.lengths

    @property
    def masses(self) -> npt.NDArray[np.float64]:
        return self._c.masses

    @property
    def com(self) -> npt.NDArray[np.float64]:
        return self._c.com

    @property
    def inertia(self) -> npt.NDArray[np.float64]:
        return self._c.inertia

    @property
    def g(self) -> float:
        return self._c.g

    @property
    def damping(self) -> npt.NDArray[np.float64]:
        """viscous damping of each joint (N m s/rad)"""
        return self._c.damping

    @property
    def friction(self) -> npt.NDArray[np.float64]:
        """Coulomb friction torque of each joint (N m)"""
        return self._c.friction

    @property
    def friction_velocity(self) -> float:
        """the friction's regularisation rate v_s (rad/s)"""
        return self._c.friction_velocity

    @property
    def cart(self) -> Optional[Cart]:
        """the :class:`Cart` carrying the pivot, or None"""
        c = self._c.cart
        return None if c is None else Cart(*c)

    @property
    def dissipative(self) -> bool:
        """whether the chain loses energy by itself (joint damping or friction, cart damping)"""
        return self._c.dissipative

    @property
    def dof(self) -> int:
        """degrees of freedom: N, or N + 1 on a cart"""
        return self.n + (self.cart is not None)

    def __repr__(self) -> str:
        return repr(self._c)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Chain) and repr(self) == repr(other)

    def __hash__(self) -> int:
        return hash(repr(self))

    def __reduce__(self) -> Tuple[Any, Tuple[Any, ...]]:
        return (_from_dict, (self.to_dict(),))

    def to_dict(self) -> Dict[str, Any]:
        """The parameters as plain data (``Chain(**d)`` rebuilds it; ``cart`` as a dict)."""
        d: Dict[str, Any] = {"lengths": self.lengths.tolist(), "masses": self.masses.tolist(), "com": self.com.tolist(),
                             "inertia": self.inertia.tolist(), "g": self.g}
        if self.damping.any() or self.friction.any():
            d.update(damping=self.damping.tolist(), friction=self.friction.tolist(),
                     friction_velocity=self.friction_velocity)
        if self.cart is not None:
            d["cart"] = {"mass": self.cart.mass, "damping": self.cart.damping}
        return d

    @classmethod
    def from_dict(cls, d: Dict[str, Any]) -> Chain:
        """The inverse of :meth:`to_dict`."""
        d = dict(d)
        cart = d.pop("cart", None)
        return cls(**d, cart=None if cart is None else Cart(**cart))

    # -- dynamics (all computed in Rust) --------------------------------------------------------
    def _states(self, **arrays: npt.ArrayLike) -> List[npt.NDArray[np.float64]]:
        out = [as_state(v, k, self.n) for k, v in arrays.items()]
        shapes = {a.shape for a in out}
        if len(shapes) > 1:
            raise InputError("shapes differ: " + ", ".join(f"{k} {a.shape}" for k, a in zip(arrays, out)))
        return out

    def mass_matrix(self, theta: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The symmetric positive definite mass matrix A(theta), shape (..., N, N); on a cart
        (..., N+1, N+1) for the coordinates ``(x, theta)``, the cart first."""
        (th,) = self._states(theta=theta)
        m = self.dof
        return _finite_result(self._c.mass_matrix(th.ravel()), "mass matrix").reshape(th.shape[:-1] + (m, m))

    def _cart_v(self, cart_v: npt.ArrayLike, shape: Tuple[int, ...]) -> Optional[List[float]]:
        v = as_floats(cart_v, "cart_v")
        if v.ndim == 0:
            return None if float(v) == 0.0 and self.cart is None else [float(v)]
        if v.shape != shape:
            raise InputError(f"cart_v must be a number or have shape {shape} (one per state), got {v.shape}")
        return v.ravel().tolist()

    def accelerations(self, theta: npt.ArrayLike, omega: npt.ArrayLike, t: float = 0.0,
                      torque: Optional[TorqueLike] = None, joint_torque: Optional[TorqueLike] = None,
                      algorithm: str = "recursive", *, pivot: Optional[Pivot] = None, cart_v: npt.ArrayLike = 0.0,
                      cart_force: Optional[ForceLike] = None) -> npt.NDArray[np.float64]:
        """theta_ddot, shape (..., N), by the O(N) recursion (or a reference route for the
        seeds' ideal chain: ``algorithm="cholesky"`` dense solve, ``"cramer"`` seed 000's
        Cramer's rule). Includes the chain's damping and friction.

        ``torque``: generalized torques conjugate to the absolute angles (seed 000);
        ``joint_torque``: joint-motor torques u_i between link i-1 and i (tau_i = u_i - u_{i+1}).
        Either is an array (N,), a built-in (:class:`Sinusoid`, :class:`Table`) or a callable
        ``f(t)`` / ``f(t, theta, omega)``. ``pivot``: a :class:`Pivot` whose acceleration at ``t``
        acts on the chain. On a cart the result is (..., N+1), ``x_ddot`` first, with the cart at
        velocity ``cart_v`` (a number or one per state) pushed by ``cart_force`` (a number,
        :class:`Sinusoid`/:class:`Table` of one value, or ``f(t, state)``, which sees ``x = 0``).
        """
        th, om = self._states(theta=theta, omega=omega)
        spec, joint = normalise_torque(torque, joint_torque, self.n)
        if not isinstance(algorithm, str):
            raise InputError(f"algorithm must be one of {', '.join(ALGORITHMS)}, got {algorithm!r}")
        out = self._c.accelerations(th.ravel(), om.ravel(), t=as_float(t, "t", finite=True),
                                    torque=core_torque(spec, joint), algorithm=algorithm,
                                    pivot=core_pivot(normalise_pivot(pivot)), cart_v=self._cart_v(cart_v, th.shape[:-1]),
                                    cart_force=core_force(normalise_force(cart_force)))
        return _finite_result(out, "accelerations").reshape(th.shape[:-1] + (self.dof,))

    def jacobian(self, theta: npt.ArrayLike, omega: npt.ArrayLike, t: float = 0.0,
                 torque: Optional[TorqueLike] = None,
                 joint_torque: Optional[TorqueLike] = None, *, pivot: Optional[Pivot] = None,
                 cart_v: float = 0.0, cart_force: Optional[ForceLike] = None) -> npt.NDArray[np.float64]:
        """The exact Jacobian (2N, 2N) of ``(theta_dot, omega_dot)`` with respect to
        ``(theta, omega)``, from the core's variational equations (torques and the cart force
        taken as depending on time only; damping and friction exactly). On a cart (2N+2, 2N+2)
        in the ordering ``(x, theta, v, omega)``. At an equilibrium this is the linearisation
        used for normal modes and LQR."""
        th, om = self._states(theta=theta, omega=omega)
        if th.ndim != 1:
            raise InputError(f"theta must have shape ({self.n},) for a Jacobian, got {th.shape}")
        spec, joint = normalise_torque(torque, joint_torque, self.n)
        out = self._c.jacobian(th.tolist(), om.tolist(), t=as_float(t, "t", finite=True), torque=core_torque(spec, joint),
                               pivot=core_pivot(normalise_pivot(pivot)), cart_v=as_float(cart_v, "cart_v", finite=True),
                               cart_force=core_force(normalise_force(cart_force)))
        m = 2 * self.dof
        return _finite_result(out, "Jacobian").reshape(m, m)

    def hamilton(self, theta: npt.ArrayLike, p: npt.ArrayLike, t: float = 0.0,
                 torque: Optional[TorqueLike] = None,
                 joint_torque: Optional[TorqueLike] = None, *,
                 pivot: Optional[Pivot] = None) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Hamilton's equations: ``(theta_dot, p_dot)``, each of shape (..., N), with the
        chain's losses; with a ``pivot``, ``p = A omega`` is the momentum in the pivot's frame."""
        th, pp = self._states(theta=theta, p=p)
        spec, joint = normalise_torque(torque, joint_torque, self.n)
        td, pd = self._c.hamilton(th.ravel(), pp.ravel(), t=as_float(t, "t", finite=True), torque=core_torque(spec, joint),
                                  pivot=core_pivot(normalise_pivot(pivot)))
        td, pd = _finite_result(td, "rates theta_dot"), _finite_result(pd, "rates p_dot")
        return td.reshape(th.shape), pd.reshape(th.shape)

    def momenta(self, theta: npt.ArrayLike, omega: npt.ArrayLike, cart_v: npt.ArrayLike = 0.0) -> npt.NDArray[np.float64]:
        """Canonical momenta p = A(theta) omega, shape (..., N); on a cart (..., N+1), ``p_x``
        first, with the cart at velocity ``cart_v``."""
        th, om = self._states(theta=theta, omega=omega)
        out = self._c.momenta(th.ravel(), om.ravel(), cart_v=self._cart_v(cart_v, th.shape[:-1]))
        return _finite_result(out, "momenta").reshape(th.shape[:-1] + (self.dof,))

    def velocities(self, theta: npt.ArrayLike, p: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Velocities from momenta: omega = A(theta)^-1 p, shape (..., N); on a cart ``p`` and
        the result are (..., N+1), the cart's first (``p_x``, ``v``)."""
        if self.cart is None:
            th, pp = self._states(theta=theta, p=p)
        else:
            (th,) = self._states(theta=theta)
            pp = as_floats(p, "p")
            if pp.shape != th.shape[:-1] + (self.dof,):
                raise InputError(f"p must have shape {th.shape[:-1] + (self.dof,)} (p_x first), got {pp.shape}")
        out = self._c.velocities(th.ravel(), np.ascontiguousarray(pp, dtype=np.float64).ravel())
        return _finite_result(out, "velocities").reshape(th.shape[:-1] + (self.dof,))

    def _energies(self, theta: npt.ArrayLike, omega: npt.ArrayLike, t: float = 0.0, pivot: Optional[Pivot] = None,
                  cart_v: npt.ArrayLike = 0.0) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        th, om = self._states(theta=theta, omega=omega)
        v = self._cart_v(cart_v, th.shape[:-1])
        kin, pot = self._c.energies(th.ravel(), om.ravel(), t=as_float(t, "t", finite=True),
                                    pivot=core_pivot(normalise_pivot(pivot)), cart_v=v)
        kin, pot = _finite_result(kin, "kinetic energy"), _finite_result(pot, "potential energy")
        shape = th.shape[:-1]
        return kin.reshape(shape), pot.reshape(shape)

    def energy(self, theta: npt.ArrayLike, omega: npt.ArrayLike, *, t: float = 0.0, pivot: Optional[Pivot] = None,
               cart_v: npt.ArrayLike = 0.0) -> Union[float, npt.NDArray[np.float64]]:
        """Total energy T + U in the lab frame (U = 0 at the origin's height; hanging at rest
        from a fixed pivot is negative): with a ``pivot`` at time ``t`` its velocity and height
        count, on a cart the cart's velocity ``cart_v`` and kinetic energy."""
        kin, pot = self._energies(theta, omega, t, pivot, cart_v)
        e = kin + pot
        return float(e) if e.ndim == 0 else e

    def kinetic_energy(self, theta: npt.ArrayLike, omega: npt.ArrayLike, *, t: float = 0.0,
                       pivot: Optional[Pivot] = None, cart_v: npt.ArrayLike = 0.0) -> Union[float, npt.NDArray[np.float64]]:
        kin, _ = self._energies(theta, omega, t, pivot, cart_v)
        return float(kin) if kin.ndim == 0 else kin

    def potential_energy(self, theta: npt.ArrayLike, *, t: float = 0.0,
                         pivot: Optional[Pivot] = None) -> Union[float, npt.NDArray[np.float64]]:
        th = as_state(theta, "theta", self.n)
        _, pot = self._energies(th, np.zeros_like(th), t, pivot)
        return float(pot) if pot.ndim == 0 else pot

    def positions(self, theta: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Joint positions, shape (..., N, 2): row i is the far end of link i (the bob of a point
        mass); the pivot is the origin, y points up."""
        (th,) = self._states(theta=theta)
        return self._c.positions(th.ravel(), com=False).reshape(th.shape + (2,))

    def com_positions(self, theta: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Centre-of-mass positions, shape (..., N, 2)."""
        (th,) = self._states(theta=theta)
        return self._c.positions(th.ravel(), com=True).reshape(th.shape + (2,))


def _from_dict(d: Dict[str, Any]) -> Chain:
    return Chain.from_dict(d)
