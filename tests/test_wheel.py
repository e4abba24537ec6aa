"""The wheel, as a user gets it: built from this tree by `pip wheel .` (the in-tree build backend,
which compiles the viewer's WebAssembly, then maturin), installed alone into a fresh virtual
environment with its runtime dependencies from PyPI, and run there: the demo writes its GIF and
plots, and `multipendulum serve` serves the page and its WebAssembly on 127.0.0.1 only.

The build reuses cargo's target directory, so after `make build` it only re-packages (seconds);
the fresh environment's dependencies come from pip's cache when it has them.
"""
import http.client
import importlib.util
import ipaddress
import json
import os
import queue
import socket
import subprocess
import sys
import threading
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
WEB = "multipendulum/web/"
WASM = WEB + "multipendulum.wasm"
PAGE_FILES = ["index.html", "engine.js", "viewer.js", "scenario.js", "style.css", "multipendulum.wasm"]
# The backend's facts (the WebAssembly's target, crate and Cargo profile), from the backend itself.
_SPEC = importlib.util.spec_from_file_location("multipendulum_build", ROOT / "build_backend" / "multipendulum_build.py")
BACKEND = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(BACKEND)
TEST_ONLY = ["pytest", "hypothesis", "sympy", "scipy", "dask", "distributed", "zarr"]

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="checks listening sockets in /proc/net")


def clean_env():
    """This environment without anything that would let the fresh venv see the source tree."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "VIRTUAL_ENV", "CONDA"))}
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    return env


def run(cmd, timeout, **kwargs):
    """Run to completion; a failure shows the command's output."""
    proc = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=timeout,
                          env=clean_env(), **kwargs)
    assert proc.returncode == 0, (f"{cmd} exited with {proc.returncode}\n--- stdout\n{proc.stdout[-6000:]}"
                                  f"\n--- stderr\n{proc.stderr[-6000:]}")
    return proc


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    out = tmp_path_factory.mktemp("wheelhouse")
    # A cold build (fat LTO, 2 cores) takes minutes; a warm one seconds.
    run([sys.executable, "-m", "pip", "wheel", ROOT, "--no-deps", "-w", out], timeout=3600, cwd=ROOT)
    wheels = sorted(out.glob("multipendulum-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


@pytest.fixture(scope="module")
def venv(wheel, tmp_path_factory):
    """A fresh virtual environment holding the wheel and its runtime dependencies only. This
    environment's pip installs into it (`--python`), which saves seeding it with its own pip;
    `--no-compile` leaves the bytecode to the first import. Half the time of the plain way."""
    home = tmp_path_factory.mktemp("venv") / "env"
    run([sys.executable, "-m", "venv", "--without-pip", home], timeout=300)
    run([sys.executable, "-m", "pip", "--python", home / "bin" / "python", "install", "-q", "--no-compile", wheel],
        timeout=1800)
    return home


def test_the_wheel_holds_the_viewer_and_its_freshly_built_webassembly(wheel):
    with zipfile.ZipFile(wheel) as zf:
        names = zf.namelist()
        wasm = zf.read(WASM) if WASM in names else b""
    assert [n for n in PAGE_FILES if WEB + n not in names] == [], names
    assert wasm.startswith(b"\0asm"), wasm[:8]
    # It is the build's own output, copied by the backend, not an old file left beside the page.
    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    built = target / BACKEND.TARGET / BACKEND.PROFILE / (BACKEND.CRATE.replace("-", "_") + ".wasm")
    assert wasm == built.read_bytes()
    assert any(n.startswith("multipendulum/_core") for n in names), names
    assert not any("build_backend" in n or "multipendulum_build" in n for n in names), names


def test_the_fresh_venv_runs_the_installed_package_with_runtime_dependencies_only(venv, tmp_path):
    code = ("import importlib.util, json, multipendulum; "
            f"print(json.dumps([multipendulum.__file__] + [m for m in {TEST_ONLY!r} if importlib.util.find_spec(m)]))")
    got = json.loads(run([venv / "bin" / "python", "-c", code], timeout=120, cwd=tmp_path).stdout)
    assert Path(got[0]).resolve().is_relative_to(venv.resolve()), got[0]  # the wheel's copy, not this tree's
    assert got[1:] == [], f"test dependencies installed with the wheel: {got[1:]}"
    script = (venv / "bin" / "multipendulum").read_text().splitlines()[0]
    assert script == f"#!{venv / 'bin' / 'python'}", script  # the command runs the venv's Python


def test_the_demo_runs_from_the_wheel(venv, tmp_path):
    from PIL import Image

    out = tmp_path / "demo"
    run([venv / "bin" / "multipendulum", "demo", "-o", out], timeout=600, cwd=tmp_path)
    with Image.open(out / "double_pendulum.gif") as gif:
        assert gif.format == "GIF" and gif.n_frames > 100, (gif.format, gif.n_frames)
    for name in ["angles", "energy", "phase", "tip"]:
        with Image.open(out / f"{name}.png") as png:
            assert png.format == "PNG" and min(png.size) > 100, (name, png.format, png.size)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def get(port, path):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.request("GET", path)
        resp = conn.getresponse()
        return resp.status, resp.getheader("Content-Type"), resp.read()
    finally:
        conn.close()


def listening_addresses(port):
    """The local addresses of this machine's TCP sockets listening on ``port`` (/proc/net)."""
    found = []
    for table in ("tcp", "tcp6"):
        path = Path("/proc/net") / table
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            addr, hex_port = local.split(":")
            if state == "0A" and int(hex_port, 16) == port:  # 0A: LISTEN
                raw = b"".join(bytes.fromhex(addr[i:i + 8])[::-1] for i in range(0, len(addr), 8))
                found.append(str(ipaddress.ip_address(raw)))
    return found


def outward_address():
    """This machine's address on its default route, if it has one (no packet is sent)."""
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.connect(("192.0.2.1", 9))
            addr = s.getsockname()[0]
    except OSError:
        return None
    return None if ipaddress.ip_address(addr).is_loopback else addr


def test_the_viewer_is_served_from_the_wheel_on_127_0_0_1_only(venv, wheel, tmp_path):
    with zipfile.ZipFile(wheel) as zf:
        page, wasm = zf.read(WEB + "index.html"), zf.read(WASM)
    port = free_port()
    proc = subprocess.Popen([str(venv / "bin" / "multipendulum"), "serve", "--port", str(port)], cwd=tmp_path,
                            env=clean_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True).start()
    try:
        try:
            first = lines.get(timeout=60)
        except queue.Empty:
            first = ""
        assert proc.poll() is None, f"serve exited with {proc.returncode}: {proc.stderr.read()}"
        assert first.startswith(f"multipendulum viewer at http://127.0.0.1:{port}/"), first

        status, kind, body = get(port, "/")
        assert (status, kind) == (200, "text/html; charset=utf-8") and body == page
        status, kind, body = get(port, "/multipendulum.wasm")
        assert (status, kind) == (200, "application/wasm")
        assert body.startswith(b"\0asm") and body == wasm

        assert listening_addresses(port) == ["127.0.0.1"]
        other = outward_address()
        if other is not None:  # the machine's own network address must not reach the viewer
            with pytest.raises(OSError):
                socket.create_connection((other, port), timeout=5).close()
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=10)
    with pytest.raises(OSError):  # it has stopped
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
