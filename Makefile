# Every target bootstraps its own virtual environment with pinned dependencies.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-loaded bench faults soak lint format clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/leadthrough demo --out demo_out

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/pytest -q

# The stack tier beside a competing CPU load: a busy process pinned to CPU 0 at the product's
# priority (tests/cpu_load.py). LOAD_ARGS="--taskset 0" also pins the product to CPU 0 beside
# it; LOAD_ARGS="--cores 0,1" loads every core.
LOAD_ARGS ?=
test-loaded: $(STAMP)
	$(BIN)/python tests/cpu_load.py $(LOAD_ARGS) -- $(BIN)/pytest -q -m stack

bench: $(STAMP)
	$(BIN)/leadthrough bench --rates 250 500 --cycles 10000 --json bench_out/bench.json
	$(BIN)/python -m gateway.zenoh_bench --n 3000
	$(BIN)/python -m drivers.can.codec_bench
	$(BIN)/python -m control.identification.bench
	$(BIN)/leadthrough teach-bench --plant-seed 0 --out bench_out/teach_bench

faults: $(STAMP)
	$(BIN)/python -m sim_bridge.faults --out faults_out
	LEADTHROUGH_FUZZ_REPLIES=100000 $(BIN)/pytest -q -p no:cacheprovider -s \
		tests/transport/test_modbus_fuzz.py

soak: $(STAMP)
	$(BIN)/python -m sim_bridge.soak --minutes 10 --rate-hz 250 --frame-loss 0.01 --out soak_out

lint: $(STAMP)
	$(BIN)/ruff check .

format: $(STAMP)
	$(BIN)/ruff format .

clean:
	rm -rf $(VENV) demo_out faults_out soak_out .cache
