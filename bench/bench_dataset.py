"""Datasets (mp.make_dataset): a million double-pendulum trajectories of 100 samples streamed to
Zarr on Dask, its time and its peak memory, against the same workload ten times smaller.

Run:  python bench/bench_dataset.py [--quick] [--trajectories N] [--json OUT.json] [--md OUT.md]
(by default the JSON goes to bench/build/dataset.json and the Markdown section is printed;
bench/bench.py runs it as a subprocess for its section (g) of bench/RESULTS.md).

The workload: ``mp.make_dataset(DIR, format="zarr", trajectories=N, t_end=9.9, sample_dt=0.1)``
(100 samples at t = 0, 0.1, ..., 9.9 s) of the double pendulum ``Chain([1, 1], [1, 1])`` (one
chain: every chunk is one batch run of the core on all cores) from angles drawn in [-1.5, 1.5]
rad and rates in [-1, 1] rad/s, dop853 at rtol 1e-10; the fields q, p, qdot, qddot, dH/dq,
dH/dp, energy and the parameters, the default chunk (about 32 MiB of output per Dask task and
Zarr chunk), Dask's threaded scheduler, then the store read back chunk by chunk for the card's
SHA-256 of every array. Each size runs in a fresh Python process, which reports its own wall
time and its peak resident memory (``resource.getrusage(RUSAGE_SELF).ru_maxrss``); a process
that only imports the same modules gives the baseline. Memory bounded by the chunk means the
peak does not grow with N: the 1M run's peak is compared with the N/10 run's. The store goes to
a temporary directory beside bench/build (``--dir`` elsewhere), removed afterwards.

The interpreter: this one if it has Dask and Zarr, else the project's .venv (bench/.venv has the
peers of the other workloads, not Dask).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent
BUILD = BENCH / "build"
sys.path.insert(0, str(BENCH))

import bench_engine as E  # noqa: E402  (run_machine, busy_compilers)

FULL, QUICK = 1_000_000, 50_000
CONFIG = dict(t_end=9.9, sample_dt=0.1, seed=0, links=2, lengths=[1.0, 1.0], masses=[1.0, 1.0],
              theta={"low": -1.5, "high": 1.5}, omega={"low": -1.0, "high": 1.0}, method="dop853",
              rtol=1e-10, atol=1e-12, format="zarr", name="bench: double pendulum")

CHILD = textwrap.dedent("""
    import json, os, resource, sys, time
    sys.path.insert(0, {python!r})
    import multipendulum as mp, dask, zarr
    kwargs = json.loads({kwargs!r})
    out = {{"baseline_rss_kib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}}
    if kwargs:
        t0 = time.perf_counter()
        ds = mp.make_dataset(**kwargs)
        out["seconds"] = time.perf_counter() - t0
        out["chunk"] = ds.card["config"]["chunk"]
        out["samples"] = ds.card["samples"]
        out["arrays"] = {{k: v["shape"] for k, v in ds.card["arrays"].items()}}
        out["q_sha256"] = ds.card["arrays"]["q"]["sha256"]
        out["versions"] = ds.card["versions"]
        out["dask"] = dask.__version__
    out["peak_rss_kib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print("RESULT " + json.dumps(out))
""")


def log(*a):
    print(*a, file=sys.stderr, flush=True)


def python_with_dask():
    for py in (sys.executable, str(ROOT / ".venv" / "bin" / "python")):
        if Path(py).exists() and subprocess.run([py, "-c", "import dask, zarr, numpy"],
                                                capture_output=True).returncode == 0:
            return py
    return None


def child(py, kwargs):
    code = CHILD.format(python=str(ROOT / "python"), kwargs=json.dumps(kwargs))
    t0 = time.perf_counter()
    proc = subprocess.run([py, "-c", code], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        raise RuntimeError(f"exit code {proc.returncode}: " + " / ".join(tail))
    out = json.loads(lines[-1][len("RESULT "):])
    out["process_seconds"] = wall
    return out


def disk_bytes(path):
    return sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file())


def run(sizes, where, py):
    rows = []
    base = child(py, {})
    for n in sizes:
        target = Path(tempfile.mkdtemp(prefix="dataset-", dir=where)) / "set"
        try:
            log(f"  {n} trajectories -> {target} ...")
            res = child(py, dict(CONFIG, path=str(target), trajectories=n))
            res.update(trajectories=n, disk_bytes=disk_bytes(target / "data.zarr"))
            rows.append(res)
            log(f"    {res['seconds']:.1f} s, peak RSS {res['peak_rss_kib'] / 1024:.0f} MiB")
        finally:
            shutil.rmtree(target.parent, ignore_errors=True)
    return {"baseline": base, "rows": rows}


def fmt_bytes(x):
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if x >= scale:
            return f"{x / scale:.1f} {unit}"
    return f"{x:.0f} B"


def markdown(data):
    m = data["machine"]
    L = ["## (g) Datasets: a million double pendulums streamed to Zarr", "",
         f"{m['cpu']}, {m['cores']} cores; {m['date']}; Python {m['python']}, NumPy {m['numpy']}; "
         f"load average (1, 5, 15 min) {m['load']} at the start.", ""]
    if data.get("status") != "ok":
        L.append(f"Not run: {data.get('why')}.")
        return "\n".join(L) + "\n"
    rows = data["rows"]
    v = rows[-1]["versions"]
    L += [f"`mp.make_dataset(DIR, format=\"zarr\", trajectories=N, t_end=9.9, sample_dt=0.1)`: the double "
          "pendulum `Chain([1, 1], [1, 1])`, angles in [-1.5, 1.5] rad, rates in [-1, 1] rad/s, dop853 at "
          "rtol 1e-10, 100 samples per trajectory, the fields q, p, qdot, qddot, dH/dq, dH/dp, energy, the "
          "parameters and the split; the default chunk, Dask's threaded scheduler, then the store read back "
          "chunk by chunk for the card's SHA-256 of every array (all included in the time). Each N in a "
          "fresh process: its wall time and its peak resident memory (`ru_maxrss`); the baseline is a "
          f"process that only imports multipendulum, Dask {rows[-1]['dask']} and Zarr {v.get('zarr', '?')}.", "",
          "| trajectories | chunk (trajectories) | time | trajectories / s | on disk (Zarr) | peak RSS | "
          "peak RSS - baseline |", "|---|---|---|---|---|---|---|"]
    base = data["baseline"]["peak_rss_kib"] * 1024
    for r in rows:
        peak = r["peak_rss_kib"] * 1024
        L.append(f"| {r['trajectories']:,} | {r['chunk']:,} | {r['seconds']:.0f} s | "
                 f"{r['trajectories'] / r['seconds']:,.0f} | {fmt_bytes(r['disk_bytes'])} | {fmt_bytes(peak)} | "
                 f"{fmt_bytes(peak - base)} |")
    L += ["", f"Baseline (imports only): {fmt_bytes(base)}."]
    if len(rows) >= 2:
        a, b = rows[0], rows[-1]
        grow = (b["peak_rss_kib"] - data["baseline"]["peak_rss_kib"]) / max(
            1, a["peak_rss_kib"] - data["baseline"]["peak_rss_kib"])
        per = b["disk_bytes"] / b["trajectories"]
        L += ["", f"Memory bounded by the chunk: {b['trajectories'] / a['trajectories']:.0f}x the trajectories "
              f"take {grow:.2f}x the memory above the baseline, while the dataset itself is "
              f"{fmt_bytes(b['disk_bytes'])} on disk ({fmt_bytes(per)} per trajectory): the peak is that of "
              f"the chunks running at once ({m['cores']} on the threaded scheduler, each {b['chunk']:,} "
              "trajectories with the run's own arrays and the derived fields), not of the dataset."]
    return "\n".join(L) + "\n"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help=f"{QUICK:,} trajectories instead of {FULL:,}")
    p.add_argument("--trajectories", type=int, help="the large size (default 1,000,000; --quick 50,000)")
    p.add_argument("--dir", type=Path, default=None, help="where the stores are written (default beside bench/build)")
    p.add_argument("--json", type=Path, default=BUILD / "dataset.json")
    p.add_argument("--md", type=Path, default=None)
    args = p.parse_args(argv)
    big = args.trajectories or (QUICK if args.quick else FULL)
    sizes = [max(1, big // 10), big]
    BUILD.mkdir(exist_ok=True)
    where = args.dir or BUILD
    where.mkdir(parents=True, exist_ok=True)
    data = {"machine": E.run_machine(), "busy": E.busy_compilers(), "sizes": sizes}
    if data["busy"]:
        log("warning: compiler processes are running; timings will be skewed")
    py = python_with_dask()
    if py is None:
        data.update(status="not run", why="no interpreter with Dask and Zarr (pip install 'multipendulum[dask]')")
    else:
        data["python"] = py
        try:
            data.update(run(sizes, where, py), status="ok")
        except Exception as exc:  # reported in the section, not raised
            data.update(status="failed", why=f"{type(exc).__name__}: {exc}"[:300])
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(data, indent=1))
    md = markdown(data)
    if args.md is not None:
        args.md.write_text(md)
    else:
        print(md)
    return 0 if data["status"] == "ok" else 1


if __name__ == "__main__":
    sys.exit(main())
