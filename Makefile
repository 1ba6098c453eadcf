# Two entry points do all set-up on a fresh machine:
#   make run   -> create .venv, install everything, run the main job
#   make test  -> create .venv, install everything, run the test suite; beside it the same in
#                 .venv-ray (Ray/RLlib, which pins gymnasium 1.2.2) for the distributed tests
PYTHON ?= python3
VENV   ?= .venv
PY      = $(VENV)/bin/python
# --no-compile: pip would byte-compile every installed module (~12,000 files here, ~15,000 with Ray);
# Python compiles the ~20 % the project imports on first use instead
PIP     = $(PY) -m pip
PIP_INSTALL = install --no-compile
# second environment: the 'distributed' extra (ray[rllib] pins gymnasium 1.2.2, .venv has the newest)
VENV_RAY ?= .venv-ray
PY_RAY    = $(VENV_RAY)/bin/python

.PHONY: setup setup-ray run test test-distributed lint bench clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --upgrade pip setuptools wheel
	# torch first, pinned: the local CPU wheel. Anything else pulls CUDA (README, "Install by hand").
	$(PIP) $(PIP_INSTALL) torch==2.13.0
	$(PIP) $(PIP_INSTALL) -e ".[all]"
	touch $@

$(VENV_RAY)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV_RAY)
	$(PY_RAY) -m pip install --upgrade pip setuptools wheel
	# torch first here too: ray[rllib] would otherwise let pip pick a CUDA build
	$(PY_RAY) -m pip $(PIP_INSTALL) torch==2.13.0
	$(PY_RAY) -m pip $(PIP_INSTALL) -e ".[all,distributed]"
	touch $@

setup: $(VENV)/.installed

setup-ray: $(VENV_RAY)/.installed

run: setup
	$(PY) scripts/main_job.py

# The main suite keeps about one core busy: the .venv-ray branch (its set-up, the distributed tests, the
# env tests under gymnasium 1.2) runs beside it, its log printed once both are done; fails if either fails.
# It runs in its own session (setsid): a background job ignores Ctrl-C, so the trap stops its whole group.
test: setup
	@ray_log=$$(mktemp); \
	setsid $(MAKE) --no-print-directory test-distributed > "$$ray_log" 2>&1 & ray_pid=$$!; \
	trap 'kill -- -$$ray_pid 2>/dev/null; rm -f "$$ray_log"; exit 130' INT TERM; \
	echo "$(PY) -m pytest -q  (beside it: make test-distributed, log below)"; \
	$(PY) -m pytest -q; rc=$$?; \
	wait $$ray_pid; ray_rc=$$?; \
	echo "--- make test-distributed (ran beside the main suite), exit $$ray_rc ---"; \
	cat "$$ray_log"; rm -f "$$ray_log"; \
	test $$rc -eq 0 && test $$ray_rc -eq 0

# Ray tests (marker 'distributed', skipped in .venv) and the env API tests under gymnasium 1.2
test-distributed: setup-ray
	$(PY_RAY) -m pytest -q -m distributed
	$(PY_RAY) -m pytest -q tests/kin_envs/envs

lint: setup
	$(PY) -m ruff check .

bench: setup
	$(PY) scripts/benchmark.py

clean:
	rm -rf $(VENV) $(VENV_RAY) outputs .pytest_cache
