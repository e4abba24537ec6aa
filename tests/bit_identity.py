"""Hashes of the arrays of a fixed set of runs: every method with and without t_eval, events,
checkpoints and resume, batches, both forms, every torque kind, the example scenarios and the
chaos tools. `tests/test_bit_identity.py` compares them with `tests/data/bit_hashes.json`, which
was recorded before the run driver was rewritten (issue 11): a refactoring must not move a bit.

Not a promise across machines (libm may differ in the last bit): regenerate on purpose, with
`python tests/bit_identity.py --record`, only when a change is meant to alter results, and say
so in its commit. `--add` records the cases that have no hash yet (a new example scenario) and
leaves every recorded one as it is.
"""
import hashlib
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

import multipendulum as mp

ROOT = Path(__file__).resolve().parents[1]
RECORD = Path(__file__).resolve().parent / "data" / "bit_hashes.json"


def _digest(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(np.asarray(a, dtype=np.float64))
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _sol(sol) -> str:
    # Accepted and rejected step counts too (not evaluations: sharing a slope between dense
    # output and event location may save some without moving a bit of the results).
    arrays = [sol.t, sol.theta, sol.omega, sol.p, sol.energy, sol.work, sol.stats.steps, sol.stats.rejected]
    events = sol.events if isinstance(sol.events, list) else []
    flat = events if not events or not isinstance(events[0], list) else [r for run in events for r in run]
    for rec in flat:
        arrays += [rec.t, rec.theta, rec.omega, rec.p]
    return _digest(*arrays)


def cases():
    """(name, thunk) pairs; each thunk returns a hex digest."""
    point = mp.Chain([1.0, 0.8], [1.0, 1.5])
    rods = mp.Chain.rods([1.0, 0.7, 0.5], [1.0, 2.0, 0.5])
    general = mp.Chain([1.0, 0.9], [1.0, 0.6], com=[0.4, 0.5], inertia=[0.05, 0.02])
    th, om = [2.0, 2.5], [0.0, 0.3]
    th3, om3 = [0.3, -1.2, 2.0], [0.5, 0.0, -1.0]
    t_eval = np.linspace(0.0, 3.0, 301)
    t_eval_off = np.linspace(0.013, 2.991, 57)  # off every step grid, without 0
    sin = mp.Sinusoid([0.3, 0.0], [2.0, 1.0])
    table = mp.Table([0.0, 1.0, 2.0, 3.0], [[0.0, 0.1], [0.2, -0.1], [0.0, 0.3], [0.1, 0.0]], kind="cubic")
    fixed = {"rk4": dict(dt=0.003), "gauss4": dict(dt=0.01), "gauss6": dict(dt=0.007)}
    out = []
    for method, kw in list(fixed.items()) + [("dop853", dict(rtol=1e-9, atol=1e-11))]:
        for label, extra in (("steps", {}), ("t_eval", dict(t_eval=t_eval)), ("t_eval_off", dict(t_eval=t_eval_off))):
            out.append((f"{method}/{label}/point", lambda m=method, k={**kw, **extra}: _sol(
                mp.simulate(point, th, om, 3.0, method=m, **k))))
        out.append((f"{method}/sinusoid/rods", lambda m=method, k=kw: _sol(
            mp.simulate(rods, th3, om3, 2.0, method=m, joint_torque=mp.Sinusoid([0.3, 0.0, 0.1], 2.0), **k))))
        out.append((f"{method}/table/general", lambda m=method, k=kw: _sol(
            mp.simulate(general, th, om, 3.0, method=m, torque=table, t_eval=t_eval_off, **k))))
        out.append((f"{method}/constant/general", lambda m=method, k=kw: _sol(
            mp.simulate(general, th, om, 2.0, method=m, torque=[0.2, -0.1], **k))))
        out.append((f"{method}/events", lambda m=method, k=kw: _sol(mp.simulate(
            point, th, om, 10.0, method=m, events=[mp.Flip(link=1), mp.Crossing(theta=[1, 0], direction=0)],
            **k))))
        out.append((f"{method}/events+t_eval", lambda m=method, k=kw: _sol(mp.simulate(
            point, th, om, 10.0, method=m, t_eval=np.linspace(0, 10, 41),
            events=[mp.Flip(link=0, terminal=False), mp.Crossing(omega=[0, 1], terminal=True, direction=-1)],
            **k))))
        out.append((f"{method}/callable", lambda m=method, k=kw: _sol(mp.simulate(
            point, th, om, 1.0, method=m, torque=lambda t, a, b: [0.1 * np.sin(t), -0.05 * b[1]], **k))))
        batch = (lambda m=method, k=kw: _sol(mp.simulate(
            rods, np.random.default_rng(3).uniform(-3, 3, (16, 3)), np.zeros((16, 3)), 2.0, method=m,
            t_eval=np.linspace(0, 2, 9), torque=sin if False else None, **k)))
        # Trajectory by trajectory (the route recorded before the lanes took rk4 batches), and
        # in whatever route the batch takes by default (rk4's and dop853's: the SIMD lanes, issue 14).
        out.append((f"{method}/batch", lambda b=batch: _with_env("MULTIPENDULUM_LANES", "scalar", b)))
        if method in ("rk4", "dop853"):
            out.append((f"{method}/batch_lanes", batch))
        out.append((f"{method}/checkpoint+resume", lambda m=method, k=kw: _checkpointed(point, th, om, m, k)))
    # The general model's O(N) route with joint losses, a moving pivot and a cart (issue 13).
    lossy = mp.Chain.rods([1.0, 0.7, 0.5, 0.6], [1.0, 2.0, 0.5, 0.8], damping=[0.05, 0.02, 0.1, 0.0], friction=0.03)
    on_cart = mp.Chain.rods([1.0, 0.7, 0.5], [1.0, 2.0, 0.5], damping=0.04, friction=[0.0, 0.02, 0.05],
                            cart=mp.Cart(2.0, damping=0.3))
    cart_pole = mp.Chain.rods([0.6, 0.6], [4.2, 4.2], cart=mp.Cart(10.5))  # the two links' closed form
    th4, om4 = [0.3, -1.2, 2.0, 0.4], [0.5, 0.0, -1.0, 2.0]
    shaken = mp.Pivot(x=mp.Sinusoid(0.01, 20.0), y=mp.Sinusoid(0.02, 30.0))
    for method, kw in (("rk4", dict(dt=0.002)), ("dop853", dict(rtol=1e-9, atol=1e-11))):
        out.append((f"{method}/lossy/rods4", lambda m=method, k=kw: _sol(mp.simulate(
            lossy, th4, om4, 3.0, method=m, t_eval=t_eval_off, pivot=shaken, **k))))
        out.append((f"{method}/lossy/cart", lambda m=method, k=kw: _sol(mp.simulate(
            on_cart, th3, om3, 2.0, method=m, cart_v0=0.4, cart_force=mp.Sinusoid(1.0, 3.0), **k))))
        out.append((f"{method}/cart/double", lambda m=method, k=kw: _sol(mp.simulate(
            cart_pole, [3.0, 3.3], [0.2, -0.3], 2.0, method=m, cart_x0=0.1, cart_v0=0.5, **k))))
    out.append(("rk4/hamiltonian", lambda: _sol(mp.simulate(point, th, om, 3.0, method="rk4", dt=0.01,
                                                            form="hamiltonian"))))
    out.append(("dop853/hamiltonian", lambda: _sol(mp.simulate(point, th, om, 3.0, form="hamiltonian"))))
    out.append(("dop853/fixed", lambda: _sol(mp.simulate(point, th, om, 3.0, dt=0.01, adaptive=False))))
    out.append(("dop853/first-dt", lambda: _sol(mp.simulate(point, th, om, 3.0, dt=0.001))))
    out.append(("dop853/default", lambda: _sol(mp.simulate(point, th, om, 20.0))))
    for path in sorted((ROOT / "examples").glob("*.toml")):
        out.append((f"scenario/{path.name}", lambda p=path: _sol(mp.load_scenario(p).run())))
    out.append(("lyapunov", lambda: _digest(*(lambda r: (r.exponents, r.times, r.history))(
        mp.lyapunov(point, th, om, 20.0)))))
    out.append(("flip_times", lambda: _digest(mp.flip_times(
        mp.Chain([1, 1], [1, 1]), np.random.default_rng(5).uniform(-3, 3, (200, 2)), t_max=5.0))))
    out.append(("flip_times/rods3", lambda: _digest(mp.flip_times(
        rods, np.random.default_rng(6).uniform(-3, 3, (50, 3)), t_max=3.0))))
    out.append(("flip_map", lambda: _digest(mp.flip_map(
        mp.Chain([1, 1], [1, 1]), np.linspace(-3, 3, 24), np.linspace(-3, 3, 20), t_max=5.0).times)))
    # (Not its energy_error: redefined on purpose against the initial state, issue 12.)
    # The per-trajectory route (recorded before dop853 ensembles took the lanes, issue 14), and
    # the lanes' own.
    ensemble = lambda: (lambda e: _digest(e.theta, e.omega, e.first_flip))(
        mp.ensemble(rods, np.random.default_rng(7).uniform(-2, 2, (32, 3)), np.zeros((32, 3)), 3.0))
    out.append(("ensemble", lambda: _with_env("MULTIPENDULUM_LANES", "scalar", ensemble)))
    out.append(("ensemble_lanes", ensemble))
    out.append(("jacobian", lambda: _digest(rods.jacobian(th3, om3))))
    return out


def _with_env(name, value, thunk):
    old = os.environ.get(name)
    os.environ[name] = value
    try:
        return thunk()
    finally:
        if old is None:
            del os.environ[name]
        else:
            os.environ[name] = old


def _checkpointed(chain, th, om, method, kw):
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "run.ckpt"
        full = mp.simulate(chain, th, om, 3.0, method=method, checkpoint=path,
                           checkpoint_every=7 if method == "dop853" else 37, **kw)
        again = mp.resume(path)
        return _digest(full.theta, full.omega, full.energy, again.theta, again.omega, again.energy)


def compute():
    return {name: thunk() for name, thunk in cases()}


if __name__ == "__main__":
    got = compute()
    if "--record" in sys.argv:
        RECORD.write_text(json.dumps(got, indent=1, sort_keys=True) + "\n")
        print(f"recorded {len(got)} hashes in {RECORD}")
    elif "--add" in sys.argv:
        want = json.loads(RECORD.read_text())
        new = {k: v for k, v in got.items() if k not in want}
        RECORD.write_text(json.dumps({**want, **new}, indent=1, sort_keys=True) + "\n")
        print(f"added {sorted(new)}; {sum(got[k] == want[k] for k in want)} of {len(want)} recorded ones identical")
    else:
        want = json.loads(RECORD.read_text())
        bad = [k for k in want if got.get(k) != want[k]]
        print(f"{len(want) - len(bad)} of {len(want)} identical; differ: {bad}")
