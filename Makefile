# Two commands do all the set-up on a fresh machine: `make demo` and `make test`.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
DEV := $(VENV)/.dev

.PHONY: demo test check lint typecheck pytest bench soak-ci soak warm warm-demo clean browser view

# Installs with uv (from PyPI, into the venv: what running needs in 4 s on a fresh machine,
# where pip takes 17 s), or with pip where uv cannot be had; the same packages either way
define install
$(PY) -m uv pip install --quiet --python $(PY) $(1) || \
	($(PY) -m pip install --quiet --upgrade pip && $(PY) -m pip install --quiet $(1))
endef

# what running needs (make demo), then the test tools (lint, types, pytest, the browser
# driver) and the live view's SDK
$(STAMP): pyproject.toml
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install --quiet uv || echo "note: no uv: pip installs instead"
	$(call install,-e .)
	touch $(STAMP)

# the live view's SDK (haptic-run --view): an extra that make demo leaves out (660 MB);
# make test installs it with the test tools
view: $(STAMP)
	$(call install,-e '.[view]')

$(DEV): $(STAMP)
	$(call install,-e '.[dev]')
	touch $(DEV)

# numba compiles the kernels once into its on-disk cache; later starts load it in < 1 s
warm: $(STAMP)
	$(PY) -m haptic_local_model.haptic_server.harness.warmup --jobs 2

# the demo's own kernels only (its scene, device and loop), in two processes: a fresh
# clone's first `make demo` compiles what it runs, not every feature's
warm-demo: $(STAMP)
	$(PY) -m haptic_local_model.haptic_server.harness.warmup --jobs 2 --demo

demo: $(STAMP) warm-demo
	$(VENV)/bin/haptic-run --duration 10 --log runs/demo.mcap --summary-json runs/demo-summary.json
	$(VENV)/bin/haptic-replay runs/demo.mcap --plot runs/demo.png

lint: $(DEV)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/lint-imports

# mypy reads the packages under their installed names through a tree of links (it does not
# run the editable install's import hook)
TYPECHECK := build/typecheck/haptic_local_model
typecheck: $(DEV)
	mkdir -p $(TYPECHECK)
	for p in shared sim_server haptic_server device_models benchmarks api; do \
		ln -sfn ../../../$$p $(TYPECHECK)/$$p; done
	$(VENV)/bin/mypy

# The tiers (tests/conftest.py enforces them): the fast tier is every test not marked slow
# or processes, independent, run on both cores; so are the slow tests that start no process
# (each computes in its own process, or paces itself on its own core: 196 s serial, 115 s
# on both cores); the tests that start processes run one at a time, so that they measure
# the machine, not each other (the 25 slowest are listed at the end: where the time goes).
FAST := -m "not slow and not processes"
pytest: $(DEV) warm browser
	$(PY) -m pytest -q -n 2 $(FAST)
	$(PY) -m pytest -q -n 2 -m "slow and not processes" --durations=10
	$(PY) -m pytest -q -m processes --durations=25

# before each commit: lint, types and the fast tier (README: 1-1.5 min on two cores)
check: lint typecheck warm
	$(PY) -m pytest -q -n 2 $(FAST)

# the live view's browser test drives Debian's Chromium (Playwright's own download is not
# used); installed here where apt-get may, else that test skips (CI requires it: .ci/run)
browser:
	@command -v chromium >/dev/null 2>&1 || { \
		(apt-get install -y -q chromium >/dev/null 2>&1 || \
		 (apt-get update -q >/dev/null 2>&1 && apt-get install -y -q chromium >/dev/null 2>&1)) \
		|| echo "note: no Chromium (apt-get install chromium): the live-view browser test will skip"; }

test: lint typecheck pytest

# the CI soak (.ci/run): every segment once (every device, every fault); locally: make soak MINUTES=60
soak-ci: $(STAMP) warm
	$(PY) -m haptic_local_model.haptic_server.harness.soak --minutes 5 --segment-s 30 --out runs/soak-ci

MINUTES ?= 60
soak: $(STAMP) warm
	$(PY) -m haptic_local_model.haptic_server.harness.soak --minutes $(MINUTES) --out runs/soak-$(MINUTES)min

bench: $(STAMP) warm
	$(PY) -m haptic_local_model.benchmarks.loop_timing

clean:
	-test -x $(PY) && $(PY) -c "import shutil, haptic_local_model.shared as s; shutil.rmtree(s.cache_dir(), True)"
	rm -rf $(VENV) runs build .pytest_cache .mypy_cache .ruff_cache
