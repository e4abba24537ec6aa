"""Chaos indicators in SIMD lanes (issue 14): the tangent-carrying lanes against the per-state
route in the same run, and the time of a 1024 x 1024 certified MEGNO map of the double pendulum.

Run:  python bench/bench_atlas.py [--quick] [--size S] [--json OUT.json] [--md OUT.md]
(needs only multipendulum; without --json/--md the markdown section is printed).

(1) Rates, for N = 2, 3, 8: B equal point-mass chains (l = m = 1) released from rest at angles
drawn uniformly from [-1.5, 1.5] rad (a fixed seed), `mp.megno` of the batch over 1000 rk4 steps
of dt = 0.01 on all cores; the per-state route is `MULTIPENDULUM_LANES=scalar`. What is counted is
trajectory-steps (each carrying its deviation vector and MEGNO's two integrals) over the median
wall time of alternating repeats.

(2) The map: `mp.indicator_map(chain, x, x, t_end=100, dt=0.02, certify=True)` over theta_1,
theta_2 in [-pi, pi] (S x S cells, S = 1024 unless --size or --quick), every cell run at dt and
again at dt/2 (15000 steps per cell); one timed run. The issue's target: under 10 minutes on 2
cores.
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

SWITCH = "MULTIPENDULUM_LANES"
DT, STEPS = 0.01, 1000
NS = (2, 3, 8)
MAP_T, MAP_DT = 100.0, 0.02
TARGET_S = 600.0


def timed(route, chain, th):
    os.environ[SWITCH] = route
    try:
        t0 = time.perf_counter()
        mp.megno(chain, th, np.zeros_like(th), t_end=STEPS * DT, dt=DT)
        return time.perf_counter() - t0
    finally:
        os.environ.pop(SWITCH, None)


def rates(n, b, b_scalar, rounds):
    chain = mp.Chain(np.ones(n), np.ones(n))
    th = np.random.default_rng(n).uniform(-1.5, 1.5, (b, n))
    cases = {"lanes": ("auto", th), "per state": ("scalar", th[:b_scalar])}
    for route, states in cases.values():
        timed(route, chain, states[:64])  # warm-up
    runs = {k: [] for k in cases}
    for r in range(rounds):
        for k in (list(cases) if r % 2 == 0 else list(cases)[::-1]):
            runs[k].append(timed(cases[k][0], chain, cases[k][1]))
    out = {"n": n, "b": b, "b_scalar": b_scalar}
    for k, (_, states) in cases.items():
        out[k] = {"traj_steps_per_s": len(states) * STEPS / float(np.median(runs[k])), "runs": runs[k]}
    out["lanes_over_per_state"] = out["lanes"]["traj_steps_per_s"] / out["per state"]["traj_steps_per_s"]
    return out


def certified_map(size):
    chain = mp.Chain([1.0, 1.0], [1.0, 1.0])
    x = np.linspace(-np.pi, np.pi, size)
    t0 = time.perf_counter()
    im = mp.indicator_map(chain, x, x, t_end=MAP_T, dt=MAP_DT, certify=True)
    wall = time.perf_counter() - t0
    v = np.asarray(im.values)
    return {"size": size, "wall_s": wall, "uncertain": float(np.mean(im.uncertain)),
            "chaotic": float(np.mean(v > im.threshold)), "threshold": im.threshold,
            "traj_steps_per_s": size * size * (MAP_T / MAP_DT) * 3 / wall}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer chains and repeats, a 256 x 256 map (about a minute)")
    ap.add_argument("--size", type=int, help="the map's cells per side (default 1024; 256 with --quick)")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--md", type=Path)
    args = ap.parse_args(argv)
    b, rounds = (2048, 3) if args.quick else (8192, 5)
    rows = [rates(n, b, max(64, b // 16), rounds) for n in NS]
    size = args.size or (256 if args.quick else 1024)
    report = {"date": time.strftime("%Y-%m-%dT%H:%M:%S"), "cores": os.cpu_count(), "quick": args.quick,
              "rows": rows, "map": certified_map(size), "target_s": TARGET_S}
    md = markdown(report)
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    if args.md:
        args.md.write_text(md)
    if not (args.json or args.md):
        print(md)
    return report


def markdown(rep):
    lines = ["| N | lanes, trajectory-steps/s | per state, trajectory-steps/s | lanes / per state |",
             "|---|---|---|---|"]
    for row in rep["rows"]:
        lines.append(f"| {row['n']} | {row['lanes']['traj_steps_per_s']:.3g} | "
                     f"{row['per state']['traj_steps_per_s']:.3g} | {row['lanes_over_per_state']:.1f}x |")
    m = rep["map"]
    full = m["size"] == 1024
    if full:
        verdict = "met" if m["wall_s"] < rep["target_s"] else "**missed**"
    else:
        verdict = "not judged (the issue's map is 1024 x 1024)"
    head = ("## (k) Chaos indicators in lanes, and a certified MEGNO map\n\n"
            "`bench/bench_atlas.py`. Rates: B equal point-mass chains released from rest at angles in "
            "[-1.5, 1.5] rad, `mp.megno` of the batch over 1000 rk4 steps of 0.01 s on all cores, each state "
            "carrying its deviation vector and MEGNO's integrals; the per-state route is "
            "`MULTIPENDULUM_LANES=scalar`. Medians of alternating repeats. "
            f"Measured {rep['date']}, {rep['cores']} cores, B = {rep['rows'][0]['b']} "
            f"(per state: {rep['rows'][0]['b_scalar']}){' (quick)' if rep['quick'] else ''}.\n\n")
    tail = (f"\n\nThe map: `mp.indicator_map(chain, x, x, t_end={MAP_T:g}, dt={MAP_DT:g}, certify=True)` of the "
            f"double pendulum (l = m = 1) over theta_1, theta_2 in [-pi, pi], {m['size']} x {m['size']} cells, each "
            f"run at dt and again at dt/2: **{m['wall_s']:.0f} s** ({m['wall_s'] / 60:.1f} min; "
            f"{m['traj_steps_per_s']:.3g} trajectory-steps/s). {100 * m['chaotic']:.1f}% of the cells have "
            f"MEGNO > {m['threshold']:g}, {100 * m['uncertain']:.2f}% are uncertain. The issue's target, under "
            f"{rep['target_s'] / 60:.0f} minutes on 2 cores: {verdict}.\n")
    return head + "\n".join(lines) + tail


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
