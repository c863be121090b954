# fignetctl: set up, run the main job, test, benchmark.
#   make demo    set up a fresh machine (.venv) and run the main job (the pipeline) on the bundled capture
#   make test    set up and run the whole test suite
#   make bench   print (and write json of) the benchmarks

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
OUT    ?= out
JOBS   ?= 2

.PHONY: FORCE setup demo dataset-demo test bench checkpoints two-frame-checkpoints velocity-checkpoints evaluate-checkpoints evaluate-two-frame-checkpoints evaluate-velocity-checkpoint clean

# torch is pinned and installed first: an open range would pull a CUDA build of several GB.
$(BIN)/fignetctl: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $@

setup: $(BIN)/fignetctl

# The main job: the whole pipeline on the bundled capture (pipeline.mk has a target per stage;
# `make -j2 -f pipeline.mk scenes SEEDS="0 1"` runs several scenes). Each stage prints its time.
demo: setup
	$(MAKE) --no-print-directory -f pipeline.mk SCENE=$(OUT)/scene FIGNETCTL=$(BIN)/fignetctl PYTHON=$(BIN)/python

# A small MOVi-B-style dataset from PyBullet, its summary, a rerun recording and an mp4 preview.
dataset-demo: setup
	mkdir -p $(OUT)
	$(BIN)/fignetctl make-dataset --preset movi-b -n 8 --seed 1 --jobs $(JOBS) --overwrite -o $(OUT)/movi-b.h5
	$(BIN)/fignetctl show $(OUT)/movi-b.h5 --video $(OUT)/movi-b.mp4 --rerun $(OUT)/movi-b.rrd --overwrite
	@echo "done: $(OUT)/movi-b.h5 $(OUT)/movi-b.mp4 $(OUT)/movi-b.rrd" >&2

# One pytest worker per core (JOBS): the suite is mostly single-threaded.
test: setup
	$(BIN)/python -m pytest -q -n $(JOBS)

bench: setup
	$(BIN)/python benchmarks/bench_geometry.py
	$(BIN)/python benchmarks/bench_dataset.py

# The two-frame checkpoints (benchmarks/results/two-frame-models/), reproduced: the data, then
# FIGNet* and FIGNet with the same settings (docs/simulator.md has their figures). Hours on a
# 2-core CPU. Three stages: 10,000 steps with the target of the first runs (it undoes position
# noise too); 1500 steps from those weights with the target that keeps the noise; 3500 steps
# from those at twice the batch and a fifth of the learning rate.
# MODEL_FLAGS name every setting in which these models differ from `train`'s defaults (two frames,
# static receivers, quadric decimation, uniform frames, float32); `train`'s defaults keep static
# meshes whole and clamp face-face offsets to 1 m; the model file
# records the physical properties of its training data (rollout warns outside them).
DATA    ?= data
MODEL_FLAGS  := --size small --max-faces 256 --collision-radius 0.2 --loss huber \
                --state positions --static-receivers --decimation quadric --frame-sampling uniform --precision fp32
TRAIN_FLAGS  := $(MODEL_FLAGS) --batch-size 4 --steps 10000 --checkpoint-every 250 --seed 0 --no-target-keeps-noise --learning-rate 1e-3 1e-4
TUNE_FLAGS   := $(MODEL_FLAGS) --batch-size 4 --steps 1500 --checkpoint-every 100 --seed 1 --learning-rate 1e-3 1e-4
POLISH_FLAGS := $(MODEL_FLAGS) --batch-size 8 --steps 3500 --checkpoint-every 100 --seed 3 --learning-rate 2e-4 2e-5

$(DATA)/movi-b-train.h5: | setup
	mkdir -p $(DATA)
	$(BIN)/fignetctl make-dataset --preset movi-b -n 600 --seed 1 -o $@
$(DATA)/movi-b-test.h5: | setup
	mkdir -p $(DATA)
	$(BIN)/fignetctl make-dataset --preset movi-b -n 40 --seed 2 --split test -o $@

