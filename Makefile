# zsbfm: `make train` and `make test` set everything up on a fresh machine.
ENV    ?= fourrooms
ALGO   ?= fb
SEEDS  ?= 3
SIZE   ?= cpu
ARGS   ?=
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: train test test-all bench data table clean help

help:
	@echo "make train [ENV=fourrooms|doors|pointmass|antwind] [ALGO=fb] [SEEDS=3] [SIZE=cpu|long|paper (zsbfm.names.SIZES)] [ARGS='--set steps=2000']"
	@echo "make test        fast test suite (CPU, minutes)"
	@echo "make test-all    including slow tests"
	@echo "make bench       throughput benchmarks"
	@echo "make data        collect and save the ENV dataset (antwind: train the wind-aware expert, record, cache)"
	@echo "make table [ENV=fourrooms|doors|pointmass|antwind] [SEEDS=3] [ARGS='--set steps=2000']  every method -> results/ENV.{json,md,png}"

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

train: $(STAMP)
	$(PY) -m zsbfm train --env $(ENV) --algo $(ALGO) --seeds $(SEEDS) --size $(SIZE) $(ARGS)

# pytest exits 5 when it collects no tests; make treats any non-zero exit as failure.
# -n auto: one pytest-xdist worker per core; the suite is mostly XLA compiles, which are
# single-threaded, so two workers on 2 cores take ~0.6x the time of one.
test: $(STAMP)
	$(PY) -m pytest -q -n auto

test-all: $(STAMP)
	$(PY) -m pytest -q -n auto -m ""

bench: $(STAMP)
	$(PY) benchmarks/throughput.py

data: $(STAMP)
	$(PY) -m zsbfm collect --env $(ENV)

table: $(STAMP)
	$(PY) experiments/table.py --env $(ENV) --seeds $(SEEDS) --size $(SIZE) $(ARGS)

clean:
	rm -rf runs datasets .pytest_cache
