# subterra: `make demo` runs the main job, `make test` the whole test suite.
# Needs only Python 3.11+, a Rust toolchain and a C compiler.

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
# maturin gets its own target dir so `cargo test` and the extension build don't rebuild pyo3 for each other.
MATURIN_TARGET := target/maturin
STAMP  := $(VENV)/.subterra-built
SOURCES := $(shell find crates python -name '*.rs' -o -name '*.py' -o -name '*.pyi' -o -name 'Cargo.toml' 2>/dev/null) pyproject.toml Cargo.toml

.PHONY: demo test test-rust test-python build bench fuzz wheel clean

$(VENV)/.deps: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet "maturin>=1.9,<2" numpy pillow pyyaml matplotlib tqdm pytest hypothesis mujoco scipy scikit-image osqp rosbags mcap mcap-ros2-support mcap-ros1-support rerun-sdk "ray>=2.9" atheris cyclonedds pymavlink foxglove-sdk websockets ruff vermin pytest-xdist
	touch $@

$(STAMP): $(VENV)/.deps $(SOURCES)
	VIRTUAL_ENV=$(abspath $(VENV)) CARGO_TARGET_DIR=$(MATURIN_TARGET) $(VENV)/bin/maturin develop --release --quiet
	touch $@

build: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/subterra demo

test: test-rust test-python

test-rust:
	cargo test --workspace --exclude subterra-py
	# The workspace lints (Cargo.toml [workspace.lints]) on every target, the criterion benches
	# and examples included (`cargo test` does not build them); without clippy, a plain check.
	if cargo clippy --version >/dev/null 2>&1; then \
		cargo clippy --workspace --exclude subterra-py --all-targets -- -D warnings; \
	else \
		echo "clippy is not installed (rustup component add clippy): checking without lints"; \
		cargo check --workspace --exclude subterra-py --benches --examples; \
	fi
	# Every intra-doc link resolves and no public doc links to a private item (units in doc
	# comments are written \[m\] so that rustdoc does not read them as links).
	RUSTDOCFLAGS="-D warnings" cargo doc --workspace --exclude subterra-py --no-deps --quiet

# Two workers (pytest-xdist): the suite on the 2-core CI machine in about 6 minutes instead of 9.5.
PYTEST_WORKERS ?= 2
test-python: $(STAMP)
	$(PY) -m ruff check --no-cache python tests fuzz docs
	$(PY) -m pytest -q -n $(PYTEST_WORKERS)

bench: $(STAMP)
	cargo bench -p subterra --bench perception
	$(VENV)/bin/subterra bench perception

# Every fuzz target under libFuzzer for FUZZ_SECONDS each (docs/robustness.md); findings in fuzz/crashes/.
# FUZZ_UNTIL=N stops each target once its running total (fuzz/totals.json) reaches N executions.
FUZZ_SECONDS ?= 60
FUZZ_JOBS    ?= 1
FUZZ_UNTIL   ?=
fuzz: $(STAMP)
	$(PY) fuzz/run.py --seconds $(FUZZ_SECONDS) --jobs $(FUZZ_JOBS) $(if $(FUZZ_UNTIL),--until $(FUZZ_UNTIL))

# The abi3 wheel (CPython >= 3.10) of this machine's platform, in dist/.
wheel: $(VENV)/.deps
	VIRTUAL_ENV=$(abspath $(VENV)) CARGO_TARGET_DIR=$(MATURIN_TARGET) $(VENV)/bin/maturin build --release --quiet --out dist

clean:
	rm -rf $(VENV) target runs
