"""The Gymnasium environments (multipendulum.envs) against gymnasium's own: vector throughput and
the cost of one step.

Run:  bench/.venv/bin/python bench/bench_envs.py [--quick] [--json OUT.json] [--md OUT.md]
(by default the JSON goes to bench/build/envs.json and the Markdown section is printed;
bench/bench.py runs it as a subprocess for its section (f) of bench/RESULTS.md).

1. Vector environments of 256 copies, random actions sampled before timing (the same sequence
   on every repeat), env-steps per second = 256 x vector steps / s, episodes ending and
   resetting inside the timed run as they come (autoreset):
   - peer A: gymnasium's ``Acrobot-v1`` in ``gym.make_vec(..., vectorization_mode="sync")``
     (a ``SyncVectorEnv``: 256 Python environments stepped in a loop);
   - peer B: gymnasium's MuJoCo ``InvertedDoublePendulum-v5``, the same way;
   - ours: ``gym.make_vec("multipendulum/Acrobot-v0", num_envs=256)`` (its own vector env, the
     defaults), ``multipendulum/CartPole-v0`` and ``multipendulum/AcrobotCompat-v0`` (timed
     only where make_vec returns our own vector env), and for scale the bare core of the
     first: ``multipendulum._core.Steppers`` of 256 copies, ``step`` over 0.2 s + ``report()``.
   The models differ (peer A: the book acrobot, one RK4 step of 0.2 s per env step; peer B:
   MuJoCo's RK4, 5 steps of 0.01 s; ours: its default RK4 substeps, docs/envs.md), so no trajectory is
   compared: this is the cost of the environment interface at each one's own physics.
2. One environment, microseconds per ``env.step(a)`` from a Python loop (reset when an episode
   ends): ``gym.make("multipendulum/Acrobot-v0")`` with the wrappers gym.make adds and its
   ``.unwrapped``; gymnasium's ``Acrobot-v1`` the same two ways; and the bare core:
   ``Steppers(chain._c, 1, method="rk4", ..., dt=h)`` on ``Chain.rods([1, 1], [1, 1])`` with
   Acrobot-v0's default substep ``h``, ``step(torques, zeros(0), 0.2)`` (its substeps), the same
   plus ``report()``, and ``step(..., h)`` (one RK4 step: the Python -> Rust -> Python call
   itself).

Everything is timed in alternation (bench_engine.measure: one warm-up call, batches, medians of
the repeats with their ranges); nothing here asserts a speed: ratios and verdicts are reported.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import traceback
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parent
BUILD = BENCH / "build"
sys.path.insert(0, str(BENCH))

import bench_engine as E  # noqa: E402  (measure, fmt_time, verdicts, busy_compilers)

NUM_ENVS = 256
PEER_A, PEER_B = "Acrobot-v1", "InvertedDoublePendulum-v5"
OURS = ("multipendulum/Acrobot-v0", "multipendulum/CartPole-v0",
        "multipendulum/AcrobotCompat-v0")
TARGET_ID = "multipendulum/Acrobot-v0"
TARGET_A, TARGET_B = 100.0, 10.0  # ours / peer env-steps per second, at least
CORE_SPAN = 0.2  # Acrobot-v0's env step
CORE_KW = dict(method="rk4", rtol=1e-10, atol=1e-12, max_steps=10**8)


def core_dt():
    """Acrobot-v0's default RK4 substep, from its own rule (multipendulum.envs)."""
    from multipendulum.envs._engine import stepping

    dt, sub, _ = stepping(CORE_SPAN, None, "rk4", 2, upright=False)
    return dt / sub
THETA0, OMEGA0 = (0.1, -0.05), (0.0, 0.0)


def log(*a):
    print(*a, file=sys.stderr, flush=True)


def err_text(exc):
    return f"{type(exc).__name__}: {exc}".splitlines()[0][:300]


def qualname(obj):
    t = type(obj)
    return f"{t.__module__}.{t.__qualname__}"


def is_ours(obj):
    return type(obj).__module__.split(".")[0] == "multipendulum"


# ----------------------------------------------------------------------------- helpers


def core_steppers(mp, count):
    from multipendulum import _core

    chain = mp.Chain.rods([1.0, 1.0], [1.0, 1.0])
    st = _core.Steppers(chain._c, count, **CORE_KW, dt=core_dt())
    th0, om0 = np.array(THETA0, dtype=np.float64), np.array(OMEGA0, dtype=np.float64)
    for i in range(count):
        st.reset(i, th0, om0)
    return st, chain, th0, om0


