# The two commands of the README: `make demo` (main job) and `make test` (the suite).
# Both create the virtual environment first; nothing else needs to be installed by hand.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test acceptance bench env clean system-packages

demo: $(VENV)/.installed
	$(BIN)/daq warm
	$(BIN)/daq demo

# two workers (pytest-xdist), a file each at a time in conftest.py's order (longest files first, the real-time files
# paired): 607-726 s, clean clones of the 2-core machine, 2026-11-28, 703 s on 2026-11-29 (746 s before 11-28's kernel
# change; 22-26 min on the one it had earlier that day, at half its speed).
# `$(BIN)/python -m pytest` alone runs it serially, `-m "not slow"` quickly.
PYTEST_WORKERS ?= 2
# `daq warm` first: the kernels compiled once into the cache, not by both workers and their pools side by side.
test: $(VENV)/.installed system-packages
	$(BIN)/daq warm
	$(BIN)/python -m pytest -n $(PYTEST_WORKERS) --dist loadfile --no-loadscope-reorder --durations=25

acceptance: $(VENV)/.installed  # the long acceptance runs (tests/long, minutes each), outside `make test`
	$(BIN)/daq warm
	$(BIN)/python -m pytest tests/long

system-packages:  # Octave + h5dump (tests/test_old_readers.py), Chromium + chromedriver (tests/test_web.py); only what is missing
	bash deploy/system-packages.sh

bench: $(VENV)/.installed
	$(BIN)/daq bench sim

env: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $@

clean:
	rm -rf $(VENV) out .pytest_cache
