# Quick start: `make demo` (set up, then run the main job on the built-in sample)
# and `make test` (set up, then run the tests). Both need only python3.
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
OUT ?= out

.PHONY: setup test test-large demo verify devices bench bench-quick oclgrind clean

$(STAMP): setup.cfg pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $@

setup: $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -q -ra --durations=15

test-large: $(STAMP)
	CLSS_LARGE=1 $(BIN)/python -m pytest -q -ra -m large

demo: $(STAMP)
	$(BIN)/clss demo -o $(OUT)/demo --overwrite

verify: $(STAMP)
	$(BIN)/clss verify --precision all

devices: $(STAMP)
	$(BIN)/clss devices

bench-quick: $(STAMP)
	$(BIN)/clss bench --quick --out $(OUT)/bench

bench: $(STAMP)
	$(BIN)/clss bench --out $(OUT)/bench

oclgrind: $(STAMP)
	$(BIN)/python -m pytest -q -ra tests/test_oclgrind.py

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info .pytest_cache .hypothesis
