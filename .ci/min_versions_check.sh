#!/usr/bin/env bash
# Run the test suite against the lowest versions of phoid's dependencies: a temporary virtual
# environment gets phoid (editable, with the test extras) under the constraints of
# .ci/min-versions.txt (pyproject.toml's lower bounds, pinned), then pytest runs in the
# checkout with it. Arguments go to pytest (default: the whole suite), e.g.
#   .ci/min_versions_check.sh tests/test_cli.py tests/test_io.py
# The environment is removed afterwards unless KEEP_VENV=1. `make min-versions` runs it.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
PYTHON="${PYTHON:-python3}"
TMP="$(mktemp -d "${TMPDIR:-/tmp}/phoid-minver.XXXXXX")"
[ "${KEEP_VENV:-0}" = 1 ] || trap 'rm -rf "$TMP"' EXIT
cd "$ROOT"
"$PYTHON" -m venv "$TMP/venv"
"$TMP/venv/bin/python" -m pip install -q --upgrade pip
"$TMP/venv/bin/python" -m pip install -q -c .ci/min-versions.txt -e '.[test]'
# the pins must be what got installed
"$TMP/venv/bin/python" - <<'PY'
import importlib.metadata as md, re, sys
bad = []
for line in open(".ci/min-versions.txt"):
    m = re.match(r"^([A-Za-z0-9_.-]+)==(\S+)", line)
    if m and md.version(m.group(1)) != m.group(2):
        bad.append(f"{m.group(1)} {md.version(m.group(1))} (pinned {m.group(2)})")
print("min-versions:", ", ".join(f"{n} {md.version(n)}" for n in
      ("numpy", "scipy", "matplotlib", "typer", "rich", "tomli-w", "threadpoolctl", "click",
       "pyarrow", "h5py", "pandas", "control", "dask", "distributed")))
sys.exit(f"min-versions: not installed as pinned: {bad}" if bad else 0)
PY
MPLBACKEND=Agg "$TMP/venv/bin/python" -m pytest -q "$@"
