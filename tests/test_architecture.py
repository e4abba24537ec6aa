"""The architecture holds: no import cycles in the package (import-linter's layers contract in
pyproject.toml, every module but the command line in it), and the modules below the command
line reach the package root only for the compiled core; the compiled module matches its type
stubs (mypy's stubtest)."""
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "python" / "multipendulum"
BIN = Path(sys.executable).parent


def test_the_layers_contract_holds():
    lint = BIN / "lint-imports"
    assert lint.exists(), "import-linter is a test dependency (pip install -e '.[test]')"
    proc = subprocess.run([str(lint), "--config", str(ROOT / "pyproject.toml")], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "1 kept, 0 broken" in proc.stdout, proc.stdout


ROOT_IMPORT = re.compile(r"^\s*(import multipendulum(?!\._core as _core\b)|from multipendulum import|from \. import)", re.M)


@pytest.mark.parametrize("module", ["viewer", "notebook", "fractal", "modes", "animation", "plotting", "results", "scenario",
                                    "sweeps", "chaos", "_simulate", "_notebook", "checkpoint", "_lyapunov", "_indicators", "_zero_one", "_chain", "_base", "_torque",
                                    "_convert", "_progress", "_files", "_frames", "errors"])
def test_api_modules_import_only_the_core_from_the_package_root(module):
    code = "\n".join(line for line in (PKG / f"{module}.py").read_text().splitlines()
                     if not line.lstrip().startswith((">>>", "...", "#")))
    assert not ROOT_IMPORT.findall(code), f"{module}.py imports from the package root: {ROOT_IMPORT.findall(code)}"


def test_the_compiled_module_matches_its_stubs():
    if shutil.which("stubtest", path=str(BIN)) is None and not (BIN / "stubtest").exists():
        pytest.fail("mypy is a test dependency (pip install -e '.[test]')")
    proc = subprocess.run([sys.executable, "-m", "mypy.stubtest", "multipendulum._core"],
                          cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
