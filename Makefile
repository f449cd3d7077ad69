# Lamina: every target bootstraps the pinned virtual environment from requirements.txt first.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
VENV42 := .venv-blender-4.2
PY42 := $(VENV42)/bin/python
EXT_TOOL = $(wildcard $(VENV)/lib/python3.11/site-packages/bpy/*/scripts/addons_core/bl_pkg/cli/blender_ext.py)
OUT ?= out
# One BLAS thread per process: make runs two on the two cores, and numpy's threaded OpenBLAS makes each small solve
# wait for the busy core (the fitter's figures: addon/nodes/fitted.py, one_blas_thread).
export OPENBLAS_NUM_THREADS := 1
# Multiple-scattering training data: a cache outside the repository (resumable; see docs/training.md).
DATA ?= $(HOME)/.cache/lamina/spongecake-ms
ENERGY_DATA ?= $(HOME)/.cache/lamina/spongecake-ms-energy
# Neural participating media: tables of double and multiple scattering per material (resumable; docs/training.md).
MEDIUM_DATA ?= $(HOME)/.cache/lamina/neural-medium

.PHONY: venv test test-5.0 test-unit test-unit-1 test-unit-2 test-blender-5.0 test-4.2 test-all demo bench assets extension dataset train train-1 train-2 train-energy validation-set medium-dataset medium-networks clean

venv: $(VENV)/.stamp

$(VENV)/.stamp: requirements.txt
	@echo "lamina: installing the pinned Blender 5.0 environment into $(VENV) (bpy, numpy, OpenEXR, torch CPU, pytest; about 1.8 GB, a few minutes, once)"
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt
	touch $@

$(VENV42)/.stamp: requirements-blender-4.2.txt
	@echo "lamina: installing Blender 4.2 LTS (bpy 4.2) into $(VENV42) for the API check of make test (about 1 GB, once)"
	$(PYTHON) -m venv $(VENV42)
	$(PY42) -m pip install --quiet -r requirements-blender-4.2.txt
	touch $@

# The unit tests in two halves by file name (test_me* and test_mi* (media, micrograin) and test_o* to test_z*, then
# the rest), so that each core takes one after its Blender suite: the longer half follows the shorter Blender 4.2
# suite, and the two cores end together (on a5ee15f: 4.2 10:36 then 12:49 + the neural-medium files' 1:17; 5.0
# 16:34 then 9:16 less them).
UNIT_2 := $(wildcard tests/unit/test_me*.py tests/unit/test_mi*.py tests/unit/test_[o-z]*.py)
UNIT_1 := $(filter-out $(UNIT_2),$(wildcard tests/unit/test_*.py))

# Four runs on the two cores, the longest first: the Blender tests on bpy 5.0 and on Blender 4.2 LTS (the oldest
# supported; tests marked version_independent run on 5.0 only, tests/blender/conftest.py), then each half of the unit
# tests on the core that frees first; each run's output is printed whole when it ends (-O), and make fails if any
# does. test-5.0 is both suites on bpy 5.0.
test: venv $(VENV42)/.stamp
	$(MAKE) --no-print-directory -j2 -O test-blender-5.0 test-4.2 test-unit-1 test-unit-2

test-5.0: test-unit test-blender-5.0

test-unit: venv
	$(PY) -m pytest -m "not slow" -q -p no:cacheprovider tests/unit

test-unit-1: venv
	$(PY) -m pytest -m "not slow" -q -p no:cacheprovider $(UNIT_1)

test-unit-2: venv
	$(PY) -m pytest -m "not slow" -q -p no:cacheprovider $(UNIT_2)

test-blender-5.0: venv
	$(PY) -m pytest -m "not slow" -q -p no:cacheprovider tests/blender

test-4.2: $(VENV42)/.stamp
	$(PY42) -m pytest -m "not slow" -q -p no:cacheprovider tests/blender

test-all: venv
	$(PY) -m pytest -q

demo: venv
	$(PY) -m addon.cli demo --out $(OUT) --overwrite --resolution 64 --samples 64

bench: venv
	$(PY) -m addon.cli bench --out docs --resolution 48 --samples 32

# The documented default dataset, what the shipped networks saw: 5075 one-layer and 12000 two-layer configurations
# (resumable; about 2.5 hours on 2 cores beside other work, from the runs' logs: docs/training.md, *Dataset*).
dataset: venv
	$(PY) -m training.dataset --out $(DATA)

# The two networks side by side, one core each, in the forms of the shipped ones, from scratch (their manifests say
# what they saw and how long they trained). The shipped networks are chains of warm starts (--init
# addon/bake/weights): the two-layer one this recipe run for 65 minutes on the 6825 configurations made by then, then
# 52 minutes on all 12000 (docs/training.md measures it against a 52-minute run from scratch), then 45 minutes with
# --scaled-loss --energy-weight 0.5 (the shape the energy scale renders); the one-layer one 40 minutes of this recipe
# from the network trained on 1800 configurations before it, on 4568 of the 5075.
TRAIN_1 ?= --area --float32 --wi-per-step 4 --minutes 40
TRAIN_2 ?= --area --hidden 192 192 192 --float32 --wi-per-step 4 --minutes 65
train: venv
	$(MAKE) --no-print-directory -j2 train-1 train-2

train-1 train-2: venv
	$(PY) -m training.train --data $(DATA) --layers $(subst train-,,$@) --threads 1 $(TRAIN_$(subst train-,,$@)) --out addon/bake/weights

# The energy-fraction networks (the share of what single scattering leaves that multiple scattering returns) for
# 1 to 4 layers: the random walk's tallies first (resumable; 54200 stacks, 17476 worker seconds in the shipped
# manifests, about 2.5 hours on 2 cores), then one network after the other on 2 cores, ENERGY_MINUTES each.
ENERGY_MINUTES ?= 10
train-energy: venv
	$(PY) -m training.energy_train --data $(ENERGY_DATA) --layers 1 2 3 4 --threads 2 --minutes $(ENERGY_MINUTES) --out addon/bake/weights

# The neural_medium tables: 56 materials (7 albedos x 8 g), about an hour on 2 cores, resumable; and 4 materials
# between the grid's albedos, only for evaluating the networks off the grid.
medium-dataset: venv
	$(PY) -m training.medium_dataset --out $(MEDIUM_DATA)
	$(PY) -m training.medium_dataset --out $(MEDIUM_DATA)-off-grid --albedos 0.95 0.995 --gs 0.3 0.7 --seed 2

# The neural_medium networks from that dataset (addon/bake/weights/neural_medium_*.npz, 11.8 KB each): 30 minutes of
# training for the multiple network, half of each material's loss weight in proportion to the power within a render's
# reach (falling as exp(-r / 2 mfp)); 15 for the double one (the bake computes double scattering by quadrature; the
# network is kept for comparison), half of its loss weight in proportion to power.
medium-networks: venv
	$(PY) -m training.medium_train --data $(MEDIUM_DATA) --out addon/bake/weights --kinds multiple --minutes 30 \
		--power-share 0.5 --power-range 2 --off-grid $(MEDIUM_DATA)-off-grid
	$(PY) -m training.medium_train --data $(MEDIUM_DATA) --out addon/bake/weights --kinds double --minutes 15 \
		--power-share 0.5 --off-grid $(MEDIUM_DATA)-off-grid

# The asset library (every preset as a material asset with a preview) into $(OUT)/assets, built by this Blender.
assets: venv
	$(PY) -m addon.cli assets --out $(OUT)/assets --overwrite

# The held-out validation sets shipped in tests/data (independent seed, 4x the paths; 3 and 4 layers score the
# grouped prediction): the lobes' and the energy fraction's.
validation-set: venv
	$(PY) -m training.dataset --out tests/data/spongecake_ms_validation --seed 1001 --layers 1 2 3 4 \
		--configs 64 64 16 16 --shard 16 --paths 16000 --n-wi 9 --n-wo 72
	$(PY) -m training.energy_train --layers 1 2 3 4 --validation-set tests/data/spongecake_ms_energy_validation.npz

extension: venv
	mkdir -p dist
	$(PY) $(EXT_TOOL) build --source-dir . --output-dir dist

clean:
	rm -rf dist build $(OUT) .pytest_cache
