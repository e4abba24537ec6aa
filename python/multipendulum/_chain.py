"""The chain model: a thin layer over the Rust core that converts and reshapes arrays."""
from __future__ import annotations

import math
from typing import Any, Dict, List, Optional, Tuple, Type, Union

import numpy as np
import numpy.typing as npt

import multipendulum._core as _core
from ._convert import as_float, as_floats
from ._torque import TorqueLike, core_torque, normalise_torque
from .errors import InputError

#: The routes to the accelerations and the most links each takes (None: any), from the core.
ALGORITHMS = dict(_core.ALGORITHMS)
MAX_STATE = _core.LIMITS["max_angle"]  # the largest |angle| a state may hold (the core's limit)


def _finite_result(out: npt.NDArray[np.float64], what: str) -> npt.NDArray[np.float64]:
    """Finite inputs can still overflow (huge masses times huge rates): say so, never return NaN."""
    if not math.isfinite(np.vdot(out, out)) and not np.isfinite(out).all():
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
    # This is on every call's path, so first one cheap test that any NaN or inf fails (and a sum
    # of squares that overflows only sends finite input on to the exact test); details on failure.
    theta = "theta" in name
    squares = np.vdot(a, a)
    if squares <= MAX_STATE**2 if theta else math.isfinite(squares):
        return a
    for bad, what in ((~np.isfinite(a), "must be finite"),
                      (np.abs(a) > MAX_STATE if theta else np.zeros(a.shape, bool), f"must be within +-{MAX_STATE:.0e} rad")):
        if bad.any():
            idx = tuple(int(i) for i in np.argwhere(bad)[0])
            raise InputError(f"{name}[{idx[0] if len(idx) == 1 else idx}] {what}, got {a[idx]}")
    return a


