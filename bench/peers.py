"""The peers of bench/bench.py, each built for the same physical chain as a ``mp.Chain``.

Conventions: multipendulum's angles are absolute, from the downward vertical, counter-clockwise;
MuJoCo and Pinocchio use joint (relative) angles, so theta_i = s * (q_1 + ... + q_i) with
s = +1 for MuJoCo (hinge axis -y in its x-z plane) and s = -1 for Pinocchio (JointModelRY,
rotation about +y). Link i's body frame sits at its pivot; its centre of mass is at -c_i along
z, its inertia about the centre of mass is I_i about the hinge axis (the other two principal
moments are set to I_i as well; they never act in planar motion, and MuJoCo needs them
positive).

- NumPy right-hand sides for SciPy's solve_ivp: the closed-form double pendulum and the dense
  mass-matrix chain (``np.linalg.solve``), as a NumPy user writes them.
- Numba: classical RK4 over the dense mass-matrix chain (Cholesky written out), jitted.
- MuJoCo: a planar chain of hinge joints built with ``mujoco.MjSpec`` (the XML loader refuses
  deep nesting), contacts disabled, no damping, armature 0, ``integrator = RK4``.
- Pinocchio: the same chain of ``JointModelRY`` joints, for ``pin.aba``.
"""

from __future__ import annotations

import numpy as np


def params(chain):
    """(lengths, masses, com, inertia, g) of an ``mp.Chain`` as float arrays."""
    return (np.asarray(chain.lengths, float), np.asarray(chain.masses, float),
            np.asarray(chain.com, float), np.asarray(chain.inertia, float), float(chain.g))


def coefficients(chain):
    """K (N, N) and h (N,) of the seed formulas: M_ab = K_ab cos(theta_a - theta_b)."""
    l, m, c, inertia, g = params(chain)
    n = l.size
    below = np.concatenate([np.cumsum(m[::-1])[::-1][1:], [0.0]])
    h = m * c + l * below
    idx = np.arange(n)
    lo, hi = np.minimum.outer(idx, idx), np.maximum.outer(idx, idx)
    K = l[lo] * h[hi]
    K[idx, idx] = inertia + m * c**2 + l**2 * below
    return K, h, g


# ----------------------------------------------------------------------------- NumPy (SciPy)


def numpy_rhs(chain):
    """solve_ivp right-hand side f(t, y), y = (theta, omega): closed form for N = 2."""
    K, h, g = coefficients(chain)
    n = chain.n
    gh = g * h
    if n == 2:
        k11, k12, k22 = K[0, 0], K[0, 1], K[1, 1]

        def rhs2(t, y):
            th1, th2, w1, w2 = y
            d = th1 - th2
            s, c = np.sin(d), np.cos(d)
            r1 = -k12 * s * w2 * w2 - gh[0] * np.sin(th1)
            r2 = k12 * s * w1 * w1 - gh[1] * np.sin(th2)
            det = k11 * k22 - (k12 * c) ** 2
            return np.array([w1, w2, (k22 * r1 - k12 * c * r2) / det,
                             (k11 * r2 - k12 * c * r1) / det])

        return rhs2

    def rhs(t, y):
        th, w = y[:n], y[n:]
        d = th[:, None] - th[None, :]
        a = np.linalg.solve(K * np.cos(d), -(K * np.sin(d)) @ (w * w) - gh * np.sin(th))
        return np.concatenate([w, a])

    return rhs


# ----------------------------------------------------------------------------- Numba


_NUMBA = {}


