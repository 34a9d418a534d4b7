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
# Test processes (pytest-xdist): most tests wait on sockets, subprocesses and clocks, so two workers
# halve the wall time on 2 cores. PYTEST_WORKERS=0 runs in one process.
PYTEST_WORKERS ?= 2

.PHONY: help demo test check lint browser tmux install install-dev model evaluate cross-sensor cross-contact replay fine-tune operator-eval clean
.DEFAULT_GOAL := help
.DELETE_ON_ERROR:

help:
	@echo "make demo    run the main job on the built-in simulated hardware (installs what it needs into .venv)"
	@echo "make test    lint and run the whole test suite"
	@echo "make check   lint and run the tests not marked slow, train or robot_sim (while working)"
	@echo "make clean   remove .venv and the tools' caches"
	@echo "Also: install, install-dev, model, evaluate, cross-sensor, cross-contact, replay, fine-tune, operator-eval"
	@echo "(the README says what each does). PYTHON=/path/to/python3.11 picks the interpreter."

# A .venv whose Python is older than 3.11 or has no pip (a venv cut short: killed, or python3-venv
# missing) is made again; a stamp, not the interpreter's link, says it is done.
$(VENV)/.created:
	@if ! $(BIN)/python -c 'import sys, pip; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then \
		$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null || { \
			echo "make: Python 3.11 or later is needed, and PYTHON=$(PYTHON) is not that: install python3.11" \
				"(e.g. sudo apt-get install python3.11 python3.11-venv) or set PYTHON=/path/to/python3.11" >&2; \
			exit 1; }; \
		echo "creating $(VENV) with $(PYTHON)"; rm -rf $(VENV) && $(PYTHON) -m venv $(VENV) && \
		$(PIP) install --quiet --upgrade pip; fi
	touch $@

# Stamps record what was installed; they go stale when the project metadata changes.
$(VENV)/.installed-run: $(VENV)/.created pyproject.toml $(CONSTRAINTS)
	$(PIP) install --quiet -c $(CONSTRAINTS) -e .
	touch $@

# What `make check` runs needs neither the train extra's torch nor robot-sim's franky-sim (1.3 GB between
# them, half the install's time): its tests marked train or robot_sim are left to `make test`.
$(VENV)/.installed-check: $(VENV)/.created pyproject.toml $(CONSTRAINTS)
	$(PIP) install --quiet -c $(CONSTRAINTS) -e '.[robot,dev]'
	touch $@ $(VENV)/.installed-run

# After check's install, not beside it (make -j): the two would write one .venv at once.
$(VENV)/.installed-dev: $(VENV)/.installed-check
	$(PIP) install --quiet -c $(CONSTRAINTS) -e '.[robot,robot-sim,train,dev]'
	touch $@

install: $(VENV)/.installed-run
install-dev: $(VENV)/.installed-dev

demo: $(VENV)/.installed-run
	$(BIN)/teleop demo --operator sim

lint: $(VENV)/.installed-check
	$(BIN)/ruff check .

# Headless Chromium, for the report's browser test and `teleop report --screenshot`: installed when missing
# (as root), else how to install it is printed and the test skips (it fails where CI=true).
browser:
	@command -v chromium >/dev/null || { if [ "$$(id -u)" = 0 ]; then apt-get update -q && apt-get install -y -q chromium; \
		else echo "no chromium: install it with sudo apt-get install -y chromium"; fi; }

# tmux, for the operator console's test in a real terminal: installed when missing (as root), as for browser.
tmux:
	@command -v tmux >/dev/null || { if [ "$$(id -u)" = 0 ]; then apt-get update -q && apt-get install -y -q tmux; \
		else echo "no tmux: install it with sudo apt-get install -y tmux"; fi; }

test: $(VENV)/.installed-dev lint browser tmux
	$(BIN)/python -m pytest -n $(PYTEST_WORKERS) --dist loadgroup $(PYTEST_ARGS)

