# The whole pipeline of one scene, one target per stage, so `make -j` runs many scenes side by
# side and re-running a stage reuses what is done.
#
#   make -f pipeline.mk SCENE=out/scene                 the bundled capture (seed 0) end to end
#   make -f pipeline.mk SCENE=out/s1 SEED=1 DEVICE=cuda another bundled capture, on a GPU
#   make -j2 -f pipeline.mk scenes SEEDS="0 1 2"       several scenes: out/scene-0, -1, -2
#
# Each stage prints how long it took ("stage <name>: <seconds> s") on stderr. The folder holds:
#   capture/            render-views: images, video, prompts, measurements, ground truth
#   cameras.npz         capture-poses (COLMAP; metres from the measured camera height)
#   nerf.pt             fit-nerf
#   object/             extract-mesh: object.obj, environment.obj, volume.npz, masks/
#   scene.h5            build-graph: the object dropped from DROP metres above its place
#   rollout.h5          rollout with the bundled FIGNet*, simulated at the size it was trained
#                       on (--sim-scale auto), objects at rest put to sleep; then a check that
#                       the object landed and came to rest (benchmarks/drop_check.py)
#   video.mp4 (+ video_frames/)  rerender from camera VIEW, every EVERY-th frame at FPS
#                       (slow motion: the frames are dt/sqrt(scale) apart), the path traced
#   pipeline.rrd        rerun recording of the rollout
#   <stage>.json        each stage's summary (--json): poses, PSNR, mesh sizes and outline IoU,
#                       drop start, rollout scale and final positions, rerender timings, each
#                       with fignetctl_version and the SHA-256 of the stage's inputs

FIGNETCTL ?= .venv/bin/fignetctl
PYTHON    ?= .venv/bin/python
SCENE     ?= out/scene
SEED      ?= 0
DEVICE    ?= auto
PRESET    ?= fast
NERF_FLAGS ?=
EXTRACT_FLAGS ?=
# The fast preset's field of the bundled capture has 17 mm voxels, so its 12 cm ball is 7 voxels
# across, which extract-mesh refuses by default (a side can be off by a voxel, 14 %): the main
# job accepts it (docs/extract-mesh.md, step 9, has what that costs).
MAX_VOXEL ?= 0.2
FACES     ?= 1000
DROP      ?= 0.15
STEPS     ?= 120
EVERY     ?= 2
FPS       ?= 15
VIEW      ?= 5
OBJECT    ?=

SHELL := /bin/bash
# `time` of bash, one line per stage.
STAGE = TIMEFORMAT="stage $(1): %R s"; time

.PHONY: all scenes
.DELETE_ON_ERROR:

all: $(SCENE)/video.mp4

# Every stage writes atomically, so a target that exists is complete.
$(SCENE)/capture/measurements.json:
	@mkdir -p $(SCENE)
	@$(call STAGE,render-views) $(FIGNETCTL) render-views -o $(SCENE)/capture --seed $(SEED) --overwrite >/dev/null

$(SCENE)/cameras.npz: $(SCENE)/capture/measurements.json
	@$(call STAGE,capture-poses) $(FIGNETCTL) capture-poses --images $(SCENE)/capture/images \
	  --camera-height $$($(PYTHON) -c "import json,sys; print(json.load(open(sys.argv[1]))['camera_height_m'])" $<) \
	  --seed $(SEED) --json $(SCENE)/capture-poses.json -o $@ --overwrite >/dev/null

$(SCENE)/nerf.pt: $(SCENE)/cameras.npz
	@$(call STAGE,fit-nerf) $(FIGNETCTL) fit-nerf $(SCENE)/capture/images $< --preset $(PRESET) $(NERF_FLAGS) \
	  --device $(DEVICE) --seed $(SEED) --json $(SCENE)/fit-nerf.json -o $@ --overwrite >/dev/null

$(SCENE)/object/volume.npz: $(SCENE)/nerf.pt
	@$(call STAGE,extract-mesh) $(FIGNETCTL) extract-mesh $< --cameras $(SCENE)/cameras.npz \
	  --images $(SCENE)/capture/images --prompts $(SCENE)/capture/prompts.json $(if $(OBJECT),--object $(OBJECT)) \
	  --faces $(FACES) --max-voxel $(MAX_VOXEL) $(EXTRACT_FLAGS) --device $(DEVICE) --json $(SCENE)/extract-mesh.json -o $(SCENE)/object --overwrite >/dev/null

$(SCENE)/scene.h5: $(SCENE)/object/volume.npz
	@$(call STAGE,build-graph) $(FIGNETCTL) build-graph $< --drop-height $(DROP) --json $(SCENE)/build-graph.json -o $@ --overwrite

$(SCENE)/rollout.h5: $(SCENE)/scene.h5
	@$(call STAGE,rollout) $(FIGNETCTL) rollout $< --steps $(STEPS) --sim-scale auto --sleep --device $(DEVICE) \
	  --rerun $(SCENE)/pipeline.rrd --json $(SCENE)/rollout.json -o $@ --overwrite
	@$(PYTHON) benchmarks/drop_check.py $@ --json $(SCENE)/drop.json || true

$(SCENE)/video.mp4: $(SCENE)/rollout.h5
	@$(call STAGE,rerender) $(FIGNETCTL) rerender $(SCENE)/nerf.pt $(SCENE)/object/volume.npz $< \
	  --cameras $(SCENE)/cameras.npz --camera $(VIEW) --every $(EVERY) --fps $(FPS) --trace --device $(DEVICE) \
	  --json $(SCENE)/rerender.json -o $@ --overwrite >/dev/null
	@echo "$(SCENE): video $@, intermediate files and $(SCENE)/pipeline.rrd" >&2

# Many scenes, one bundled capture per seed: make -j2 -f pipeline.mk scenes SEEDS="0 1 2"
# gives out/scene-0, out/scene-1, out/scene-2, each a whole pipeline.
SEEDS ?= 0
OUT   ?= out
scenes: $(foreach seed,$(SEEDS),$(OUT)/scene-$(seed)/video.mp4)
$(OUT)/scene-%/video.mp4:
	@$(MAKE) --no-print-directory -f pipeline.mk SCENE=$(OUT)/scene-$* SEED=$*
