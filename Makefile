# nespm: every target creates and uses the local virtual environment .venv.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
NESPM  := $(BIN)/nespm
DATA   ?=
RUNS   ?= 100
JOBS   ?= 2
DATA_OPT := $(if $(DATA),--data-dir $(DATA),)

.PHONY: setup warm-up run tune-main test smoke aided sensors table1 table2 anukf-table1 anukf-table2 nespm-table1 weights sweep-misalignment sweep-heading gp-ukf bench bench-compare clean check-data recorded-table1 recorded-table2 recorded-anukf-table1 recorded-anukf-table2 recorded-nespm-table1 recorded-weights akit akit-data

setup: $(VENV)/.installed

# pip prints one line per package it collects and installs (no --quiet): the first install takes
# minutes (numpy, scipy, pandas, pyarrow, matplotlib, numba, scikit-learn, dask, rosbags).
$(VENV)/.installed: pyproject.toml
	@echo "setup: creating $(VENV) and installing nespm with its dependencies (numpy, scipy, pandas, pyarrow, matplotlib, numba, scikit-learn, optuna, Py-BOBYQA, dask, rosbags, pytest): a few minutes the first time"
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --progress-bar on -e '.[test,dask,onnx]'
	@echo "setup: done; the filters' kernels compile on the first run (seconds: 6 s for the main job's, once per machine)"
	touch $@

# The filters' numba kernels compiled into the per-user cache (~/.cache/nespm, or $NESPM_CACHE_DIR): once
# per machine and nespm version; CI images run it so that the first mc does not compile.
warm-up: setup
	$(NESPM) warm-up

# The main job: EKF, UKF and UKF-NESPM on tracks 5 and 6, 100 MC runs, then the report.
run: setup
	$(NESPM) mc --tracks 5 6 --runs $(RUNS) --jobs $(JOBS) $(DATA_OPT) --out results/main
	$(NESPM) report results/main

# The main job with tuned filters: EKF, UKF and UKF-NESPM each tuned with the same budget on
# tracks 1-4 (1-4 and 7-13 with DATA=; training runs, their own seeds), held out on tracks 5 and 6 (default and tuned
# settings, results/tune-main/report.md), then the main job re-run with the tuned settings
# (docs/tuning.md). TUNE_TRIALS and TUNE_RUNS set the budget. TUNE_SPACE widens the default search
# space (noise factors): by default each filter also calibrates the DVL's fore-aft lever arm on the
# training tracks (the embedded DVL sits 1.6 m aft of the IMU, which the papers' filters are not told);
# TUNE_SPACE= tunes the noise alone. TUNE_OPTS adds model options to every step (e.g.
# TUNE_SPACE= TUNE_OPTS="--dvl-lever-arm -1.6 0 0" TUNE_OUT=results/tune-told TUNED_OUT=results/main-tuned-told:
# the filters told the lever arm; README "Tune before you compare").
TUNE_TRIALS ?= 50
TUNE_RUNS ?= 10
TUNE_OPTS ?=
TUNE_SPACE ?= --tune-range '*.lever_arm_x_dvl=-3:3'
TUNE_OUT ?= results/tune-main
TUNED_OUT ?= results/main-tuned
TRAIN_TRACKS := $(if $(DATA),1 2 3 4 7 8 9 10 11 12 13,1 2 3 4)
tune-main: setup
	$(NESPM) tune --tracks $(TRAIN_TRACKS) --runs $(TUNE_RUNS) --trials $(TUNE_TRIALS) --filters ekf,ukf,ukf-nespm --test-tracks 5 6 --test-runs $(RUNS) --jobs $(JOBS) $(DATA_OPT) $(TUNE_SPACE) $(TUNE_OPTS) --out $(TUNE_OUT)
	$(NESPM) report $(TUNE_OUT)
	$(NESPM) mc --config $(TUNE_OUT)/tuned.toml --tracks 5 6 --runs $(RUNS) --jobs $(JOBS) $(DATA_OPT) $(TUNE_OPTS) --out $(TUNED_OUT)
	$(NESPM) report $(TUNED_OUT)

