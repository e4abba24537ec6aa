# Two commands on a fresh machine (Python 3.9+, Rust and a C compiler present):
#   make demo   create .venv, build the Rust core in release mode (runtime dependencies only),
#               run the default scenario
#   make test   the same set-up plus the test dependencies, then the Rust and Python test suites
VENV    ?= .venv
PY      := $(VENV)/bin/python
OUT     ?= out/demo
WEB     := python/multipendulum/web
CHROMIUM ?= /usr/bin/chromium
export PATH := $(HOME)/.cargo/bin:$(PATH)

.PHONY: setup build build-test wasm browser demo test test-rust test-python lint fuzz bench docs clean

$(PY):
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip maturin

# The browser viewer's engine: the core compiled to WebAssembly (the target added with rustup
# if missing), copied next to the page. The wheel's build backend runs the same step.
wasm:
	python3 build_backend/multipendulum_build.py

# maturin is incremental (cargo caches), so every make rebuilds only what changed. `build` installs
# the runtime dependencies only; `build-test` adds the test suites' (pyproject's `test` extras).
build: $(PY) wasm
	VIRTUAL_ENV=$(abspath $(VENV)) $(VENV)/bin/maturin develop --release -q

build-test: $(PY) wasm
	VIRTUAL_ENV=$(abspath $(VENV)) $(VENV)/bin/maturin develop --release --extras test -q

setup: build

demo: setup
	$(VENV)/bin/multipendulum demo -o $(OUT)

# The viewer's browser tests drive Debian's chromium with Playwright (never `playwright install`).
# Without root or network they are skipped, and say why.
browser: $(PY)
	@if [ ! -x $(CHROMIUM) ]; then \
	  if [ "$$(id -u)" = 0 ]; then SUDO=; elif sudo -n true 2>/dev/null; then SUDO=sudo; else SUDO=none; fi; \
	  if [ "$$SUDO" != none ] && command -v apt-get >/dev/null; then \
	    $$SUDO apt-get update -q && $$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium \
	      || echo "note: could not install chromium; the browser tests will be skipped"; \
	  else echo "note: $(CHROMIUM) is missing and cannot be installed here; the browser tests will be skipped"; fi; \
	fi
	@$(PY) -c "import playwright" 2>/dev/null || $(PY) -m pip install -q playwright \
	  || echo "note: could not install playwright; the browser tests will be skipped"

# Cargo.toml's `tests` profile (unoptimised, with overflow checks). Unoptimised, one flip-kernel
# test's frames pass the 2 MiB of a test thread, so threads get 8 MiB (a main thread's usual).
test-rust: lint
	RUST_MIN_STACK=8388608 cargo test --profile tests -p multipendulum-core -p multipendulum-wasm -q

# The Rust crates' form, checked before their tests (seconds): rustfmt's layout (rustfmt.toml),
# clippy on every target with its warnings as errors, and the developer documentation (private
# items included, as the crates document themselves) with no broken or ambiguous link. rustfmt and
# clippy are added with rustup if the toolchain came without them (as `wasm` adds its target).
lint:
	@cargo fmt --version >/dev/null 2>&1 || rustup component add rustfmt
	@cargo clippy --version >/dev/null 2>&1 || rustup component add clippy
	cargo fmt --all --check
	cargo clippy --workspace --release --all-targets -q -- -D warnings
	RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --document-private-items -q

# tests/test_wheel.py also builds the wheel (`pip wheel .`) and runs it in a fresh venv.
test-python: build-test browser
	$(PY) -m pytest -q

# After the suites, both fuzz targets briefly, so CI exercises them (`make fuzz` runs longer,
# from a random seed; CI's fixed seed makes a failure there reproducible).
test: test-rust test-python
	$(MAKE) --no-print-directory fuzz FUZZ_SECONDS=30 FUZZ_SEED=1

# Fuzz the scenario parser and the core's constructors with atheris (libFuzzer), FUZZ_SECONDS
# each; seeds in fuzz/corpus, new inputs in out/fuzz/, a crash in out/fuzz/crash-*. Without
# atheris this fails: it never skips.
FUZZ_SECONDS ?= 60
FUZZ_SEED ?=
FUZZ_FLAGS = -max_total_time=$(FUZZ_SECONDS) -timeout=30 -rss_limit_mb=4096 -artifact_prefix=out/fuzz/ \
	$(if $(FUZZ_SEED),-seed=$(FUZZ_SEED))
fuzz: setup
	@$(PY) -c "import atheris" 2>/dev/null || $(PY) -m pip install -q atheris==3.0.0 \
	  || { echo "error: atheris could not be installed: the fuzz targets cannot run"; exit 1; }
	@mkdir -p out/fuzz/scenario out/fuzz/core
	$(PY) fuzz/fuzz_scenario.py $(FUZZ_FLAGS) out/fuzz/scenario fuzz/corpus
	$(PY) fuzz/fuzz_core.py $(FUZZ_FLAGS) out/fuzz/core fuzz/corpus

# Benchmarks against every peer (bench/RESULTS.md, bench/img/): the peers go into their own
# bench/.venv (bench/requirements.txt), not into $(VENV). `make bench QUICK=1`: under 5 minutes.
BENCH_ARGS ?= $(if $(QUICK),--quick)
bench: setup
	bench/run $(BENCH_ARGS)

# The documentation site (mkdocs.yml) into out/site: the package as `build` leaves it, plus
# pyproject's `docs` extra installed by name (read with tomllib; pip does not rebuild the
# package), then a strict build that runs the tutorial notebooks: any warning fails it. Needs no
# network once the extra is installed.
DOCS_EXTRA = import sys, pathlib; t = __import__("tomllib" if sys.version_info >= (3, 11) else "tomli"); \
	print("\n".join(t.loads(pathlib.Path("pyproject.toml").read_text())["project"]["optional-dependencies"]["docs"]))
docs: build
	@mkdir -p out
	$(PY) -c '$(DOCS_EXTRA)' > out/docs-requirements.txt
	$(PY) -m pip install -q -r out/docs-requirements.txt
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict -d out/site

clean:
	rm -rf $(VENV) target out $(WEB)/multipendulum.wasm
