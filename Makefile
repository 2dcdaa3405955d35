# stereojax — every target creates its own virtual environment on first use.
PYTHON   ?= python3
VENV     ?= .venv
PY       := $(VENV)/bin/python
CLI      := $(VENV)/bin/stereojax
STAMP    := $(VENV)/.installed-stamp
DATA     ?= ../shared/data
DATASET  ?= kitti2015
# KITTI 2015 defaults to the validation split (frames 1-20 were used for tuning and training)
FRAMES   ?= $(if $(filter kitti2015,$(DATASET)),000021-000030,all)
METHOD   ?= census
OUT      ?= out
LEFT     ?=
RIGHT    ?=
MAX_DISP ?= 228

.PHONY: help install test test-fast demo predict evaluate bench train clean

help:  ## list the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | sed 's/:.*## /\t/' | expand -t 14

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -q --upgrade pip
	$(VENV)/bin/pip install -q -e ".[test]"
	touch $(STAMP)

install: $(STAMP)  ## create .venv and install stereojax with its dependencies

test: $(STAMP)  ## run the whole test suite (slow tests included)
	$(PY) -m pytest -q

test-fast: $(STAMP)  ## run the tests not marked slow
	$(PY) -m pytest -q -m "not slow"

demo: $(STAMP)  ## disparity of the built-in Motorcycle pair -> $(OUT)/demo
	$(CLI) demo --out $(OUT)/demo

predict: $(STAMP)  ## LEFT=... RIGHT=... [MAX_DISP=228 METHOD=census] -> $(OUT)/predict
	@test -n "$(LEFT)" -a -n "$(RIGHT)" || { echo "usage: make predict LEFT=left.png RIGHT=right.png [MAX_DISP=228]" >&2; exit 2; }
	$(CLI) predict "$(LEFT)" "$(RIGHT)" --out $(OUT)/predict --max-disp $(MAX_DISP) --method $(METHOD)

evaluate: $(STAMP)  ## [DATA=../shared/data DATASET=kitti2015|kitti2012|middlebury FRAMES=... METHOD=census] (+ OpenCV SGBM)
	$(CLI) evaluate --data $(DATA) --dataset $(DATASET) --frames $(FRAMES) --method $(METHOD) --sgbm \
	  $(if $(filter middlebury,$(DATASET)),--gt occ) --out experiments/results/evaluate_$(DATASET)_$(METHOD)

bench: $(STAMP)  ## time each stage on a KITTI-sized frame -> experiments/results/bench.{json,md}
	$(PY) experiments/bench.py --out experiments/results

train: $(STAMP)  ## train the downsize/relaxed model on KITTI 2015 000001-000020 (cpu preset, ~35 min) -> runs/kitti2015_downsize
	$(CLI) train --data $(DATA) --dataset kitti2015 --frames 000001-000020 --val-frames 000021-000030 \
	  --preset cpu --head downsize --loss relaxed --out runs/kitti2015_downsize

clean:  ## remove the virtual environment and generated outputs
	rm -rf $(VENV) $(OUT) .pytest_cache build *.egg-info
