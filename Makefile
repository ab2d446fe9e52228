# dcsms_ros developer entry points. `make demo` and `make test` are all a newcomer needs; the
# first call builds .venv (CPython 3.11, pinned requirements.txt, editable install of this
# package) and later calls reuse it.

SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
.DEFAULT_GOAL := help

# .venv's interpreter: CPython 3.11, which the ROS 2 Jazzy wheels on PyPI are built for. Unless
# PYTHON is set, the first of PYTHON_CANDIDATES that is 3.11 and can make a venv: the
# distribution's own first. On this machine Debian's 3.11 ran the one-process-per-node graph with
# 21-31 % less CPU a sample than pyenv's 3.11, a build without --enable-optimizations and with a
# shared libpython (10 alternating pairs, docs/performance.md).
PYTHON ?=
PYTHON_CANDIDATES := /usr/bin/python3.11 python3.11 python3
# pip >= 25.3 always installs `-e .` as a PEP 660 editable wheel: console scripts land in
# .venv/bin and setup.cfg's [develop] script_dir (meant for colcon) is never used.
PIP_VERSION := 26.3
VENV := .venv
PY := $(VENV)/bin/python
DCSMS := $(VENV)/bin/dcsms
# Rebuilt when requirements.txt, setup.py or setup.cfg change; flock: parallel `make` calls
# share one venv.
STAMP := $(VENV)/.dcsms-stamp
DEMO_OUT ?= out/demo
PYTEST_ARGS ?=

# Every process the project starts stays on this host; the tests choose their own domain ids.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export ROS_DOMAIN_ID ?= 42
# No .pyc files or caches written into the shared source tree by the checks below.
export PYTHONDONTWRITEBYTECODE := 1
export MPLBACKEND := Agg
# numba's compiled-function cache (the batch engine fast path) lives in the venv, not the tree.
export NUMBA_CACHE_DIR ?= $(CURDIR)/$(VENV)/numba-cache

.PHONY: help venv test lint typecheck pytest demo model-demo bench colcon-check clean distclean

help:
	@echo "make demo          graph in lockstep, six modes recorded and analysed -> out/demo/report.md"
	@echo "make model-demo    analytic model only (eig, DFBC+FFC transmissibility, c1 sweep)"
	@echo "make test          ruff + mypy + pytest (creates .venv on first use)"
	@echo "make bench         performance benchmark (bench/run.py)"
	@echo "make colcon-check  real colcon build into a temp dir; checks the ros2 run layout"
	@echo "make clean         remove build outputs; make distclean also removes .venv"

venv $(VENV): $(STAMP)

$(STAMP): requirements.txt setup.py setup.cfg
	@mkdir -p $(VENV) && flock $(VENV)/.lock $(MAKE) --no-print-directory _venv-locked

# Runs under the lock; re-checks so that a second waiter does not install again.
.PHONY: _venv-locked
_venv-locked:
	@if [ -f $(STAMP) ] && [ -z "$$(find requirements.txt setup.py setup.cfg -newer $(STAMP))" ]; \
	then exit 0; fi; \
	if [ ! -x $(PY) ]; then \
	  py='$(PYTHON)'; \
	  if [ -z "$$py" ]; then \
	    for c in $(PYTHON_CANDIDATES); do \
	      if $$c -c 'import sys, ensurepip; assert sys.version_info[:2] == (3, 11)' 2>/dev/null; \
	      then py=$$c; break; fi; \
	    done; \
	  fi; \
	  py=$${py:-python3}; \
	  $$py -c 'import sys; assert sys.version_info[:2] == (3, 11), sys.version' \
	    || { echo "need CPython 3.11, which the ROS 2 Jazzy wheels are built for (set PYTHON=...)" >&2; exit 1; }; \
	  echo "creating $(VENV) with $$($$py --version) ($$(command -v $$py))"; \
	  $$py -m venv $(VENV); \
	fi; \
	$(PY) -m pip install --quiet --upgrade pip==$(PIP_VERSION); \
	$(PY) -m pip install --quiet -r requirements.txt; \
	$(PY) -m pip install --quiet --no-deps --no-build-isolation -e .; \
	touch $(STAMP)

test: lint typecheck pytest

lint: $(STAMP)
	$(VENV)/bin/ruff check .

typecheck: $(STAMP)
	$(VENV)/bin/mypy dcsms_ros bench

# pytest exits 5 when it collects nothing; that fails the target like any other error.
pytest: $(STAMP)
	$(PY) -m pytest --durations=10 $(PYTEST_ARGS) || { rc=$$?; \
	  [ $$rc -eq 5 ] && echo "pytest collected no tests" >&2; exit $$rc; }

# The main job end to end: lockstep graph + recording, the six modes, analysis, Table 4.
# SCHED_FIFO for the control path where permitted (root / CAP_SYS_NICE): lockstep runs ~1.5-2x
# faster and gives the same bits; elsewhere the nodes log a warning and run as usual.
DEMO_ARGS ?= --rt-priority 50
demo: $(STAMP)
	$(DCSMS) demo --out $(DEMO_OUT) $(DEMO_ARGS)

MODEL_OUT ?= out/model
model-demo: $(STAMP)
	$(DCSMS) model eig
	$(DCSMS) model tf --mode DFBC+FFC --plot $(MODEL_OUT)
	$(DCSMS) model sweep --param c1 --factors 1:101:2 --plot $(MODEL_OUT)

BENCH_ARGS ?=
bench: $(STAMP)
	$(PY) bench/run.py $(BENCH_ARGS)

colcon-check: $(STAMP)
	$(PY) -m pytest -p no:cacheprovider test/test_packaging.py -v

clean:
	rm -rf build install log out .pytest_cache .ruff_cache .mypy_cache *.egg-info
	find . -path ./$(VENV) -prune -o -name __pycache__ -type d -prune -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV)
