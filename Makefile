# Two entry points do all set-up on a fresh machine:
#   make run   -> create .venv, install everything, run the main job
#   make test  -> create .venv, install everything, run the test suite
PYTHON ?= python3
VENV   ?= .venv
PY      = $(VENV)/bin/python
PIP     = $(PY) -m pip

.PHONY: setup run test lint bench clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --upgrade pip setuptools wheel
	# torch first, pinned: the local CPU wheel. Anything else pulls CUDA (see DEVELOPERS.md).
	$(PIP) install torch==2.13.0
	$(PIP) install -e ".[all]"
	touch $@

setup: $(VENV)/.installed

run: setup
	$(PY) scripts/main_job.py

test: setup
	$(PY) -m pytest -q

lint: setup
	$(PY) -m ruff check .

bench: setup
	$(PY) scripts/benchmark.py

clean:
	rm -rf $(VENV) outputs .pytest_cache