# The suite on two pytest workers (pytest-xdist), one test file per worker at a time (--dist
# loadfile: a module's shared fixtures are computed once). TEST_WORKERS=0 runs it in one process.
TEST_WORKERS ?= 2
test: setup
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

# A short end-to-end CLI run (about a minute).
smoke: setup
	$(NESPM) tracks $(DATA_OPT)
	$(NESPM) mc --tracks 5 --runs 2 --filters ekf,ukf,ukf-nespm --jobs $(JOBS) $(DATA_OPT) --out results/smoke
	$(NESPM) report results/smoke

table1: setup
	$(NESPM) mc --config experiments/table1.toml --jobs $(JOBS) $(DATA_OPT) --out results/table1$(if $(DATA),-data,)
	$(NESPM) report results/table1$(if $(DATA),-data,)

table2: setup
	$(NESPM) mc --config experiments/table2.toml --jobs $(JOBS) $(DATA_OPT) --out results/table2$(if $(DATA),-data,)
	$(NESPM) report results/table2$(if $(DATA),-data,)

# The adaptive filters' tables. With DATA, ProcessNet is first trained on that folder's
# tracks 1-4 (as in anukf.md); without, the weights shipped with the package are used.
SUFFIX := $(if $(DATA),-data,)
WEIGHTS := $(if $(DATA),results/processnet-data.npz,)
WEIGHTS_OPT := $(if $(WEIGHTS),--weights $(WEIGHTS),)

weights: setup $(WEIGHTS)

results/processnet-data.npz: | setup
	$(NESPM) train --tracks 1 2 3 4 --test-tracks 5 6 $(DATA_OPT) --out $@

anukf-table1 anukf-table2 nespm-table1: setup $(WEIGHTS)
	$(NESPM) mc --config experiments/$@.toml --jobs $(JOBS) $(DATA_OPT) $(WEIGHTS_OPT) --out results/$@$(SUFFIX)
	$(NESPM) report results/$@$(SUFFIX)

sweep-misalignment sweep-heading: setup
	$(NESPM) sweep --config experiments/$@.toml --jobs $(JOBS) $(DATA_OPT) --out results/$@$(if $(DATA),-data,)
	$(NESPM) report results/$@$(if $(DATA),-data,) --baseline ukf-nespm

# gp-ukf.md Tables 3 and 4: GP-UKF vs ideal UKF, 20 simulated REMUS 100 helix runs of 800 s.
# Position in the state, DVL + depth + 3-D fixes every 10 s (docs/sensors.md).
aided: setup
	$(NESPM) mc --config experiments/aided.toml --jobs $(JOBS) --out results/aided
	$(NESPM) report results/aided

# What each sensor buys (issue 24): six cases on the same realizations (DVL; + depth; + fixes every
# 60 s; DVL beams with two lost for 60 s against the whole DVL lost; + heading), 15 states, EKF,
# UKF-NESPM and IEKF, 50 runs on tracks 5 and 6 (DATA=folder for the real tracks), then the
# comparison (nespm compare) and the fix-interval sweep.
SENSOR_CASES := a-dvl b-depth c-fix d-beams-lost d-dvl-lost e-heading
SENSORS_OUT := results/sensors$(if $(DATA),-data,)
sensors: setup
	for c in $(SENSOR_CASES); do \
	  $(NESPM) mc --config experiments/sensors-base.toml --config experiments/sensors-$$c.toml --jobs $(JOBS) $(DATA_OPT) --out $(SENSORS_OUT)/$$c || exit 1; \
	done
	$(NESPM) compare $(foreach c,$(SENSOR_CASES),$(SENSORS_OUT)/$(c)) --out $(SENSORS_OUT)/compare
	$(NESPM) sweep --config experiments/sensors-base.toml --config experiments/sensors-fix-interval.toml --jobs $(JOBS) $(DATA_OPT) --out $(SENSORS_OUT)/fix-interval
	$(NESPM) report $(SENSORS_OUT)/fix-interval --baseline ekf