class Chain:
    """A planar chain of N rigid links hanging from a fixed pivot at the origin.

    Parameters (SI units; arrays of length N, link 1 hangs from the pivot):
        lengths: pivot-to-next-joint length of each link, > 0.
        masses: mass of each link, >= 0.
        com: distance of each link's centre of mass from its own pivot (default: ``lengths``,
            i.e. point masses at the link ends, seed 000).
        inertia: moment of inertia of each link about its centre of mass (default: 0).
        g: gravitational acceleration along -y.

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
                 inertia: Optional[npt.ArrayLike] = None, g: float = 9.81) -> None:
        args: Dict[str, Any] = {}
        for name, v in (("lengths", lengths), ("masses", masses), ("com", com), ("inertia", inertia)):
            if v is None and name in ("com", "inertia"):
                args[name] = None
                continue
            a = as_floats(v, name)
            if a.ndim != 1:
                raise InputError(f"{name} must be a 1-D sequence of numbers, got shape {a.shape}")
            args[name] = a.tolist()
        self._c = _core.Chain(args["lengths"], args["masses"], args["com"], args["inertia"], as_float(g, "g"))

    @classmethod
    def rods(cls, lengths: npt.ArrayLike, masses: npt.ArrayLike, g: float = 9.81) -> Chain:
        """Uniform rods (seed 001's arms): centre of mass mid-link, inertia m l^2 / 12."""
        lengths = as_floats(lengths, "lengths")
        masses = as_floats(masses, "masses")
        if lengths.shape != masses.shape:
            raise InputError(f"masses must have {lengths.size} entries (one per link), got {masses.size}")
        if lengths.ndim != 1:
            raise InputError(f"lengths must be a 1-D sequence of numbers, got shape {lengths.shape}")
        return cls._wrap(_core.Chain.rods(lengths.tolist(), masses.tolist(), as_float(g, "g")))

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

    def __repr__(self) -> str:
        return repr(self._c)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Chain) and repr(self) == repr(other)

    def __hash__(self) -> int:
        return hash(repr(self))

    def __reduce__(self) -> Tuple[Type[Chain], Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64],
                                                    npt.NDArray[np.float64], npt.NDArray[np.float64], float]]:
        return (Chain, (self.lengths, self.masses, self.com, self.inertia, self.g))

    def to_dict(self) -> Dict[str, Any]:
        return {"lengths": self.lengths.tolist(), "masses": self.masses.tolist(), "com": self.com.tolist(),
                "inertia": self.inertia.tolist(), "g": self.g}

    # -- dynamics (all computed in Rust) --------------------------------------------------------
    def _states(self, **arrays: npt.ArrayLike) -> List[npt.NDArray[np.float64]]:
        out = [as_state(v, k, self.n) for k, v in arrays.items()]
        shapes = {a.shape for a in out}
        if len(shapes) > 1:
            raise InputError("shapes differ: " + ", ".join(f"{k} {a.shape}" for k, a in zip(arrays, out)))
        return out

    def mass_matrix(self, theta: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The symmetric positive definite mass matrix A(theta), shape (..., N, N)."""
        (th,) = self._states(theta=theta)
        return _finite_result(self._c.mass_matrix(th.ravel()), "mass matrix").reshape(th.shape + (self.n,))

    def accelerations(self, theta: npt.ArrayLike, omega: npt.ArrayLike, t: float = 0.0,
                      torque: Optional[TorqueLike] = None, joint_torque: Optional[TorqueLike] = None,
                      algorithm: str = "recursive") -> npt.NDArray[np.float64]:
        """theta_ddot, shape (..., N), by the O(N) recursion (or a reference route:
        ``algorithm="cholesky"`` dense solve, ``"cramer"`` seed 000's Cramer's rule).

        ``torque``: generalized torques conjugate to the absolute angles (seed 000);
        ``joint_torque``: joint-motor torques u_i between link i-1 and i (tau_i = u_i - u_{i+1}).
        Either is an array (N,), a built-in (:class:`Sinusoid`, :class:`Table`) or a callable
        ``f(t)`` / ``f(t, theta, omega)``.
        """
        th, om = self._states(theta=theta, omega=omega)
        spec, joint = normalise_torque(torque, joint_torque, self.n)
        if not isinstance(algorithm, str):
            raise InputError(f"algorithm must be one of {', '.join(ALGORITHMS)}, got {algorithm!r}")
        out = self._c.accelerations(th.ravel(), om.ravel(), t=as_float(t, "t", finite=True),
                                    torque=core_torque(spec, joint), algorithm=algorithm)
        return _finite_result(out, "accelerations").reshape(th.shape)

    def jacobian(self, theta: npt.ArrayLike, omega: npt.ArrayLike, t: float = 0.0,
                 torque: Optional[TorqueLike] = None,
                 joint_torque: Optional[TorqueLike] = None) -> npt.NDArray[np.float64]:
        """The exact Jacobian (2N, 2N) of ``(theta_dot, omega_dot)`` with respect to
        ``(theta, omega)``, from the core's variational equations (torques taken as depending on
        time only). At an equilibrium this is the linearisation used for normal modes and LQR."""
        th, om = self._states(theta=theta, omega=omega)
        if th.ndim != 1:
            raise InputError(f"theta must have shape ({self.n},) for a Jacobian, got {th.shape}")
        spec, joint = normalise_torque(torque, joint_torque, self.n)
        out = self._c.jacobian(th.tolist(), om.tolist(), t=as_float(t, "t", finite=True), torque=core_torque(spec, joint))
        return _finite_result(out, "Jacobian").reshape(2 * self.n, 2 * self.n)

    def hamilton(self, theta: npt.ArrayLike, p: npt.ArrayLike, t: float = 0.0,
                 torque: Optional[TorqueLike] = None,
                 joint_torque: Optional[TorqueLike] = None) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Hamilton's equations: ``(theta_dot, p_dot)``, each of shape (..., N)."""
        th, pp = self._states(theta=theta, p=p)
        spec, joint = normalise_torque(torque, joint_torque, self.n)
        td, pd = self._c.hamilton(th.ravel(), pp.ravel(), t=as_float(t, "t", finite=True), torque=core_torque(spec, joint))
        td, pd = _finite_result(td, "rates theta_dot"), _finite_result(pd, "rates p_dot")
        return td.reshape(th.shape), pd.reshape(th.shape)

    def momenta(self, theta: npt.ArrayLike, omega: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Canonical momenta p = A(theta) omega, shape (..., N)."""
        th, om = self._states(theta=theta, omega=omega)
        return _finite_result(self._c.momenta(th.ravel(), om.ravel()), "momenta").reshape(th.shape)

    def velocities(self, theta: npt.ArrayLike, p: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Angular velocities omega = A(theta)^-1 p, shape (..., N)."""
        th, pp = self._states(theta=theta, p=p)
        return _finite_result(self._c.velocities(th.ravel(), pp.ravel()), "velocities").reshape(th.shape)

    def _energies(self, theta: npt.ArrayLike,
                  omega: npt.ArrayLike) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        th, om = self._states(theta=theta, omega=omega)
        kin, pot = self._c.energies(th.ravel(), om.ravel())
        kin, pot = _finite_result(kin, "kinetic energy"), _finite_result(pot, "potential energy")
        shape = th.shape[:-1]
        return kin.reshape(shape), pot.reshape(shape)

    def energy(self, theta: npt.ArrayLike, omega: npt.ArrayLike) -> Union[float, npt.NDArray[np.float64]]:
        """Total energy T + U (U = 0 at the pivot's height; hanging at rest is negative)."""
        kin, pot = self._energies(theta, omega)
        e = kin + pot
        return float(e) if e.ndim == 0 else e

    def kinetic_energy(self, theta: npt.ArrayLike, omega: npt.ArrayLike) -> Union[float, npt.NDArray[np.float64]]:
        kin, _ = self._energies(theta, omega)
        return float(kin) if kin.ndim == 0 else kin

    def potential_energy(self, theta: npt.ArrayLike) -> Union[float, npt.NDArray[np.float64]]:
        th = as_state(theta, "theta", self.n)
        _, pot = self._energies(th, np.zeros_like(th))
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
