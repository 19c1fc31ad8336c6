# phoid — one-command set-up on a fresh machine (Python 3.11 + pip).
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
LINTED := src tests bench examples .ci

.PHONY: demo test lint readme wheel min-versions bench mcu fuzz clean

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test,bench]'
	touch $(STAMP)

## install and run the main job: the seed paper's Table 1 and Figure 1
demo: $(STAMP)
	$(VENV)/bin/phoid paper --overwrite

## install and run the test suite (and the linter), on TEST_WORKERS processes (pytest-xdist):
## one per CPU, at most 4 (`make test TEST_WORKERS=0` runs it in one process); each test file
## runs whole on one worker (--dist loadfile), so a module's fixtures are computed once
TEST_WORKERS ?= $(shell n=$$(nproc 2>/dev/null || getconf _NPROCESSORS_ONLN 2>/dev/null || echo 2); \
                  [ "$$n" -gt 4 ] 2>/dev/null && n=4; echo "$$n")
test: $(STAMP)
	$(VENV)/bin/ruff check $(LINTED)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

lint: $(STAMP)
	$(VENV)/bin/ruff check $(LINTED)

## run every sh and python block of README.md as written, in a temporary copy of the checkout
readme: $(STAMP)
	$(PY) .ci/readme_check.py --venv $(VENV)

## build the wheel, install it into a clean venv and run `phoid paper` there
wheel:
	.ci/wheel_check.sh

## the test suite against the lowest dependency versions (.ci/min-versions.txt)
min-versions:
	.ci/min_versions_check.sh

## benchmarks (not part of the tests): writes BENCHMARKS.md and bench/results.json
bench: $(STAMP)
	$(PY) bench/run.py

## the microcontroller tests alone (tests/test_mcu_*.py and the controller's host and cross
## builds, tests/test_rig_controller_mcu.py; skipped without Debian's cross toolchains, QEMU and
## simavr: .ci/run installs them), then the per-target cost table
mcu: $(STAMP)
	$(PY) -m pytest -q $(wildcard tests/test_mcu_*.py) tests/test_rig_controller_mcu.py
	$(PY) bench/bench_mcu.py

## fuzz the readers for FUZZ_SECONDS (default 600; docs/fuzzing.md); findings: fuzz/crash-*
FUZZ_SECONDS ?= 600
fuzz: $(STAMP)
	$(PY) -m pip install -q -e '.[fuzz]'
	mkdir -p $${TMPDIR:-/tmp}/phoid-fuzz-corpus
	$(PY) fuzz/fuzz_readers.py $${TMPDIR:-/tmp}/phoid-fuzz-corpus fuzz/seeds -dict=fuzz/readers.dict -max_len=8192 -timeout=30 -rss_limit_mb=2048 -artifact_prefix=fuzz/ -max_total_time=$(FUZZ_SECONDS)

clean:
	rm -rf $(VENV) phoid-out build dist *.egg-info