# While working: lint and the tests not marked slow, train or robot_sim.
check: lint
	$(BIN)/python -m pytest -n $(PYTEST_WORKERS) --dist loadgroup -m "not slow and not train and not robot_sim" $(PYTEST_ARGS)

# Retrain the default model from scratch: the model card's recipe (simulation, dataset, three trainings and
# their pool; the parts' measured times, about 134 minutes added up, are in the model card's Recipe).
# Grasps of every object on the nominal simulated Wedge rig, and on randomized rigs with other gels (the
# Wedge's optics, and a GelSight R1.5's measured optics); the GelSight Mini stays out for `make cross-sensor`.
# Writes MODEL_OUT (default runs/retrain/model); MODEL_OUT=estimator/models/default replaces the shipped one.
OBJECT_TABLE ?= ../shared/seed/dataset_objects_and_compliance.csv
MODEL_RUN ?= runs/retrain
MODEL_OUT ?= $(MODEL_RUN)/model
MODEL_VARIANT ?= depth+fw+analytical
# The model's input window (mm): the R1.5's pad, the smallest of its training sensors.
MODEL_WINDOW_MM ?= 12.98x17.70
SHIPPED_MODELS := estimator/models/default estimator/models/cnn-depth-fw estimator/models/hybrid-depth-analytical
model: $(VENV)/.installed-dev
	rm -rf $(MODEL_RUN)/records $(MODEL_RUN)/dataset $(MODEL_RUN)/seed0 $(MODEL_RUN)/seed1 $(MODEL_RUN)/seed2
	$(BIN)/teleop simulate --objects $(OBJECT_TABLE) --grasps-per-object 12 --seed 1 \
		--out $(MODEL_RUN)/records/wedge_nominal --workers 2
	$(BIN)/teleop simulate --objects $(OBJECT_TABLE) --grasps-per-object 6 --seed 2 --randomize-rig --vary-gel \
		--out $(MODEL_RUN)/records/wedge_rig_gel --workers 2
	$(BIN)/teleop simulate --objects $(OBJECT_TABLE) --grasps-per-object 6 --seed 3 --randomize-rig --vary-gel \
		--settings configs/rigs/gelsight.toml --out $(MODEL_RUN)/records/gelsight_rig_gel --workers 2
	$(BIN)/estimator build-dataset --records $(MODEL_RUN)/records --out $(MODEL_RUN)/dataset \
		--frames 3 --shifts 3 --size 64x88 --window $(MODEL_WINDOW_MM) --workers 2
	$(foreach seed,0 1 2,$(BIN)/estimator train --data $(MODEL_RUN)/dataset --out $(MODEL_RUN)/seed$(seed) \
		--variant $(MODEL_VARIANT) --seed $(seed) --patience 30 --threads 2 &&) true
	$(BIN)/estimator pool --model $(MODEL_RUN)/seed0 --model $(MODEL_RUN)/seed1 --model $(MODEL_RUN)/seed2 \
		--data $(MODEL_RUN)/dataset --out $(MODEL_OUT) --overwrite

