"""The package's PEP 517 build backend: maturin's, after building the viewer's WebAssembly.

The wheel ships the browser viewer (``python/multipendulum/web/``), whose engine is the core
compiled to WebAssembly. maturin builds only the Python extension, so before it builds a wheel,
an editable wheel or an sdist this backend builds ``multipendulum.wasm`` with cargo and copies
it next to the page; maturin then packages it (pyproject's ``[tool.maturin] include``: the file
is gitignored). A wheel is never built without it: if the WebAssembly target cannot be
installed or the build fails, the build stops with the reason. Every other hook is maturin's.

``python3 build_backend/multipendulum_build.py`` runs the WebAssembly step alone (``make wasm``,
before ``maturin develop``), so the step is written once. It needs only the standard library.

maturin's sdist holds only the extension's crates, not ``crates/wasm``; it carries the
``multipendulum.wasm`` built when the sdist was made, and a wheel built from it uses that file.
"""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TARGET = "wasm32-unknown-unknown"
CRATE = "multipendulum-wasm"
PROFILE = "wasm"  # Cargo.toml's [profile.wasm]: release, built in parallel
WASM = ROOT / "python" / "multipendulum" / "web" / "multipendulum.wasm"


def _fail(message: str) -> "SystemExit":
    return SystemExit(f"error: {message}\n(the wheel ships the browser viewer and is not built without it)")


def _ensure_target() -> None:
    """Add the WebAssembly target with rustup unless the toolchain has it already."""
    rustc = os.environ.get("RUSTC") or shutil.which("rustc") or "rustc"
    try:
        libdir = subprocess.run([rustc, "--print", "target-libdir", "--target", TARGET],
                                capture_output=True, text=True, cwd=ROOT).stdout.strip()
    except OSError:
        libdir = ""
    if libdir and Path(libdir).is_dir():
        return
    rustup = shutil.which("rustup")
    if rustup is None:
        raise _fail(f"the Rust target {TARGET} is not installed and there is no rustup to add it: "
                    f"install it (`rustup target add {TARGET}`, or your distribution's rust-std for {TARGET})")
    if subprocess.run([rustup, "target", "add", TARGET], cwd=ROOT).returncode != 0:
        raise _fail(f"`rustup target add {TARGET}` failed (offline?): the viewer's WebAssembly cannot be built")


def build_wasm() -> Path:
    """Build the viewer's engine (Cargo profile ``PROFILE``) and copy it to ``web/multipendulum.wasm``."""
    if not (ROOT / "crates" / "wasm" / "Cargo.toml").is_file():  # an sdist: use the file it carries
        if WASM.is_file():
            print(f"multipendulum: using the prebuilt {WASM.name} of this source distribution", file=sys.stderr)
            return WASM
        raise _fail(f"neither crates/wasm nor a prebuilt {WASM} is here")
    cargo = shutil.which("cargo")
    if cargo is None:
        raise _fail("cargo is not on PATH: install Rust (https://rustup.rs) to build the viewer's WebAssembly")
    _ensure_target()
    # cargo reports where it wrote the artifact (CARGO_TARGET_DIR or not); its messages go to stderr.
    command = [cargo, "build", "--profile", PROFILE, "-p", CRATE, "--target", TARGET,
               "--message-format=json-render-diagnostics"]
    print("multipendulum: " + " ".join(command[1:-1]), file=sys.stderr, flush=True)
    run = subprocess.run(command, cwd=ROOT, stdout=subprocess.PIPE, text=True)
    if run.returncode != 0:
        raise _fail(f"building the viewer's WebAssembly failed (`cargo build -p {CRATE} --target {TARGET}`)")
    built = [f for line in run.stdout.splitlines() if line.startswith("{")
             for message in [json.loads(line)] if message.get("reason") == "compiler-artifact"
             and message["target"]["name"] == CRATE.replace("-", "_")
             for f in message.get("filenames", []) if f.endswith(".wasm")]
    if not built:
        raise _fail(f"cargo built {CRATE} but reported no .wasm file")
    # Written beside the page under another name and renamed: a reader never sees half a file.
    partial = WASM.with_name(WASM.name + ".partial")
    shutil.copyfile(built[-1], partial)
    os.replace(partial, WASM)
    print(f"multipendulum: {built[-1]} -> {WASM.relative_to(ROOT)}", file=sys.stderr, flush=True)
    return WASM


# ---- PEP 517 hooks: build the WebAssembly, then hand over to maturin --------------------------


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    build_wasm()
    import maturin

    return maturin.build_wheel(wheel_directory, config_settings, metadata_directory)


def build_editable(wheel_directory, config_settings=None, metadata_directory=None):
    build_wasm()  # an editable install serves web/ from this tree: the file must be there too
    import maturin

    return maturin.build_editable(wheel_directory, config_settings, metadata_directory)


def build_sdist(sdist_directory, config_settings=None):
    build_wasm()  # the sdist cannot rebuild it (no crates/wasm), so it carries the file
    import maturin

    return maturin.build_sdist(sdist_directory, config_settings)


# Metadata and build requirements do not depend on the WebAssembly: maturin's hooks as they are.


def get_requires_for_build_wheel(config_settings=None):
    import maturin

    return maturin.get_requires_for_build_wheel(config_settings)


def get_requires_for_build_editable(config_settings=None):
    import maturin

    return maturin.get_requires_for_build_editable(config_settings)


def get_requires_for_build_sdist(config_settings=None):
    import maturin

    return maturin.get_requires_for_build_sdist(config_settings)


def prepare_metadata_for_build_wheel(metadata_directory, config_settings=None):
    import maturin

    return maturin.prepare_metadata_for_build_wheel(metadata_directory, config_settings)


def prepare_metadata_for_build_editable(metadata_directory, config_settings=None):
    import maturin

    return maturin.prepare_metadata_for_build_editable(metadata_directory, config_settings)


if __name__ == "__main__":
    build_wasm()
