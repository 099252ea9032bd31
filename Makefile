# Two commands on a fresh machine: `make run` trains, `make test` tests.
# Both install from the lock in requirements/ (every package pinned with its hashes, for CPython
# 3.11 on Linux x86-64), so what installs today installs tomorrow; `make lock` refreshes it.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip --disable-pip-version-check
# Installs resolve nothing: each lock is the whole set, taken as it is (--no-deps) and checked by hash.
LOCKED := install --quiet --require-hashes --no-deps
# uv (pinned by hash in requirements/uv.txt, put into the venv by pip) installs a lock in seconds from its cache,
# where pip takes a minute or more for the test set: the same files, checked against the same hashes. Where uv
# cannot install it (no uv wheel for the platform, an index only pip is configured for), pip installs the lock.
UV         := $(VENV)/bin/uv
FIND_LINKS ?= $(PIP_FIND_LINKS)
UV_SOURCES  = $(if $(FIND_LINKS),--find-links $(FIND_LINKS)) $(if $(PIP_EXTRA_INDEX_URL),--extra-index-url $(PIP_EXTRA_INDEX_URL))
install_lock = ($(UV) pip install --python $(PY) --quiet --require-hashes --no-deps $(UV_SOURCES) -r $(1) \
	|| (echo "uv could not install $(1); pip installs it" && $(PIP) $(LOCKED) -r $(1)))

.PHONY: run test install install-test lock clean

# The package and its core dependencies: enough to train, evaluate and render.
$(VENV)/.installed: pyproject.toml requirements/core.txt requirements/uv.txt
	$(PYTHON) -m venv $(VENV)
	$(PIP) $(LOCKED) --only-binary :all: -r requirements/uv.txt || echo "no uv wheel for this platform; pip installs the locks"
	$(call install_lock,requirements/core.txt)
	$(PIP) install --quiet --no-deps --no-build-isolation -e .
	$(PIP) check
	touch $@

# Test extras on top (the same versions of everything core has): pytest, notebooks, and
# Stable-Baselines3 (its adapter test trains SB3's PPO on our Gymnasium environment; torch is
# the CPU build, found through pip's find-links; see docs/install.md).
$(VENV)/.installed-test: $(VENV)/.installed requirements/test.txt
	$(call install_lock,requirements/test.txt)
	$(PIP) check
	touch $@

install: $(VENV)/.installed

install-test: $(VENV)/.installed-test

run: install
	$(PY) train_ppo.py $(ARGS)

test: install-test
	$(PY) -m pytest -n 2 --dist loadscope --no-loadscope-reorder $(PYTEST_ARGS)

# Re-resolve pyproject.toml's ranges into the two locks (uv, pinned, in a venv of its own). The test
# lock is resolved first and constrains the core one, so core's versions are the test set's.
LOCK_VENV  := .venv-lock
UV_COMPILE = $(LOCK_VENV)/bin/uv pip compile --quiet --no-header --generate-hashes \
	--python-version 3.11 --python-platform x86_64-manylinux_2_28 \
	$(if $(FIND_LINKS),--find-links $(FIND_LINKS))

lock:
	$(PYTHON) -m venv $(LOCK_VENV)
	$(LOCK_VENV)/bin/pip install --quiet --require-hashes --no-deps -r requirements/uv.txt
	$(UV_COMPILE) pyproject.toml requirements/build.in --extra dev --extra notebooks --extra sb3 -o requirements/test.txt
	$(UV_COMPILE) pyproject.toml requirements/build.in -c requirements/test.txt -o requirements/core.txt

clean:
	rm -rf $(VENV) $(LOCK_VENV) .pytest_cache .hypothesis