def numba_rk4():
    """A jitted ``rk4(y0, dt, steps, K, gh) -> y``: classical RK4 on the dense chain."""
    if "rk4" in _NUMBA:
        return _NUMBA["rk4"]
    import numba

    @numba.njit(cache=False, fastmath=False)
    def deriv(y, K, gh, out):
        n = K.shape[0]
        s = np.sin(y[:n])
        c = np.cos(y[:n])
        A = np.empty((n, n))
        r = np.empty(n)
        for a in range(n):
            acc = -gh[a] * s[a]
            for b in range(n):
                if a == b:
                    A[a, b] = K[a, a]
                else:
                    A[a, b] = K[a, b] * (c[a] * c[b] + s[a] * s[b])
                    acc -= K[a, b] * (s[a] * c[b] - c[a] * s[b]) * y[n + b] * y[n + b]
            r[a] = acc
        # Cholesky A = L L^T in place (lower triangle), then two triangular solves.
        for j in range(n):
            v = A[j, j]
            for k in range(j):
                v -= A[j, k] * A[j, k]
            A[j, j] = np.sqrt(v)
            for i in range(j + 1, n):
                v = A[i, j]
                for k in range(j):
                    v -= A[i, k] * A[j, k]
                A[i, j] = v / A[j, j]
        for i in range(n):
            v = r[i]
            for k in range(i):
                v -= A[i, k] * r[k]
            r[i] = v / A[i, i]
        for i in range(n - 1, -1, -1):
            v = r[i]
            for k in range(i + 1, n):
                v -= A[k, i] * r[k]
            r[i] = v / A[i, i]
        for i in range(n):
            out[i] = y[n + i]
            out[n + i] = r[i]

    @numba.njit(cache=False, fastmath=False)
    def rk4(y0, dt, steps, K, gh):
        m = y0.size
        y = y0.copy()
        k1, k2, k3, k4, tmp = (np.empty(m), np.empty(m), np.empty(m), np.empty(m),
                               np.empty(m))
        for _ in range(steps):
            deriv(y, K, gh, k1)
            for i in range(m):
                tmp[i] = y[i] + 0.5 * dt * k1[i]
            deriv(tmp, K, gh, k2)
            for i in range(m):
                tmp[i] = y[i] + 0.5 * dt * k2[i]
            deriv(tmp, K, gh, k3)
            for i in range(m):
                tmp[i] = y[i] + dt * k3[i]
            deriv(tmp, K, gh, k4)
            for i in range(m):
                y[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        return y

    _NUMBA["rk4"] = rk4
    return rk4


def numba_runner(chain):
    """``run(theta0, omega0, dt, steps) -> (theta, omega)`` with the jitted RK4 (compiled here)."""
    rk4 = numba_rk4()
    K, h, g = coefficients(chain)
    gh = g * h
    n = chain.n

    def run(theta0, omega0, dt, steps):
        y = rk4(np.concatenate([theta0, omega0]).astype(float), float(dt), int(steps), K, gh)
        return y[:n], y[n:]

    run(np.zeros(n), np.zeros(n), 1e-3, 1)  # compile outside any timing
    return run


# ----------------------------------------------------------------------------- MuJoCo


def mujoco_model(chain, dt):
    """The chain as an ``MjModel`` (hinges about -y, x-z plane, RK4, no contacts)."""
    import mujoco

    l, m, c, inertia, g = params(chain)
    spec = mujoco.MjSpec()
    spec.option.timestep = dt
    spec.option.gravity = [0.0, 0.0, -g]
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_RK4
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    parent, offset = spec.worldbody, 0.0
    for li, mi, ci, ii in zip(l, m, c, inertia):
        body = parent.add_body(pos=[0.0, 0.0, -offset])
        body.explicitinertial = True
        body.mass = mi
        body.ipos = [0.0, 0.0, -ci]
        body.inertia = [ii, ii, ii]
        body.add_joint(type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0.0, -1.0, 0.0])
        parent, offset = body, li
    model = spec.compile()
    # What the comparison relies on, checked rather than assumed.
    assert np.all(model.dof_damping == 0) and np.all(model.dof_armature == 0)
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    return model


def mujoco_runner(chain, dt):
    """``run(theta0, omega0, steps) -> (theta, omega)`` with ``mj_step(m, d, nstep=steps)``."""
    import mujoco

    model = mujoco_model(chain, dt)
    data = mujoco.MjData(model)

    def run(theta0, omega0, steps):
        mujoco.mj_resetData(model, data)
        data.qpos[:] = np.diff(theta0, prepend=0.0)
        data.qvel[:] = np.diff(omega0, prepend=0.0)
        mujoco.mj_step(model, data, nstep=int(steps))
        return np.cumsum(data.qpos), np.cumsum(data.qvel)

    def forward(theta, omega):
        data.qpos[:] = np.diff(theta, prepend=0.0)
        data.qvel[:] = np.diff(omega, prepend=0.0)
        mujoco.mj_forward(model, data)
        return np.cumsum(data.qacc)

    def bind_forward(theta, omega):
        """The bare ``mj_forward`` call at this state, to time."""
        forward(theta, omega)
        return lambda: mujoco.mj_forward(model, data)

    run.forward = forward
    run.bind_forward = bind_forward
    run.model = model
    return run


# ----------------------------------------------------------------------------- Pinocchio


def pinocchio_aba(chain):
    """``acc(theta, omega) -> theta''`` through ``pin.aba`` on a chain of JointModelRY."""
    import pinocchio as pin

    l, m, c, inertia, g = params(chain)
    model = pin.Model()
    model.gravity = pin.Motion(np.array([0.0, 0.0, -g, 0.0, 0.0, 0.0]))
    parent, offset = 0, 0.0
    for i, (li, mi, ci, ii) in enumerate(zip(l, m, c, inertia)):
        jid = model.addJoint(parent, pin.JointModelRY(),
                             pin.SE3(np.eye(3), np.array([0.0, 0.0, -offset])), f"joint{i + 1}")
        model.appendBodyToJoint(jid, pin.Inertia(mi, np.array([0.0, 0.0, -ci]), np.eye(3) * ii),
                                pin.SE3.Identity())
        parent, offset = jid, li
    data = model.createData()
    tau = np.zeros(model.nv)

    def acc(theta, omega):
        q = -np.diff(theta, prepend=0.0)
        v = -np.diff(omega, prepend=0.0)
        return -np.cumsum(pin.aba(model, data, q, v, tau))

    def bind(theta, omega):
        """The bare ``pin.aba`` call at this state (joint coordinates prepared once), to time."""
        q = -np.diff(theta, prepend=0.0)
        v = -np.diff(omega, prepend=0.0)
        return lambda: pin.aba(model, data, q, v, tau)

    acc.bind = bind
    return acc
