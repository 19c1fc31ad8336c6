#!/usr/bin/env python3
"""Run every ``sh`` and ``python`` code block of README.md as written, in a copy of the checkout.

The README's examples are meant to be run from a clone alone, in order, from the checkout's
root after ``make demo`` (the first block activates the venv: ``. .venv/bin/activate``). This
script does exactly that in a temporary copy of the checkout (its git-tracked files, as they are
in the working tree, and ``.venv`` a link to the venv given), so nothing beside the clone (no
``../shared``) is reachable by a relative path and the checkout itself is left untouched:

* each ``sh`` block runs with ``bash -e -o pipefail``, each ``python`` block with the virtual
  environment's python, in block order, in the same folder, each under a timeout;
* the first failing block stops the check: the block, its exit status and the tail of its
  standard output and error are printed, and the exit status is 1;
* a ``text`` block that directly follows a run block (only blank lines between) is the output
  to expect: each of its lines must be a line the block printed (spaces collapsed, standard
  output or error, in order); a line starting with ``…`` stands for lines left out, a ``…``
  inside a line for characters left out (digits that depend on the CPU, say);
* afterwards every file the blocks created must be git-ignored (``git status`` in the copy is
  clean), so that running the README leaves no clutter to commit.

A block preceded by the line ``<!-- readme-check: skip: REASON -->`` is not run; the reason is
printed (the set-up block: CI runs ``make test`` itself, and ``make demo`` builds a venv).

Usage (from the checkout; ``make readme`` does this)::

    .venv/bin/python .ci/readme_check.py [--venv .venv] [--timeout 600] [--keep]
    .venv/bin/python .ci/readme_check.py --file docs/examples.md   # the site's examples page
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FENCE = re.compile(r"^```([A-Za-z0-9_+-]*)\s*$")
SKIP = re.compile(r"^<!--\s*readme-check:\s*skip:\s*(.*?)\s*-->\s*$")
RUNNABLE = {"sh": "sh", "bash": "sh", "shell": "sh", "python": "python", "py": "python"}


def _fenced(text: str, name: str = "README.md") -> list[tuple[int, str, int, int]]:
    """Every fenced block of ``text``: (its opening fence's index, language (lower case), its
    first and its past-the-end code line's index), in order; a block never closed is an error
    naming ``name`` and the line."""
    lines = text.splitlines()
    out = []
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        j = i + 1
        while j < len(lines) and not lines[j].startswith("```"):
            j += 1
        if j == len(lines):
            raise SystemExit(f"{name}:{i + 1}: code block never closed")
        out.append((i, m.group(1).lower(), i + 1, j))
        i = j + 1
    return out


def blocks(text: str, name: str = "README.md") -> list[tuple[int, str, str, str | None]]:
    """(line number, kind, code, skip reason) of every runnable fenced block, in order."""
    lines = text.splitlines()
    out = []
    for i, lang, start, j in _fenced(text, name):
        prev = next((lines[k] for k in range(i - 1, -1, -1) if lines[k].strip()), "")
        skip = SKIP.match(prev)
        if lang in RUNNABLE:
            out.append((start, RUNNABLE[lang], "\n".join(lines[start:j]) + "\n",
                        skip.group(1) if skip else None))
    return out


def expected_outputs(text: str, name: str = "README.md") -> dict[int, list[str]]:
    """The output excerpt of each run block: {run block's first code line: the lines of the
    ``text`` block that directly follows it (only blank lines between)}, elisions included."""
    lines = text.splitlines()
    out: dict[int, list[str]] = {}
    last: tuple[int, int] | None = None  # the previous block, when it was a run block
    for i, lang, start, j in _fenced(text, name):
        if lang == "text" and last is not None and not any(
                x.strip() for x in lines[last[1] + 1:i]):
            out[last[0]] = lines[start:j]
        last = (start, j) if lang in RUNNABLE else None
    return out


def _squeeze(line: str) -> str:
    return " ".join(line.split())


def missing_lines(expected: list[str], stdout: str, stderr: str = "") -> list[str]:
    """The lines of ``expected`` (an output excerpt) that the block did not print: each must be
    a line of ``stdout`` or ``stderr`` (spaces collapsed), after the previous one matched in the
    same stream; blank lines and lines starting with ``…`` are skipped."""
    streams = [[_squeeze(x) for x in stdout.splitlines()],
               [_squeeze(x) for x in stderr.splitlines()]]
    cursor = [0, 0]
    missing = []
    for line in expected:
        want = _squeeze(line)
        if not want or want.startswith("…"):
            continue
        pattern = re.compile(".*?".join(map(re.escape, want.split("…"))))
        for k, stream in enumerate(streams):
            hit = next((n for n in range(cursor[k], len(stream))
                        if pattern.fullmatch(stream[n])), None)
            if hit is not None:
                cursor[k] = hit + 1
                break
        else:
            missing.append(line)
    return missing


def copy_checkout(dest: Path, venv: Path | None = None) -> None:
    """The git-tracked files of the checkout (working-tree content) into ``dest``, made a git
    repository with them committed, so that ``git status`` there lists what the blocks create.

    With ``venv``, ``dest/.venv`` is a link to it (excluded from ``git status``), so that a block
    reads as in a clone after ``make demo``: ``. .venv/bin/activate``, ``.venv/bin/python``."""
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, check=True,
                           capture_output=True).stdout.decode().split("\0")
    for f in filter(None, files):
        src = ROOT / f
        if not src.exists():  # deleted in the working tree
            continue
        (dest / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dest / f, follow_symlinks=False)
    git = ["git", "-c", "init.defaultBranch=main", "-c", "core.autocrlf=false",
           "-c", "user.name=readme-check", "-c", "user.email=readme-check@localhost"]
    subprocess.run([*git, "init", "-q"], cwd=dest, check=True)
    subprocess.run([*git, "add", "-A"], cwd=dest, check=True)
    subprocess.run([*git, "commit", "-q", "--no-verify", "-m", "checkout"], cwd=dest, check=True)
    if venv is not None:
        (dest / ".venv").symlink_to(venv, target_is_directory=True)
        with open(dest / ".git" / "info" / "exclude", "a", encoding="utf-8") as f:
            f.write("/.venv\n")  # a link: .gitignore's `.venv/` names a folder only


def tail(s: str, n: int = 4000) -> str:
    return s if len(s) <= n else "…" + s[-n:]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--venv", type=Path, default=ROOT / ".venv",
                    help="virtual environment with phoid installed (default: .venv)")
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds per block")
    ap.add_argument("--keep", action="store_true", help="keep the temporary copy")
    ap.add_argument("--file", default="README.md",
                    help="the Markdown file whose blocks to run, relative to the checkout "
                         "(default README.md; e.g. docs/examples.md)")
    args = ap.parse_args(argv)
    venv = args.venv.resolve()
    py = venv / "bin" / "python"
    if not (venv / "bin" / "phoid").is_file():
        print(f"readme-check: no phoid in {venv}/bin (run `make .venv/.installed-test` first: "
              "the README's examples use the extras it installs)",
              file=sys.stderr)
        return 2
    env = dict(os.environ, VIRTUAL_ENV=str(venv),
               PATH=f"{venv / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}",
               MPLBACKEND="Agg")
    env.pop("PYTHONHOME", None)
    name = args.file
    readme = (ROOT / name).read_text(encoding="utf-8")
    todo = blocks(readme, name)
    excerpts = expected_outputs(readme, name)
    tmp = Path(tempfile.mkdtemp(prefix="phoid-readme-"))
    work = tmp / "phoid"
    work.mkdir()
    status = 0
    try:
        copy_checkout(work, venv)
        t_all = time.perf_counter()
        for n, (line, kind, code, skip) in enumerate(todo, start=1):
            head = f"block {n}/{len(todo)} ({name}:{line}, {kind})"
            if skip is not None:
                print(f"{head}: skipped: {skip}", flush=True)
                continue
            if kind == "sh":
                cmd = ["bash", "-e", "-o", "pipefail", "-c", code]
            else:
                script = tmp / f"block{n}.py"
                script.write_text(code, encoding="utf-8")
                cmd = [str(py), str(script)]
            t0 = time.perf_counter()
            try:
                r = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True,
                                   timeout=args.timeout, stdin=subprocess.DEVNULL)
                rc, out, err = r.returncode, r.stdout, r.stderr
            except subprocess.TimeoutExpired as e:
                rc = f"timeout after {args.timeout:g} s"
                out = (e.stdout or b"").decode(errors="replace") if isinstance(
                    e.stdout, bytes) else (e.stdout or "")
                err = (e.stderr or b"").decode(errors="replace") if isinstance(
                    e.stderr, bytes) else (e.stderr or "")
            dt = time.perf_counter() - t0
            missing = missing_lines(excerpts.get(line, []), out, err) if rc == 0 else []
            if missing:
                print(f"{head}: its output lacks these lines of the excerpt after it:\n"
                      + "\n".join(missing) + f"\n--- stdout (tail) ---\n{tail(out)}"
                      f"\n--- stderr (tail) ---\n{tail(err)}", file=sys.stderr, flush=True)
                status = 1
                break
            if rc != 0:
                print(f"{head}: FAILED ({rc}) after {dt:.1f} s\n--- block ---\n{code}"
                      f"--- stdout (tail) ---\n{tail(out)}\n--- stderr (tail) ---\n{tail(err)}",
                      file=sys.stderr, flush=True)
                status = 1
                break
            print(f"{head}: ok ({dt:.1f} s)", flush=True)
        if status == 0:
            left = subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"],
                                  cwd=work, check=True, capture_output=True,
                                  text=True).stdout
            if left.strip():
                print("readme-check: the README's commands left files that are not git-ignored:\n"
                      + left, file=sys.stderr)
                status = 1
            else:
                print(f"readme-check: all blocks ran ({time.perf_counter() - t_all:.0f} s); "
                      "everything they created is git-ignored")
    finally:
        if args.keep:
            print(f"readme-check: the copy is kept in {work}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    return status


if __name__ == "__main__":
    sys.exit(main())
