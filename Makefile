# mepnet: `make demo` and `make test` work on a machine that has never seen the project.
# They create .venv, install the package (release build of the Rust extension) and its
# dependencies, then run.

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
export VIRTUAL_ENV := $(abspath $(VENV))
export PATH := $(abspath $(VENV))/bin:$(PATH)

.PHONY: all demo test bench lint install venv fmt clean

all: install

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip

# The build tool; the package's own dependencies come from pyproject.toml through maturin.
$(VENV)/.deps: pyproject.toml | $(PY)
	$(PY) -m pip install --quiet "maturin>=1.7,<2"
	touch $@

# The extension is rebuilt (incrementally) every time: cargo decides what changed.
install: $(VENV)/.deps
	$(VENV)/bin/maturin develop --release --quiet --extras dev

demo: install
	$(PY) -m mepnet.infer

test: install
	cargo test --workspace --exclude brickgeom-py
	$(PY) -m pytest -q

bench: install
	$(PY) tests/benchmarks/bench_geom.py --out docs/benchmarks.md
	$(PY) tests/benchmarks/bench_render.py --out docs/benchmarks.md
	$(PY) tests/benchmarks/bench_synth.py --out docs/benchmarks.md
	$(PY) tests/benchmarks/bench_stage2.py --out docs/benchmarks.md
	$(PY) tests/benchmarks/bench_cameras.py --out docs/benchmarks.md
	$(PY) tests/benchmarks/bench_detector.py --out docs/benchmarks.md
	$(PY) tests/benchmarks/bench_styles.py --out docs/benchmarks.md
	$(PY) tests/benchmarks/bench_repair.py --out docs/benchmarks.md

lint: install
	cargo fmt --all -- --check
	cargo clippy --workspace --all-targets -- -D warnings
	$(VENV)/bin/ruff check python tests
	$(PY) -m mypy.stubtest mepnet._brickgeom --allowlist tests/stubtest-allowlist.txt

fmt:
	cargo fmt --all
	$(VENV)/bin/ruff format python tests

clean:
	rm -rf $(VENV) target
