"""Engine benchmarks: multipendulum against peers measured in the same run.

A part of the benchmark harness: bench/bench.py (``make bench``) imports its helpers (timing in
alternation, medians, machine information, verdicts, the C peer) and its three workloads below,
and puts their sections into bench/RESULTS.md. Run alone it writes bench/build/RESULTS-engine.md:
    bench/.venv/bin/python bench/bench_engine.py [--quick]

Three comparisons, each reported as a ratio against a peer timed on this machine in this run
(never as a timed assertion in a test):

1. Double pendulum, classical RK4, ns per step: ``mp.simulate(method="rk4", dt=...)`` against
   the plain C program ``bench/c/double_pendulum.c`` compiled with ``cc -O3`` (no -march, no
   fast-math: the Rust build uses neither). Both must end in the same state (to 1e-9) before
   the times are compared; a peer that disagrees is reported, not timed.
2. ``chain.accelerations`` cost for N = 10, 100, 1000, 10000 (per call, Python call included),
   the call overhead measured at N = 1, the growth exponent of (time - overhead) against N, and
   the dense Cholesky route (``algorithm="cholesky"``) for N <= 1000.
3. Double pendulum over 100 s: SciPy ``solve_ivp(method="DOP853")`` with a NumPy right-hand
   side against ``mp.simulate(method="dop853")`` at equal final error, found by scanning the
   tolerance of each and interpolating time against error on log-log axes.

Every time is the median of at least 5 repeats.
"""

from __future__ import annotations

import argparse
import datetime
import gc
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parent
C_SOURCE = BENCH / "c" / "double_pendulum.c"
BUILD = BENCH / "build"
C_EXE = BUILD / "double_pendulum"
RESULTS = BUILD / "RESULTS-engine.md"
C_FLAGS = ["-O3", "-std=c99"]

# The double pendulum every comparison uses: two unit point masses on unit rods.
L1, L2, M1, M2, G = 1.0, 1.0, 1.0, 1.0, 9.81
# Mild, regular (non-chaotic) motion: at high energy the double pendulum's Lyapunov time is
# about a second, so over 100 s rounding alone would decide the final state and no method's
# "error" would mean anything.
THETA0 = (0.5, 0.3)
OMEGA0 = (0.0, 0.0)

TARGET_RK4_RATIO = 1.0  # multipendulum time / C time, at most
TARGET_ACC_10K_S = 0.3e-3  # seconds per accelerations call at N = 10000, at most
TARGET_GROWTH = 1.10  # fitted exponent of (time - overhead) ~ N^k, at most (linear is 1)
TARGET_DOP853_SPEEDUP = 300.0  # SciPy time / multipendulum time at equal error, at least
AGREE_TOL = 1e-9


# ----------------------------------------------------------------------------- timing helpers


def measure(fns, repeats, min_time):
    """Median seconds per call of each ``fns[key]()``, timed round-robin.

    Each function gets one warm-up call, then a batch size k so one batch lasts about
    ``min_time`` seconds. The batches are interleaved (repeat 1 of every function, then repeat
    2, ...) so that load from other processes or clock changes hit every contender alike. The
    garbage collector is off while timing, as in ``timeit``.
    Returns {key: (median, min, max)} in seconds per call.
    """
    ks = {}
    for key, fn in fns.items():
        t0 = time.perf_counter()
        fn()
        first = time.perf_counter() - t0
        ks[key] = max(1, math.ceil(min_time / max(first, 1e-9)))
    per_call = {key: [] for key in fns}
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        for _ in range(repeats):
            for key, fn in fns.items():
                k = ks[key]
                t0 = time.perf_counter()
                for _ in range(k):
                    fn()
                per_call[key].append((time.perf_counter() - t0) / k)
    finally:
        if gc_was_enabled:
            gc.enable()
    return {key: (float(np.median(v)), float(min(v)), float(max(v)))
            for key, v in per_call.items()}


