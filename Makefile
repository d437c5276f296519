# Two entry points (see README "Quick start"); each sets up its own virtual environment.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint docs venv clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

## Main job: emulated rig -> capture over a pseudo-terminal -> fit -> report in out/demo
demo: $(STAMP)
	$(BIN)/difflattice demo --out out/demo --overwrite

## Test suite
test: $(STAMP)
	$(BIN)/python -m pytest -q

## Lint (ruff) and type check (mypy); CI runs it
lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks fitting designs docs data
	$(BIN)/ruff format --check src tests benchmarks fitting designs docs data
	$(BIN)/mypy

## Documentation site (mkdocs, warnings as errors; its own .venv-docs) in out/site
docs: $(STAMP)
	bash docs/build.sh

clean:
	rm -rf $(VENV) out
