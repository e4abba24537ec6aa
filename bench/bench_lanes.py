"""Flip times of chains of any N in SIMD lanes (issue 14): throughput per link-step against the
double pendulum's own flip kernel and against the per-trajectory route, all in the same run.

Run:  python bench/bench_lanes.py [--quick] [--json OUT.json] [--md OUT.md]
(needs only multipendulum; without --json/--md the markdown section is printed).

Workload, for each N: B equal point-mass chains (l = m = 1, g = 9.81) released from rest at
angles drawn uniformly from [-0.5, 0.5] rad (a fixed seed): too little energy for any link to
flip, so every trajectory takes all 1000 RK4 steps of dt = 0.01 while its flip is watched for,
and the rate is the stepping rate (released high, chains of many links flip within a few hundred
steps and the cost per trajectory of locating its flip would weigh in, differently for each N). N = 2 runs through the double pendulum's
closed-form kernel, every other N through the lanes of `integrators::lanes::Rk4Lanes` (the O(N)
recursion); the per-trajectory route is `MULTIPENDULUM_FLIP_KERNEL=scalar`. What is counted is
the useful trajectory-steps (each trajectory's steps up to its flip), times N for link-steps;
throughput is that count over the median wall time of alternating repeats on all cores.
The issue's targets: per link-step within 2x of the flip kernel's for N = 2..16, and the generic
lanes (MULTIPENDULUM_FLIP_KERNEL=generic, `Rk4Lanes` with the two-link closed form) on the double
pendulum within 1.3x of its own kernel. One more row, without a target: the double pendulum on a
pivot shaken along x (0.05 m at 7 rad/s), in the lanes (the pivot's forces at each lane's own
time) and per trajectory.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

import multipendulum as mp

SWITCH = "MULTIPENDULUM_FLIP_KERNEL"
DT, STEPS = 0.01, 1000
NS = (2, 3, 4, 6, 8, 12, 16)
TARGET = 2.0  # the flip kernel's per link-step rate over ours, at most
TARGET_N2 = 1.3  # the same for the generic lanes on the double pendulum
SHAKE = mp.Pivot(x=mp.Sinusoid(amplitude=0.05, frequency=7.0))


def useful_steps(times):
    t = np.asarray(times)
    s = np.where(np.isfinite(t), np.clip(np.ceil(t / DT), 1, STEPS), STEPS)
    return float(np.where(t == 0.0, 0, s).sum())


def run(route, chain, th, pivot=None):
    os.environ[SWITCH] = route
    try:
        t0 = time.perf_counter()
        times = mp.flip_times(chain, th, t_max=STEPS * DT, dt=DT, pivot=pivot)
        return times, time.perf_counter() - t0
    finally:
        os.environ.pop(SWITCH, None)


def measure(n, b, b_scalar, rounds, generic=False, pivot=None):
    chain = mp.Chain(np.ones(n), np.ones(n))
    th = np.random.default_rng(n).uniform(-0.5, 0.5, (b, n))
    cases = {"lanes": ("generic" if generic else "auto", th), "per trajectory": ("scalar", th[:b_scalar])}
    runs = {k: [] for k in cases}
    steps = {}
    for k, (route, states) in cases.items():
        times, _ = run(route, chain, states, pivot)  # warm-up, and the useful steps of this route
        steps[k] = useful_steps(times)
    for r in range(rounds):
        for k in (list(cases) if r % 2 == 0 else list(cases)[::-1]):
            runs[k].append(run(cases[k][0], chain, cases[k][1], pivot)[1])
    out = {"n": n, "b": b, "b_scalar": b_scalar, "generic": generic, "shaken": pivot is not None}
    for k in cases:
        rate = steps[k] / float(np.median(runs[k]))
        out[k] = {"traj_steps_per_s": rate, "link_steps_per_s": rate * n, "runs": runs[k]}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer chains and repeats (under a minute)")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--md", type=Path)
    args = ap.parse_args(argv)
    b, rounds = (2048, 3) if args.quick else (8192, 5)
    rows = [measure(n, b, max(64, b // (4 * n)), rounds) for n in NS]
    # The generic lanes (any chain's) on the double pendulum, against its own kernel.
    rows.insert(1, measure(2, b, max(64, b // 8), rounds, generic=True))
    rows.insert(2, measure(2, b, max(64, b // 8), rounds, pivot=SHAKE))
    kernel = rows[0]["lanes"]["link_steps_per_s"]
    for row in rows:
        row["flip_kernel_over_ours"] = kernel / row["lanes"]["link_steps_per_s"]
        row["lanes_over_per_trajectory"] = row["lanes"]["traj_steps_per_s"] / row["per trajectory"]["traj_steps_per_s"]
    report = {"date": time.strftime("%Y-%m-%dT%H:%M:%S"), "cores": os.cpu_count(), "quick": args.quick,
              "rows": rows, "target": TARGET, "target_n2": TARGET_N2}
    md = markdown(report)
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    if args.md:
        args.md.write_text(md)
    if not (args.json or args.md):
        print(md)
    return report


def markdown(rep):
    lines = ["| N | route | trajectory-steps/s | link-steps/s | flip kernel (N = 2) / this, per link-step | "
             "lanes / per trajectory | target (<= 2x; N = 2 generic <= 1.3x) |", "|---|---|---|---|---|---|---|"]
    for row in rep["rows"]:
        lanes, one = row["lanes"], row["per trajectory"]
        generic, shaken = row.get("generic", False), row.get("shaken", False)
        route = ("generic lanes (`Rk4Lanes`, closed form)" if generic else "flip kernel (closed form)") \
            if row["n"] == 2 else "lanes (recursion)"
        if shaken:
            route = "lanes, pivot shaken along x (0.05 m, 7 rad/s)"
        ratio = row["flip_kernel_over_ours"]
        target = rep.get("target_n2", 1.3) if generic else rep["target"]
        verdict = "—" if (row["n"] == 2 and not generic) or shaken else ("met" if ratio <= target else "**missed**")
        lines.append(f"| {row['n']} | {route} | {lanes['traj_steps_per_s']:.3g} | {lanes['link_steps_per_s']:.3g} | "
                     f"{ratio:.2f}x | {row['lanes_over_per_trajectory']:.1f}x (per trajectory: "
                     f"{one['traj_steps_per_s']:.3g}/s) | {verdict} |")
    others = [row for row in rep["rows"] if row["n"] != 2]
    met = sum(1 for row in others if row["flip_kernel_over_ours"] <= rep["target"])
    n2 = next((row for row in rep["rows"] if row.get("generic")), None)
    n2_text = "" if n2 is None else (
        f" The generic kernel at N = 2 within {rep.get('target_n2', 1.3):g}x of the flip kernel: "
        f"{n2['flip_kernel_over_ours']:.2f}x, " + ("met." if n2["flip_kernel_over_ours"] <= rep.get("target_n2", 1.3)
                                                   else "**missed**."))
    head = ("## (i) Lanes: flip times of chains of any N\n\n"
            "`bench/bench_lanes.py`: B equal point-mass chains released from rest at angles in [-0.5, 0.5] rad "
            "(no flip: every trajectory takes all 1000 rk4 steps of 0.01 s while its flip is watched for), "
            "`mp.flip_times` on all cores; N = 2 through the double pendulum's closed-form flip kernel, every "
            "other N through the lanes (`integrators::lanes::Rk4Lanes`, the O(N) recursion); the per-trajectory "
            "route is `MULTIPENDULUM_FLIP_KERNEL=scalar`. Medians of alternating repeats. The issue's target, "
            f"per link-step within {rep['target']:g}x of the flip kernel's: met for {met} of "
            f"{len(others)} N.{n2_text} Measured {rep['date']}, {rep['cores']} cores, B = {rep['rows'][0]['b']} "
            f"chains per N{' (quick)' if rep['quick'] else ''}.\n\n")
    return head + "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
