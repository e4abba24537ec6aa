"""An ensemble of triple pendulums in lanes against a hand-vectorised C peer (issue 14).

Run:  python bench/bench_ensemble.py [--quick] [--json OUT.json] [--md OUT.md]
(needs only multipendulum and a C compiler with OpenMP; without --json/--md the markdown
section is printed).

Workload: 16384 equal point-mass triple pendulums (l = m = 1, g = 9.81) released from rest at
angles drawn uniformly from [-0.5, 0.5] rad (a fixed seed; regular motion, so that two
different but correct integrations agree on the final states), classical RK4, dt = 0.01,
1000 steps. Ours: `mp.ensemble(chain, theta0, 0, 10.0, method="rk4", dt=0.01)` (the lanes;
final states, momenta, energy errors and first flips), wall time of the call. The peer:
bench/c/ensemble_omp.c as the issue describes it (OpenMP across blocks of 8 trajectories,
`omp simd` across them, -O3 -march=native -ffast-math with libmvec's sin/cos, the dense mass
matrix solved by Gaussian elimination), its integration loop timed inside the program. Both on
all cores (2 threads), medians of alternating repeats; the peer must first agree with ours on
the final states (1e-8). The issue's target: at least 3x the peer's trajectory-steps/s.

Also (j2): `mp.ensemble` with its default method, dop853 at its default tolerances, of 2048 equal
point-mass chains of N = 2, 3 and 8 links released from rest at angles in [-0.5, 0.5] rad over
10 s: the lanes (each trajectory with its own steps) against the per-trajectory route
(`MULTIPENDULUM_LANES=scalar`) in the same run, as accepted trajectory-steps per second (the two
take the same steps, give or take one per trajectory).

Also (j3): a batch `mp.simulate` by rk4 (dt = 0.01, 1000 steps) and by dop853 (its defaults), 11
output times over 10 s, of 4096 equal point-mass chains of N = 2, 3 and 8 links released from
rest at angles in [-0.5, 0.5] rad, with
every output a batch gives (angles, rates, momenta, energies, work, energy errors): the lanes
against the per-trajectory route (`MULTIPENDULUM_LANES=scalar`) in the same run.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import multipendulum as mp

BENCH = Path(__file__).resolve().parent
SOURCE = BENCH / "c" / "ensemble_omp.c"
FLAGS = ["-O3", "-march=native", "-fopenmp", "-ffast-math", "-fno-builtin-sin", "-fno-builtin-cos"]
N, B, DT, STEPS, G = 3, 16384, 0.01, 1000, 9.81
THREADS = 2
TARGET = 3.0
AGREE = 1e-8


def build(tmp):
    cc = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
    exe = Path(tmp) / "ensemble_omp"
    cmd = [cc, *FLAGS, str(SOURCE), "-o", str(exe), "-lm", "-lmvec"]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    return exe, " ".join(["cc", *FLAGS, "bench/c/ensemble_omp.c", "-lm", "-lmvec"])


def run_c(exe, tmp, th, steps):
    src, dst = Path(tmp) / "in.bin", Path(tmp) / "out.bin"
    th.astype(np.float64).tofile(src)
    env = {**os.environ, "OMP_NUM_THREADS": str(THREADS)}
    out = subprocess.run([str(exe), str(src), str(dst), str(N), str(steps), repr(DT), "1", "1", repr(G)],
                         check=True, capture_output=True, text=True, env=env)
    return np.fromfile(dst).reshape(len(th), 2 * N), float(out.stdout.strip())


def run_ours(chain, th, steps):
    t0 = time.perf_counter()
    ens = mp.ensemble(chain, th, np.zeros_like(th), steps * DT, method="rk4", dt=DT)
    return np.hstack([ens.theta, ens.omega]), time.perf_counter() - t0


DOP853_NS, DOP853_B, DOP853_T = (2, 3, 8), 2048, 10.0


def on_route(route, run):
    """``run()`` timed with ``MULTIPENDULUM_LANES=route``: (its result, seconds)."""
    os.environ["MULTIPENDULUM_LANES"] = route
    try:
        t0 = time.perf_counter()
        out = run()
        return out, time.perf_counter() - t0
    finally:
        os.environ.pop("MULTIPENDULUM_LANES", None)


def both_routes(rounds, run):
    """``run()`` on the lanes and on the per-trajectory route, alternated: the last result and
    every time of each."""
    results, times = {}, {"lanes": [], "per trajectory": []}
    for r in range(rounds):
        for who in (("lanes", "per trajectory") if r % 2 == 0 else ("per trajectory", "lanes")):
            results[who], t = on_route("auto" if who == "lanes" else "scalar", run)
            times[who].append(t)
    return results, times


def measure_dop853(rounds):
    rows = []
    for n in DOP853_NS:
        chain = mp.Chain(np.ones(n), np.ones(n), g=G)
        th = np.random.default_rng(n).uniform(-0.5, 0.5, (DOP853_B, n))
        steps, times = both_routes(rounds, lambda c=chain, x=th: float(mp.ensemble(c, x, np.zeros_like(x), DOP853_T).steps.sum()))
        rate = {k: steps[k] / float(np.median(v)) for k, v in times.items()}
        rows.append({"n": n, "steps": steps, "times": times, "rate": rate, "speedup": rate["lanes"] / rate["per trajectory"]})
    return rows


BATCH_B, BATCH_NS = 4096, (2, 3, 8)


def measure_batch(rounds):
    rows = []
    for method in ("rk4", "dop853"):
        fixed = dict(method="rk4", dt=DT) if method == "rk4" else {}
        for n in BATCH_NS:
            chain = mp.Chain(np.ones(n), np.ones(n), g=G)
            th = np.random.default_rng(n).uniform(-0.5, 0.5, (BATCH_B, n))
            sols, times = both_routes(rounds, lambda c=chain, x=th, k=fixed: mp.simulate(
                c, x, np.zeros_like(x), DT * STEPS, t_eval=np.linspace(0.0, DT * STEPS, 11), **k))
            steps = {k: float(np.sum(v.stats.steps)) for k, v in sols.items()}
            rate = {k: steps[k] / float(np.median(v)) for k, v in times.items()}
            gap = float(np.max(np.abs(sols["lanes"].theta - sols["per trajectory"].theta)))
            rows.append({"method": method, "n": n, "times": times, "rate": rate, "max_difference": gap,
                         "speedup": rate["lanes"] / rate["per trajectory"]})
    return rows


def batch_markdown(rows):
    lines = [
        "### (j3) Batch runs: `mp.simulate` in lanes against the per-trajectory route\n",
        f"A batch `mp.simulate(chain, theta0, 0, {DT * STEPS:g}, t_eval=11 times)` of {BATCH_B} equal point-mass "
        "chains released from rest at angles in [-0.5, 0.5] rad, by rk4 (`method=\"rk4\", "
        f"dt={DT}`: {STEPS} steps) and by the default dop853 (rtol 1e-10, each trajectory with its own steps), "
        f"{THREADS} threads, with every output a batch gives (angles, rates, momenta, energies, work, energy "
        "errors at the 11 times); the lanes against `MULTIPENDULUM_LANES=scalar` in the same run. Accepted "
        "trajectory-steps per second, medians of alternating repeats; the largest difference of the angles "
        "between the routes (rk4: round-off grown over 10 s; dop853: each route within its tolerance).\n",
        "| method | N | lanes (steps/s) | per trajectory (steps/s) | speed-up | largest difference |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['method']} | {r['n']} | {r['rate']['lanes']:.3g} | {r['rate']['per trajectory']:.3g} | "
                     f"{r['speedup']:.1f}x | {r['max_difference']:.1e} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 repeats instead of 7")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--md", type=Path)
    args = ap.parse_args(argv)
    os.environ.setdefault("RAYON_NUM_THREADS", str(THREADS))
    rounds = 3 if args.quick else 7
    chain = mp.Chain(np.ones(N), np.ones(N), g=G)
    th = np.random.default_rng(0).uniform(-0.5, 0.5, (B, N))
    with tempfile.TemporaryDirectory() as tmp:
        exe, cmd = build(tmp)
        ours, _ = run_ours(chain, th, STEPS)
        theirs, _ = run_c(exe, tmp, th, STEPS)
        gap = float(np.max(np.abs(ours - theirs)))
        times = {"ours": [], "C": []}
        for r in range(rounds):
            for who in (("ours", "C") if r % 2 == 0 else ("C", "ours")):
                times[who].append(run_ours(chain, th, STEPS)[1] if who == "ours" else run_c(exe, tmp, th, STEPS)[1])
    rate = {k: B * STEPS / float(np.median(v)) for k, v in times.items()}
    report = {"date": time.strftime("%Y-%m-%dT%H:%M:%S"), "cores": os.cpu_count(), "threads": THREADS,
              "quick": args.quick, "n": N, "b": B, "steps": STEPS, "dt": DT, "c_build": cmd,
              "max_difference": gap, "agrees": gap <= AGREE, "times": times, "traj_steps_per_s": rate,
              "ratio": rate["ours"] / rate["C"], "target": TARGET, "dop853": measure_dop853(rounds),
              "batch": measure_batch(rounds)}
    md = markdown(report)
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    if args.md:
        args.md.write_text(md)
    if not (args.json or args.md):
        print(md)
    return report


def markdown(rep):
    r = rep["traj_steps_per_s"]
    verdict = "met" if rep["ratio"] >= rep["target"] else "**missed**"
    return (
        "## (j) An ensemble of triple pendulums against hand-vectorised C\n\n"
        f"`bench/bench_ensemble.py`: {rep['b']} equal point-mass triple pendulums released from rest at angles in "
        f"[-0.5, 0.5] rad, rk4, dt = {rep['dt']}, {rep['steps']} steps, {rep['threads']} threads. Ours: "
        "`mp.ensemble(..., method=\"rk4\", dt=0.01)` (the lanes; also momenta, energy errors and first flips), wall "
        "time of the call. The peer: `bench/c/ensemble_omp.c` (OpenMP across blocks of 8, `omp simd` across them, "
        f"the dense mass matrix by Gaussian elimination), built `{rep['c_build']}`, its loop timed inside. "
        f"Largest difference of the final states: {rep['max_difference']:.1e} (required <= {AGREE:g}). Medians of "
        f"alternating repeats, {rep['date']}.\n\n"
        "| | trajectory-steps/s | median time |\n|---|---|---|\n"
        f"| multipendulum (lanes) | {r['ours']:.3g} | {np.median(rep['times']['ours']):.3f} s |\n"
        f"| C + OpenMP SIMD, libmvec, -ffast-math | {r['C']:.3g} | {np.median(rep['times']['C']):.3f} s |\n\n"
        f"Ratio {rep['ratio']:.2f}x the peer's rate; the target, at least {rep['target']:g}x: {verdict}.\n\n"
        + dop853_markdown(rep["dop853"]) + "\n" + batch_markdown(rep["batch"])
    )


def dop853_markdown(rows):
    lines = [
        "### (j2) dop853 ensembles: lanes against the per-trajectory route\n",
        f"`mp.ensemble` with its defaults (dop853, rtol 1e-10, atol 1e-12) of {DOP853_B} equal point-mass chains "
        f"released from rest at angles in [-0.5, 0.5] rad, to t = {DOP853_T:g} s, {THREADS} threads; the lanes (each "
        "trajectory with its own steps, rejected ones masked) against `MULTIPENDULUM_LANES=scalar`, in the same run. "
        "Accepted trajectory-steps per second, medians of alternating repeats.\n",
        "| N | lanes (steps/s) | per trajectory (steps/s) | speed-up |",
        "|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['n']} | {r['rate']['lanes']:.3g} | {r['rate']['per trajectory']:.3g} | {r['speedup']:.1f}x |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
