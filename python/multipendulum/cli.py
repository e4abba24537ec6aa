"""The ``multipendulum`` command.

Subcommands: ``run`` a scenario file, ``animate`` or ``plot`` a results file, ``demo`` (the
chaotic double pendulum, end to end), ``serve`` the browser viewer, ``fractal`` a flip-time map
of a scenario's chain, ``atlas`` a map of a chaos indicator (or the flip-time map) of it,
``dataset`` an ML dataset of random trajectories from a dataset config. Each subcommand is one
function decorated with :func:`command`, which adds its parser and sets its handler; adding a
subcommand means adding one such function.
Handlers return the exit status.

Exit status: 0 on success, 1 for a bad scenario, bad input or a failed integration (the message
names the problem and nothing is written), 2 for bad command-line usage, 130 when interrupted
(Ctrl-C), 143 when a checkpointed run is stopped by SIGTERM.
"""
from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import time
from pathlib import Path
from typing import Any, Callable, List, Optional, Sequence, TextIO

from ._progress import Steps, TextBar

__all__ = ["main", "command", "ProgressBar", "build_parser"]

PROG = "multipendulum"
_COMMANDS: List[Callable[[Any, argparse.ArgumentParser], None]] = []


def command(add: Callable[[Any, argparse.ArgumentParser], None]):
    """Register a subcommand: ``add(subparsers, common)`` adds its parser (with
    ``parents=[common]`` for the shared options such as ``--quiet``) and calls
    ``set_defaults(handler=fn)`` with ``fn(args) -> int``."""
    _COMMANDS.append(add)
    return add


# ----------------------------------------------------------------------------------------------
# Progress


class ProgressBar(TextBar):
    """The command's progress bar (:class:`multipendulum._progress.TextBar`): one line on stderr
    with the time elapsed and the time remaining, shown only on a terminal, only when not quiet,
    and only once the job has taken more than ``delay`` seconds. Call it with a fraction in [0, 1]."""

    def __init__(self, label: str, quiet: bool = False, stream: Optional[TextIO] = None,
                 delay: float = 1.0, width: int = 30):
        super().__init__(label, stream=stream, delay=delay, width=width, quiet=quiet, tty_only=True)


# ----------------------------------------------------------------------------------------------
# Shared pieces


def _say(args, *lines: str) -> None:
    if not args.quiet:
        for line in lines:
            print(line, flush=True)


def _summary(scenario, sol) -> List[str]:
    stats = sol.stats
    n = sol.theta.shape[1]
    head = f"{scenario.name}: " if scenario.name else ""
    steps = f"{stats.steps} steps"
    if getattr(stats, "rejected", 0):
        steps += f" ({stats.rejected} rejected)"
    return [
        f"{head}N = {n}, method {sol.method}, t_end = {scenario.t_end:g} s, {len(sol.t)} samples",
        f"  {steps}, {stats.evaluations} evaluations, wall time {stats.wall_time:.3g} s",
        *_energy_lines(scenario, sol),
        _trust_line(sol, scenario),
    ]


#: The work terms of the energy balance: the name of each part of ``sol.work``, its symbol in the
#: balance and its label in the summary.
_WORK_TERMS = (("torque", "W_torque", "torque"), ("pivot", "W_pivot", "pivot"), ("cart", "W_cart", "cart force"),
               ("dissipated", "D", "dissipated"))


def _work_terms(scenario) -> List[str]:
    """The parts of the energy balance a scenario's run has: torque, pivot, cart (its force),
    dissipated (damping, friction, the cart's damping)."""
    chain = scenario.chain
    cart = scenario.cart
    present = {
        "torque": scenario.torque is not None,
        "pivot": any(axis.kind != "constant" for axis in (scenario.pivot or {}).values()),
        "cart": cart is not None and cart.force is not None,
        "dissipated": any(v > 0 for v in chain.get("damping", []) + chain.get("friction", []))
                      or (cart is not None and cart.damping > 0),
    }
    return [name for name, _, _ in _WORK_TERMS if present[name]]


def _energy_lines(scenario, sol) -> List[str]:
    # The run's own measure (sol.stats.energy_error, already the balance's residual), never
    # recomputed here.
    error = sol.stats.energy_error
    scale = "S: well depth + max kinetic energy"
    terms = _work_terms(scenario)
    if not set(terms) - {"torque"}:  # conservative, or driven by a torque alone: W is the torque's
        return [f"  max energy error {error:.3g} (|E - E0 - W| / S; {scale})"]
    balance = "E - E0" + "".join(f" - {symbol}" for name, symbol, _ in _WORK_TERMS[:3] if name in terms)
    if "dissipated" in terms:
        balance += " + D"
    work = ", ".join(f"{label} {float(getattr(sol.work, name)[-1]):.4g} J"
                     for name, _, label in _WORK_TERMS if name in terms)
    return [f"  max energy-balance residual {error:.3g} (|{balance}| / S, E in the lab frame; {scale})",
            f"  work done by t = {float(sol.t[-1]):g} s: {work}"]


def _trust_line(sol, scenario=None) -> str:
    # An auxiliary estimate: it never blocks the results (sol.trustworthy says why it is missing).
    until, how = sol.trustworthy()
    if until is None:
        torque = getattr(scenario, "torque", None)
        if torque is not None and torque.convention == "joint":
            how = f"not estimated under joint-motor torques (a {torque.kind} torque here)"
        return f"  trustworthy until: unknown ({how})"
    if until == float("inf"):
        return "  trustworthy until: the end (no exponential divergence: regular motion)"
    note = "" if until >= sol.t[-1] else "; later samples are one of many possible motions"
    return f"  trustworthy to 1e-2 rad until ~{until:.3g} s ({how}){note}"


class Terminated(KeyboardInterrupt):
    """SIGTERM during a checkpointed run: it stops as on Ctrl-C, leaving a final checkpoint."""


@contextlib.contextmanager
def _sigterm_stops():
    """While a checkpointed run goes on, SIGTERM raises :class:`Terminated` (checked by the core
    with Ctrl-C, ten times a second) instead of killing the process outright."""
    def handler(signum, frame):
        raise Terminated()

    try:
        old = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def _stopped(path: Path, exc: BaseException) -> int:
    """Report a checkpointed run stopped by a signal; the exit status says which."""
    from .checkpoint import load_checkpoint

    what = "terminated" if isinstance(exc, Terminated) else "interrupted"
    try:
        archive = load_checkpoint(path)
    except Exception:
        print(f"\n{PROG}: {what} before the first checkpoint; nothing written", file=sys.stderr)
    else:
        print(f"\n{PROG}: {what} at t = {archive.t:g} s of {archive.t_end:g} s; checkpoint {path} is "
              f"complete; continue with: {PROG} resume {path}", file=sys.stderr)
    return 143 if isinstance(exc, Terminated) else 130