# The shipped models on simulated grasps of objects none of them trained on (their test split), after
# `make model` made the records: the model card's figures. The nominal Wedge rig (runs/evaluate/figures.json),
# then the randomized rigs of the two training optics (runs/evaluate/<rig>/), each shown on its own display.
RANDOMIZED_RIGS := wedge_rig_gel:configs/settings.toml gelsight_rig_gel:configs/rigs/gelsight.toml
UNSEEN_BY_SHIPPED = $(foreach m,$(SHIPPED_MODELS),--unseen-by $(m) --model $(m))
evaluate: $(VENV)/.installed-dev
	mkdir -p runs/evaluate
	$(BIN)/estimator evaluate $(MODEL_RUN)/records/wedge_nominal $(UNSEEN_BY_SHIPPED) \
		--workers 2 --rows runs/evaluate/rows.csv --plot runs/evaluate/plot.png --json > runs/evaluate/figures.json
	for r in $(RANDOMIZED_RIGS); do rig=$${r%%:*}; mkdir -p runs/evaluate/$$rig && \
		$(BIN)/estimator evaluate $(MODEL_RUN)/records/$$rig --settings $${r#*:} $(UNSEEN_BY_SHIPPED) --workers 2 \
		--rows runs/evaluate/$$rig/rows.csv --json > runs/evaluate/$$rig/figures.json || exit 1; done

# A sensor held out of training and model selection: the shipped models' test objects (their metadata's
# data.objects.test) rendered through the GelSight Mini's measured optics on randomized rigs, estimated with
# that rig's settings and its own calibration (fitted by `estimator calibrate` on its simulated presses).
# About 75 s (measured). Writes runs/cross-sensor/.
CROSS_RIG ?= configs/rigs/gelsight_mini.toml
TEST_OBJECTS = $(shell $(BIN)/python -c "import json; print(','.join(json.load(open('estimator/models/default/metadata.json'))['data']['objects']['test']))")
cross-sensor: $(VENV)/.installed-dev
	rm -rf runs/cross-sensor
	$(BIN)/teleop simulate --objects $(OBJECT_TABLE) --only $(TEST_OBJECTS) --grasps-per-object 4 --seed 4 \
		--randomize-rig --settings $(CROSS_RIG) --out runs/cross-sensor/records --workers 2
	$(BIN)/estimator evaluate runs/cross-sensor/records --settings $(CROSS_RIG) \
		$(UNSEEN_BY_SHIPPED) --workers 2 \
		--rows runs/cross-sensor/rows.csv --plot runs/cross-sensor/plot.png --json > runs/cross-sensor/figures.json

# A contact model held out of training and model selection: the shipped models' test objects on the nominal
# Wedge rig with the gel simulated as a half-space instead of the layer bonded to acrylic that every training
# grasp assumed. About 2 minutes. Writes runs/cross-contact/ (figures.json: soft_* for the soft objects).
cross-contact: $(VENV)/.installed-dev
	rm -rf runs/cross-contact
	$(BIN)/teleop simulate --objects $(OBJECT_TABLE) --only $(TEST_OBJECTS) --grasps-per-object 3 --seed 4 \
		--gel-model half-space --out runs/cross-contact/records --workers 2
	$(BIN)/estimator evaluate runs/cross-contact/records $(UNSEEN_BY_SHIPPED) --workers 2 \
		--rows runs/cross-contact/rows.csv --plot runs/cross-contact/plot.png --json > runs/cross-contact/figures.json

# A rehearsal set for fine-tuning: the shipped models' kind of training data, smaller (4 grasps of every object on
# the nominal Wedge rig, 2 on randomized Wedge rigs and 2 on randomized R1.5 rigs, other gels: `make model`'s
# recipe and seeds with fewer grasps). About 12 minutes on 2 cores. Writes runs/replay/.
replay: $(VENV)/.installed-dev
	rm -rf runs/replay
	$(BIN)/teleop simulate --objects $(OBJECT_TABLE) --grasps-per-object 4 --seed 1 \
		--out runs/replay/records/wedge_nominal --workers 2
	$(BIN)/teleop simulate --objects $(OBJECT_TABLE) --grasps-per-object 2 --seed 2 --randomize-rig --vary-gel \
		--out runs/replay/records/wedge_rig_gel --workers 2
	$(BIN)/teleop simulate --objects $(OBJECT_TABLE) --grasps-per-object 2 --seed 3 --randomize-rig --vary-gel \
		--settings configs/rigs/gelsight.toml --out runs/replay/records/gelsight_rig_gel --workers 2
	$(BIN)/estimator build-dataset --records runs/replay/records --out $(REPLAY_DATA) \
		--frames 3 --shifts 3 --size 64x88 --window $(MODEL_WINDOW_MM) --workers 2

# Fine-tuning for the held-out sensor, after `make cross-sensor` and `make replay`: 3 grasps on randomized Mini
# rigs of each of 5 objects the shipped models trained on (on other sensors; never their test objects): the
# train-split objects nearest five log-spaced moduli over the display's range, from the softest to 3 MPa (rigid
# objects need no scale; the replay keeps what the model knew of them). It rehearses FINE_TUNE_REPLAY (the models'
# own kind of training data) and recalibrates on its validation objects; FINE_TUNE_REPLAY= fine-tunes without.
# Then the shipped and the fine-tuned models on the cross-sensor records. About 3 minutes. Writes runs/fine-tune/.
FINE_TUNE_OBJECTS ?= pillow,blue_foam_brick,green_elastic_ball,fake_half_rose,rubber_band_ball
REPLAY_DATA := runs/replay/dataset
FINE_TUNE_REPLAY ?= $(REPLAY_DATA)
FINE_TUNED := default cnn-depth-fw
fine-tune: $(VENV)/.installed-dev
	@test -d runs/cross-sensor/records || { echo "no runs/cross-sensor/records: run make cross-sensor first"; exit 1; }
	@test -z "$(FINE_TUNE_REPLAY)" -o -d "$(FINE_TUNE_REPLAY)" || { echo "no $(FINE_TUNE_REPLAY): run make replay first"; exit 1; }
	rm -rf runs/fine-tune
	$(BIN)/teleop simulate --objects $(OBJECT_TABLE) --only $(FINE_TUNE_OBJECTS) --grasps-per-object 3 --seed 5 \
		--randomize-rig --settings $(CROSS_RIG) --out runs/fine-tune/records --workers 2
	$(BIN)/estimator build-dataset --records runs/fine-tune/records --out runs/fine-tune/dataset \
		--frames 3 --shifts 3 --size 64x88 --window $(MODEL_WINDOW_MM) --settings $(CROSS_RIG) --workers 2
	$(foreach m,$(FINE_TUNED),$(BIN)/estimator fine-tune --model estimator/models/$(m) \
		--data runs/fine-tune/dataset --out runs/fine-tune/models/$(m) $(if $(FINE_TUNE_REPLAY),--replay $(FINE_TUNE_REPLAY)) &&) true
	$(BIN)/estimator evaluate runs/cross-sensor/records --settings $(CROSS_RIG) --workers 2 \
		$(foreach m,$(FINE_TUNED),--unseen-by estimator/models/$(m) --model estimator/models/$(m) \
		--unseen-by runs/fine-tune/models/$(m) --model runs/fine-tune/models/$(m)) \
		--rows runs/fine-tune/rows.csv --json > runs/fine-tune/figures.json

# Grasps a person makes against the paper's scripted grasp: the shipped models' test objects grasped by the
# simulated operator (variable speed, pauses, back-offs and re-squeezes, grasps that never hold still), by
# the scripted grasp, and by the scripted grasp squeezing lightly (4.8-12 N, where the nominal rig's training
# grasps go to 12-30 N), same seeds, poses and objects; the hybrid scored on each. 12 grasps of each object
# (516 a set, as the nominal rig's test set): with 3, one grasp moves a set's dangerous misses and felt error
# more than the sets differ. About 6 minutes. Writes runs/operator-eval/{script,sim,light}/figures.json.
OPERATOR_GRASPS ?= 12
OPERATOR_EVAL_SETS := script:--operator=script sim:--operator=sim light:--target-force-n=12
operator-eval: $(VENV)/.installed-dev
	rm -rf runs/operator-eval
	for s in $(OPERATOR_EVAL_SETS); do name=$${s%%:*}; mkdir -p runs/operator-eval/$$name && \
		$(BIN)/teleop simulate --objects $(OBJECT_TABLE) --only $(TEST_OBJECTS) --grasps-per-object $(OPERATOR_GRASPS) \
			--seed 6 $${s#*:} --out runs/operator-eval/$$name/records --workers 2 && \
		$(BIN)/estimator evaluate runs/operator-eval/$$name/records --methods hybrid \
			--unseen-by estimator/models/default --model estimator/models/default --workers 2 \
			--rows runs/operator-eval/$$name/rows.csv --json > runs/operator-eval/$$name/figures.json || exit 1; done

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
