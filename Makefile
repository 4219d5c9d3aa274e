# `make demo` and `make test` create .venv with python3.12 and install the package on first use.
PYTHON312 := $(shell for candidate in python3.12 $$HOME/.pyenv/versions/3.12*/bin/python3.12 /usr/bin/python3.12 /usr/local/bin/python3.12; do \
	"$$candidate" --version >/dev/null 2>&1 && { echo "$$candidate"; break; }; done)
VENV := .venv
INSTALLED := $(VENV)/.installed

.PHONY: gl-library demo pseudo-demos train-data train train-standing results results-suite eval-suite perception-eval eval-metaworld osmesa results-candidate test install clean

install: $(INSTALLED)

# uv (from PyPI, into the venv) installs from its cache where pip, which may keep no copy of the wheels it downloaded,
# fetches and unpacks torch and its CUDA libraries again for about 3 minutes; where uv cannot install (an index only
# pip's configuration names, say), pip does. Byte-compiled at install, as pip does: where PYTHONDONTWRITEBYTECODE is
# set, an uncompiled venv compiles every module it imports again in every process.
$(INSTALLED): pyproject.toml
	@test -n "$(PYTHON312)" || { echo "error: python3.12 not found (LeRobot 0.6 needs Python 3.12)"; exit 1; }
	test -x $(VENV)/bin/python || $(PYTHON312) -m venv $(VENV)
	$(VENV)/bin/pip install --quiet --upgrade pip 'uv>=0.9,<1'
	@echo "installing lerobot-instant-policy and its dependencies (lerobot, torch with its CUDA libraries) into $(VENV);\
	 the first install on a machine downloads them and compiles pybullet and fpsample from source (no wheels for \
	Python 3.12): several minutes with no output; later installs come from uv's cache in about a minute"
	$(VENV)/bin/uv pip install --quiet --compile-bytecode --python $(VENV)/bin/python -e '.[dev]' || \
	$(VENV)/bin/pip install --quiet -e '.[dev]'
	touch $(INSTALLED)
	@echo "installed; $(VENV)/bin holds the lerobot-* and lerobot-ip-* commands"

# MuJoCo's offscreen rendering (the MetaWorld env, its tests, make eval-metaworld) needs the OSMesa library: Debian's
# libosmesa6, installed here where this user can (root with apt-get). Elsewhere it says so and goes on: the MetaWorld
# tests that render then skip with that one-line reason, every other test runs.
gl-library:
	@ldconfig -p 2>/dev/null | grep -q libOSMesa || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && \
	{ echo "installing Debian's libosmesa6 (MuJoCo's offscreen rendering for the MetaWorld env)"; \
	DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libosmesa6 >/dev/null 2>&1 || \
	{ apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libosmesa6 >/dev/null; }; }; } || \
	echo "note: the OSMesa library is missing and cannot be installed here (needs root and apt-get): the MetaWorld \
	tests that render will be skipped"

# Record 2 demonstrations of a bullet_tabletop task, evaluate the best available policy, print success + videos.
demo: $(INSTALLED)
	$(VENV)/bin/lerobot-ip-demo

pseudo-demos: $(INSTALLED)
	$(VENV)/bin/lerobot-ip-generate --config configs/generate/default.json --overwrite \
		--preview outputs/pseudo_demos_preview.png

# The default model (InstantPolicyConfig's defaults: the shipped model) on the default pseudo-demonstrations, 2 CPU
# cores. Both steps resume where they stopped (generation shard by shard, training from its last checkpoint). The
# shipped checkpoint is a save of the standing run (make train-standing).
TRAIN_DIR ?= outputs/train/instant_policy_small
TRAIN_STEPS ?= 2000
train-data: $(INSTALLED)
	test -d outputs/pseudo_demos_val/meta || OMP_NUM_THREADS=1 $(VENV)/bin/lerobot-ip-generate --config configs/generate/val_held_out.json
	test -d outputs/pseudo_demos_train/meta || OMP_NUM_THREADS=1 $(VENV)/bin/lerobot-ip-generate \
		--config configs/generate/train_cpu.json $(if $(wildcard outputs/pseudo_demos_train/.shards),--resume,)

