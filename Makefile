# roverav: `make demo` runs the main job, `make test` runs the suite (after `make lint`:
# ruff, then mypy over the typed packages listed in pyproject.toml's [tool.mypy]).
# Both set everything up on a fresh machine first (Debian libraries for headless
# MuJoCo rendering, a .venv with the CPU build of torch).

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.roverav-installed
export MUJOCO_GL ?= egl
export PYOPENGL_PLATFORM ?= egl

.PHONY: setup demo demo-finetune test lint typecheck bench clean-shm

setup: $(STAMP)

# EGL + Mesa (llvmpipe) for MuJoCo's offscreen renderer; installed only when missing.
.sysdeps:
	@if ! ldconfig -p | grep -q 'libEGL.so.1' || ! ls /usr/lib/*/dri/swrast_dri.so /usr/lib/*/dri/libdril_dri.so >/dev/null 2>&1; then \
	  echo "installing EGL/Mesa libraries for headless rendering"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libegl1 libgl1 libgles2 libegl-mesa0 libgl1-mesa-dri >/dev/null; \
	fi
	@touch .sysdeps

$(STAMP): pyproject.toml constraints.txt .sysdeps
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# CPU torch first, pinned, so no dependency range can pull a CUDA build.
	$(PY) -m pip install -q -c constraints.txt torch==2.13.0
	$(PY) -m pip install -q -c constraints.txt -e '.[train,dev,onnx,ray,ros]'
	@touch $(STAMP)

# The main job: a supervised daemon + trainer pair; PPO learns to drive RoverEnvFused from
# the reward, from scratch, over the camera scan and behind the collision shield (8 envs of
# 256-step rollouts, a daemon slot each), then random and each checkpoint drive the same 20
# evaluation episodes, at once over the slots: the learning curve, the table and a video land
# in runs/demo/ (the same command continues a stopped run).
DEMO_STEPS ?= 200000
demo: setup
	$(PY) launch/run_pair.py --name roverav_demo --slots 8 --daemon-arg=--log-level --daemon-arg=WARNING -- $(PY) -m rover_train.demo --n-steps 256 --timesteps $(DEMO_STEPS) --points 4 --episodes 20 --out runs/demo

# The main job before: DAgger fine-tunes the zoo's fused-maze student with the daemon in the loop.
demo-finetune: setup
	$(PY) launch/run_pair.py --name roverav_demo_ft --daemon-arg=--log-level --daemon-arg=WARNING -- $(PY) -m rover_train.imitation.demo --timesteps 24000 --episodes 20 --out runs/demo-finetune

# Two workers at most on this 2-core class of machine (one per core, four on bigger ones); a
# test file runs whole on one worker, so its module fixtures (a daemon, a Ray cluster) start once.
test: setup lint
	$(PY) -m pytest -q -n auto --maxprocesses 4 --dist loadfile

lint: setup
	$(VENV)/bin/ruff check .
	$(MAKE) --no-print-directory typecheck

typecheck: setup
	$(PY) -m mypy

bench: setup
	$(PY) -m benchmarks.ipc_latency
	$(PY) -m benchmarks.env_speed
	$(PY) -m benchmarks.perception_speed
	$(PY) -m benchmarks.fused_speed