def _run_scenario(args, scenario, outdir: Path) -> int:
    """Simulate a checked scenario and write its outputs into ``outdir``."""
    import multipendulum as mp

    if getattr(args, "t_end", None) is not None:
        _check_positive("--t-end", args.t_end)
        scenario = scenario.replace(t_end=args.t_end)
    scenario.check_limits()  # the samples and steps of the run, before anything is made
    _check_outputs(args, scenario)
    path = getattr(args, "checkpoint", None)
    if path is None:
        if getattr(args, "checkpoint_every", None) is not None or getattr(args, "checkpoint_seconds", None) is not None:
            raise mp.InputError("--checkpoint-every / --checkpoint-seconds need --checkpoint FILE")
        with ProgressBar("simulate", quiet=args.quiet) as bar:
            sol = scenario.run(progress=bar)
        return _write_outputs(args, scenario, sol, outdir)
    info = {"scenario": scenario.metadata(),
            "cli": {"output": str(outdir), "format": args.format, "no_animation": args.no_animation,
                    "no_plots": args.no_plots}}
    try:
        with ProgressBar("simulate", quiet=args.quiet) as bar, _sigterm_stops():
            sol = mp.simulate(scenario.build_chain(), scenario.theta0, scenario.omega0, scenario.t_end,
                              progress=bar, checkpoint=path, checkpoint_every=args.checkpoint_every,
                              checkpoint_seconds=args.checkpoint_seconds, checkpoint_info=info,
                              **scenario.simulate_kwargs())
    except KeyboardInterrupt as exc:
        return _stopped(path, exc)
    return _write_outputs(args, scenario, sol, outdir)


def _check_positive(option: str, value: float) -> None:
    import math

    from multipendulum import InputError

    if not math.isfinite(value):
        raise InputError(f"{option} must be finite, got {value:g}")
    if not value > 0:
        raise InputError(f"{option} must be > 0, got {value:g}")


#: How the scenario's output settings are named in messages from `run`, `demo` and `resume`.
_OUTPUT_WORDS = {"format": "write .mp4 (output.animation; its frames are streamed, not kept), or run with "
                           "--no-animation"}


def _check_outputs(args, scenario) -> None:
    """Refuse, before anything is simulated or written, an animation the scenario asks for
    that would not fit (frames, pixels, memory): naming the scenario's keys."""
    if scenario.outputs.animation and not args.no_animation:
        scenario.check_animation(names=_OUTPUT_WORDS)


def _write_outputs(args, scenario, sol, outdir: Path) -> int:
    """Print the run's summary and write its results, animation and plots into ``outdir``."""
    from .animation import animate, frame_count
    from .plotting import plot
    from .results import save_results

    outputs = scenario.outputs
    _check_outputs(args, scenario)  # again, for a resumed run: before the results are written
    _say(args, *_summary(scenario, sol))

    results_name = outputs.results
    if args.format is not None:
        results_name = str(Path(results_name).with_suffix("." + args.format))
    outdir.mkdir(parents=True, exist_ok=True)
    # Say each file as soon as it exists, so an interrupted run still tells what it left.
    _say(args, f"wrote {save_results(sol, outdir / results_name, scenario=scenario)}")
    if outputs.animation and not args.no_animation:
        with ProgressBar("animate ", quiet=args.quiet) as bar:
            path = animate(
                sol, outdir / outputs.animation, fps=outputs.fps, trail=outputs.trail,
                speed=outputs.speed, dpi=outputs.dpi, progress=bar,
                title=f"{scenario.name} ({sol.method})" if scenario.name else None,
            )
        frames = int(frame_count(sol.t[0], sol.t[-1], outputs.fps, outputs.speed))
        _say(args, f"wrote {path} ({frames} frames)")
    if outputs.plots and not args.no_plots:
        for kind in outputs.plots:
            _say(args, *(f"wrote {p}" for p in plot(sol, outdir, kinds=(kind,), title=scenario.name or None)))
    return 0


def _add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--t-end", type=float, metavar="SECONDS",
                   help="simulate this long instead of the scenario's t_end (recorded in the results)")
    p.add_argument("--format", choices=("npz", "csv"),
                   help="results file format (default: from the scenario's output.results, npz)")
    p.add_argument("--no-animation", action="store_true", help="do not write the animation")
    p.add_argument("--no-plots", action="store_true", help="do not write the plots")


# ----------------------------------------------------------------------------------------------
# Subcommands


@command
def _add_run(sub, common) -> None:
    p = sub.add_parser(
        "run", parents=[common], help="simulate a scenario file and write results, animation, plots",
        description="Simulate a scenario (TOML, see docs/cli.md); print a summary; write the results "
                    "file and, unless told not to, the animation and the plots into DIR.",
    )
    p.add_argument("scenario", type=Path, metavar="SCENARIO", help="scenario file (.toml)")
    p.add_argument("-o", "--output", type=Path, metavar="DIR",
                   help="output directory (default: out/<scenario file name without .toml>)")
    _add_run_options(p)
    p.add_argument("--checkpoint", type=Path, metavar="FILE",
                   help="write the run's complete state to FILE now and then, and on Ctrl-C or SIGTERM; "
                        "continue with `multipendulum resume FILE`")
    p.add_argument("--checkpoint-every", type=int, metavar="K", help="a checkpoint every K steps")
    p.add_argument("--checkpoint-seconds", type=float, metavar="S",
                   help="a checkpoint every S seconds of wall time (default 60 when neither is given)")
    p.set_defaults(handler=_cmd_run)


def _cmd_run(args) -> int:
    from .scenario import load_scenario

    scenario = load_scenario(args.scenario)
    outdir = args.output if args.output is not None else Path("out") / args.scenario.stem
    return _run_scenario(args, scenario, outdir)


@command
def _add_resume(sub, common) -> None:
    p = sub.add_parser(
        "resume", parents=[common], help="continue a run from its checkpoint archive",
        description="Continue a `multipendulum run --checkpoint FILE` from FILE to its t_end, then print "
                    "the summary and write the same outputs the run would have written (into its output "
                    "directory unless -o says otherwise). The results are bit-for-bit those of an "
                    "uninterrupted run. Checkpoints go on being written to FILE.",
    )
    p.add_argument("archive", type=Path, metavar="ARCHIVE", help="checkpoint archive written by run --checkpoint")
    p.add_argument("-o", "--output", type=Path, metavar="DIR", help="output directory (default: the run's)")
    p.add_argument("--format", choices=("npz", "csv"), help="results file format (default: the run's)")
    p.add_argument("--no-animation", action="store_true", help="do not write the animation")
    p.add_argument("--no-plots", action="store_true", help="do not write the plots")
    p.set_defaults(handler=_cmd_resume)