train: train-data
	OMP_NUM_THREADS=1 $(VENV)/bin/lerobot-train $(if $(wildcard $(TRAIN_DIR)/checkpoints/last), \
		--config_path=$(TRAIN_DIR)/checkpoints/last/pretrained_model/train_config.json --resume=true, \
		--policy.type=instant_policy \
		--dataset.repo_id=local/pseudo_demos_train --dataset.root=outputs/pseudo_demos_train \
		--steps=$(TRAIN_STEPS) --batch_size=16 --num_workers=1 --log_freq=50 --save_freq=250 --seed=1000 \
		--wandb.enable=false --output_dir=$(TRAIN_DIR))
	$(VENV)/bin/lerobot-ip-loss-curve --run $(TRAIN_DIR) --train-root outputs/pseudo_demos_train \
		--val-root outputs/pseudo_demos_val --samples 128 --out docs/training_curve.png

# The standing run (workbench/standing.py, docs/training.md), which trained the shipped checkpoint's later steps: it
# continues the committed save checkpoints/stream/last on the rolling pool of fresh pseudo-tasks
# (configs/generate/stream_bounded_mixed.json) for HOURS of wall time at nice 10, validates its last save on the two
# 96-task held-out sets (configs/generate/val_moved_objects.json, val_one_layout.json), paired with the best save's
# and the shipped checkpoint's errors, makes it the new last save and, where it beats the best on both sets, the new
# checkpoints/stream/best, and appends its point to docs/scaling_curve.{json,png}. Commit checkpoints/stream/ and the
# curve after it.
HOURS ?= 2.5
train-standing: $(INSTALLED)
	$(VENV)/bin/python -m workbench.cli.standing run --hours $(HOURS)

# docs/deployment.md: demo_replay on the simulator's segmented clouds and on processed raw depth (--obs-type rgbd),
# every task, 10 episodes each (issue 14's RGB-D vs segmented table).
perception-eval: $(INSTALLED)
	OMP_NUM_THREADS=1 $(VENV)/bin/lerobot-ip-eval-suite --policy demo_replay --episodes 10 \
		--out outputs/perception_eval --run-name segmented
	OMP_NUM_THREADS=1 $(VENV)/bin/lerobot-ip-eval-suite --policy demo_replay --obs-type rgbd --episodes 10 \
		--out outputs/perception_eval --run-name rgbd

# docs/results.md: the suite protocol (evaluation/suite.py, docs/evaluation.md) on the held-out test split (SPLIT=dev
# for studies and option choices): every task x 3 disjoint demonstration sets x 10 episodes, N=2, the same seeds for
# every policy, success held for the task's hold time; every policy that reads demonstrations also with each task
# handed another group's demonstrations (the context swap). Then one table with Wilson 95% intervals, the columns'
# manifests (seeds, demonstration fingerprints, each episode) and the paired differences: the shipped checkpoint
# against demo_replay, and each option against the baseline it starts from. lerobot-eval renders a video frame after
# every step of its first 10 episodes: at 64 px a frame takes about a tenth of the time and changes no observation.
# SUITE_ARGS=--resume continues an interrupted run (cells of the same settings are kept).
CKPT ?= lerobot_instant_policy/assets/checkpoints/instant_policy
SPLIT ?= test
SUITE_OUT ?= outputs/results/suite_$(SPLIT)
SUITE = OMP_NUM_THREADS=1 $(VENV)/bin/lerobot-ip-eval-suite --episodes 10 --demo-sets 3 --split $(SPLIT) --out $(SUITE_OUT) \
	--env-arg render_size=64 $(SUITE_ARGS)
IP = --policy instant_policy --policy-path $(CKPT)
OPTION = --policy-arg replay_init_strength=0.125 --policy-arg inference_steps=8 --policy-arg replay_per_object=true
PER_OBJECT = --policy demo_replay --policy-arg replay_per_object=true
SUITE_COLUMNS = instant_policy instant_policy-swap ip_per_object_s0125_K8 ip_per_object_s0125_K8-swap demo_replay \
	demo_replay-swap demo_replay_per_object demo_replay_per_object-swap do_nothing
results: results-suite

