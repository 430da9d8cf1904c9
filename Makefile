# Developer entry points. `make test` is the full check CI runs (see .ci/run).
#
# `make setup` keeps a virtual environment in .venv with the test tools and the package itself
# (built in release mode by maturin). Stamp files inside .venv make re-runs cheap: the tools are
# reinstalled only when pyproject.toml (or this file) changes, the native module is rebuilt only
# when a Rust source or manifest changes. Delete .venv to start over.

PYTHON ?= python3
VENV := .venv
VENV_PY := $(VENV)/bin/python
TOOLS_STAMP := $(VENV)/.tools-stamp
BUILD_STAMP := $(VENV)/.build-stamp

# Everything the native module is built from (the binding crate and the core it links).
RUST_INPUTS := Cargo.toml Cargo.lock $(shell find crates -name '*.rs' -o -name Cargo.toml)

# pyo3's build script picks an interpreter from PYO3_PYTHON; pointing cargo (clippy included)
# and maturin at the same one lets them share build results instead of rebuilding pyo3.
export PYO3_PYTHON := $(abspath $(VENV_PY))
export PIP_DISABLE_PIP_VERSION_CHECK := 1

.PHONY: setup test test-rust test-python demo pipeline pipeline-tiny validation report lint bench clean

setup: $(BUILD_STAMP)

$(VENV_PY):
	$(PYTHON) -m venv $(VENV)

$(TOOLS_STAMP): pyproject.toml Makefile | $(VENV_PY)
	$(VENV_PY) -m pip install --upgrade pip
	$(VENV_PY) -m pip install 'maturin>=1.9.4,<2' pytest hypothesis 'numpy>=2' ruff mypy \
		'torch>=2.4' 'safetensors>=0.4' 'gymnasium>=1.0' 'matplotlib>=3.8' 'polars>=2' 'tqdm>=4.66' 'ray>=2.30'
	touch $@

# `maturin develop` installs the runtime dependencies, copies the extension module into
# python/rmi_sph/ and points the venv at python/ so edits to .py files need no reinstall.
$(BUILD_STAMP): $(TOOLS_STAMP) $(RUST_INPUTS) pyproject.toml
	VIRTUAL_ENV=$(abspath $(VENV)) $(VENV)/bin/maturin develop --release
	touch $@

test: setup test-rust test-python

# The workspace's default members leave out the binding, so this needs no Python.
test-rust:
	cargo test --release

# A hung test (a deadlock) fails the run after 30 minutes instead of holding CI: SIGABRT makes
# pytest's fault handler print every thread's traceback first. The suite takes about 3 minutes.
test-python: setup
	timeout --signal=ABRT 1800 $(VENV_PY) -m pytest -q tests

demo: setup
	cargo run --release -p rmi-benches --bin demo

# The main job: sweep -> dataset -> analysis -> world models -> policies -> ranking -> closed
# loop -> report on the quick preset (PRESET=paper for the paper's grid). Resumable: run it
# again after an interruption. The engine validation records go into the same report.
PRESET ?= quick
OUT ?= results/$(PRESET)
pipeline: setup
	@test -d $(OUT)/validation || $(MAKE) --no-print-directory validation OUT=$(OUT)
	$(VENV)/bin/rmi pipeline --preset $(PRESET) --out $(OUT)

# The whole chain on the tiny preset (CI runs this after `make test`).
pipeline-tiny:
	$(MAKE) --no-print-directory pipeline PRESET=tiny

# Physical validation against analytic answers (physics.md sec. 5), recorded for the report.
validation:
	RMI_VALIDATION_OUT=$(abspath $(OUT))/validation cargo test --release -p rmi-sph --test validation

report: setup
	$(VENV)/bin/rmi report --out $(OUT)

lint: setup
	cargo fmt --all -- --check
	cargo clippy --workspace --all-targets -- -D warnings
	$(VENV)/bin/ruff check python tests benches

# Rust benchmarks only; benches/compare_splishsplash.py needs pysplishsplash (see its docstring).
bench:
	cargo bench

clean:
	rm -rf $(VENV) python/rmi_sph/_rmi_sph*.so python/rmi_sph/_rmi_sph*.pyd