def _cmd_resume(args) -> int:
    import multipendulum as mp
    from ._simulate import resume
    from .checkpoint import load_checkpoint
    from .results import scenario_from_metadata

    archive = load_checkpoint(args.archive)
    info = archive.info
    if not info.get("scenario"):
        raise mp.InputError(f"{str(args.archive)!r} was written by mp.simulate, not `multipendulum run`: "
                            "continue it in Python with mp.resume(path)")
    scenario = scenario_from_metadata(info["scenario"])
    cli = info.get("cli") or {}
    outdir = args.output if args.output is not None else Path(cli.get("output") or Path("out") / "resumed")
    args.format = args.format or cli.get("format")
    args.no_animation = args.no_animation or bool(cli.get("no_animation"))
    args.no_plots = args.no_plots or bool(cli.get("no_plots"))
    _check_outputs(args, scenario)
    _say(args, f"resuming {args.archive} at t = {archive.t:g} s of {archive.t_end:g} s")
    try:
        with ProgressBar("simulate", quiet=args.quiet) as bar, _sigterm_stops():
            sol = resume(archive, progress=bar)
    except KeyboardInterrupt as exc:
        return _stopped(args.archive, exc)
    return _write_outputs(args, scenario, sol, outdir)


@command
def _add_animate(sub, common) -> None:
    p = sub.add_parser(
        "animate", parents=[common], help="animate a results file (GIF or MP4)",
        description="Draw an animation of a results file: rods, bobs sized by mass, a fading trail "
                    "of the last tip, time and energy error on each frame. Real-time by default.",
    )
    p.add_argument("results", type=Path, metavar="RESULTS", help="results file (.npz or .csv)")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                   help="animation file, ending in .gif or .mp4")
    p.add_argument("--fps", type=float, help="frames per second (default: the scenario's, or 30)")
    p.add_argument("--trail", type=float, metavar="SECONDS",
                   help="length of the tip's trail in simulated seconds, 0 for none (default 2)")
    p.add_argument("--speed", type=float, help="simulated seconds per second of playback (default 1)")
    p.add_argument("--dpi", type=float, help="resolution (default 80, for a 400x400 frame)")
    p.set_defaults(handler=_cmd_animate)


#: How `animate`'s messages name its settings.
_ANIMATE_WORDS = {"fps": "--fps", "speed": "--speed", "dpi": "--dpi", "trail": "--trail",
                  "duration": "a shorter run", "format": "write .mp4 (-o OUT.mp4; its frames are streamed, not kept)"}


def _cmd_animate(args) -> int:
    from .animation import animate, frame_count
    from .results import load_results
    from .scenario import Outputs

    results = _load(args.results, load_results)
    outputs = Outputs()
    try:
        scenario = results.scenario()
    except Exception:  # a stored scenario that no longer checks does not stop an animation
        scenario = None
    if scenario is not None:
        outputs = scenario.outputs
    fps = args.fps if args.fps is not None else outputs.fps
    speed = args.speed if args.speed is not None else outputs.speed
    with ProgressBar("animate ", quiet=args.quiet) as bar:
        path = animate(
            results, args.output, fps=fps,
            trail=args.trail if args.trail is not None else outputs.trail,
            speed=speed, dpi=args.dpi if args.dpi is not None else outputs.dpi, progress=bar,
            names=_ANIMATE_WORDS,
        )
    frames = int(frame_count(results.t[0], results.t[-1], fps, speed))
    _say(args, f"wrote {path} ({frames} frames)")
    return 0


@command
def _add_plot(sub, common) -> None:
    from .plotting import PLOT_KINDS

    p = sub.add_parser(
        "plot", parents=[common], help="plot a results file (angles, energy error, phase, tip)",
        description="Write PNG plots of a results file: angles vs time, energy error vs time (log "
                    "scale), phase portraits, and the trace of the last link's tip.",
    )
    p.add_argument("results", type=Path, metavar="RESULTS", help="results file (.npz or .csv)")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="output directory")
    p.add_argument("--kinds", nargs="+", choices=PLOT_KINDS, default=list(PLOT_KINDS), metavar="KIND",
                   help=f"which plots (default: all of {', '.join(PLOT_KINDS)})")
    p.set_defaults(handler=_cmd_plot)


def _cmd_plot(args) -> int:
    from .plotting import plot
    from .results import load_results

    results = _load(args.results, load_results)
    paths = plot(results, args.output, kinds=args.kinds)
    _say(args, *(f"wrote {p}" for p in paths))
    return 0


@command
def _add_demo(sub, common) -> None:
    p = sub.add_parser(
        "demo", parents=[common], help="the chaotic double pendulum, end to end",
        description="Run the default scenario (a chaotic double pendulum) and write its results, "
                    "GIF and plots. The scenario is printed by --show-scenario: copy it to start "
                    "your own.",
    )
    p.add_argument("-o", "--output", type=Path, default=Path("out") / "demo", metavar="DIR",
                   help="output directory (default: out/demo)")
    p.add_argument("--show-scenario", action="store_true",
                   help="print the demo's scenario file and exit")
    _add_run_options(p)
    p.set_defaults(handler=_cmd_demo)


def _cmd_demo(args) -> int:
    from .scenario import default_scenario_path, load_scenario

    path = default_scenario_path()
    if args.show_scenario:
        sys.stdout.write(path.read_text(encoding="utf-8"))
        return 0
    return _run_scenario(args, load_scenario(path), args.output)


@command
def _add_serve(sub, common) -> None:
    p = sub.add_parser(
        "serve", parents=[common], help="serve the browser viewer on this machine",
        description="Serve the browser viewer (the engine compiled to WebAssembly) and print its "
                    "address; open it in a browser. With SCENARIO, the page starts from that "
                    "scenario file. Binds 127.0.0.1 unless --host says otherwise; serves only the "
                    "viewer's own files; opens nothing else. Stop it with Ctrl-C.",
    )
    p.add_argument("scenario", type=Path, nargs="?", metavar="SCENARIO", help="scenario file (.toml)")
    p.add_argument("--port", default="8000", metavar="N",
                   help="TCP port (default 8000; 0 picks a free one)")
    p.add_argument("--host", default="127.0.0.1", metavar="ADDRESS",
                   help="address to bind (default 127.0.0.1, this machine only; 0.0.0.0 exposes "
                        "the viewer to the network)")
    p.set_defaults(handler=_cmd_serve)


