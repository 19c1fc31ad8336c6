# phoid — one-command set-up on a fresh machine (Python 3.11 + pip).
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test,bench]'
	touch $(STAMP)

## install and run the main job: the seed paper's Table 1 and Figure 1
demo: $(STAMP)
	$(VENV)/bin/phoid paper --overwrite

## install and run the test suite (and the linter)
test: $(STAMP)
	$(VENV)/bin/ruff check src tests bench
	$(PY) -m pytest -q

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests bench

## benchmarks (not part of the tests): writes BENCHMARKS.md and bench/results.json
bench: $(STAMP)
	$(PY) bench/run.py

clean:
	rm -rf $(VENV) phoid-out build *.egg-info
