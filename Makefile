# phoid — one-command set-up on a fresh machine (Python 3.11 + pip).
VENV   ?= .venv
PY     := $(VENV)/bin/python
LINTED := src tests bench examples .ci
# what is installed in $(VENV), each stamp newer than pyproject.toml once it is: phoid with its
# own dependencies alone (what `phoid paper` and the CLI need: `make demo`); with the test
# extras (`make test`, the linter, the README check); with the test and bench extras (`make
# bench`). A wider install touches the narrower stamps too, and pip never downgrades what a
# wider one installed, so `make demo` after `make test` installs nothing.
STAMP       := $(VENV)/.installed
TEST_STAMP  := $(VENV)/.installed-test
BENCH_STAMP := $(VENV)/.installed-bench

.PHONY: demo test lint readme wheel min-versions bench mcu fuzz clean

# $(call install,EXTRAS): phoid, editable, with EXTRAS (e.g. [test]) into $(VENV), made if absent
# (a comma in EXTRAS is written $(comma))
comma := ,
define install
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check --upgrade pip
	$(PY) -m pip install -q --disable-pip-version-check -e '.$(1)'
endef

$(STAMP): pyproject.toml
	$(call install,)
	touch $@

$(TEST_STAMP): pyproject.toml
	$(call install,[test])
	touch $(STAMP) $@

$(BENCH_STAMP): pyproject.toml
	$(call install,[test$(comma)bench])
	touch $(STAMP) $(TEST_STAMP) $@

## install phoid alone (no extras) and run the main job: the seed paper's Table 1 and Figure 1
demo: $(STAMP)
	$(VENV)/bin/phoid paper --overwrite

## install phoid with the test extras and run the linter and the test suite, on TEST_WORKERS
## processes (pytest-xdist): one per CPU, at most 4 (`make test TEST_WORKERS=0` runs it in one
## process); each test file runs whole on one worker (--dist loadfile), so a module's fixtures are
## computed once
TEST_WORKERS ?= $(shell n=$$(nproc 2>/dev/null || getconf _NPROCESSORS_ONLN 2>/dev/null || echo 2); \
                  [ "$$n" -gt 4 ] 2>/dev/null && n=4; echo "$$n")
test: $(TEST_STAMP)
	$(VENV)/bin/ruff check $(LINTED)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

lint: $(TEST_STAMP)
	$(VENV)/bin/ruff check $(LINTED)

## run every sh and python block of README.md, then of docs/examples.md (the commands the README
## showed before it became a quick start), as written, in a temporary copy of the checkout
readme: $(TEST_STAMP)
	$(PY) .ci/readme_check.py --venv $(VENV)
	$(PY) .ci/readme_check.py --venv $(VENV) --file docs/examples.md

## build the wheel, install it into a clean venv and run `phoid paper` there
wheel:
	.ci/wheel_check.sh

## the test suite against the lowest dependency versions (.ci/min-versions.txt)
min-versions:
	.ci/min_versions_check.sh

## benchmarks (not part of the tests): writes BENCHMARKS.md and bench/results.json
bench: $(BENCH_STAMP)
	$(PY) bench/run.py

## the microcontroller tests alone (tests/test_mcu_*.py and the controller's host and cross
## builds, tests/test_rig_controller_mcu.py; skipped without Debian's cross toolchains, QEMU and
## simavr: .ci/run installs them), then the per-target cost table
mcu: $(TEST_STAMP)
	$(PY) -m pytest -q $(wildcard tests/test_mcu_*.py) tests/test_rig_controller_mcu.py
	$(PY) bench/bench_mcu.py

## fuzz the readers for FUZZ_SECONDS (default 600; docs/fuzzing.md); findings: fuzz/crash-*
FUZZ_SECONDS ?= 600
fuzz: $(STAMP)
	$(PY) -m pip install -q -e '.[fuzz]'
	mkdir -p $${TMPDIR:-/tmp}/phoid-fuzz-corpus
	$(PY) fuzz/fuzz_readers.py $${TMPDIR:-/tmp}/phoid-fuzz-corpus fuzz/seeds -dict=fuzz/readers.dict -max_len=8192 -timeout=30 -rss_limit_mb=2048 -artifact_prefix=fuzz/ -max_total_time=$(FUZZ_SECONDS)

## the documentation site (docs/, docs/about.md) into docs/_build/html with warnings as errors
## (-W --keep-going), offline, from a clean state (-E: a page added since the last build gets
## its reference stubs): installs the docs extra once, then builds, executing the tutorials and
## the commands shown with their output, and stamps the build (.phoid-docs-ok) once it passed;
## tests/test_docs_site.py checks the reference's names, and the stamped build's pages in
## headless Chromium while it is newer than its sources (PHOID_DOCS_BUILD=1: builds its own)
DOCS_STAMP := $(VENV)/.installed-docs
.PHONY: docs
$(DOCS_STAMP): pyproject.toml $(STAMP)
	$(PY) -m pip install -q -e '.[docs]'
	touch $@

docs: $(DOCS_STAMP)
	rm -f docs/_build/html/.phoid-docs-ok
	$(PY) -m sphinx -b html -W --keep-going -E -q docs docs/_build/html
	touch docs/_build/html/.phoid-docs-ok

clean:
	rm -rf $(VENV) phoid-out build dist *.egg-info