# Its first 10 trajectories recorded for 7 s, so 200-step rollouts have the recording beside them.
$(DATA)/movi-b-test-7s.h5: | setup
	mkdir -p $(DATA)
	$(BIN)/fignetctl make-dataset --preset movi-b -n 10 --seed 2 --split test --duration 7 -o $@

$(DATA)/%-movi-b-base.pt: $(DATA)/movi-b-train.h5 FORCE
	$(BIN)/fignetctl train $< -o $@ --model $* $(TRAIN_FLAGS) --log-csv $(DATA)/$*-base-loss.csv $(if $(wildcard $@),--resume)

$(DATA)/%-movi-b-tuned.pt: $(DATA)/%-movi-b-base.pt FORCE
	$(BIN)/fignetctl train $(DATA)/movi-b-train.h5 -o $@ --model $* $(TUNE_FLAGS) --log-csv $(DATA)/$*-tuned-loss.csv $(if $(wildcard $@),--resume,--init-from $<)

$(DATA)/%-movi-b.pt: $(DATA)/%-movi-b-tuned.pt FORCE
	$(BIN)/fignetctl train $(DATA)/movi-b-train.h5 -o $@ --model $* $(POLISH_FLAGS) --log-csv $(DATA)/$*-loss.csv $(if $(wildcard $@),--resume,--init-from $<)

# Kept when make is interrupted: a half-trained model file is where `--resume` starts from. A model
# file newer than its inputs may still be half-trained, so these recipes always run (FORCE):
# `train --resume` goes on to the run's last step, and leaves a finished file untouched, so what
# was built from it is not built again.
FORCE:
.PRECIOUS: $(DATA)/%-movi-b-base.pt $(DATA)/%-movi-b-tuned.pt $(DATA)/%-movi-b.pt $(DATA)/%-movi-b-velocities.pt

# The first velocity-state models (the bundled ones come from `make checkpoints` below;
# docs/training-record.md has the figures of both): 4000 trajectories, frame t and instantaneous
# velocities in, static nodes that do not aggregate, MSE, graphs built by a worker process, bf16
# where the CPU has it. One torch thread: the worker takes the other core. Resumable (re-run the
# target).
VELOCITY_FLAGS := --size small --max-faces 256 --collision-radius 0.2 --state velocities --no-static-receivers --loss mse \
                  --decimation quadric --frame-sampling uniform \
                  --batch-size 8 --steps 8000 --checkpoint-every 250 --seed 0 --workers 1 --precision auto --learning-rate 1e-3 1e-4

$(DATA)/movi-b-train-4k.h5: | setup
	mkdir -p $(DATA)
	$(BIN)/fignetctl make-dataset --preset movi-b -n 4000 --seed 1 --jobs $(JOBS) -o $@

$(DATA)/%-movi-b-velocities.pt: $(DATA)/movi-b-train-4k.h5 FORCE
	OMP_NUM_THREADS=1 $(BIN)/fignetctl train $< -o $@ --model $* $(VELOCITY_FLAGS) --log-csv $(DATA)/$*-velocities-loss.csv $(if $(wildcard $@),--resume)

velocity-checkpoints: $(DATA)/fignet-star-movi-b-velocities.pt $(DATA)/fignet-movi-b-velocities.pt

# The 8000-step velocity-state FIGNet* on the held-out set, beside its guards, the baselines and
# the PyBullet ceilings; 120 steps of the network alone on 10 trajectories, for how deep objects
# go into the floor (docs/training-record.md).
evaluate-velocity-checkpoint: $(DATA)/movi-b-test.h5 $(DATA)/fignet-star-movi-b-velocities.pt
	$(BIN)/fignetctl evaluate $< --model $(DATA)/fignet-star-movi-b-velocities.pt --with-guards --ceilings -o docs/results/fignet-star-velocities-movi-b-test.json --overwrite
	$(BIN)/python benchmarks/long_rollout.py --model $(DATA)/fignet-star-movi-b-velocities.pt --data $< -n 10 --steps 120 \
	    --out docs/results/long-rollout-network-alone-velocities.json

