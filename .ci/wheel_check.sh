#!/usr/bin/env bash
# Build phoid's sdist and wheel (`python -m build`, the wheel made from the sdist) from the
# checkout's git-tracked files, install the wheel into a clean virtual environment, and run
# `phoid paper` (and a simulate + identify round trip) there, outside the checkout, so that
# nothing is imported from src/ and any module or package data missing from the wheel shows.
# Works in a temporary folder and removes it afterwards; the checkout is not touched.
# Usage: .ci/wheel_check.sh   (or `make wheel`); needs python3 (3.11+) and pip's index.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
PYTHON="${PYTHON:-python3}"
TMP="$(mktemp -d "${TMPDIR:-/tmp}/phoid-wheel.XXXXXX")"
trap 'rm -rf "$TMP"' EXIT

echo "wheel-check: copying the tracked files to $TMP/src"
mkdir -p "$TMP/src"
(cd "$ROOT" && git ls-files -z | xargs -0 cp --parents -t "$TMP/src" 2>/dev/null \
    || git ls-files -z | while IFS= read -r -d '' f; do
           [ -e "$f" ] && mkdir -p "$TMP/src/$(dirname "$f")" && cp -p "$f" "$TMP/src/$f"
       done)

echo "wheel-check: python -m build"
"$PYTHON" -m venv "$TMP/build-venv"
"$TMP/build-venv/bin/python" -m pip install -q --upgrade pip build
(cd "$TMP/src" && "$TMP/build-venv/bin/python" -m build --outdir "$TMP/dist" . >"$TMP/build.log" 2>&1) \
    || { tail -40 "$TMP/build.log"; echo "wheel-check: build failed" >&2; exit 1; }
ls -l "$TMP/dist"

WHEEL="$(ls "$TMP"/dist/*.whl)"
# every tracked file of src/phoid (the modules of every subpackage, package data) is in the wheel
missing="$("$TMP/build-venv/bin/python" - "$WHEEL" "$TMP/src/src" <<'PY'
import pathlib, sys, zipfile
names = set(zipfile.ZipFile(sys.argv[1]).namelist())
src = pathlib.Path(sys.argv[2])
for f in sorted((src / "phoid").rglob("*")):
    if f.is_file() and "__pycache__" not in f.parts and f.suffix != ".pyc":
        rel = f.relative_to(src).as_posix()
        if rel not in names:
            print(" " + rel, end="")
PY
)"
[ -z "$missing" ] || { echo "wheel-check: missing from the wheel:$missing" >&2; exit 1; }

echo "wheel-check: pip install the wheel into a clean venv"
"$PYTHON" -m venv "$TMP/venv"
"$TMP/venv/bin/python" -m pip install -q --upgrade pip
"$TMP/venv/bin/python" -m pip install -q "$WHEEL"

mkdir "$TMP/run"
cd "$TMP/run"   # outside the checkout: phoid must come from the installed wheel
export MPLBACKEND=Agg
"$TMP/venv/bin/python" -c "import phoid, sys; p = phoid.__file__; print('phoid from', p); \
sys.exit(0 if '/site-packages/' in p else 1)"
"$TMP/venv/bin/phoid" --help >/dev/null
"$TMP/venv/bin/phoid" paper --out paper-out
test -n "$(ls paper-out)" || { echo "wheel-check: phoid paper wrote no figures" >&2; exit 1; }
"$TMP/venv/bin/phoid" simulate s/ --m 2 --c 1 --k 64 --delay 0.1 --P 0.25:25:6 --D 0.6:6:6 \
    --noise 1e-4 --seed 1 >/dev/null
"$TMP/venv/bin/phoid" identify s/ --json >/dev/null
echo "wheel-check: ok ($(basename "$WHEEL"))"
