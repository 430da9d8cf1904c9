# Developer entry points. `make test` is the full check CI runs (see .ci/run).
#
# `make setup` keeps a virtual environment in .venv with the exact versions of
# requirements-dev.txt and the package itself (built in release mode by maturin). Stamp files
# inside .venv make re-runs cheap: the tools are reinstalled only when requirements-dev.txt
# changes, the native module is rebuilt only when a Rust source or manifest changes. Delete
# .venv to start over.

PYTHON ?= python3
# CI passes VENV=<dir in its cache> so one environment serves every fresh clone it tests.
VENV ?= .venv
VENV_PY := $(VENV)/bin/python
# The exact versions to install (see its header). The stamp's name carries a hash of the pins:
# changing one reinstalls, and an environment that already holds this set (CI's) is used as it is.
LOCK := requirements-dev.txt
TOOLS_STAMP := $(VENV)/.tools-$(shell grep -v '^\#' $(LOCK) | sha256sum | cut -c1-16)
BUILD_STAMP := $(VENV)/.build-stamp
# torch and the CUDA libraries it links to: about 4 GB installed.
BIG_WHEELS := ^(torch|nvidia-|cuda-)

# Everything the native module is built from (the binding crate and the core it links).
RUST_INPUTS := Cargo.toml Cargo.lock $(shell find crates -name '*.rs' -o -name Cargo.toml)

# pyo3's build script picks an interpreter from PYO3_PYTHON; pointing cargo (clippy included)
# and maturin at the same one lets them share build results instead of rebuilding pyo3.
export PYO3_PYTHON := $(abspath $(VENV_PY))
export PIP_DISABLE_PIP_VERSION_CHECK := 1

.PHONY: setup lock test test-rust test-python demo pipeline pipeline-tiny validation report lint bench
.PHONY: wheel wheel-check
.PHONY: clean

setup: $(BUILD_STAMP)

# The pinned versions need CPython 3.11+ (numpy 2.4 and others dropped 3.10); say so before
# pip fails on the first of them. (`pip install .[learn]` still works on 3.10.)
$(VENV_PY):
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else \
		"make setup needs Python 3.11 or newer for requirements-dev.txt; this is " \
		+ sys.version.split()[0] + ": pass PYTHON=python3.11 (or newer)")'
	$(PYTHON) -m venv $(VENV)

# Every line --no-deps (the lock is complete and leaves out torch's optional triton) and no wheel
# cache: the wheels would hold another 3 GB on disk beside the environment. The big wheels go one
# per pip call, so at most one of them (<= 1 GB) waits on disk while it is installed.
$(TOOLS_STAMP): | $(VENV_PY)
	grep -E '^pip==' $(LOCK) | xargs $(VENV_PY) -m pip install --no-cache-dir
	grep -E '$(BIG_WHEELS)' $(LOCK) | xargs -n1 $(VENV_PY) -m pip install --no-cache-dir --no-deps
	grep -vE '$(BIG_WHEELS)|^pip==|^#|^$$' $(LOCK) | xargs $(VENV_PY) -m pip install --no-cache-dir --no-deps
	touch $@

# Re-resolves requirements-dev.txt from pyproject.toml's extras against PyPI (metadata only,
# about 20 s); see tools/lock.py.
lock: | $(VENV_PY)
	$(VENV_PY) tools/lock.py

# `maturin develop` installs the runtime dependencies, copies the extension module into
# python/rmi_sph/ and points the venv at python/ so edits to .py files need no reinstall.
# The module is built against the stable ABI (one _rmi_sph.abi3.so serves CPython 3.10+);
# an older per-interpreter build (_rmi_sph.cpython-3XX-*.so) would be imported before it,
# so it goes first.
$(BUILD_STAMP): $(TOOLS_STAMP) $(RUST_INPUTS) pyproject.toml
	rm -f python/rmi_sph/_rmi_sph.*.so python/rmi_sph/_rmi_sph.*.pyd
	VIRTUAL_ENV=$(abspath $(VENV)) $(VENV)/bin/maturin develop --release
	touch $@

test: setup test-rust test-python

# The workspace's default members leave out the binding, so this needs no Python.
test-rust:
	cargo test --release

# A hung test (a deadlock) fails the run after 30 minutes instead of holding CI: SIGABRT makes
# pytest's fault handler print every thread's traceback first. The slowest tests are listed at
# the end, so a run that grows shows where.
test-python: setup
	timeout --signal=ABRT 1800 $(VENV_PY) -m pytest -q --durations=15 tests

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

# An abi3 wheel for CPython 3.10+ that installs on glibc 2.28 and newer (RHEL/Rocky 8, Ubuntu
# 20.04 and later; the plain `maturin build` wheel needs the build machine's glibc): maturin
# links through zig (PyPI's ziglang) against glibc 2.28. Its tools live in an environment of
# their own, outside the lock. `make wheel-check` installs the wheel into a fresh environment
# without torch and checks that a trial there ends in the same bits as the source build.
WHEEL_TOOLS := $(VENV)-wheel-tools
ZIGLANG := ziglang==0.17.0
MATURIN := $(shell grep '^maturin==' $(LOCK))
DIST ?= dist

$(WHEEL_TOOLS)/bin/maturin:
	$(PYTHON) -m venv $(WHEEL_TOOLS)
	$(WHEEL_TOOLS)/bin/pip install -q $(ZIGLANG) $(MATURIN)

wheel: $(WHEEL_TOOLS)/bin/maturin
	rm -f $(DIST)/rmi-*.whl
	PATH="$(abspath $(WHEEL_TOOLS))/bin:$$PATH" maturin build --release --zig \
		--compatibility manylinux_2_28 --interpreter $(PYTHON) --out $(DIST)

wheel-check: wheel setup
	rm -rf $(DIST)/check-venv
	$(PYTHON) -m venv $(DIST)/check-venv
	$(DIST)/check-venv/bin/pip install -q $(DIST)/rmi-*-manylinux_2_28_x86_64.whl
	$(DIST)/check-venv/bin/python tools/wheel_check.py --installed > $(DIST)/wheel.txt
	$(VENV_PY) tools/wheel_check.py > $(DIST)/source.txt
	diff $(DIST)/source.txt $(DIST)/wheel.txt && cat $(DIST)/wheel.txt

# Physical validation against analytic answers (docs/physics.md §5), recorded for the report.
validation:
	RMI_VALIDATION_OUT=$(abspath $(OUT))/validation cargo test --release -p rmi-sph --test validation

report: setup
	$(VENV)/bin/rmi report --out $(OUT)

lint: setup
	cargo fmt --all -- --check
	cargo clippy --workspace --all-targets -- -D warnings
	$(VENV)/bin/ruff check python tests benches studies tools examples

# Rust benchmarks only; benches/compare_splishsplash.py needs pysplishsplash (see its docstring).
bench:
	cargo bench

clean:
	rm -rf $(VENV) python/rmi_sph/_rmi_sph*.so python/rmi_sph/_rmi_sph*.pyd
