"""Fuzz target: the scenario parser, from raw bytes (atheris / libFuzzer).

Any input must either load as a checked scenario (finite state, t_end > 0, a chain the core
accepts) or raise ``ScenarioError`` with a message. Anything else -- another exception, a Rust
panic (pyo3 ``PanicException``), a hang (``-timeout``) or runaway memory (``-rss_limit_mb``) --
is a crash that libFuzzer reports with the input that caused it.

    python fuzz/fuzz_scenario.py -max_total_time=60 out/fuzz/scenario fuzz/corpus

(the first directory collects new inputs; ``fuzz/corpus`` holds the seeds: the shipped examples).
"""
import sys
from pathlib import Path

import atheris

with atheris.instrument_imports():
    import numpy as np

    from multipendulum.scenario import ScenarioError, loads_scenario

# Only the examples' directory is offered for torque tables named in the input.
EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def TestOneInput(data: bytes) -> None:
    try:
        scenario = loads_scenario(data, base_dir=EXAMPLES)
    except ScenarioError as e:
        if not str(e).strip():
            raise AssertionError("ScenarioError without a message") from e
        return
    if not (np.isfinite(scenario.theta0).all() and np.isfinite(scenario.omega0).all() and scenario.t_end > 0):
        raise AssertionError(f"accepted a scenario with a bad state: {scenario!r}")


def main() -> None:
    atheris.Setup(sys.argv, TestOneInput)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
