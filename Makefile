# Two commands on a fresh machine (Python 3.9+, Rust and a C compiler present):
#   make demo   create .venv, build the Rust core in release mode, run the default scenario
#   make test   the same set-up, then the Rust and Python test suites
VENV    ?= .venv
PY      := $(VENV)/bin/python
OUT     ?= out/demo
export PATH := $(HOME)/.cargo/bin:$(PATH)

.PHONY: setup build demo test test-rust test-python bench clean

$(PY):
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip maturin

# maturin is incremental (cargo caches), so every make rebuilds only what changed.
build: $(PY)
	VIRTUAL_ENV=$(abspath $(VENV)) $(VENV)/bin/maturin develop --release --extras test -q

setup: build

demo: setup
	$(VENV)/bin/multipendulum demo -o $(OUT)

test-rust:
	cargo test --release -p multipendulum-core -q

test-python: setup
	$(PY) -m pytest -q

test: test-rust test-python

bench: setup
	$(PY) bench/bench_engine.py

clean:
	rm -rf $(VENV) target out