def _cmd_serve(args) -> int:
    from .viewer import make_server, parse_host, parse_port

    host, port = parse_host(args.host), parse_port(args.port)  # refuse bad values before reading files
    scenario = None
    if args.scenario is not None:
        from .scenario import load_scenario

        scenario = load_scenario(args.scenario)
    server = make_server(host, port, scenario=scenario, quiet=args.quiet)
    url = server.url + (server.redirect.lstrip("/") if server.redirect else "")
    print(f"multipendulum viewer at {url}  (Ctrl-C to stop)", flush=True)
    if not _is_loopback(host):
        print(f"warning: bound to {host}: other machines can reach the viewer", file=sys.stderr, flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        print("stopped", flush=True)
    finally:
        server.server_close()
    return 0


def _is_loopback(host: str) -> bool:
    import ipaddress

    return ipaddress.ip_address(host).is_loopback


@command
def _add_fractal(sub, common) -> None:
    p = sub.add_parser(
        "fractal", parents=[common], help="flip-time map of a scenario's chain (PNG; optionally Dask, Zarr)",
        description="Release the scenario's chain from a grid of initial states (by default theta_1 "
                    "against theta_2 over -180..180 degrees, the other values from the scenario's "
                    "[initial]) and colour each by the time its first flip (a link over the top) took. "
                    "Where the energy is below the least a flip needs, no flip is possible: that region "
                    "is hatched and its boundary, the energy bound, drawn. The map is of the chain with "
                    "its losses and its pivot's motion (a shaken pivot: no energy bound), not the "
                    "scenario's torque. Runs on all cores; --dask spreads it over a cluster and --zarr "
                    "writes it chunk by chunk.",
    )
    _add_map_options(p, zarr_what="times, allowed, x, y")
    p.add_argument("--z", metavar="QUANTITY",
                   help="a third varied quantity (thetaK or omegaK): a 3-D map of --size x --size x --z-size "
                        "initial states, drawn as up to nine slices; with --zarr written chunk by chunk "
                        "(times, allowed, x, y, z), --chunks rows of one slice per task")
    p.add_argument("--z-range", type=float, nargs=2, metavar=("LO", "HI"), help="z range, as --x-range")
    p.add_argument("--z-size", type=int, default=9, metavar="K", help="values of --z (default 9)")
    p.add_argument("--t-max", type=float, metavar="SECONDS",
                   help="how long to wait for a flip (default: the scenario's t_end)")
    p.add_argument("--dt", type=float, default=FLIP_DT, metavar="SECONDS",
                   help=f"rk4 step of the flip kernel (default {FLIP_DT:g}; flips are root-found within a step)")
    _add_flip_options(p)
    p.set_defaults(handler=_cmd_fractal)


#: The flip kernel's rk4 step when the command line gives none (`fractal`, `atlas --indicator flip`).
FLIP_DT = 0.01


def _add_map_options(p: argparse.ArgumentParser, zarr_what: str) -> None:
    """The options a map's command shares (`fractal`, `atlas`): the scenario, the picture, the
    grid (its size, the quantities along x and y and their ranges) and where it is computed."""
    p.add_argument("scenario", type=Path, metavar="SCENARIO", help="scenario file (.toml)")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="MAP.png", help="picture to write (.png)")
    p.add_argument("--size", type=int, default=256, metavar="N", help="grid of N x N initial states (default 256)")
    p.add_argument("--x", default="theta1", metavar="QUANTITY",
                   help="quantity along x: thetaK or omegaK for link K = 1..N (default theta1)")
    p.add_argument("--y", default="theta2", metavar="QUANTITY", help="quantity along y (default theta2)")
    p.add_argument("--x-range", type=float, nargs=2, metavar=("LO", "HI"),
                   help="x range in degrees (degrees/s for omega); default -180 180 (omega: -720 720)")
    p.add_argument("--y-range", type=float, nargs=2, metavar=("LO", "HI"), help="y range, as --x-range")
    p.add_argument("--dask", metavar="ADDRESS",
                   help="compute on Dask: a dask.distributed scheduler address (tcp://host:8786), or "
                        "'threads' / 'processes' for Dask's local schedulers; needs multipendulum[dask]")
    p.add_argument("--chunks", type=int, metavar="ROWS", help="rows of the grid per Dask task (default: about "
                   "16384 initial states per task)")
    p.add_argument("--zarr", type=Path, metavar="PATH",
                   help=f"also write the map ({zarr_what}) to this Zarr store, chunk by chunk, "
                        "without gathering it in one process; needs multipendulum[dask]")
    p.add_argument("--dpi", type=float, default=150, help="resolution of the picture (default 150)")


def _add_flip_options(p: argparse.ArgumentParser, only: str = "") -> None:
    p.add_argument("--link", type=int, metavar="K", help=f"time the flips of link K only (default: any link){only}")
    p.add_argument("--linear", action="store_true", help=f"linear colour scale in time (default logarithmic){only}")
    what = ("whose flip decision, or time by more than --time-tolerance, changes" if not only else
            "that change: a flip's decision or time (by more than --time-tolerance), an indicator's side of "
            "--threshold")
    p.add_argument("--certify", action="store_true",
                   help=f"compute every cell again at dt/2 and mark (magenta) and count the cells {what} "
                        "(three times the work)")
    p.add_argument("--time-tolerance", type=float, metavar="SECONDS",
                   help=f"with --certify: how far a flip time may move at dt/2 (default: one step dt){only}")


def _fractal_axis(text: str, n: int, option: str):
    import re

    from multipendulum import InputError

    m = re.fullmatch(r"(theta|omega)_?(\d+)", text.strip().lower())
    if m is None or not 1 <= int(m.group(2)) <= n:
        raise InputError(f"{option} must be theta1..theta{n} or omega1..omega{n}, got {text!r}")
    return m.group(1), int(m.group(2)) - 1


def _fractal_counts(fm, rows: int = 256):
    """Counts of flipped, never-flipped, forbidden and (a certified map's) uncertain states, a
    block of rows at a time (the map may be a Zarr store larger than memory)."""
    import numpy as np

    flipped = never = forbidden = uncertain = 0
    for r in range(0, fm.y.size, rows):
        t = np.asarray(fm.times[r:r + rows])
        a = np.asarray(fm.allowed[r:r + rows], dtype=bool)
        fin = np.isfinite(t)
        flipped += int(fin.sum())
        never += int((~fin & a).sum())
        forbidden += int((~a).sum())
        if fm.uncertain is not None:
            uncertain += int(np.asarray(fm.uncertain[r:r + rows], dtype=bool).sum())
    return flipped, never, forbidden, uncertain


#: The most rk4 steps (initial states x steps each) a flip-time map may take on this machine:
#: about an hour or more on a few cores; beyond it, --dask spreads the work over a cluster.
MAX_LOCAL_MAP_STEPS = 1e12
#: Initial states per block when a map is computed here: enough for the kernel's SIMD lanes and
#: threads, few enough for the progress bar to move (and Ctrl-C to be heard) often.
_BLOCK_STATES = 16384


