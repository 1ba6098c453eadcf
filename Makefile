# Two entry points do all set-up on a fresh machine:
#   make run   -> create .venv, install everything, run the main job
#   make test  -> create .venv, install everything, run the test suite; then the same in
#                 .venv-ray (Ray/RLlib, which pins gymnasium 1.2.2) for the distributed tests
PYTHON ?= python3
VENV   ?= .venv
PY      = $(VENV)/bin/python
PIP     = $(PY) -m pip
# second environment: the 'distributed' extra (ray[rllib] pins gymnasium 1.2.2, .venv has the newest)
VENV_RAY ?= .venv-ray
PY_RAY    = $(VENV_RAY)/bin/python

.PHONY: setup setup-ray run test test-distributed lint bench clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --upgrade pip setuptools wheel
	# torch first, pinned: the local CPU wheel. Anything else pulls CUDA (see DEVELOPERS.md).
	$(PIP) install torch==2.13.0
	$(PIP) install -e ".[all]"
	touch $@

$(VENV_RAY)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV_RAY)
	$(PY_RAY) -m pip install --upgrade pip setuptools wheel
	# torch first here too: ray[rllib] would otherwise let pip pick a CUDA build
	$(PY_RAY) -m pip install torch==2.13.0
	$(PY_RAY) -m pip install -e ".[all,distributed]"
	touch $@

setup: $(VENV)/.installed

setup-ray: $(VENV_RAY)/.installed

run: setup
	$(PY) scripts/main_job.py

test: setup
	$(PY) -m pytest -q
	$(MAKE) --no-print-directory test-distributed

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