TWO_FRAME := benchmarks/results/two-frame-models
two-frame-checkpoints: $(DATA)/fignet-star-movi-b.pt $(DATA)/fignet-movi-b.pt
	$(BIN)/python scripts/export_model.py $(DATA)/fignet-star-movi-b.pt $(TWO_FRAME)/fignet-star-movi-b.pt
	$(BIN)/python scripts/export_model.py $(DATA)/fignet-movi-b.pt $(TWO_FRAME)/fignet-movi-b.pt

# The bundled models, reproduced from scratch: sixteen stages of training, each from the one before
# (scripts/velocity_lineage.py; docs/simulator.md, "The bundled models' lineage"), then both
# exported with the four turns about gravity `rollout` averages them over. About 21 hours on a
# 2-core CPU (its stage 13 uses a GPU where there is one); re-run to go on after an interruption.
$(DATA)/movi-b-train-16k.h5: | setup
	mkdir -p $(DATA)
	$(BIN)/fignetctl make-dataset --preset movi-b -n 16000 --seed 1 --jobs $(JOBS) -o $@

checkpoints: $(DATA)/movi-b-train.h5 $(DATA)/movi-b-train-4k.h5 $(DATA)/movi-b-train-16k.h5
	$(BIN)/python scripts/velocity_lineage.py --data $(DATA) --out $(DATA)/lineage
	$(BIN)/python scripts/export_model.py $(DATA)/lineage/unroll-4-mean.pt fignetctl/assets/models/fignet-star-movi-b.pt --rotations 4
	$(BIN)/python scripts/export_model.py $(DATA)/lineage/fignet-rest-weight-100.pt fignetctl/assets/models/fignet-movi-b.pt --rotations 4

# The bundled models on the held-out set (with and without the guards; FIGNet* beside the
# PyBullet ceilings), the plot of their error curves, 200-step rollouts as `rollout` runs them,
# and the suite's learned hard cases (docs/simulator.md, docs/stability.md).
evaluate-checkpoints: $(DATA)/movi-b-test.h5 $(DATA)/movi-b-test-7s.h5
	$(BIN)/fignetctl evaluate $< --model fignet-star-movi-b --with-guards --ceilings -o docs/results/fignet-star-movi-b-test.json --overwrite
	$(BIN)/fignetctl evaluate $< --model fignet-movi-b --with-guards -o docs/results/fignet-movi-b-test.json --overwrite
	$(BIN)/python benchmarks/error_curves.py docs/results/fignet-star-movi-b-test.json="FIGNet*" \
	    docs/results/fignet-movi-b-test.json="FIGNet" docs/results/two-frame-fignet-star-movi-b-test.json="FIGNet*, two frames" \
	    --plot docs/images/error-curves-movi-b.png
	$(BIN)/python benchmarks/long_rollout.py --model fignetctl/assets/models/fignet-star-movi-b.pt --data $(DATA)/movi-b-test-7s.h5 \
	    -n 10 --steps 200 --free-flight --keep-out --sleep --out docs/results/long-rollout-fignet-star.json
	$(BIN)/python benchmarks/learned_hard_cases.py --out docs/results/learned-hard-cases.json

evaluate-two-frame-checkpoints: $(DATA)/movi-b-test.h5
	$(BIN)/fignetctl evaluate $< --model $(TWO_FRAME)/fignet-star-movi-b.pt --ceilings -o docs/results/two-frame-fignet-star-movi-b-test.json --overwrite
	$(BIN)/fignetctl evaluate $< --model $(TWO_FRAME)/fignet-star-movi-b.pt --free-flight --keep-out -o docs/results/two-frame-fignet-star-movi-b-test-free-flight-keep-out.json --overwrite
	$(BIN)/fignetctl evaluate $< --model $(TWO_FRAME)/fignet-movi-b.pt -o docs/results/two-frame-fignet-movi-b-test.json --overwrite

clean:
	rm -rf $(OUT) .pytest_cache