def _fractal_budget(args, n: int, t_max: float) -> None:
    """Refuse, before any grid exists, a map that would not fit in memory or take too long."""
    import math

    import multipendulum as mp

    size = args.size
    depth = args.z_size if getattr(args, "z", None) is not None else 1
    cells = float(size) * size * depth
    if args.zarr is None:
        # The map's times (8 bytes) and flags (1, and 1 more certified) for every state, and one
        # block's initial states, energies and times while it is computed.
        block = max(_BLOCK_STATES, size) * (2 * n + 3) * 8.0
        grid = f"{size} x {size}" + (f" x {depth}" if depth > 1 else "")
        mp._core.check_memory(cells * (10.0 if args.certify else 9.0) + block, f"a flip-time map of {grid} initial states",
                              "use a smaller --size, or --zarr PATH to write the map chunk by chunk "
                              "(with --dask ADDRESS to compute it on a cluster)")
    if args.dask is None and math.isfinite(t_max) and t_max > 0 and math.isfinite(args.dt) and args.dt > 0:
        steps = math.ceil(t_max / args.dt)
        work = cells * steps * (3 if args.certify else 1)  # certified: again at dt/2
        if work > MAX_LOCAL_MAP_STEPS:
            raise mp.InputError(
                f"a{' certified' if args.certify else ''} flip-time map of {size} x {size}"
                f"{f' x {depth}' if depth > 1 else ''} initial states with up "
                f"to t_max / dt = {steps:.4g} steps each is up to {work:.3g} rk4 steps, more than the {MAX_LOCAL_MAP_STEPS:.0e} one machine is "
                "given (hours of work); use a smaller --size, a shorter --t-max or a larger --dt, or spread it "
                "over a cluster with --dask ADDRESS")


def _bound_share(threshold: float, forbidden: int, total: int) -> str:
    """The summary's words on the energy bound: the share of cells below it, or that there is
    none (a moving pivot can pump energy in)."""
    if threshold == float("-inf"):
        return "no energy bound (the pivot moves)"
    return f"no flip possible (energy below E_flip = {threshold:.4g} J) {100 * forbidden / total:.1f}%"


