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


def test_no_closure_of_the_core_calls_fma_on_the_baseline_target():
    """The lanes' kernels compile inside `#[target_feature(enable = "avx512f,fma")]` (and AVX2)
    wrappers, where `mul_add` is one instruction. A closure in them (`array::from_fn`,
    `get_or_insert_with`, an iterator adapter) that LLVM does not inline is a function of its own
    on the baseline target, where every `mul_add` is a call to libm's `fma()`: the same bits, up to
    14x slower (the observations of 256 double pendulums took 22 us for 3). No closure of the
    compiled module may reach `fma` (through its GOT slot, as the shared library calls it)."""
    objdump, readelf = shutil.which("objdump"), shutil.which("readelf")
    if objdump is None or readelf is None:
        pytest.skip("binutils (objdump, readelf) not installed")
    lib = next(PKG.glob("_core*.so"), None)
    if lib is None:
        pytest.skip("no compiled module (a wheel install, or not Linux)")
    dis = subprocess.run([objdump, "-d", "--no-show-raw-insn", str(lib)], capture_output=True, text=True, check=True).stdout
    start = re.search(r"^0*([0-9a-f]+) <fma>:$", dis, re.M)
    if start is None:
        pytest.skip("fma is not linked into the module (a build without a portable path)")
    relocs = subprocess.run([readelf, "-rW", str(lib)], capture_output=True, text=True, check=True).stdout
    slots = {int(r.split()[0], 16) for r in relocs.splitlines() if r.split()[-1:] == [start.group(1)]}
    callers, name = set(), None
    for line in dis.splitlines():
        head = re.match(r"^[0-9a-f]+ <(.*)>:$", line)
        if head:
            name = head.group(1)
            continue
        target = re.search(r"#\s*([0-9a-f]+) <", line) or re.search(r"call\s+([0-9a-f]+) <fma>", line)
        if name and "closure" in name and target and (int(target.group(1), 16) in slots or "<fma>" in line):
            callers.add(name)
    assert not callers, f"closures calling fma() outside the target features: {sorted(callers)}"
