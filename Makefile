# Two commands on a fresh machine with Python 3.11 and make:
#   make demo   - run the main job on the built-in simulated hardware
#   make test   - lint and run the whole test suite
# Both create .venv when missing and install what they need.

PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
PIP := $(BIN)/python -m pip
CONSTRAINTS := constraints.txt
PYTEST_ARGS ?=

.PHONY: demo test lint install install-dev model clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet --upgrade pip

# Stamps record what was installed; they go stale when the project metadata changes.
$(VENV)/.installed-run: $(BIN)/python pyproject.toml $(CONSTRAINTS)
	$(PIP) install --quiet -c $(CONSTRAINTS) -e .
	touch $@

$(VENV)/.installed-dev: $(BIN)/python pyproject.toml $(CONSTRAINTS)
	$(PIP) install --quiet -c $(CONSTRAINTS) -e '.[robot,train,dev]'
	touch $@ $(VENV)/.installed-run

install: $(VENV)/.installed-run
install-dev: $(VENV)/.installed-dev

demo: $(VENV)/.installed-run
	$(BIN)/teleop demo

lint: $(VENV)/.installed-dev
	$(BIN)/ruff check .

test: lint
	$(BIN)/python -m pytest $(PYTEST_ARGS)

# Retrain the default model from scratch: the model card's recipe (about 20 minutes on 2 cores, measured).
# Writes MODEL_OUT (default runs/retrain/model); MODEL_OUT=estimator/models/default replaces the shipped one.
OBJECT_TABLE ?= ../shared/seed/dataset_objects_and_compliance.csv
MODEL_RUN ?= runs/retrain
MODEL_OUT ?= $(MODEL_RUN)/model
model: $(VENV)/.installed-dev
	rm -rf $(MODEL_RUN)/records $(MODEL_RUN)/dataset
	$(BIN)/teleop simulate --objects $(OBJECT_TABLE) --grasps-per-object 12 --seed 1 \
		--out $(MODEL_RUN)/records --workers 2
	$(BIN)/estimator build-dataset --records $(MODEL_RUN)/records --out $(MODEL_RUN)/dataset \
		--frames 3 --shifts 3 --size 64x88 --workers 2
	$(BIN)/estimator train --data $(MODEL_RUN)/dataset --out $(MODEL_OUT) \
		--variant depth+fw+analytical --seed 0 --threads 2

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