results-suite: $(INSTALLED)
	$(SUITE) $(IP)
	$(SUITE) $(IP) --swap
	$(SUITE) $(IP) $(OPTION) --run-name ip_per_object_s0125_K8
	$(SUITE) $(IP) $(OPTION) --swap --run-name ip_per_object_s0125_K8-swap
	$(SUITE) --policy demo_replay
	$(SUITE) --policy demo_replay --swap
	$(SUITE) $(PER_OBJECT) --run-name demo_replay_per_object
	$(SUITE) $(PER_OBJECT) --swap --run-name demo_replay_per_object-swap
	$(SUITE) --policy do_nothing
	$(VENV)/bin/lerobot-ip-eval-table $(foreach run,$(SUITE_COLUMNS),$(run)=$(SUITE_OUT)/runs/$(run)) \
		--allow-difference policy_options --paired instant_policy=demo_replay_per_object \
		--paired instant_policy=demo_replay --paired ip_per_object_s0125_K8=demo_replay_per_object \
		--paired demo_replay_per_object=demo_replay --paired instant_policy=instant_policy-swap \
		--paired ip_per_object_s0125_K8=ip_per_object_s0125_K8-swap --out docs/results_suite_$(SPLIT)

# docs/metaworld.md: the suite protocol in LeRobot's MetaWorld env (--env.type=metaworld_pointcloud) on MT10, the
# test split, 3 sets of N=2 expert demonstrations x METAWORLD_EPISODES episodes per task: MetaWorld's scripted expert
# (the upper bound), do_nothing, demo_replay and the shipped checkpoint, each policy that reads demonstrations also
# with another kind of task's (the swap), then one table with the columns' manifests and paired differences.
# make eval-metaworld METAWORLD_TASKS=ml45_test: ML45's held-out tasks. Needs the metaworld extra (in .[dev]) and
# an OpenGL library for MuJoCo's offscreen rendering (libosmesa6, installed by gl-library where it can be). Videos at
# 64 px: osmesa draws a 480 px frame in about 29 ms and a 64 px one in 14, against 11 ms for the step itself.
METAWORLD_EPISODES ?= 10
METAWORLD_TASKS ?= mt10
METAWORLD_SETS ?= 3
METAWORLD_OUT ?= outputs/eval_metaworld_$(METAWORLD_TASKS)_$(SPLIT)
METAWORLD = MUJOCO_GL=osmesa OMP_NUM_THREADS=1 $(VENV)/bin/lerobot-ip-eval-metaworld --tasks $(METAWORLD_TASKS) \
	--episodes $(METAWORLD_EPISODES) --demo-sets $(METAWORLD_SETS) --split $(SPLIT) --out $(METAWORLD_OUT) \
	--env-arg render_size=64 $(SUITE_ARGS)
METAWORLD_COLUMNS = metaworld_expert do_nothing demo_replay demo_replay-swap instant_policy instant_policy-swap
# The MetaWorld evaluations stop at once where gl-library could not install the OSMesa library.
osmesa: gl-library
	@ldconfig -p | grep -q libOSMesa || { echo "error: MuJoCo renders with OSMesa here (MUJOCO_GL=osmesa): install \
	Debian's libosmesa6 (apt-get install libosmesa6, as root)"; exit 1; }

eval-metaworld: $(INSTALLED) osmesa
	$(METAWORLD) $(IP)
	$(METAWORLD) --policy demo_replay
	$(METAWORLD) $(IP) --swap
	$(METAWORLD) --policy demo_replay --swap
	$(METAWORLD) --policy do_nothing
	$(METAWORLD) --policy metaworld_expert
	$(VENV)/bin/lerobot-ip-eval-table $(foreach run,$(METAWORLD_COLUMNS),$(run)=$(METAWORLD_OUT)/runs/$(run)) \
		--env-type metaworld_pointcloud --paired instant_policy=demo_replay --paired instant_policy=instant_policy-swap \
		--paired demo_replay=demo_replay-swap --out docs/results_metaworld_$(METAWORLD_TASKS)_$(SPLIT)