def _flip_map_in_blocks(chain, x, y, report, **kwargs):
    """``mp.flip_map`` computed a block of rows at a time, reporting the fraction of initial
    states done after each block: the same map, bit for bit (each state's flip time does not
    depend on what else is computed with it)."""
    import numpy as np

    import multipendulum as mp

    rows = max(1, min(y.size, -(-max(_BLOCK_STATES, x.size * y.size // 100) // x.size)))
    done = Steps(report, total=x.size * y.size)
    parts = []
    for r in range(0, y.size, rows):
        parts.append(mp.flip_map(chain, x, y[r:r + rows], **kwargs))
        done.add(parts[-1].times.size)
    last = parts[-1]
    join = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
    return mp.FlipMap(x, y, join("times"), join("allowed"), last.t_max, last.threshold,
                      None if last.uncertain is None else join("uncertain"), last.time_tolerance)


def _map_vary(args, n: int, what: str):
    """``vary`` from --x and --y, checked against the chain's N, and --size checked."""
    import multipendulum as mp

    if n < 2 and args.x.startswith("theta") and args.y.startswith("theta"):
        raise mp.InputError(f"{what} varies two quantities; a 1-link chain has theta1 and omega1: "
                            "use --x theta1 --y omega1")
    kx, ix = _fractal_axis(args.x, n, "--x")
    ky, iy = _fractal_axis(args.y, n, "--y")
    if (kx, ix) == (ky, iy):
        raise mp.InputError(f"--x and --y must differ, both are {args.x!r}")
    if args.size < 2:
        raise mp.InputError(f"--size must be at least 2, got {args.size}")
    return kx, ix, ky, iy


def _map_output(args) -> None:
    import multipendulum as mp

    if args.output.suffix.lower() != ".png":
        raise mp.InputError(f"the map is written as PNG: -o must end in .png, got {str(args.output)!r}")


def _map_axes(args, vary):
    """The picture's resolution checked, then the grid's x and y (radians): the centres of
    --size pixels across --x-range and --y-range."""
    import numpy as np

    import multipendulum as mp
    from .fractal import check_picture

    check_picture(args.dpi, names={"dpi": "--dpi"})

    return _map_axis(vary[0], args.x_range, args.size), _map_axis(vary[2], args.y_range, args.size)


def _map_axis(kind: str, rng, size: int):
    """``size`` values (radians) of a varied quantity: the pixel centres across its range in
    degrees (default -180..180, for a rate -720..720 degrees/s)."""
    import numpy as np

    import multipendulum as mp

    lo, hi = rng if rng is not None else ((-180.0, 180.0) if kind == "theta" else (-720.0, 720.0))
    if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
        raise mp.InputError(f"a range must have HI > LO, got {lo:g} {hi:g}")
    step = (hi - lo) / size
    return np.radians(lo + step * (np.arange(size) + 0.5))  # pixel centres


def _cmd_fractal(args) -> int:
    import numpy as np

    import multipendulum as mp
    from .fractal import plot_flip_map
    from .scenario import load_scenario

    scenario = load_scenario(args.scenario)
    chain = scenario.build_chain()
    n = chain.n
    vary = _map_vary(args, n, "a flip map")
    if args.link is not None and not 1 <= args.link <= n:
        raise mp.InputError(f"--link must be between 1 and {n}, got {args.link}")
    _map_output(args)
    t_max = scenario.t_end if args.t_max is None else args.t_max
    link = None if args.link is None else args.link - 1
    _fractal_budget(args, n, t_max)
    x, y = _map_axes(args, vary)
    if args.time_tolerance is not None and not args.certify:
        raise mp.InputError("--time-tolerance applies to a certified map: add --certify")
    # A moving pivot is applied (the chain on a cart is mapped with the cart starting at rest).
    pivot = scenario.build_base().get("pivot")
    kwargs = dict(t_max=t_max, dt=args.dt, vary=vary, base_theta=scenario.theta0, base_omega=scenario.omega0,
                  link=link, certify=args.certify, time_tolerance=args.time_tolerance, pivot=pivot)
    # Arguments checked on no states, so that a bad one fails here and not in the first block.
    if args.certify:
        mp.certified_flip_times(chain, np.zeros((0, n)), t_max=t_max, dt=args.dt, link=link,
                                time_tolerance=args.time_tolerance, pivot=pivot)
    else:
        mp.flip_times(chain, np.zeros((0, n)), t_max=t_max, dt=args.dt, link=link, pivot=pivot)
    title = scenario.name or args.scenario.stem
    if getattr(args, "z", None) is not None:
        return _fractal_volume(args, scenario, chain, vary, x, y, title, kwargs)
    for option, given in (("--z-range", getattr(args, "z_range", None) is not None),
                          ("--z-size", getattr(args, "z_size", 9) != 9)):
        if given:
            raise mp.InputError(f"{option} applies to a 3-D map: add --z QUANTITY")
    _say(args, f"{title}: flip-time map of {args.size} x {args.size} initial states, N = {n}, "
               f"t_max = {t_max:g} s, dt = {args.dt:g} s" + (" (certified: again at dt/2)" if args.certify else ""))
    if scenario.torque is not None:
        _say(args, "  note: the scenario's torque is not applied; the map is of the free chain")
    start = time.perf_counter()
    with ProgressBar("flip map", quiet=args.quiet) as bar:
        if args.dask is not None or args.zarr is not None or args.chunks is not None:
            try:
                fm = mp.sweep_flip_map(chain, x, y, chunks=args.chunks, scheduler=args.dask,
                                       zarr=args.zarr, progress=bar, **kwargs)
            except ImportError as exc:
                return _error(str(exc))
        else:
            fm = _flip_map_in_blocks(chain, x, y, bar, **kwargs)
        bar(1.0)
    wall = time.perf_counter() - start
    total = args.size * args.size
    flipped, never, forbidden, uncertain = _fractal_counts(fm)
    _say(args, f"  flipped {100 * flipped / total:.1f}%, no flip by t_max {100 * never / total:.1f}%, "
               f"{_bound_share(fm.threshold, forbidden, total)}; "
               f"wall time {wall:.3g} s")
    if fm.uncertain is not None:
        _say(args, f"  uncertain: {uncertain} of {total} cells ({100 * uncertain / total:.1f}%) change their flip "
                   f"decision, or their time by more than {fm.time_tolerance:g} s, at dt/2 = {args.dt / 2:g} s")
    if args.zarr is not None:
        _say(args, f"wrote {args.zarr}")
    path = plot_flip_map(fm, args.output, chain=chain, vary=vary, base_theta=scenario.theta0,
                         base_omega=scenario.omega0, title=f"{title}: time of the first flip"
                         + ("" if link is None else f" of link {link + 1}"), dpi=args.dpi, log=not args.linear)
    _say(args, f"wrote {path}")
    return 0


def _fractal_volume(args, scenario, chain, vary, x, y, title: str, kwargs) -> int:
    """`fractal --z`: the 3-D map, here slice by slice (each `mp.flip_map` with the third
    quantity fixed: the same cells as `mp.flip_volume`, bit for bit) or on Dask into Zarr, drawn
    as slices."""
    import numpy as np

    import multipendulum as mp
    from .fractal import plot_flip_volume

    n = chain.n
    kz, iz = _fractal_axis(args.z, n, "--z")
    if (kz, iz) in ((vary[0], vary[1]), (vary[2], vary[3])):
        raise mp.InputError(f"--z must differ from --x and --y, got {args.z!r}")
    if args.z_size < 1:
        raise mp.InputError(f"--z-size must be at least 1, got {args.z_size}")
    z = _map_axis(kz, args.z_range, args.z_size)
    vary3 = (*vary, kz, iz)
    base_theta, base_omega = np.asarray(scenario.theta0, float), np.asarray(scenario.omega0, float)
    _say(args, f"{title}: 3-D flip-time map of {args.size} x {args.size} x {args.z_size} initial states, N = {n}, "
               f"t_max = {kwargs['t_max']:g} s, dt = {args.dt:g} s" + (" (certified: again at dt/2)" if args.certify else ""))
    if scenario.torque is not None:
        _say(args, "  note: the scenario's torque is not applied; the map is of the free chain")
    start = time.perf_counter()
    with ProgressBar("flip volume", quiet=args.quiet) as bar:
        if args.dask is not None or args.zarr is not None or args.chunks is not None:
            rest = {k: v for k, v in kwargs.items() if k != "vary"}
            chunks = None if args.chunks is None else (1, args.chunks, args.size)
            try:
                fv = mp.sweep_flip_volume(chain, x, y, z, vary=vary3, chunks=chunks, scheduler=args.dask,
                                          zarr=args.zarr, progress=bar, **rest)
            except ImportError as exc:
                return _error(str(exc))
        else:
            done = Steps(bar, total=x.size * y.size * z.size)
            parts = []
            for value in z:
                th, om = base_theta.copy(), base_omega.copy()
                (th if kz == "theta" else om)[iz] = value
                parts.append(mp.flip_map(chain, x, y, **{**kwargs, "base_theta": th, "base_omega": om}))
                done.add(parts[-1].times.size)
            last = parts[-1]
            stack = lambda name: np.stack([getattr(p, name) for p in parts])  # noqa: E731
            fv = mp.FlipVolume(x, y, z, stack("times"), stack("allowed"), last.t_max, last.threshold, vary3,
                               None if last.uncertain is None else stack("uncertain"), last.time_tolerance)
        bar(1.0)
    wall = time.perf_counter() - start
    total = args.size * args.size * args.z_size
    counts = np.sum([_fractal_counts(fv.slice(k)) for k in range(z.size)], axis=0)
    flipped, never, forbidden, uncertain = (int(c) for c in counts)
    _say(args, f"  flipped {100 * flipped / total:.1f}%, no flip by t_max {100 * never / total:.1f}%, "
               f"{_bound_share(fv.threshold, forbidden, total)}; "
               f"wall time {wall:.3g} s")
    if fv.uncertain is not None:
        _say(args, f"  uncertain: {uncertain} of {total} cells ({100 * uncertain / total:.1f}%) change their flip "
                   f"decision, or their time by more than {fv.time_tolerance:g} s, at dt/2 = {args.dt / 2:g} s")
    if args.zarr is not None:
        _say(args, f"wrote {args.zarr}")
    link = kwargs["link"]
    path = plot_flip_volume(fv, args.output, chain=chain, base_theta=base_theta, base_omega=base_omega,
                            title=f"{title}: time of the first flip" + ("" if link is None else f" of link {link + 1}"),
                            dpi=min(args.dpi, 120), log=not args.linear)
    _say(args, f"wrote {path}")
    return 0


@command
def _add_atlas(sub, common) -> None:
    import multipendulum as mp

    choices = (*mp.INDICATORS, "flip")
    p = sub.add_parser(
        "atlas", parents=[common], help="map of a chaos indicator of a scenario's chain (PNG; optionally Dask, Zarr)",
        description="Release the scenario's chain from the grid of initial states `fractal` uses (by default "
                    "theta_1 against theta_2 over -180..180 degrees, the other values from the scenario's "
                    "[initial]) and colour each by a chaos indicator at --t-end, computed with the "
                    "variational equations: MEGNO, FLI, OFLI, SALI, GALI_k (with --k) or the largest "
                    "Lyapunov exponent. --indicator flip draws the flip-time map, exactly as `fractal` "
                    "does (--t-end is then its --t-max). The map is of the chain with its damping, friction "
                    "and pivot motion (a scenario's torque is not applied). Runs on all cores; "
                    "--dask spreads it over a cluster and --zarr writes it chunk by chunk.",
    )
    _add_map_options(p, zarr_what="values, x, y; with --indicator flip times, allowed, x, y")
    p.add_argument("--indicator", choices=choices, default="megno", metavar="NAME",
                   help=f"what to map: one of {', '.join(choices)} (default megno)")
    p.add_argument("--k", type=int, metavar="K", help="GALI's order, 2 <= K <= 2N (--indicator gali only)")
    p.add_argument("--t-end", type=float, metavar="SECONDS",
                   help="the time at which the indicator is taken (flip: how long to wait for a flip); "
                        "default: the scenario's t_end")
    p.add_argument("--dt", type=float, metavar="SECONDS",
                   help=f"rk4 step (default {_indicator_dt():g} for the indicators, {FLIP_DT:g} for flip)")
    _add_flip_options(p, only="; --indicator flip only")
    p.add_argument("--threshold", type=float, metavar="VALUE",
                   help="with --certify: the value separating regular from chaotic cells (default: the "
                        "indicator's rule of thumb, MEGNO 4, SALI and GALI 1e-8; FLI, OFLI and lyapunov need one)")
    p.set_defaults(handler=_cmd_atlas)


def _indicator_dt() -> float:
    """mp.indicator_map's own default step."""
    import inspect

    import multipendulum as mp

    return float(inspect.signature(mp.indicator_map).parameters["dt"].default)


def _atlas_stats(values, name: str, rows: int = 256, uncertain=None):
    """min, mean and max of the finite values, the number of cells without one, the number the
    core's rule of thumb calls chaotic (None without a rule) and of uncertain cells (0 without
    flags); a block of rows at a time (the map may be a Zarr store larger than memory)."""
    import numpy as np

    import multipendulum as mp

    lo, hi, total, finite, bad, chaotic, unsure = np.inf, -np.inf, 0.0, 0, 0, 0, 0
    above, level = mp.CHAOS_RULES[name]
    rule = None if level is None else (">" if above else "<", level)
    for r in range(0, values.shape[0], rows):
        if uncertain is not None:
            unsure += int(np.asarray(uncertain[r:r + rows], dtype=bool).sum())
        v = np.asarray(values[r:r + rows], dtype=float)
        ok = np.isfinite(v)
        good = v[ok]
        bad += int((~ok).sum())
        if good.size:
            lo, hi = min(lo, float(good.min())), max(hi, float(good.max()))
            total += float(good.sum())
            finite += int(good.size)
        if rule is not None:
            chaotic += int((good > rule[1]).sum() if rule[0] == ">" else (good < rule[1]).sum())
    mean = total / finite if finite else float("nan")
    return lo, mean, hi, bad, (chaotic if rule is not None else None), unsure


def _atlas_budget(args, n: int, t_end: float, dt: float, what: str) -> None:
    """Refuse, before any grid exists, an indicator map that would not fit in memory or take
    too long (as `fractal` refuses a flip-time map)."""
    import math

    import multipendulum as mp

    size = args.size
    cells = float(size) * size
    sweep = args.dask is not None or args.zarr is not None or args.chunks is not None
    if args.zarr is None:
        # Here: the grid's initial states and the values (mp.indicator_map); on Dask: the values
        # gathered and Dask's pieces of them.
        need = cells * 16.0 if sweep else cells * (2 * n + 1) * 8.0
        mp._core.check_memory(need, f"{what} of {size} x {size} initial states",
                              "use a smaller --size, or --zarr PATH to write the map chunk by chunk "
                              "(with --dask ADDRESS to compute it on a cluster)")
    if args.dask is None and math.isfinite(t_end) and t_end > 0 and math.isfinite(dt) and dt > 0:
        steps = math.ceil(t_end / dt)
        work = cells * steps * (3 if args.certify else 1)  # certified: again at dt/2
        if work > MAX_LOCAL_MAP_STEPS:
            raise mp.InputError(
                f"{what} of {size} x {size} initial states with t_end / dt = {steps:.4g} steps each is "
                f"{work:.3g} rk4 steps, more than the {MAX_LOCAL_MAP_STEPS:.0e} one machine is given (hours of "
                "work); use a smaller --size, a shorter --t-end or a larger --dt, or spread it over a cluster "
                "with --dask ADDRESS")


def _cmd_atlas(args) -> int:
    import numpy as np

    import multipendulum as mp
    from .fractal import indicator_label, plot_indicator_map
    from .scenario import load_scenario

    name = args.indicator
    if name != "gali" and args.k is not None:
        raise mp.InputError(f"--k is GALI's order (--indicator gali); {name} takes none")
    if name == "flip":
        if args.threshold is not None:
            raise mp.InputError("--threshold is for the indicators' certified maps; a flip map takes --time-tolerance")
        # The flip-time map is `fractal`'s, made by the same code: --t-end is its --t-max.
        args.t_max = args.t_end
        args.dt = FLIP_DT if args.dt is None else args.dt
        return _cmd_fractal(args)
    for option, given in (("--link", args.link is not None), ("--linear", args.linear),
                          ("--time-tolerance", args.time_tolerance is not None)):
        if given:
            raise mp.InputError(f"{option} is for --indicator flip only (a flip-time map)")
    if args.threshold is not None and not args.certify:
        raise mp.InputError("--threshold applies to a certified map: add --certify")
    if args.certify and args.threshold is None and mp.CHAOS_RULES[name][1] is None:
        raise mp.InputError(f"--certify with --indicator {name} needs --threshold VALUE, the value above which a "
                            "cell counts as chaotic (megno, sali and gali have their own)")
    scenario = load_scenario(args.scenario)
    chain = scenario.build_chain()
    n = chain.n
    if name == "gali" and (args.k is None or not 2 <= args.k <= 2 * n):
        got = "none given" if args.k is None else f"got {args.k}"
        raise mp.InputError(f"--indicator gali needs --k K, its order, between 2 and 2N = {2 * n}; {got}")
    label = indicator_label(name, args.k)
    vary = _map_vary(args, n, f"a {label} map")
    _map_output(args)
    t_end = scenario.t_end if args.t_end is None else args.t_end
    dt = _indicator_dt() if args.dt is None else args.dt
    for option, value in (("--t-end", t_end), ("--dt", dt)):
        _check_positive(option, value)
    _atlas_budget(args, n, t_end, dt, f"a {label} map")
    x, y = _map_axes(args, vary)
    base_theta, base_omega = np.asarray(scenario.theta0, float), np.asarray(scenario.omega0, float)
    pivot = scenario.build_base().get("pivot")
    kwargs = dict(t_end=t_end, indicator=name, k=args.k, dt=dt, vary=vary, base_theta=base_theta,
                  base_omega=base_omega, certify=args.certify, threshold=args.threshold, pivot=pivot)
    # Arguments checked on one state (the core refuses an empty batch only after checking them):
    # a bad one fails here, before the header and the work.
    mp.indicator(chain, base_theta[None], base_omega[None], t_end, name, k=args.k, dt=dt, pivot=pivot)
    title = scenario.name or args.scenario.stem
    _say(args, f"{title}: {label} map of {args.size} x {args.size} initial states, N = {n}, "
               f"t_end = {t_end:g} s, dt = {dt:g} s" + (" (certified: again at dt/2)" if args.certify else ""))
    if scenario.torque is not None:
        _say(args, "  note: the scenario's torque is not applied; the map is of the free chain")
    start = time.perf_counter()
    with ProgressBar(f"{name} map", quiet=args.quiet) as bar:
        if args.dask is not None or args.zarr is not None or args.chunks is not None:
            from .sweeps import sweep_indicator_map

            try:
                im = sweep_indicator_map(chain, x, y, chunks=args.chunks, scheduler=args.dask, zarr=args.zarr,
                                         progress=bar, **kwargs)
            except ImportError as exc:
                return _error(str(exc))
        else:
            im = mp.indicator_map(chain, x, y, progress=bar, **kwargs)
        bar(1.0)
    wall = time.perf_counter() - start
    total = args.size * args.size
    lo, mean, hi, bad, chaotic, uncertain = _atlas_stats(im.values, name, uncertain=im.uncertain)
    line = f"  {label} at t_end: min {lo:.4g}, mean {mean:.4g}, max {hi:.4g}" if bad < total \
        else f"  {label} at t_end: no finite value"
    if bad:
        line += f"; no finite value {100 * bad / total:.1f}%"
    above, level = mp.CHAOS_RULES[name]
    if chaotic is not None and level is not None:
        op = ">" if above else "<"
        line += f"; {100 * chaotic / total:.1f}% with {label} {op} {level:g} (chaotic by the usual rule of thumb)"
    _say(args, line + f"; wall time {wall:.3g} s")
    if im.uncertain is not None:
        op = ">" if above else "<"
        _say(args, f"  certified: {100 * uncertain / total:.2f}% of cells uncertain ({uncertain} of {total}: "
                   f"{label} {op} {im.threshold:g} changes at dt/2)")
    if args.zarr is not None:
        _say(args, f"wrote {args.zarr}")
    path = plot_indicator_map(im, args.output, chain=chain, vary=vary, base_theta=base_theta, base_omega=base_omega,
                              k=args.k, title=f"{title}: {label} at t = {t_end:g} s", dpi=args.dpi)
    _say(args, f"wrote {path}")
    return 0


@command
def _add_dataset(sub, common) -> None:
    p = sub.add_parser(
        "dataset", parents=[common], help="make an ML dataset of random trajectories (NPZ or Zarr, with a card)",
        description="Simulate the random trajectories a dataset config (TOML, see docs/datasets.md) describes and "
                    "write them into DIR: data.npz or data.zarr (q, p, qdot, qddot, dH/dq, dH/dp, energy, the "
                    "parameters, the split, optionally frames) and the dataset card, card.json and card.md. The "
                    "same config and seed give the same files as mp.make_dataset(DIR, **config).",
    )
    p.add_argument("config", type=Path, metavar="CONFIG", help="dataset config (.toml)")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="output directory")
    p.add_argument("--trajectories", type=int, metavar="N", help="make N trajectories instead of the config's "
                   "(recorded in the card)")
    p.add_argument("--format", choices=("auto", "npz", "zarr"), help="output format instead of the config's")
    p.add_argument("--chunk", type=int, metavar="K", help="trajectories per Dask task and Zarr chunk")
    p.add_argument("--dask", metavar="ADDRESS", help="a dask.distributed scheduler address (tcp://host:8786), or "
                   "'threads' (the default) / 'processes' / 'sync' for Dask's local schedulers")
    p.set_defaults(handler=_cmd_dataset)


def _cmd_dataset(args) -> int:
    import multipendulum as mp
    from ._dataset import make_dataset, read_dataset_config

    config = read_dataset_config(args.config)  # its messages name the file
    for key in ("trajectories", "format", "chunk"):
        if getattr(args, key) is not None:
            config[key] = getattr(args, key)
    start = time.perf_counter()
    with ProgressBar("dataset", quiet=args.quiet) as bar:
        try:
            ds = make_dataset(args.output, scheduler=args.dask, progress=bar, **config)
        except ImportError as exc:
            return _error(str(exc))
        except mp.InputError as exc:
            raise mp.InputError(f"{args.config}: {exc}") from None
    card = ds.card
    splits = ", ".join(f"{k} {v}" for k, v in ds.splits.items())
    _say(args, f"{card['name'] or args.config.stem}: {card['trajectories']} trajectories x {card['samples']} "
               f"samples, N = {card['links']}, {card['format']}; splits {splits}; wall time "
               f"{time.perf_counter() - start:.3g} s",
         f"wrote {args.output / card['data']}", f"wrote {args.output / 'card.json'}",
         f"wrote {args.output / 'card.md'}")
    return 0


# ----------------------------------------------------------------------------------------------
# Entry point


def _load(path: Path, loader):
    if not path.exists():
        from multipendulum import InputError

        raise InputError(f"{path}: no such file")
    return loader(path)


def build_parser() -> argparse.ArgumentParser:
    from multipendulum import __version__

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-q", "--quiet", action="store_true",
                        help="print nothing but errors (no summary, no progress bar)")
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Simulate, animate and plot planar N-link pendulums. "
                    "Start with `multipendulum demo`; see `multipendulum COMMAND --help`.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND")
    for add in _COMMANDS:
        add(sub, common)
    return parser


def _error(message: str) -> int:
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 1


def main(argv: Optional[Sequence[str]] = None) -> int:
    import multipendulum as mp
    from .scenario import ScenarioError

    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, usage errors
        return int(exc.code or 0) if not isinstance(exc.code, str) else 2
    handler = getattr(args, "handler", None)
    if handler is None:
        parser.print_help(sys.stderr)
        return 2
    try:
        return int(handler(args) or 0)
    except ScenarioError as exc:
        where = f"{exc.path}: " if exc.path is not None else ""
        return _error(f"{where}{exc}")
    except mp.IntegrationError as exc:
        return _error(f"{exc}; nothing written")
    except (mp.InputError, OSError) as exc:
        return _error(str(exc))
    except KeyboardInterrupt:
        print(f"\n{PROG}: interrupted; files being written were removed", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