def fmt_time(seconds):
    if seconds is None or not math.isfinite(seconds):
        return "n/a"
    for unit, scale in (("s", 1.0), ("ms", 1e-3), ("µs", 1e-6), ("ns", 1e-9)):
        if seconds >= scale:
            return f"{seconds / scale:.3g} {unit}"
    return f"{seconds / 1e-9:.3g} ns"


def verdict_at_most(value, target):
    if value <= target:
        return f"met ({(1 - value / target) * 100:.0f}% under)"
    return f"**missed** by {(value / target - 1) * 100:.0f}%"


def verdict_at_least(value, target):
    if value >= target:
        return f"met ({(value / target - 1) * 100:.0f}% over)"
    return f"**missed** by {(1 - value / target) * 100:.0f}% (needs {target / value:.2f}x more)"


def busy_compilers():
    """Compiler processes running now (they would skew any timing on a 2-core machine)."""
    if shutil.which("pgrep") is None:
        return []
    # Match process names exactly (-x): command lines of unrelated processes can mention cargo.
    found = []
    for name in ("rustc", "cargo", "maturin", "cc1", "ld"):
        out = subprocess.run(["pgrep", "-l", "-x", name], capture_output=True, text=True)
        found += [line for line in out.stdout.splitlines() if line]
    return found


# ----------------------------------------------------------------------------- machine info