gp-ukf: setup
	$(NESPM) gp-ukf --runs 20 --jobs $(JOBS) --out results/gp-ukf
	$(NESPM) report results/gp-ukf

bench: setup
	$(BIN)/python benchmarks/bench_foundation.py
	$(BIN)/python benchmarks/bench_mc.py $(DATA_OPT)
	$(BIN)/python benchmarks/bench_onnx_noise_model.py

# This tree against an earlier commit (issue 33): make bench-compare BASE=b27d778 [QUICK=1]
bench-compare:
	@test -n "$(BASE)" || { echo "bench-compare: give BASE=<commit>"; exit 2; }
	$(MAKE) setup
	PYTHONPATH=. $(BIN)/python benchmarks/bench_compare.py --base $(BASE) $(if $(QUICK),--quick,)

clean:
	rm -rf $(VENV) *.egg-info

# Recorded IMU (docs/checking-data.md): check the folder against its GT, then run the tables'
# protocol on the recorded IMU with the corrections the check justifies.
IMU_DATA ?= ../shared/data/snapir-akit-imu
RUNS_OPT := $(if $(filter-out 100,$(RUNS)),--runs $(RUNS),)

check-data: setup
	$(NESPM) check --data-dir $(IMU_DATA) --out results/check

results/check/corrections.json: | setup
	$(NESPM) check --data-dir $(IMU_DATA) --out results/check

# Each also runs its synthetic-IMU twin (same tracks, DVL corrections, filters and seeds), which
# the report sets beside the recorded-IMU numbers and the published ones.
recorded-table1 recorded-table2: setup results/check/corrections.json
	$(NESPM) mc --config experiments/$@.toml --jobs $(JOBS) --data-dir $(IMU_DATA) $(RUNS_OPT) \
		--corrections results/check/corrections.json --out results/$@
	$(NESPM) mc --config experiments/$@.toml --imu synthetic --jobs $(JOBS) --data-dir $(IMU_DATA) $(RUNS_OPT) \
		--corrections results/check/corrections.json --out results/$@-synthetic-imu
	$(NESPM) report results/$@ --beside results/$@-synthetic-imu

# ProcessNet trained on the recorded IMU windows of tracks 1-4 (as anukf.md), with the corrections.
# (The synthetic-IMU twins of the adaptive tables use the packaged weights, trained on synthesized IMU.)
recorded-weights: setup results/processnet-recorded.npz

results/processnet-recorded.npz: results/check/corrections.json | setup
	$(NESPM) train --tracks 1 2 3 4 --test-tracks 5 6 --data-dir $(IMU_DATA) --imu recorded \
		--corrections results/check/corrections.json --out $@

recorded-anukf-table1 recorded-anukf-table2 recorded-nespm-table1: setup results/check/corrections.json results/processnet-recorded.npz
	$(NESPM) mc --config experiments/$@.toml --jobs $(JOBS) --data-dir $(IMU_DATA) $(RUNS_OPT) \
		--corrections results/check/corrections.json --weights results/processnet-recorded.npz --out results/$@
	$(NESPM) mc --config experiments/$@.toml --imu synthetic --jobs $(JOBS) --data-dir $(IMU_DATA) $(RUNS_OPT) \
		--corrections results/check/corrections.json --out results/$@-synthetic-imu
	$(NESPM) report results/$@ --beside results/$@-synthetic-imu