# Step 5 of the standing training (docs/training.md): a candidate checkpoint, by default the standing run's best
# save, on the test split of the suite and of MetaWorld MT10. Only its column is evaluated: it is joined to the
# committed tables' columns through their manifests (the same cells, seeds and demonstration sets, checked) and
# paired with the shipped checkpoint and demo_replay (the suite's per-object one too). The candidate loads another
# checkpoint than the shipped column (--allow-difference checkpoint); the replay columns differ in their options.
# A demonstration set recorded here with other bytes than the committed column's (pybullet on another CPU: 7 of the
# suite's 36 sets on 2026-11-27) would pair other demonstrations: the committed columns' tasks with such a set are
# evaluated again here (runs redo-<column>) and amend those columns before the join. Episodes on other machines may
# still end otherwise (float arithmetic in a closed loop): docs/training.md, "Shipping on evidence". Last, the ship gate
# (workbench/ship_gate.py): the candidate ships when its difference from the shipped checkpoint pooled over both
# benchmarks' 22 tasks is resolved above zero and neither benchmark's is resolved below.
# SUITE_ARGS=--resume continues an interrupted run.
CANDIDATE ?= checkpoints/stream/best/pretrained_model
CANDIDATE_NAME ?= standing_best
SUITE_TABLE := docs/results_suite_$(SPLIT).manifest.json
METAWORLD_TABLE := docs/results_metaworld_$(METAWORLD_TASKS)_$(SPLIT).manifest.json
# Each committed column the candidate is paired with, and the options it was evaluated with.
COLUMN_instant_policy = $(IP)
COLUMN_demo_replay_per_object = $(PER_OBJECT)
COLUMN_demo_replay = --policy demo_replay
# One half of results-candidate, after the candidate's own run: $(1) the evaluation command, $(2) its output folder,
# $(3) the committed table's manifest, $(4) the committed columns, $(5) lerobot-ip-eval-table's further options
# (given to both of its calls: with --recorded-differently it only prints).
define candidate_join
	join="$(CANDIDATE_NAME)=$(2)/runs/$(CANDIDATE_NAME) $(foreach run,$(4),$(run)=$(3))"; \
	redo=$$($(VENV)/bin/lerobot-ip-eval-table $$join $(5) --recorded-differently) || exit 1; amend=; \
	if [ -n "$$redo" ]; then echo "recorded here with other bytes: $$redo; the committed columns evaluate them again"; \
	rm -rf $(foreach run,$(4),$(2)/runs/redo-$(run)); \
	$(foreach run,$(4),$(1) $(COLUMN_$(run)) --tasks $$redo --run-name redo-$(run) &&) true || exit 1; \
	amend="$(foreach run,$(4),$(run)=$(2)/runs/redo-$(run))"; fi; \
	$(VENV)/bin/lerobot-ip-eval-table $$join $$amend $(5) --allow-difference checkpoint \
		$(foreach run,$(4),--paired $(CANDIDATE_NAME)=$(run))
endef
results-candidate: $(INSTALLED) osmesa
	$(SUITE) --policy instant_policy --policy-path $(CANDIDATE) --run-name $(CANDIDATE_NAME)
	$(call candidate_join,$(SUITE),$(SUITE_OUT),$(SUITE_TABLE),instant_policy demo_replay_per_object demo_replay,\
		--allow-difference policy_options --out docs/results_suite_$(SPLIT)_$(CANDIDATE_NAME))
	$(METAWORLD) --policy instant_policy --policy-path $(CANDIDATE) --run-name $(CANDIDATE_NAME)
	$(call candidate_join,$(METAWORLD),$(METAWORLD_OUT),$(METAWORLD_TABLE),instant_policy demo_replay,\
		--env-type metaworld_pointcloud --out docs/results_metaworld_$(METAWORLD_TASKS)_$(SPLIT)_$(CANDIDATE_NAME))
	$(VENV)/bin/python -m workbench.cli.ship_gate $(CANDIDATE_NAME) instant_policy \
		docs/results_suite_$(SPLIT)_$(CANDIDATE_NAME).manifest.json \
		docs/results_metaworld_$(METAWORLD_TASKS)_$(SPLIT)_$(CANDIDATE_NAME).manifest.json

POLICY ?= demo_replay
eval-suite: $(INSTALLED)
	$(VENV)/bin/lerobot-ip-eval-suite --policy $(POLICY) --episodes 10 --out outputs/eval_suite

# CI=true skips tests marked slow; the summary at the end lists every skipped test with its reason. TEST_WORKERS
# pytest-xdist workers share the cores (tests/conftest.py gives each its share of torch threads); a test file runs in
# one worker, so its module fixtures are built once; the files go out heaviest first by tests/durations.json
# (conftest.py; `pytest --store-durations` rewrites it from a run). TEST_WORKERS=0 runs in this process.
TEST_WORKERS ?= 2
test: $(INSTALLED) gl-library
	$(VENV)/bin/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder \
		$(if $(filter true,$(CI)),-m "not slow",)

clean:
	rm -rf outputs .pytest_cache