def core_step(st, count):
    """``st.step`` as the brief's ``step(torques, forces, span)``; should the binding come to
    require a fourth argument (the copies that move), the same call with ``None`` (all)."""
    u, empty = np.zeros(2 * count), np.zeros(0)
    try:
        st.step(u, empty, core_dt())
        return st.step, "step(torques, forces, span)"
    except TypeError:
        st.step(u, empty, core_dt(), None)
        return (lambda a, b, c: st.step(a, b, c, None)), "step(torques, forces, span, None)"


def acrobot_torques(count, steps, seed):
    """Acrobot's actions as the core's torques: {-1, 0, 1} N m on joint 2, count x 2 flat."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(steps):
        u = np.zeros((count, 2))
        u[:, 1] = rng.integers(0, 3, count) - 1.0
        out.append(np.ascontiguousarray(u.reshape(-1), dtype=np.float64))
    return out


def vector_rollout(envs, actions):
    step = envs.step

    def go():
        for a in actions:
            step(a)
    return go


def count_ends(envs, actions):
    """One untimed pass (it is also the warm-up): episodes ended (terminated | truncated)."""
    ends = 0
    for a in actions:
        _, _, term, trunc, _ = envs.step(a)
        ends += int(np.count_nonzero(np.logical_or(term, trunc)))
    return ends


def env_loop(env, actions):
    step, reset = env.step, env.reset

    def go():
        for a in actions:
            _, _, term, trunc, _ = step(a)
            if term or trunc:
                reset()
    return go


def count_single_ends(env, actions):
    ends = 0
    for a in actions:
        _, _, term, trunc, _ = env.step(a)
        if term or trunc:
            ends += 1
            env.reset()
    return ends


def describe_vector(envs):
    d = {"class": qualname(envs), "ours": is_ours(envs),
         "action_space": str(envs.action_space)[:120],
         "observation_space": str(getattr(envs, "single_observation_space",
                                          envs.observation_space))[:120]}
    md = getattr(envs, "metadata", {}) or {}
    if "autoreset_mode" in md:
        d["autoreset_mode"] = str(md["autoreset_mode"])
    for attr in ("dt", "num_envs"):  # on the vector env itself (AcrobotCompat's dt)
        v = getattr(envs, attr, None)
        if isinstance(v, (int, float, str)):
            d[attr] = v
    task = getattr(envs, "task", None)  # ours: the task the vector env steps
    if task is not None:
        t = {}
        for attr in ("n", "dt", "substeps", "method", "discrete"):
            v = getattr(task, attr, None)
            if isinstance(v, (bool, int, float, str, np.integer, np.floating)):
                t[attr] = v.item() if isinstance(v, np.generic) else v
        chain = getattr(task, "chain", None)
        if chain is not None:
            t["cart"] = getattr(chain, "cart", None) is not None
        d["task"] = t
    return d


def settings_text(r):
    """How one of our vector envs steps, as read from it."""
    t = r.get("task") or {}
    if {"n", "dt", "substeps", "method"} <= set(t):
        sub = t["dt"] / t["substeps"]
        acts = {True: ", discrete actions", False: ", continuous actions"}.get(
            t.get("discrete"), "")
        return (f"{t['n']} link{'s' * (t['n'] != 1)}{' on a cart' if t.get('cart') else ''}, "
                f"{t['substeps']} {t['method']} steps of {sub:g} s per env step of {t['dt']:g} s"
                + acts)
    if "dt" in r:
        return (f"env step of {r['dt']:g} s"
                + (", one rk4 step per env step like Acrobot-v1" if "Compat" in r["key"] else ""))
    return "settings not readable"


def agreement(a, b, actions, seed=123):
    """max |observation difference| of two vector envs from reset(seed) under the same actions
    (AcrobotCompat-v0 is meant to reproduce Acrobot-v1's transitions)."""
    oa, _ = a.reset(seed=seed)
    ob, _ = b.reset(seed=seed)
    worst = float(np.abs(np.asarray(oa, float) - np.asarray(ob, float)).max())
    for act in actions:
        oa = a.step(act)[0]
        ob = b.step(act)[0]
        worst = max(worst, float(np.abs(np.asarray(oa, float) - np.asarray(ob, float)).max()))
    return worst


def peer_physics(gym):
    """What one env step of each peer integrates, read from the environments themselves."""
    out = {}
    try:
        a = gym.make(PEER_A).unwrapped
        out[PEER_A] = f"one RK4 step of {a.dt:g} s (gymnasium's own rk4, book dynamics)"
        a.close()
    except Exception as exc:  # noqa: BLE001
        out[PEER_A] = err_text(exc)
    try:
        import mujoco

        b = gym.make(PEER_B).unwrapped
        integ = mujoco.mjtIntegrator(b.model.opt.integrator).name.replace("mjINT_", "")
        out[PEER_B] = (f"MuJoCo {integ}, {b.frame_skip} steps of {b.model.opt.timestep:g} s "
                       f"(env dt {b.dt:g} s)")
        b.close()
    except Exception as exc:  # noqa: BLE001
        out[PEER_B] = err_text(exc)
    return out


# ----------------------------------------------------------------------------- 1. vector


def bench_vector(mp, gym, quick, repeats):
    k_peer = 12 if quick else 48  # vector steps per timed call (a peer's vector step: ~40 ms)
    k_ours = 200 if quick else 400  # (AcrobotCompat-v0: ~10 ms per vector step)
    min_time = 0.1 if quick else 0.3
    rows, fns, made = [], {}, {}

    def add(key, label, make, k, kind):
        row = {"key": key, "label": label, "kind": kind, "vector_steps": k}
        rows.append(row)
        try:
            t0 = time.perf_counter()
            envs = make()
            row["make_s"] = time.perf_counter() - t0
            made[key] = envs
            row.update(describe_vector(envs))
            if kind == "ours" and not row["ours"]:
                row["skipped"] = (f"make_vec returned {row['class']}, not our own vector env: "
                                  "not timed")
                return
            envs.reset(seed=0)
            envs.action_space.seed(0)
            actions = [envs.action_space.sample() for _ in range(k)]
            t0 = time.perf_counter()
            row["ends_in_first_pass"] = count_ends(envs, actions)
            row["first_pass_s"] = time.perf_counter() - t0
            fns[key] = vector_rollout(envs, actions)
        except Exception as exc:  # noqa: BLE001 - a failure is a result
            row["error"] = err_text(exc)
            log(f"  {label}: failed: {row['error']}")
            log("".join(traceback.format_exception(exc)[-3:]).rstrip())

    add("peer_a", f"gymnasium {PEER_A}, SyncVectorEnv",
        lambda: gym.make_vec(PEER_A, num_envs=NUM_ENVS, vectorization_mode="sync"), k_peer,
        "peer")
    add("peer_b", f"gymnasium {PEER_B} (MuJoCo), SyncVectorEnv",
        lambda: gym.make_vec(PEER_B, num_envs=NUM_ENVS, vectorization_mode="sync"), k_peer,
        "peer")
    envs_error = None
    try:
        import multipendulum.envs  # noqa: F401  (registers the ids)
    except Exception as exc:  # noqa: BLE001
        envs_error = err_text(exc)
        log(f"  import multipendulum.envs failed: {envs_error}")
    for env_id in OURS:
        if envs_error:
            rows.append({"key": env_id, "label": env_id, "kind": "ours",
                         "error": f"import multipendulum.envs: {envs_error}"})
            continue
        add(env_id, env_id, lambda env_id=env_id: gym.make_vec(env_id, num_envs=NUM_ENVS),
            k_ours, "ours")

    # The core of Acrobot-v0 alone: what the vector env adds on top of it.
    row = {"key": "core", "label": f"core: Steppers({NUM_ENVS}).step(0.2 s) + report()",
           "kind": "core", "vector_steps": k_ours}
    rows.append(row)
    try:
        st, *_ = core_steppers(mp, NUM_ENVS)
        step, row["call"] = core_step(st, NUM_ENVS)
        states = st.report
        torques = acrobot_torques(NUM_ENVS, k_ours, 0)
        empty = np.zeros(0)

        def core_go():
            for u in torques:
                step(u, empty, CORE_SPAN)
                states()
        fns["core"] = core_go
    except Exception as exc:  # noqa: BLE001
        row["error"] = err_text(exc)
        log(f"  core Steppers failed: {row['error']}")

    by = {r["key"]: r for r in rows}
    compat, peer = OURS[2], "peer_a"
    if compat in fns and peer in fns:  # both made: same observations under the same actions?
        try:
            ea, ec = made[peer], made[compat]
            ea.action_space.seed(7)
            acts = [ea.action_space.sample() for _ in range(k_peer)]
            by[compat]["agree_with_peer_a"] = agreement(ea, ec, acts)
            by[compat]["agree_steps"] = k_peer
            log(f"  {compat} vs {PEER_A}: max |obs difference| over {k_peer} vector steps "
                f"{by[compat]['agree_with_peer_a']:.1e}")
        except Exception as exc:  # noqa: BLE001
            by[compat]["agree_error"] = err_text(exc)
            log(f"  agreement check failed: {by[compat]['agree_error']}")

    log(f"  timing {', '.join(fns)} ...")
    t = E.measure(fns, repeats, min_time)
    for key, v in t.items():
        r = by[key]
        r["s_per_vector_step"] = [x / r["vector_steps"] for x in v]
        # the median time gives the median rate; the range inverts
        r["env_steps_per_s"] = [NUM_ENVS / x for x in (r["s_per_vector_step"][0],
                                                       r["s_per_vector_step"][2],
                                                       r["s_per_vector_step"][1])]
        if "ends_in_first_pass" in r:
            r["episode_ends_per_1000_env_steps"] = (
                1000.0 * r["ends_in_first_pass"] / (NUM_ENVS * r["vector_steps"]))
        log(f"  {r['label']}: {r['env_steps_per_s'][0]:.3g} env-steps/s")
    for r in rows:
        if "env_steps_per_s" not in r or r["kind"] == "peer":
            continue
        for peer in ("peer_a", "peer_b"):
            p = by.get(peer, {})
            if "env_steps_per_s" in p:
                r[f"ratio_{peer}"] = r["env_steps_per_s"][0] / p["env_steps_per_s"][0]
    for envs in made.values():
        try:
            envs.close()
        except Exception:  # noqa: BLE001
            pass
    return {"rows": rows, "num_envs": NUM_ENVS, "envs_import_error": envs_error,
            "k_peer": k_peer, "k_ours": k_ours}


# ----------------------------------------------------------------------------- 2. one env


def bench_single(mp, gym, quick, repeats):
    k = 500 if quick else 2000  # steps per timed call
    min_time = 0.05 if quick else 0.2
    rows, fns, keep = [], {}, []

    def add(key, label, make):
        row = {"key": key, "label": label, "steps": k}
        rows.append(row)
        try:
            env = make()
            keep.append(env)
            row["class"] = qualname(env)
            env.reset(seed=0)
            env.action_space.seed(0)
            actions = [env.action_space.sample() for _ in range(k)]
            row["ends_in_first_pass"] = count_single_ends(env, actions)
            fns[key] = env_loop(env, actions)
        except Exception as exc:  # noqa: BLE001
            row["error"] = err_text(exc)
            log(f"  {label}: failed: {row['error']}")

    envs_error = None
    try:
        import multipendulum.envs  # noqa: F401
    except Exception as exc:  # noqa: BLE001
        envs_error = err_text(exc)
    if envs_error is None:
        add("ours_wrapped", f'gym.make("{TARGET_ID}").step', lambda: gym.make(TARGET_ID))
        add("ours_unwrapped", f'gym.make("{TARGET_ID}").unwrapped.step',
            lambda: gym.make(TARGET_ID).unwrapped)
        # The wrappers gym.make put around ours.
        try:
            env, chain_ = gym.make(TARGET_ID), []
            while hasattr(env, "env"):
                chain_.append(type(env).__name__)
                env = env.env
            rows[0]["wrappers"] = chain_
        except Exception:  # noqa: BLE001
            pass
    else:
        for key, label in (("ours_wrapped", f'gym.make("{TARGET_ID}").step'),
                           ("ours_unwrapped", f'gym.make("{TARGET_ID}").unwrapped.step')):
            rows.append({"key": key, "label": label, "error":
                         f"import multipendulum.envs: {envs_error}"})
    add("peer_wrapped", f'gym.make("{PEER_A}").step', lambda: gym.make(PEER_A))
    add("peer_unwrapped", f'gym.make("{PEER_A}").unwrapped.step',
        lambda: gym.make(PEER_A).unwrapped)

    st, chain, th0, om0 = core_steppers(mp, 1)
    step, call = core_step(st, 1)
    torques = acrobot_torques(1, k, 1)
    empty = np.zeros(0)

    def core(span, with_states):
        reset, states = st.reset, st.report

        def go():
            reset(0, th0, om0)  # one reset per k steps: keeps the state bounded
            if with_states:
                for u in torques:
                    step(u, empty, span)
                    states()
            else:
                for u in torques:
                    step(u, empty, span)
        return go

    for key, label, span, states in (
            ("core_span", f"core: Steppers(1).step(torques, zeros(0), {CORE_SPAN:g}) "
                          f"({round(CORE_SPAN / core_dt())} RK4 steps)", CORE_SPAN, False),
            ("core_span_states", f"core: the same + report()", CORE_SPAN, True),
            ("core_one", f"core: Steppers(1).step(torques, zeros(0), {core_dt():.4g}) "
                         "(1 RK4 step)", core_dt(), False)):
        rows.append({"key": key, "label": label, "steps": k, "span": span})
        fns[key] = core(span, states)
    fns["core_reset"] = lambda: st.reset(0, th0, om0)
    rows.append({"key": "core_reset", "label": "core: Steppers(1).reset(0, theta0, omega0)",
                 "steps": 1})

    log(f"  timing {', '.join(fns)} ...")
    t = E.measure(fns, repeats, min_time)
    by = {r["key"]: r for r in rows}
    for key, v in t.items():
        r = by[key]
        r["s_per_step"] = [x / r["steps"] for x in v]
        log(f"  {r['label']}: {r['s_per_step'][0] * 1e6:.3g} µs")
    derived = {}
    if "core_span" in t and "core_one" in t:
        n_sub = round(CORE_SPAN / core_dt())
        big, one = by["core_span"]["s_per_step"][0], by["core_one"]["s_per_step"][0]
        per_rk4 = (big - one) / (n_sub - 1)
        derived = {"rk4_step_s": per_rk4, "call_overhead_s": one - per_rk4,
                   "physics_s": n_sub * per_rk4}
        for r in rows:
            if "s_per_step" in r:
                r["over_core"] = r["s_per_step"][0] / big
    for env in keep:
        try:
            env.close()
        except Exception:  # noqa: BLE001
            pass
    return {"rows": rows, "derived": derived, "steps": k, "core_call": call}


# ----------------------------------------------------------------------------- report


def us(v):
    return f"{v * 1e6:.3g} µs"


def us_rng(v):
    return f"{us(v[0])} ({v[1] * 1e6:.3g}–{v[2] * 1e6:.3g})"


def rate_rng(v):
    return f"{v[0]:.3g} ({v[1]:.3g}–{v[2]:.3g})"


def vector_row(rep, key):
    return next((r for r in rep["vector"].get("rows", []) if r["key"] == key), None)


def markdown(rep):
    L = ["## Gymnasium environments: vector throughput and the cost of one step", ""]
    m = rep["machine"]
    L.append(f"{m['cpu']}, {m['cores']} cores; {m['date']}; "
             f"{'--quick' if rep['quick'] else 'full'} run, medians of {rep['repeats']} "
             "repeats timed in alternation (ranges in brackets); gymnasium "
             f"{rep['versions'].get('gymnasium')}, MuJoCo {rep['versions'].get('mujoco')}; "
             f"load average (1, 5, 15 min) {m.get('load', '?')} at the start, "
             f"{rep.get('load_end', '?')} at the end.")
    L.append("")
    if rep.get("busy"):
        L.append("> **Warning:** compiler processes were running during this run: "
                 + "; ".join(rep["busy"][:4]))
        L.append("")
    vec = rep["vector"]
    L.append(f"### {NUM_ENVS} environments stepped together")
    L.append("")
    if "error" in vec:
        L.append(f"Not run: {vec['error']}")
        L.append("")
    else:
        phys = rep.get("peer_physics", {})
        L.append(
            f"Random actions sampled before timing (`envs.action_space.sample()`, seeded; the "
            f"same sequence on every repeat), {vec['k_peer']} vector steps per timed call for "
            f"the peers and {vec['k_ours']} for ours; env-steps per second = {NUM_ENVS} x "
            "vector steps / s. Episodes end and reset inside the timed runs as they come "
            "(each env's own autoreset). Peers: `gym.make_vec(id, num_envs=256, "
            f"vectorization_mode=\"sync\")` (a `SyncVectorEnv`: {NUM_ENVS} Python environments "
            f"stepped one after the other, one thread). Per env step, {PEER_A} integrates "
            f"{phys.get(PEER_A, '?')}; {PEER_B}: {phys.get(PEER_B, '?')}; ours: "
            "`gym.make_vec(id, num_envs=256)` at its defaults, its own vector env, the copies "
            f"run by the core on all {m['cores']} cores ("
            + "; ".join(f"{r['key'].split('/')[-1]}: {settings_text(r)}" for r in vec["rows"]
                        if r["kind"] == "ours" and ("task" in r or "dt" in r))
            + "). The models differ, so apart from AcrobotCompat-v0 (meant to reproduce "
            f"{PEER_A}'s transitions, checked below) no trajectory is compared: this is each "
            "environment's cost at its own physics. The core row is "
            "Acrobot-v0's engine alone (`_core.Steppers` of 256 copies, `step` over 0.2 s then "
            "`report()`), what our vector env costs without its Python layer.")
        L.append("")
        L.append("| environments | vector env | env-steps per second | per vector step | "
                 "episode ends per 1000 env-steps (first pass) | "
                 f"ours / {PEER_A} | ours / {PEER_B} |")
        L.append("|---|---|---|---|---|---|---|")
        for r in vec["rows"]:
            cls = f"`{r['class'].rsplit('.', 1)[-1]}`" if "class" in r else "—"
            if r["kind"] == "core":
                cls = "— (bare core)"
            if "env_steps_per_s" not in r:
                why = r.get("skipped") or (f"failed: {r['error']}" if "error" in r
                                           else "not timed")
                L.append(f"| {r['label']} | {cls} | {why} | — | — | — | — |")
                continue
            ends = r.get("episode_ends_per_1000_env_steps")
            bold = "**" if r["key"] == TARGET_ID else ""
            ra, rb = (("—" if x is None else f"{bold}{x:.0f}x{bold}")
                      for x in (r.get("ratio_peer_a"), r.get("ratio_peer_b")))
            L.append(f"| {r['label']} | {cls} | {rate_rng(r['env_steps_per_s'])} | "
                     f"{E.fmt_time(r['s_per_vector_step'][0])} | "
                     f"{'—' if ends is None else f'{ends:.3g}'} | {ra} | {rb} |")
        L.append("")
        cr = vector_row(rep, OURS[2])
        if cr is not None and "agree_with_peer_a" in cr:
            L.append(f"{OURS[2]} against {PEER_A}, both from `reset(seed=123)` under the same "
                     f"{cr['agree_steps']} vector steps of random actions: observations agree "
                     f"to {cr['agree_with_peer_a']:.1e} (max |difference|) — the same physics, "
                     "one RK4 step of 0.2 s, so this pair alone is a like-for-like comparison.")
            L.append("")
        elif cr is not None and "agree_error" in cr:
            L.append(f"{OURS[2]} against {PEER_A}: the agreement check failed: "
                     f"{cr['agree_error']}")
            L.append("")
        tgt = vector_row(rep, TARGET_ID)
        if tgt is not None and "ratio_peer_a" in tgt and "ratio_peer_b" in tgt:
            va = E.verdict_at_least(tgt["ratio_peer_a"], TARGET_A)
            vb = E.verdict_at_least(tgt["ratio_peer_b"], TARGET_B)
            L.append(f"Targets: {TARGET_ID} at least {TARGET_A:g}x {PEER_A}'s env-steps per "
                     f"second: {tgt['ratio_peer_a']:.0f}x, {va}; at least {TARGET_B:g}x "
                     f"{PEER_B}'s: {tgt['ratio_peer_b']:.0f}x, {vb}.")
            core = vector_row(rep, "core")
            if tgt["ratio_peer_a"] < TARGET_A:
                L.append("")
                L.append(why_missed(rep, tgt, core))
            if core is not None and "env_steps_per_s" in core:
                share = core["env_steps_per_s"][0] and (
                    tgt["env_steps_per_s"][0] / core["env_steps_per_s"][0])
                L.append("")
                if share < 1.0:
                    L.append(f"The vector env runs at {share:.0%} of its bare core's rate "
                             f"({core['env_steps_per_s'][0]:.3g} env-steps/s); the rest is "
                             "its Python layer (actions in, observations, rewards and resets "
                             "out).")
                else:
                    L.append(f"The vector env ran at {share:.0%} of its bare core's rate "
                             f"({core['env_steps_per_s'][0]:.3g} env-steps/s): its Python "
                             "layer is within this run's noise (the two are timed in "
                             "alternation, but the core's two threads suffer most from "
                             "other load on a 2-core machine).")
        else:
            L.append(f"Targets ({TARGET_ID} >= {TARGET_A:g}x {PEER_A}, >= {TARGET_B:g}x "
                     f"{PEER_B}): not measured (see the table).")
        L.append("")
    one = rep["single"]
    L.append("### One environment: the cost of `env.step`")
    L.append("")
    if "error" in one:
        L.append(f"Not run: {one['error']}")
        L.append("")
        return finish(rep, L)
    L.append(f"Microseconds per call from a Python loop of {one['steps']} pre-sampled actions "
             "(a reset where an episode ends, included; the loop itself adds ~0.1 µs). "
             "`gym.make` wraps ours in "
             + (", ".join(f"`{w}`" for w in next((r.get("wrappers") for r in one["rows"]
                                                   if r.get("wrappers")), [])) or "its wrappers")
             + ". The core rows are the same physics as Acrobot-v0 without the environment: "
             "`Steppers(chain._c, 1, method=\"rk4\", rtol=1e-10, atol=1e-12, max_steps=10**8, "
             f"dt={core_dt():.4g})` on `Chain.rods([1, 1], [1, 1])` (Acrobot-v0's default substep), "
             "torques {-1, 0, 1} N m on joint 2, "
             f"reset once per {one['steps']} calls.")
    L.append("")
    L.append("| call | per call | / core step(0.2) |")
    L.append("|---|---|---|")
    for r in one["rows"]:
        if "s_per_step" not in r:
            why = "failed: " + r["error"] if "error" in r else "not timed"
            L.append(f"| `{r['label']}` | {why} | — |")
            continue
        oc = r.get("over_core")
        L.append(f"| `{r['label']}` | {us_rng(r['s_per_step'])} | "
                 f"{'—' if oc is None else f'{oc:.1f}x'} |")
    L.append("")
    d = one.get("derived") or {}
    if d:
        L.append(f"From the two core spans: one RK4 step of the double pendulum costs "
                 f"{E.fmt_time(d['rk4_step_s'])}, so Acrobot-v0's physics per env step is "
                 f"{us(d['physics_s'])}, and the Python -> Rust -> Python call itself "
                 f"(argument checks, the GIL released and taken back) {us(d['call_overhead_s'])}.")
        by = {r["key"]: r for r in one["rows"]}
        w, u = by.get("ours_wrapped", {}), by.get("ours_unwrapped", {})
        core = by.get("core_span_states", by.get("core_span", {}))
        if "s_per_step" in w and "s_per_step" in u and "s_per_step" in core:
            wrap = w["s_per_step"][0] - u["s_per_step"][0]
            wrap_text = (f"{us(wrap)} is gym.make's wrappers" if wrap > 0 else
                         "gym.make's wrappers cost nothing measurable here (the difference, "
                         f"{us(wrap)}, is within the noise)")
            L.append(f"Of ours' {us(w['s_per_step'][0])} per wrapped step, {wrap_text}, "
                     f"and {us(u['s_per_step'][0] - core['s_per_step'][0])} is the "
                     "environment's own Python (action to torques, observation, reward, "
                     "termination, info) over the core's step + report().")
        pa = by.get("peer_unwrapped", {})
        if "s_per_step" in pa and "s_per_step" in u:
            L.append(f"Unwrapped, ours takes {u['s_per_step'][0] / pa['s_per_step'][0]:.2f}x "
                     f"the time of {PEER_A}'s step (which integrates one RK4 step of 0.2 s in "
                     f"NumPy, ours {round(CORE_SPAN / core_dt())}).")
        L.append("")
    return finish(rep, L)


def why_missed(rep, tgt, core):
    """The 100x target against Acrobot-v1, in the terms of the core's own step."""
    peer = vector_row(rep, "peer_a")
    need = TARGET_A * peer["env_steps_per_s"][0]  # env-steps/s
    cores = rep["machine"]["cores"] or 1
    t = tgt.get("task") or {}
    sub = t.get("substeps", round(CORE_SPAN / core_dt()))
    per_rk4 = cores / need / sub  # s of one core per RK4 step, with nothing else to pay
    text = (f"Why the {TARGET_A:g}x target is missed: it needs {need:.3g} env-steps/s, "
            f"{E.fmt_time(1 / need)} of wall time per env step; spread over {cores} cores "
            f"that leaves {E.fmt_time(per_rk4)} of one core per RK4 step for Acrobot-v0's "
            f"{sub} substeps, with nothing else paid (Acrobot-v1 integrates one RK4 step per "
            "env step).")
    if core is not None and "env_steps_per_s" in core:
        text += (f" The bare core alone (no Python layer at all) reaches "
                 f"{core['env_steps_per_s'][0]:.3g} env-steps/s, "
                 f"{core['env_steps_per_s'][0] / peer['env_steps_per_s'][0]:.0f}x {PEER_A}")
        # The bank's cost per RK4 step of one copy, on one core: from the bare core's rate over
        # all cores (a lone copy pays for a whole group of eight lanes; see the single-env rows).
        per_step = cores / core["env_steps_per_s"][0] / sub
        text += (f"; in the SIMD lanes an RK4 step of one copy costs {E.fmt_time(per_step)} of one "
                 f"core there, {per_step / per_rk4:.1f}x the budget")
        if core["env_steps_per_s"][0] < need:
            text += (": the target is out of the environment layer's reach at these defaults; "
                     "it needs a cheaper core step or fewer substeps per env step.")
        else:
            text += (": the core alone would meet it, so the gap is the vector env's Python "
                     "layer.")
    return text


def finish(rep, L):
    if rep["quick"]:
        L.append("(--quick: fewer steps and shorter timings; numbers are indicative only.)")
        L.append("")
    return "\n".join(L) + "\n"


def versions():
    import importlib.metadata as md

    out = {}
    for dist in ("gymnasium", "mujoco", "numpy"):
        try:
            out[dist] = md.version(dist)
        except md.PackageNotFoundError:
            out[dist] = "not installed"
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shorter timings (about a minute)")
    ap.add_argument("--repeats", type=int, default=None, help="repeats per measurement (>= 3)")
    ap.add_argument("--json", type=Path, default=BUILD / "envs.json",
                    help="write the results as JSON here (default bench/build/envs.json)")
    ap.add_argument("--md", type=Path, help="write the markdown section here (else printed)")
    ap.add_argument("--only", default="12", help="parts to run: 1 vector envs, 2 one env")
    args = ap.parse_args(argv)
    repeats = max(3, args.repeats or (5 if args.quick else 7))
    busy = E.busy_compilers()
    if busy:
        log("warning: compiler processes are running; timings will be skewed")
    import gymnasium as gym
    import multipendulum as mp

    t0 = time.perf_counter()
    rep = {"machine": E.run_machine(), "quick": args.quick, "repeats": repeats,
           "multipendulum": getattr(mp, "__version__", "?"), "versions": versions(),
           "peer_physics": peer_physics(gym)}
    rep["vector"] = {"error": "left out with --only"}
    rep["single"] = {"error": "left out with --only"}
    if "1" in args.only:
        log(f"vector environments, {NUM_ENVS} copies ...")
        try:
            rep["vector"] = bench_vector(mp, gym, args.quick, repeats)
        except Exception as exc:  # noqa: BLE001 - reported in the section, not fatal
            rep["vector"] = {"error": err_text(exc)}
            log(f"  failed: {rep['vector']['error']}")
    if "2" in args.only:
        log("one environment: the cost of a step ...")
        try:
            rep["single"] = bench_single(mp, gym, args.quick, repeats)
        except Exception as exc:  # noqa: BLE001
            rep["single"] = {"error": err_text(exc)}
            log(f"  failed: {rep['single']['error']}")
    rep["busy"] = sorted(set(busy) | set(E.busy_compilers()))
    if hasattr(os, "getloadavg"):
        rep["load_end"] = " ".join(f"{x:.2f}" for x in os.getloadavg())
    rep["seconds"] = time.perf_counter() - t0
    md = markdown(rep)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(rep, indent=1, default=str) + "\n")
    if args.md:
        args.md.write_text(md)
    else:
        print(md)
    log(f"done in {rep['seconds']:.0f} s")
    failed = [k for k in ("vector", "single")
              if isinstance(rep[k], dict) and "error" in rep[k]
              and rep[k]["error"] != "left out with --only"]
    failed += [r["key"] for r in rep["vector"].get("rows", []) if "error" in r]
    failed += [r["key"] for r in rep["single"].get("rows", []) if "error" in r]
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