def cpu_name():
    """The CPU's model name (/proc/cpuinfo), else what platform knows."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return cpu


def run_machine():
    """The machine line of a workload run as a subprocess (bench_model, bench_envs): CPU, cores,
    OS, Python and NumPy, the date and the load average."""
    import datetime

    import numpy as np

    return {"cpu": cpu_name(), "cores": os.cpu_count(), "os": platform.platform(),
            "python": platform.python_version(), "numpy": np.__version__,
            "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "load": " ".join(f"{x:.2f}" for x in os.getloadavg()) if hasattr(os, "getloadavg") else ""}


def machine_info():
    cpu = cpu_name()
    cc = subprocess.run(["cc", "--version"], capture_output=True, text=True).stdout
    rustc = ""
    if shutil.which("rustc"):
        rustc = subprocess.run(["rustc", "--version"], capture_output=True, text=True).stdout
    import scipy

    info = {
        "platform": platform.platform(),
        "cpu": cpu,
        "os.cpu_count()": os.cpu_count(),
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "cc": cc.splitlines()[0] if cc else "not found",
        "rustc (on PATH; not necessarily the one that built the extension)": (
            rustc.strip() or "not found"),
    }
    if hasattr(os, "getloadavg"):
        info["load average at start (1, 5, 15 min)"] = " ".join(
            f"{x:.2f}" for x in os.getloadavg())
    return info


# ----------------------------------------------------------------------------- the C peer


def build_c():
    BUILD.mkdir(exist_ok=True)
    cmd = ["cc", *C_FLAGS, "-o", str(C_EXE), str(C_SOURCE), "-lm"]
    subprocess.run(cmd, check=True)
    return " ".join(["cc", *C_FLAGS, "bench/c/double_pendulum.c", "-lm"])


def run_c(steps, dt, repeats):
    args = [str(C_EXE), str(steps), repr(dt), *map(repr, THETA0), *map(repr, OMEGA0),
            *map(repr, (L1, L2, M1, M2, G)), str(repeats)]
    out = subprocess.run(args, check=True, capture_output=True, text=True).stdout
    return json.loads(out)


# ----------------------------------------------------------------------------- 1. RK4 vs C


def bench_rk4(mp, quick, repeats):
    # dt a power of two, so t_end = steps * dt = 100 s is exact and both sides take exactly
    # `steps` steps.
    dt = 2.0**-12
    steps = 100 * 2**12
    t_end = steps * dt
    res = {"dt": dt, "steps": steps, "t_end": t_end}

    chain = mp.Chain(lengths=[L1, L2], masses=[M1, M2], g=G)
    theta0 = np.array(THETA0)
    omega0 = np.array(OMEGA0)

    def run():
        return mp.simulate(chain, theta0, omega0, t_end, method="rk4", dt=dt, t_eval=[t_end])

    c = run_c(steps, dt, 1)
    res["c_final"] = c["final"]
    sol = run()
    final = np.concatenate([np.asarray(sol.theta)[-1], np.asarray(sol.omega)[-1]])
    res["mp_final"] = final.tolist()
    res["mp_steps"] = int(sol.stats.steps)
    res["mp_t_last"] = float(np.asarray(sol.t)[-1])
    res["diff"] = float(np.max(np.abs(final - np.array(c["final"]))))
    res["agree"] = res["diff"] <= AGREE_TOL and res["mp_steps"] == steps
    if not res["agree"]:
        return res

    # Alternate the two contenders, one C process (its loop timed inside) and one simulate call
    # per repeat, so background load hits both alike.
    c_ns, mp_ns = [], []
    for _ in range(repeats):
        c_ns.append(run_c(steps, dt, 1)["ns_per_step"])
        t0 = time.perf_counter()
        run()
        mp_ns.append((time.perf_counter() - t0) / steps * 1e9)
    res["c_ns"] = float(np.median(c_ns))
    res["c_ns_range"] = (min(c_ns), max(c_ns))
    res["mp_ns"] = float(np.median(mp_ns))
    res["mp_ns_range"] = (min(mp_ns), max(mp_ns))
    res["ratio"] = res["mp_ns"] / res["c_ns"]

    core = getattr(mp, "_core", None)
    res["hooks"] = sorted(n for n in dir(core) if "bench" in n.lower()) if core else []
    return res


# ----------------------------------------------------------------------------- 2. accelerations


def bench_accelerations(mp, quick, repeats):
    min_time = 0.02 if quick else 0.05
    rng = np.random.default_rng(12345)
    rows, fns = [], {}
    for n in (1, 10, 100, 1000, 10000):
        chain = mp.Chain(lengths=np.ones(n), masses=np.ones(n), g=G)
        theta = np.ascontiguousarray(rng.uniform(-0.5, 0.5, n))
        omega = np.ascontiguousarray(rng.uniform(-1.0, 1.0, n))
        acc = chain.accelerations
        row = {"n": n}
        fns[("rec", n)] = lambda acc=acc, theta=theta, omega=omega: acc(theta, omega)
        if 10 <= n <= 1000:
            try:
                a_rec = np.asarray(acc(theta, omega, algorithm="recursive"))
                a_chol = np.asarray(acc(theta, omega, algorithm="cholesky"))
            except (TypeError, ValueError) as exc:  # route not offered
                row["chol_error"] = f"{type(exc).__name__}: {exc}"
            else:
                scale = max(1.0, float(np.max(np.abs(a_rec))))
                row["chol_diff"] = float(np.max(np.abs(a_rec - a_chol))) / scale
                if row["chol_diff"] <= 1e-8:
                    fns[("chol", n)] = (lambda acc=acc, theta=theta, omega=omega:
                                        acc(theta, omega, algorithm="cholesky"))
        rows.append(row)
    # More repeats than elsewhere: the small sizes differ from the N = 1 overhead by well under
    # a microsecond, so their medians need to be tight for the fit to mean anything.
    times = measure(fns, max(repeats, 15), min_time)
    for row in rows:
        n = row["n"]
        row["rec"], row["rec_lo"], row["rec_hi"] = times[("rec", n)]
        if ("chol", n) in times:
            row["chol"] = times[("chol", n)][0]

    overhead = rows[0]["rec"]
    ns = np.array([r["n"] for r in rows[1:]], dtype=float)
    net = np.array([r["rec"] - overhead for r in rows[1:]])
    for r, v in zip(rows[1:], net):
        r["net"] = v
    ok = net > 0
    fit = {"overhead": overhead, "used": ns[ok].astype(int).tolist()}
    if ok.sum() >= 2:
        fit["exponent"] = float(np.polyfit(np.log(ns[ok]), np.log(net[ok]), 1)[0])
    if net[-1] > 0 and net[-2] > 0:
        fit["tail_exponent"] = float(math.log(net[-1] / net[-2]) / math.log(ns[-1] / ns[-2]))
    return rows, fit


# ----------------------------------------------------------------------------- 3. DOP853 vs SciPy


def numpy_rhs(t, y):
    """Double-pendulum right-hand side as a NumPy user writes it (same closed form as the C)."""
    th1, th2, w1, w2 = y
    d = th1 - th2
    s, c = np.sin(d), np.cos(d)
    s1, s2 = np.sin(th1), np.sin(th2)
    den = M1 + M2 * s * s
    a1 = (-M2 * L2 * w2 * w2 * s - (M1 + M2) * G * s1 - M2 * c * (L1 * w1 * w1 * s - G * s2)) / (
        L1 * den)
    a2 = ((M1 + M2) * (L1 * w1 * w1 * s - G * s2 + G * s1 * c) + M2 * L2 * w2 * w2 * s * c) / (
        L2 * den)
    return np.array([w1, w2, a1, a2])


def bench_dop853(mp, quick, repeats):
    from scipy.integrate import solve_ivp

    t_end = 100.0
    y0 = np.array([*THETA0, *OMEGA0])
    chain = mp.Chain(lengths=[L1, L2], masses=[M1, M2], g=G)
    theta0, omega0 = np.array(THETA0), np.array(OMEGA0)

    def run_scipy(rtol):
        r = solve_ivp(numpy_rhs, (0.0, t_end), y0, method="DOP853", rtol=rtol, atol=rtol,
                      t_eval=[t_end])
        if not r.success:
            raise RuntimeError(f"solve_ivp failed at rtol={rtol}: {r.message}")
        return r.y[:, -1], int(r.nfev)

    def run_mp(rtol):
        sol = mp.simulate(chain, theta0, omega0, t_end, method="dop853", rtol=rtol, atol=rtol,
                          t_eval=[t_end])
        final = np.concatenate([np.asarray(sol.theta)[-1], np.asarray(sol.omega)[-1]])
        return final, int(sol.stats.evaluations)

    # Three independent references: each library at its tightest, and the C RK4 at dt = 2^-14.
    refs = {
        "multipendulum dop853 rtol=atol=1e-13": run_mp(1e-13)[0],
        "scipy DOP853 rtol=atol=1e-13": run_scipy(1e-13)[0],
        "C rk4 dt=2^-14": np.array(run_c(int(t_end * 2**14), 2.0**-14, 1)["final"]),
    }
    stack = np.array(list(refs.values()))
    ref = np.median(stack, axis=0)
    spread = max(float(np.max(np.abs(a - b))) for a in stack for b in stack)
    res = {"t_end": t_end, "refs": {k: v.tolist() for k, v in refs.items()}, "ref": ref.tolist(),
           "spread": spread, "agree": spread <= AGREE_TOL}
    res["rhs_call"] = measure({"rhs": lambda: numpy_rhs(0.0, y0)}, repeats, 0.02)["rhs"][0]
    if not res["agree"]:
        return res

    exps = [6, 8, 10, 12] if quick else [5, 5.5, 6, 6.5, 7, 7.5, 8, 8.5, 9, 9.5, 10, 10.5, 11,
                                         11.5, 12]
    runners = {"scipy": run_scipy, "mp": run_mp}
    scans = {name: [] for name in runners}
    fns = {}
    for e in exps:
        rtol = 10.0**-e
        for name, runner in runners.items():
            final, nfev = runner(rtol)
            scans[name].append({"rtol": rtol, "err": float(np.max(np.abs(final - ref))),
                                "nfev": nfev})
            fns[(name, rtol)] = lambda runner=runner, rtol=rtol: runner(rtol)
    # All runs of both libraries interleaved, so load from elsewhere falls on both alike.
    times = measure(fns, repeats, 0.0 if quick else 0.03)
    for name, rows in scans.items():
        for row in rows:
            row["time"] = times[(name, row["rtol"])][0]
    res["scans"] = scans

    # Equal error: the final error is not monotone in the tolerance (it oscillates with the
    # phase of the error at t = 100), so fit log(time) = a + b log(error) by least squares for
    # each library, over errors well above the references' own disagreement, and compare the
    # fitted times at each decade of error both scans cover.
    floor = 10.0 * max(spread, 1e-15)
    fits = {}
    for name, rows in scans.items():
        pts = [(math.log10(r["err"]), math.log10(r["time"])) for r in rows if r["err"] > floor]
        if len(pts) >= 2:
            x, y = np.array(pts).T
            fits[name] = (np.polyfit(x, y, 1), x.min(), x.max())
    res["fits"] = {k: v[0].tolist() for k, v in fits.items()}
    compared = []
    if len(fits) == 2:
        lo = max(f[1] for f in fits.values())
        hi = min(f[2] for f in fits.values())
        targets = [float(k) for k in range(math.ceil(lo), math.floor(hi) + 1)]
        if not targets and lo <= hi:
            targets = [0.5 * (lo + hi)]
        for x in targets:
            t_s = 10.0 ** np.polyval(fits["scipy"][0], x)
            t_m = 10.0 ** np.polyval(fits["mp"][0], x)
            compared.append({"err": 10.0**x, "scipy": t_s, "mp": t_m, "ratio": t_s / t_m})
    res["compared"] = compared
    return res


# ----------------------------------------------------------------------------- report


def render(info, args, c_cmd, versions, rk4, acc_rows, acc_fit, dop, elapsed, busy):
    L = []
    mode = "--quick" if args.quick else "full"
    L.append("# Engine benchmarks")
    L.append("")
    L.append(f"Generated by `bench/bench_engine.py` ({mode} run, {elapsed:.0f} s) on "
             f"{datetime.datetime.now().astimezone().isoformat(timespec='seconds')}. "
             "Speeds are ratios against a peer timed in the same run, the two timed in "
             "alternation so background load falls on both; every time is the median of "
             f"{args.repeats} repeats ({max(args.repeats, 15)} for the accelerations).")
    L.append("")
    if busy:
        L.append("> **Warning:** compiler processes were running during the run; the numbers "
                 "are skewed: " + "; ".join(busy[:5]))
        L.append("")
    L.append("## Machine")
    L.append("")
    L.append("| | |")
    L.append("|---|---|")
    for k, v in {**info, **versions}.items():
        L.append(f"| {k} | {v} |")
    L.append(f"| C peer build | `{c_cmd}` |")
    L.append("")

    # Summary
    L.append("## Summary")
    L.append("")
    L.append("| Measurement | multipendulum | peer | ratio | target | result |")
    L.append("|---|---|---|---|---|---|")
    if rk4.get("agree"):
        L.append(f"| double pendulum rk4, per step (simulate route) | {rk4['mp_ns']:.1f} ns | "
                 f"C -O3: {rk4['c_ns']:.1f} ns | {rk4['ratio']:.2f}x C time | "
                 f"<= {TARGET_RK4_RATIO:.1f}x | "
                 f"{verdict_at_most(rk4['ratio'], TARGET_RK4_RATIO)} |")
    else:
        L.append("| double pendulum rk4, per step | not timed | C disagrees | — | "
                 f"<= {TARGET_RK4_RATIO:.1f}x | **final states disagree** (see below) |")
    r10k = next(r for r in acc_rows if r["n"] == 10000)
    L.append(f"| accelerations, N = 10000, per call | {fmt_time(r10k['rec'])} | — | — | "
             f"< {fmt_time(TARGET_ACC_10K_S)} | {verdict_at_most(r10k['rec'], TARGET_ACC_10K_S)} |")
    if "exponent" in acc_fit:
        L.append(f"| accelerations growth exponent k, (t - t(N=1)) ~ N^k, N = 10..10000 | "
                 f"{acc_fit['exponent']:.3f} | — | — | linear (k <= {TARGET_GROWTH}) | "
                 f"{verdict_at_most(acc_fit['exponent'], TARGET_GROWTH)} |")
    if dop.get("compared"):
        worst = min(dop["compared"], key=lambda c: c["ratio"])
        L.append(f"| double pendulum 100 s dop853 at equal final error (worst of "
                 f"{len(dop['compared'])} error levels: {worst['err']:.0e}) | "
                 f"{fmt_time(worst['mp'])} | SciPy DOP853: {fmt_time(worst['scipy'])} | "
                 f"{worst['ratio']:.3g}x faster | >= {TARGET_DOP853_SPEEDUP:.0f}x | "
                 f"{verdict_at_least(worst['ratio'], TARGET_DOP853_SPEEDUP)} |")
    elif not dop.get("agree"):
        L.append("| double pendulum 100 s dop853 vs SciPy | not timed | — | — | "
                 f">= {TARGET_DOP853_SPEEDUP:.0f}x | **references disagree** (see below) |")
    else:
        L.append("| double pendulum 100 s dop853 vs SciPy | — | — | — | "
                 f">= {TARGET_DOP853_SPEEDUP:.0f}x | no overlapping error range |")
    L.append("")

    # RK4 details
    L.append("## 1. Double pendulum, classical RK4")
    L.append("")
    L.append(f"Point masses, l = ({L1}, {L2}) m, m = ({M1}, {M2}) kg, g = {G} m/s², "
             f"theta0 = {THETA0} rad, omega0 = {OMEGA0}; dt = 2^-12 s, {rk4['steps']} steps "
             f"(t_end = {rk4['t_end']:g} s). multipendulum: wall time of "
             "`mp.simulate(chain, theta0, omega0, t_end, method=\"rk4\", dt=dt, t_eval=[t_end])`"
             " divided by the step count, nothing subtracted. C: `bench/c/double_pendulum.c`, "
             "closed-form accelerations (one sincos of theta1 - theta2 and one sin of each "
             "angle per evaluation), one process per repeat, only its step loop timed with "
             "`clock_gettime(CLOCK_MONOTONIC)` (so process start-up is not charged to C).")
    L.append("")
    L.append(f"- steps taken by multipendulum: {rk4['mp_steps']} (expected {rk4['steps']}); "
             f"last time {rk4['mp_t_last']!r}")
    L.append(f"- final state, C:             {', '.join(f'{v:.15g}' for v in rk4['c_final'])}")
    L.append(f"- final state, multipendulum: {', '.join(f'{v:.15g}' for v in rk4['mp_final'])}")
    L.append(f"- max |difference|: {rk4['diff']:.2e} (required <= {AGREE_TOL:g})")
    if rk4.get("agree"):
        lo, hi = rk4["mp_ns_range"]
        L.append(f"- multipendulum per step: median {rk4['mp_ns']:.2f} ns "
                 f"(range {lo:.2f}–{hi:.2f}); C: median {rk4['c_ns']:.2f} ns (range "
                 f"{rk4['c_ns_range'][0]:.2f}–{rk4['c_ns_range'][1]:.2f}); per evaluation "
                 f"(4 per step): {rk4['mp_ns'] / 4:.1f} ns against {rk4['c_ns'] / 4:.1f} ns; "
                 f"ratio of the fastest repeats (less sensitive to background load): "
                 f"{lo / rk4['c_ns_range'][0]:.2f}x")
        if rk4["hooks"]:
            L.append(f"- lower-level benchmark hooks found in `multipendulum._core` (not timed "
                     f"here, signature unknown to this script): {', '.join(rk4['hooks'])}")
        else:
            L.append("- the package exposes no lower-level step benchmark hook; only the "
                     "simulate route is timed")
    L.append("")

    # Accelerations
    L.append("## 2. `chain.accelerations` cost against N")
    L.append("")
    L.append("Point-mass chain of unit links and masses, theta ~ U(-0.5, 0.5) rad, omega ~ "
             "U(-1, 1) rad/s (fixed seed). Per call, Python call included; N = 1 measures the "
             "call overhead, subtracted before the fit. The dense route "
             "(`algorithm=\"cholesky\"`, O(N^3)) is timed for N <= 1000 once it agrees with the "
             "recursive one to 1e-8 (relative).")
    L.append("")
    L.append("| N | recursive, per call | minus N=1 overhead | per link | cholesky, per call | "
             "cholesky / recursive | max rel. difference |")
    L.append("|---|---|---|---|---|---|---|")
    for r in acc_rows:
        net, chol, diff = r.get("net"), r.get("chol"), r.get("chol_diff")
        if chol is not None:
            chol_txt, chol_ratio = fmt_time(chol), f"{chol / r['rec']:.1f}x"
        elif diff is not None:
            chol_txt, chol_ratio = "**disagrees, not timed**", "—"
        else:
            chol_txt, chol_ratio = r.get("chol_error", "—"), "—"
        net_txt = "(the overhead)" if net is None else fmt_time(net) if net > 0 else "<= 0"
        per_link = fmt_time(net / r["n"]) if net is not None and net > 0 else "—"
        diff_txt = f"{diff:.1e}" if diff is not None else "—"
        L.append(f"| {r['n']} | {fmt_time(r['rec'])} | {net_txt} | {per_link} | {chol_txt} | "
                 f"{chol_ratio} | {diff_txt} |")
    L.append("")
    if "exponent" in acc_fit:
        L.append(f"Least-squares slope of log(t - t(N=1)) against log N over N = "
                 f"{acc_fit['used']}: **{acc_fit['exponent']:.3f}**"
                 + (f"; between N = 1000 and 10000 alone: {acc_fit['tail_exponent']:.3f}"
                    if "tail_exponent" in acc_fit else "") + ".")
    L.append("")

    # DOP853
    L.append("## 3. Double pendulum over 100 s: DOP853 against SciPy at equal error")
    L.append("")
    L.append(f"Same chain and initial state as in 1 (theta0 = {THETA0} rad: mild, regular "
             "motion, chosen because at high energy the double pendulum is chaotic with a "
             "Lyapunov time of about a second, so over 100 s no final state is reproducible). "
             "SciPy `solve_ivp(numpy_rhs, (0, 100), y0, method=\"DOP853\", rtol=r, atol=r, "
             "t_eval=[100])` with the closed-form right-hand side written in NumPy "
             f"({fmt_time(dop['rhs_call'])} per call here); multipendulum "
             "`mp.simulate(..., method=\"dop853\", rtol=r, atol=r, t_eval=[100])`. Error = max "
             "|final state - reference| over (theta1, theta2, omega1, omega2).")
    L.append("")
    L.append("References (final theta1, theta2, omega1, omega2); the reference is their "
             "component-wise median:")
    L.append("")
    for k, v in dop["refs"].items():
        L.append(f"- {k}: {', '.join(f'{x:.15g}' for x in v)}")
    L.append(f"- largest disagreement between references: {dop['spread']:.1e} (required <= "
             f"{AGREE_TOL:g}); scan points with error below 10x this are not used")
    L.append("")
    if dop.get("scans"):
        L.append("| rtol = atol | SciPy error | SciPy time | SciPy nfev | multipendulum error | "
                 "multipendulum time | multipendulum evaluations | SciPy / multipendulum time |")
        L.append("|---|---|---|---|---|---|---|---|")
        for s, m in zip(dop["scans"]["scipy"], dop["scans"]["mp"]):
            L.append(f"| {s['rtol']:.1e} | {s['err']:.2e} | {fmt_time(s['time'])} | {s['nfev']} "
                     f"| {m['err']:.2e} | {fmt_time(m['time'])} | {m['nfev']} | "
                     f"{s['time'] / m['time']:.3g}x |")
        L.append("")
        sp_eval = float(np.median([r["time"] / r["nfev"] for r in dop["scans"]["scipy"]]))
        mp_eval = float(np.median([r["time"] / r["nfev"] for r in dop["scans"]["mp"]]))
        need = sp_eval / TARGET_DOP853_SPEEDUP
        L.append(f"Per right-hand-side evaluation (median over the scan, everything included): "
                 f"SciPy {fmt_time(sp_eval)}, multipendulum dop853 {fmt_time(mp_eval)}. Both "
                 "take nearly the same steps at the same tolerance (same method, same error "
                 "control), so the speed-up is about the ratio of these: "
                 f"{sp_eval / mp_eval:.3g}x. "
                 f"A {TARGET_DOP853_SPEEDUP:.0f}x speed-up needs at most {fmt_time(need)} per "
                 "evaluation" + (
                     f"; for scale, the C peer of section 1 spends {rk4['c_ns'] / 4:.1f} ns per "
                     "evaluation (closed-form accelerations plus the RK4 update)."
                     if "c_ns" in rk4 else "."))
        L.append("")
    if dop.get("compared"):
        fs, fm = dop["fits"]["scipy"], dop["fits"]["mp"]
        L.append("At equal final error, from least-squares lines log10(time) = a + b log10(error) "
                 f"(SciPy: b = {fs[0]:.3f}; multipendulum: b = {fm[0]:.3f}; the final error is "
                 "not monotone in the tolerance, so a fit is steadier than joining the points):")
        L.append("")
        L.append("| final error | SciPy time | multipendulum time | speed-up |")
        L.append("|---|---|---|---|")
        for c in dop["compared"]:
            L.append(f"| {c['err']:.0e} | {fmt_time(c['scipy'])} | {fmt_time(c['mp'])} | "
                     f"{c['ratio']:.3g}x |")
        L.append("")
    return "\n".join(L) + "\n"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="smaller step counts and scans (< 2 min)")
    p.add_argument("--repeats", type=int, default=None, help="repeats per measurement (>= 5)")
    args = p.parse_args(argv)
    args.repeats = max(5, args.repeats or (5 if args.quick else 7))

    start = time.perf_counter()
    busy = busy_compilers()
    if busy:
        print("warning: compiler processes are running; timings will be skewed:", *busy,
              sep="\n  ", file=sys.stderr)
    info = machine_info()
    c_cmd = build_c()

    import multipendulum as mp

    versions = {"multipendulum": getattr(mp, "__version__", "unknown")
                + f" ({Path(mp.__file__).parent})"}

    print("rk4 against C ...", file=sys.stderr)
    rk4 = bench_rk4(mp, args.quick, args.repeats)
    print("accelerations ...", file=sys.stderr)
    acc_rows, acc_fit = bench_accelerations(mp, args.quick, args.repeats)
    print("dop853 against SciPy ...", file=sys.stderr)
    dop = bench_dop853(mp, args.quick, args.repeats)

    busy = sorted(set(busy) | set(busy_compilers()))
    if hasattr(os, "getloadavg"):
        info["load average at end (1, 5, 15 min)"] = " ".join(f"{x:.2f}" for x in os.getloadavg())
    report = render(info, args, c_cmd, versions, rk4, acc_rows, acc_fit, dop,
                    time.perf_counter() - start, busy)
    RESULTS.write_text(report, encoding="utf-8")
    print(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
