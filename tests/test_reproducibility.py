"""The same inputs and version give identical arrays on every run, whatever the number of threads."""
import hashlib
import os
import subprocess
import sys

import numpy as np

import multipendulum as mp

SCRIPT = r"""
import hashlib, sys
import numpy as np
import multipendulum as mp
rng = np.random.default_rng(11)
chain = mp.Chain.rods([1.0, 0.8, 0.6], [1.0, 0.9, 0.5])
th0 = rng.uniform(-3, 3, (64, 3)); om0 = rng.uniform(-1, 1, (64, 3))
h = hashlib.sha256()
for method, kw in (("rk4", dict(dt=0.01)), ("gauss6", dict(dt=0.02)), ("dop853", dict(t_eval=np.linspace(0, 5, 11)))):
    sol = mp.simulate(chain, th0, om0, 5.0, method=method, **kw)
    for a in (sol.theta, sol.omega, sol.p, sol.energy):
        h.update(np.ascontiguousarray(a).tobytes())
h.update(mp.flip_times(mp.Chain([1, 1], [1, 1]), th0[:, :2] * 1.1, t_max=5.0).tobytes())
ens = mp.ensemble(chain, th0, om0, 5.0)
h.update(ens.theta.tobytes()); h.update(ens.first_flip.tobytes())
print(h.hexdigest())
"""


def digest(threads: int) -> str:
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, check=True)
    return out.stdout.strip()


def test_results_are_bit_identical_for_one_and_two_threads_and_across_runs():
    one, two, again = digest(1), digest(2), digest(2)
    assert len(one) == 64
    assert one == two == again


def test_a_restarted_in_process_run_is_identical():
    chain = mp.Chain([1, 1], [1, 1])
    a = mp.simulate(chain, [2.0, 2.5], [0, 0], 20.0)
    b = mp.simulate(chain, [2.0, 2.5], [0, 0], 20.0)
    assert hashlib.sha256(a.theta.tobytes()).digest() == hashlib.sha256(b.theta.tobytes()).digest()
    np.testing.assert_array_equal(a.energy, b.energy)


def test_the_recorded_version_is_the_cores_and_matches_the_package_metadata():
    # Checkpoints and results record mp.__version__; it must name the code that computed them.
    try:
        import tomllib
    except ImportError:  # Python < 3.11
        import tomli as tomllib
    from importlib.metadata import version
    from pathlib import Path

    pyproject = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    assert mp.__version__ == mp._core.__version__ == pyproject["project"]["version"] == version("multipendulum")
