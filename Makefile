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
METHOD   ?= best
OUT      ?= out
LEFT     ?=
RIGHT    ?=
MAX_DISP ?= 228
# experiments (see experiments/common.py): SGD steps per model, seeds, Delta values of the sweep
STEPS    ?= 1000
SEEDS    ?= 3
SWEEP_SEEDS ?= 2
# KITTI 2015 test frames scored in Tables 1-2 (the first N of 000021-000030; Table 4 uses all 10)
KITTI_FRAMES ?= 3
DELTAS   ?= 0 0.03 0.04 0.05 0.06 0.07
EXP      := $(PY) experiments

.PHONY: help install test test-fast demo predict evaluate results-evaluate bench native-floor train train-middlebury \
        search-chain indoor-folds indoor-ship rectify-roundtrip sky-confidence dense-distill dense-distill-final band-search middlebury-folds middlebury-folds-student middlebury-cascade augment-compare compressed confidence self-training train-compact bench-anchors table1 sweep-delta table3 table4 figures depth-example report experiments clean

help:  ## list the targets
	@grep -E '^[a-z0-9-]+:.*## ' $(MAKEFILE_LIST) | sed 's/:.*## /\t/' | expand -t 18

# the native kernels (C++, built by setup.py): a changed source rebuilds them on the next make test/install
NATIVE_SRC := setup.py $(wildcard stereojax/*.h stereojax/*/*.h stereojax/*/*.cc)

$(STAMP): pyproject.toml $(NATIVE_SRC)
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -q --upgrade pip
	$(VENV)/bin/pip install -q -e ".[test,experiments]"
	touch $(STAMP)

install: $(STAMP)  ## create .venv and install stereojax with its dependencies

# two worker processes (pytest-xdist) share the suite's compile cache: 34 -> 25 min on 2 cores
TEST_WORKERS ?= 2
test: $(STAMP)  ## run the whole test suite (slow tests included) [TEST_WORKERS=2]
	$(PY) -m pytest -q -n $(TEST_WORKERS) --durations=20

test-fast: $(STAMP)  ## run the tests not marked slow
	$(PY) -m pytest -q -n $(TEST_WORKERS) -m "not slow"

demo: $(STAMP)  ## disparity of the built-in Motorcycle pair -> $(OUT)/demo
	$(CLI) demo --out $(OUT)/demo

predict: $(STAMP)  ## LEFT=... RIGHT=... [MAX_DISP=228 METHOD=best|learned|census|sad] -> $(OUT)/predict
	@test -n "$(LEFT)" -a -n "$(RIGHT)" || { echo "usage: make predict LEFT=left.png RIGHT=right.png [MAX_DISP=228]" >&2; exit 2; }
	$(CLI) predict "$(LEFT)" "$(RIGHT)" --out $(OUT)/predict --max-disp $(MAX_DISP) --method $(METHOD)

evaluate: $(STAMP)  ## [DATA=../shared/data DATASET=kitti2015|kitti2012|middlebury FRAMES=... METHOD=best|census|...] (+ OpenCV SGBM) -> $(OUT)/evaluate_<dataset>_<method>
	$(CLI) evaluate --data $(DATA) --dataset $(DATASET) --frames $(FRAMES) --method $(METHOD) --sgbm \
	  $(if $(filter middlebury,$(DATASET)),--gt occ) --out $(OUT)/evaluate_$(DATASET)_$(METHOD)

# the project's own scored runs, the only ones `make report` reads (experiments/results/evaluate_*)
RESULTS_EVAL := $(CLI) evaluate --data $(DATA) --sgbm
results-evaluate: $(STAMP)  ## the project's evaluations behind the README tables -> experiments/results/evaluate_* (then make report)
	$(RESULTS_EVAL) --dataset kitti2015 --frames 000021-000030 --method best --out experiments/results/evaluate_kitti2015_best
	$(RESULTS_EVAL) --dataset kitti2015 --frames 000021-000030 --weights kitti2015_compact --out experiments/results/evaluate_kitti2015_compact
	$(RESULTS_EVAL) --dataset kitti2015 --frames 000021-000030 --method census --out experiments/results/evaluate_kitti2015_census
	$(RESULTS_EVAL) --dataset kitti2015 --frames 000001 --gt both --method best --out experiments/results/evaluate_kitti2015_000001_both
	$(RESULTS_EVAL) --dataset kitti2012 --gt occ --method best --out experiments/results/evaluate_kitti2012_best
	$(RESULTS_EVAL) --dataset kitti2012 --gt occ --method census --out experiments/results/evaluate_kitti2012_census
	$(RESULTS_EVAL) --dataset middlebury --frames Cones_2003Q,Teddy_2003Q,Tsukuba_2001,Venus_2001,Motorcycle_MiddEval3Q --gt both --method best --out experiments/results/evaluate_middlebury_best
	$(RESULTS_EVAL) --dataset middlebury --gt occ --method census --out experiments/results/evaluate_middlebury_census

bench: $(STAMP)  ## time best, exact head, census chain and OpenCV SGBM on KITTI 000021, cold/warm/cache, peak RSS, stage profile, entries/s vs OpenCV, make demo's computation; issue targets -> experiments/results/bench.{json,md}
	$(CLI) bench --data $(DATA) --out experiments/results
	$(EXP)/bench_report.py --results experiments/results

native-floor: $(STAMP)  ## issue 51: each native kernel beside a copy of the chain's volume (the memory floor), kept and fresh pages, SGBM in the same run (~1 min) -> experiments/results/native_floor.{json,md}
	$(EXP)/native_floor.py --data $(DATA)

dense-distill: $(STAMP)  ## issue 26: students distilled from the full KITTI model's band costs (targets cached in runs/dense_targets, ~45 min) -> experiments/results/dense_distill.{json,md,png}
	$(EXP)/dense_distill.py --data $(DATA)

dense-distill-final: $(STAMP)  ## issue 26's last step: the chosen student on all 20 frames + unlabeled pairs, 90 000 steps (~40 min), scored on 000021-000030 -> experiments/results/dense_distill_final.*
	$(EXP)/dense_distill.py --data $(DATA) --final

band-search: $(STAMP)  ## band settings (width, coarse scale, widening) on KITTI 2015 000001-000019 (odd): coverage, > 3 px and time beside the full range (~10 min) -> experiments/results/band_search_census.*
	$(PY) experiments/band_search.py --data $(DATA) --method census

ANCHORS_VENV ?= .venv-anchors
bench-anchors: $(STAMP)  ## optional: CNES Pandora (MC-CNN + libsgm) in its own venv, timed on the bench frame beside best and SGBM (~5 min with the install) -> experiments/results/anchors.*
	test -x $(ANCHORS_VENV)/bin/python || $(PYTHON) -m venv $(ANCHORS_VENV)
	$(ANCHORS_VENV)/bin/pip install -q torch==2.13.0
	$(ANCHORS_VENV)/bin/pip install -q pandora pandora-plugin-libsgm libsgm mccnn pandora-plugin-mccnn
	$(PY) experiments/bench_anchors.py --data $(DATA) --anchors-python $(ANCHORS_VENV)/bin/python

# stage 1 of the KITTI model, also the common pre-trained model of the Middlebury recipe
runs/kitti2015_downsize/train_summary.json: $(STAMP)
	$(CLI) train --data $(DATA) --dataset kitti2015 --frames 000001-000020 --val-frames 000021-000030 \
	  --preset cpu --head downsize --loss relaxed --out runs/kitti2015_downsize

train: runs/kitti2015_downsize/train_summary.json  ## train the shipped KITTI model on KITTI 2015 000001-000020: 50000 steps from scratch, then 40000 more at lr 0.01 (cpu preset, about 95 min here) -> runs/kitti2015_continue
	$(CLI) train --data $(DATA) --dataset kitti2015 --frames 000001-000020 --val-frames 000021-000030 \
	  --preset cpu --head downsize --loss relaxed --init runs/kitti2015_downsize/checkpoint.msgpack \
	  --lr 0.01 --steps 40000 --out runs/kitti2015_continue

train-middlebury: runs/kitti2015_downsize/train_summary.json  ## the shipped Middlebury model: the 50000-step KITTI model fine-tuned 3000 steps on six scenes (Motorcycle held out), then its chain settings searched (about 20 min after stage 1 of make train) -> runs/middlebury_finetune
	$(CLI) train --data $(DATA) --dataset middlebury \
	  --frames Aloe_opencv,Cones_2003Q,Reindeer_2006H,Teddy_2003Q,Tsukuba_2001,Venus_2001 \
	  --val-frames Motorcycle_MiddEval3Q --preset cpu --steps 3000 --lr 0.005 --head downsize --loss relaxed \
	  --init runs/kitti2015_downsize/checkpoint.msgpack --out runs/middlebury_finetune
	$(EXP)/search_chain.py --dataset middlebury --frames Cones_2003Q,Reindeer_2006H,Teddy_2003Q,Tsukuba_2001,Venus_2001 \
	  --rounds 1 --space small --weights runs/middlebury_finetune/checkpoint.msgpack --tag _finetune

search-chain: $(STAMP)  ## search the KITTI model's chain settings on training frames 1-19 (odd), cached volumes (~40 min) -> experiments/results/chain_search_kitti2015.*
	$(EXP)/search_chain.py --dataset kitti2015 --frames 1,3,5,7,9,11,13,15,17,19 --rounds 2

middlebury-folds-student: $(STAMP)  ## issue 26: the same folds for the compact student distilled from each fold's teacher (~35 min) -> experiments/results/middlebury_folds_student.*
	$(EXP)/middlebury_folds.py --data $(DATA) --init kitti2015 --border neutral --student

middlebury-cascade: $(STAMP)  ## issue 38: the folds of middlebury-folds-student plus the cascade (fold student everywhere, fold teacher at q = 5-40 % of pixels) and the fold teacher's time (~55 min) -> experiments/results/middlebury_folds_cascade.*
	$(EXP)/middlebury_folds.py --data $(DATA) --init kitti2015 --border neutral --cascade 0.05,0.1,0.2,0.4

middlebury-folds: $(STAMP)  ## Middlebury, 3 folds: fine-tune the shipped KITTI model, search settings, score held-out scenes vs SGBM, neutral strip (~40 min) -> experiments/results/middlebury_folds_neutral.*
	$(EXP)/middlebury_folds.py --data $(DATA) --init kitti2015 --border neutral

indoor-folds: $(STAMP)  ## issue 52: 24 Middlebury scenes in 3 folds by family: reference rows, then each fold's model (train, search, bands or full, score); resumable, hours on 2 cores -> experiments/results/indoor_folds.{json,md}
	$(EXP)/indoor_folds.py reference --data $(DATA)
	for i in 0 1 2; do $(EXP)/indoor_folds.py fold $$i --data $(DATA) || exit 1; done
	$(EXP)/indoor_folds.py table --data $(DATA)

indoor-ship: $(STAMP)  ## issue 52: the shipped `middlebury` model: kitti2015 fine-tuned on the 23 scenes (not Motorcycle), chain searched, bands or full range chosen, weights + card written (~40 min on 2 cores) -> stereojax/models/weights/middlebury_*
	$(EXP)/indoor_folds.py ship --data $(DATA)

rectify-roundtrip: $(STAMP)  ## issue 54: KITTI pairs made raw on purpose, rectified by stereojax, depth vs the GT points (~3 min) -> experiments/results/rectify_roundtrip.{json,md}
	$(EXP)/rectify_roundtrip.py --data $(DATA)

sky-confidence: $(STAMP)  ## issue 55: saturated textureless sky under --min-confidence 0.3 on KITTI 000001-000030 (~6 min) -> experiments/results/sky_confidence.{json,md}
	$(EXP)/sky_confidence.py --data $(DATA)

compressed: $(STAMP)  ## issue 16: train the compressed candidates on KITTI 2015 1-15 (direct and distilled), score them, choose by experiments/PROTOCOL.md (~45 min) -> experiments/results/compressed.*
	$(EXP)/compressed.py --data $(DATA)

self-training: $(STAMP)  ## issue 19: label the 60 unlabeled KITTI pairs with the shipped chain, fine-tune kitti2015 on GT + pseudo-labels, score student and teacher vs SGBM (~40 min) -> experiments/results/self_training.*
	$(EXP)/self_training.py --data $(DATA)

train-compact: $(STAMP)  ## the shipped compressed model (kitti2015_compact): tower 16, head 64-32, distilled from the shipped kitti2015 model, 30000 steps on KITTI 2015 1-15 (~17 min), then its chain settings searched on 1-15 (odd, ~12 min) -> runs/kitti2015_compact
	$(CLI) train --data $(DATA) --dataset kitti2015 --frames 000001-000015 --val-frames 000016-000020 \
	  --preset cpu --features 16 --widths 64,32 --distill kitti2015 --steps 30000 --out runs/kitti2015_compact
	$(EXP)/search_chain.py --dataset kitti2015 --frames 1,3,5,7,9,11,13,15 --rounds 1 --space local \
	  --weights runs/kitti2015_compact/checkpoint.msgpack --start kitti2015_compact --tag _compact

confidence: $(STAMP)  ## issue 19: sparsification curves of the confidence map on KITTI 2015 000021-000030 beside oracle and random (~6 min) -> experiments/results/confidence_000021-000030.*
	$(EXP)/confidence.py --data $(DATA)

augment-compare: $(STAMP)  ## patch augmentation on/off, 2 seeds, KITTI selection fold 16-20 (~25 min) -> experiments/results/augment_compare.*
	$(EXP)/augment_compare.py --data $(DATA) --steps 1500

table1: $(STAMP)  ## Table 1: BCE vs relaxed loss, SEEDS seeds, four train->test columns -> experiments/results/table1.*
	$(EXP)/table1.py --seeds $(SEEDS) --steps $(STEPS) --kitti-frames $(KITTI_FRAMES)

sweep-delta: $(STAMP)  ## Table 2: sweep of Delta (DELTAS="0 0.03 ...") with a plot -> experiments/results/table2.*
	$(EXP)/sweep_delta.py --deltas $(DELTAS) --seeds $(SWEEP_SEEDS) --steps $(STEPS) --kitti-frames $(KITTI_FRAMES)

table3: $(STAMP)  ## Table 3: SGBM, census, MC-CNN-fast/accurate, proposed on KITTI 2012 -> experiments/results/table3.*
	$(EXP)/compare.py --dataset kitti2012 --steps $(STEPS)

table4: $(STAMP)  ## Table 4: the same comparison on KITTI 2015 000021-000030 -> experiments/results/table4.*
	$(EXP)/compare.py --dataset kitti2015 --steps $(STEPS)

figures: $(STAMP)  ## Figures 5-8: images, disparity, error and depth maps of KITTI frames -> experiments/results/figures/
	$(EXP)/figures.py

depth-example: $(STAMP)  ## metric depth and a point cloud from a KITTI pair with KITTI calibration
	$(EXP)/depth_example.py

report: $(STAMP)  ## collect the tables and figures into experiments/results/REPORT.md and fill the generated tables of README.md and docs/results.md
	$(EXP)/report.py

experiments: table1 sweep-delta table3 table4 figures depth-example report  ## all of the above

clean:  ## remove the virtual environment and generated outputs
	rm -rf $(VENV) $(OUT) .pytest_cache build *.egg-info
