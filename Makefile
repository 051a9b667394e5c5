# Two commands on a fresh machine: `make repro` (set up + run the pipeline) and `make test`.
# Both (re)create .venv from environment.lock when it is missing or older than the lock.
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-from-lock
BENCH_STAMP := $(VENV)/.installed-bench-extra
export DVC_NO_ANALYTICS := 1
export PYTHONHASHSEED := 0
export PATH := $(CURDIR)/$(VENV)/bin:$(PATH)   # papermill and dvc of the venv, for the pipeline's stages

.PHONY: setup test test-fast repro bench reference lint clean-venv

$(STAMP): environment.lock pyproject.toml
	rm -rf $(VENV)
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r environment.lock
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	$(PY) -m ipykernel install --sys-prefix --name python3 >/dev/null
	touch $(STAMP)

setup: $(STAMP)

# The full suite (CI runs it); `make test-fast` leaves out the tests marked slow (the pipeline end to end,
# trainings of a minute or more), for local work.
test: $(STAMP)
	$(VENV)/bin/pytest

test-fast: $(STAMP)
	$(VENV)/bin/pytest -m "not slow"

repro: $(STAMP)
	$(VENV)/bin/dvc repro

# BenchMARL, torchrl and VMAS for the side-by-side figures: an extra that only the benchmarks install.
$(BENCH_STAMP): $(STAMP) benchmarks/bench.lock
	$(PY) -m pip install --quiet --disable-pip-version-check -c environment.lock -r benchmarks/bench.lock
	touch $(BENCH_STAMP)

# `make bench ARGS="--only 3 5"` runs some sections only; `make bench ARGS=--quick` every figure within 15 minutes.
bench: $(BENCH_STAMP)
	$(PY) benchmarks/bench.py $(ARGS)

# Regenerate the reduced-episode regression references on purpose (after a change meant to alter curves).
reference: $(STAMP)
	$(PY) -m replicate.learn.regression --write tests/reference

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks
	$(VENV)/bin/lint-imports

clean-venv:
	rm -rf $(VENV)