# The A-KIT question on the recorded data (issue 32; docs/learned.md, "The A-KIT protocol"): the check's
# corrections; ProcessNet trained (and exported to ONNX) and every filter tuned with the same budget on
# A-KIT's training tracks 1-4, 7-13; on its test tracks 5 and 6 every filter in three mc folders on the
# same realizations (default EKF, iae/sh/vb-ekf and anekf; the same five tuned; anekf with the ONNX
# model); the report and the comparison; then the README table (between its akit-table markers) from
# those folders. DATA=folder (default IMU_DATA);
# AKIT_RUNS (runs per test track), AKIT_TRIALS and AKIT_TUNE_RUNS (tuning budget) set the cost.
# NESPM and NESPM_PYTHON may be overridden (e.g. an installed nespm); setup runs only for the .venv's.
AKIT_DATA := $(if $(DATA),$(DATA),$(IMU_DATA))
AKIT_OUT ?= results/akit
AKIT_RUNS ?= 100
AKIT_TRIALS ?= 50
AKIT_TUNE_RUNS ?= 4
NESPM_PYTHON ?= $(BIN)/python
AKIT_OPTS = --config experiments/akit/common.toml --data-dir $(AKIT_DATA) --corrections $(AKIT_OUT)/check/corrections.json
AKIT_MC = $(NESPM) mc $(AKIT_OPTS) --config experiments/akit/mc.toml --runs $(AKIT_RUNS) --jobs $(JOBS)
AKIT_SETUP := $(if $(filter $(BIN)/nespm,$(NESPM)),setup,)
akit: $(AKIT_SETUP) akit-data $(AKIT_OUT)/check/corrections.json $(AKIT_OUT)/processnet.npz
	$(NESPM) tune $(AKIT_OPTS) --config experiments/akit/tune.toml --weights $(AKIT_OUT)/processnet.npz --runs $(AKIT_TUNE_RUNS) --trials $(AKIT_TRIALS) --jobs $(JOBS) --out $(AKIT_OUT)/tune
	$(NESPM) report $(AKIT_OUT)/tune
	$(AKIT_MC) --weights $(AKIT_OUT)/processnet.npz --out $(AKIT_OUT)/mc
	$(AKIT_MC) --config $(AKIT_OUT)/tune/tuned.toml --weights $(AKIT_OUT)/processnet.npz --out $(AKIT_OUT)/mc-tuned
	$(AKIT_MC) --filters anekf --noise-model $(AKIT_OUT)/processnet.onnx --out $(AKIT_OUT)/mc-onnx
	$(NESPM) report $(AKIT_OUT)/mc
	$(NESPM) compare $(AKIT_OUT)/mc $(AKIT_OUT)/mc-tuned $(AKIT_OUT)/mc-onnx --labels default,tuned,onnx --out $(AKIT_OUT)/compare
	$(NESPM_PYTHON) -m nespm_cli.reports.akit_table $(AKIT_OUT) --readme README.md

akit-data:
	@test -d "$(AKIT_DATA)" || { echo "make akit: no data folder at $(AKIT_DATA) (give DATA=folder: the Snapir tracks with their IMU files)" >&2; exit 2; }

# made once (delete $(AKIT_OUT) to start over: the mc folders refuse to resume on other inputs)
$(AKIT_OUT)/check/corrections.json: | $(AKIT_SETUP) akit-data
	$(NESPM) check --data-dir $(AKIT_DATA) --out $(AKIT_OUT)/check

$(AKIT_OUT)/processnet.npz: $(AKIT_OUT)/check/corrections.json | $(AKIT_SETUP) akit-data
	$(NESPM) train --config experiments/akit/train.toml --data-dir $(AKIT_DATA) --corrections $(AKIT_OUT)/check/corrections.json --no-progress --out $@

# Does adapting pay? (issue 40; README "Does adapting pay?", docs/adapting.md): on the papers' dynamic IMU
# schedule and on a x4 DVL-noise step with 5 % outliers, the fixed EKF, the adaptive-R EKFs (iae, sh, vb),
# the adaptive-Q EKF (aq-ekf), the learned-Q EKF (anekf, shipped ProcessNet weights) and the EKF told the
# true noise (ekf-oracle), tracks 5 and 6 (the embedded tracks; ADAPT_RUNS runs each), then the reports
# with each adaptive filter's share of the oracle's gain. Tuned filters are not in it (make tune-main).
ADAPT_RUNS ?= 100
ADAPT_OUT ?= results/adapt
.PHONY: adapt
adapt: setup
	for c in imu dvl; do \
	  $(NESPM) mc --config experiments/adapt-$$c.toml --runs $(ADAPT_RUNS) --jobs $(JOBS) --out $(ADAPT_OUT)/$$c || exit 1; \
	  $(NESPM) report $(ADAPT_OUT)/$$c || exit 1; \
	done
