# Two entry points (see README "Quick start"); each sets up its own virtual environment.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-quick lint docs venv clean

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

## The everyday subset (under 3 minutes on 2 cores): units, configs, scene files, outputs, CLI,
## capture, the front page's example; not the native-kernel, gradient, fit and design studies
## (`make test` runs everything, as CI does)
QUICK_TESTS := tests/test_architecture.py tests/test_transforms.py tests/test_cli_habits.py \
	tests/test_outputs.py tests/test_scene_rz.py tests/test_scene_3d.py tests/test_design_shapes.py \
	tests/capture tests/fit/test_bad_configs.py tests/fit/test_disc_model.py tests/fit/test_robust.py \
	tests/core/test_grid_units.py tests/core/test_interfaces.py tests/core/test_dispersion.py \
	tests/core/test_stability_energy.py tests/core/test_sources_sensors.py tests/core/test_farfield_lobe.py \
	tests/test_docs_examples.py::test_the_front_page_example_gives_the_piston_beam \
	tests/test_docs_examples.py::test_the_api_reference_lists_every_public_module
test-quick: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow" $(QUICK_TESTS)

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
