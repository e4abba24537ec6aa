"""The package's public API is typed: mypy checks the whole package with the configuration in
pyproject.toml ([tool.mypy]), under which the API modules must annotate every function and method
(disallow_untyped_defs, disallow_incomplete_defs) and their bodies type-check against each other,
the compiled core's stubs (_core.pyi) and NumPy's types."""
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_public_api_is_typed():
    try:
        import mypy  # noqa: F401
    except ImportError:
        pytest.fail("mypy is a test dependency (pip install -e '.[test]')")
    proc = subprocess.run([sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"),
                           "-p", "multipendulum"], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
