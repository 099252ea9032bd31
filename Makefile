# Two commands on a fresh machine: `make run` trains, `make test` tests.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python

.PHONY: run test install install-test clean

# The package and its core dependencies: enough to train, evaluate and render.
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e .
	touch $@

# Test extras on top: pytest, notebooks, and Stable-Baselines3 (its adapter test
# trains SB3's PPO on our Gymnasium environment; torch is the CPU build).
$(VENV)/.installed-test: $(VENV)/.installed
	$(PY) -m pip install --quiet -e ".[dev,notebooks,sb3]"
	touch $@

install: $(VENV)/.installed

install-test: $(VENV)/.installed-test

run: install
	$(PY) train_ppo.py $(ARGS)

test: install-test
	$(PY) -m pytest -n 2 --dist loadscope --no-loadscope-reorder $(PYTEST_ARGS)

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis
