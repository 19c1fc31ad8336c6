"""What the set-up installs: `make demo` phoid alone, `make test` the test extras (issue 30).

* ``phoid paper`` (what ``make demo`` runs) and ``phoid --help`` work with only phoid's own
  dependencies: they run in a subprocess in which every installed module outside the closure
  of pyproject.toml's ``[project] dependencies`` cannot be imported, as in the venv
  ``make demo`` makes (the extras and whatever else this environment holds are blocked).
* The Makefile's stamps (``make -n`` in a copy of the Makefile and pyproject.toml): a fresh
  ``make demo`` installs phoid without extras, ``make test`` with the test extras, ``make
  bench`` with the test and bench extras; once a wider install is done, ``make demo`` installs
  nothing (it cannot downgrade what ``make test`` installed), and after ``make demo``,
  ``make test`` still installs the test extras.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# In the subprocess: the modules of every installed distribution outside the closure of
# phoid's own dependencies (markers evaluated, extras of a requirement followed) are blocked.
BLOCK_EXTRAS = textwrap.dedent(
    """
    import importlib.abc, importlib.metadata as md, re, sys, tomllib
    from packaging.requirements import Requirement

    def canon(name):
        return re.sub(r"[-_.]+", "-", name).lower()

    core, todo = set(), [("phoid", frozenset())]
    deps = tomllib.load(open(sys.argv[1], "rb"))["project"]["dependencies"]
    todo += [(Requirement(r).name, frozenset(Requirement(r).extras)) for r in deps]
    seen = set()
    while todo:
        name, extras = todo.pop()
        if (canon(name), extras) in seen:
            continue
        seen.add((canon(name), extras))
        core.add(canon(name))
        try:
            requires = md.distribution(name).requires or []
        except md.PackageNotFoundError:
            continue
        for r in map(Requirement, requires):
            envs = [{"extra": e} for e in extras] or [{"extra": ""}]
            if r.marker is None or any(r.marker.evaluate(env) for env in envs):
                todo.append((r.name, frozenset(r.extras)))
    blocked = {mod for mod, dists in md.packages_distributions().items()
               if not any(canon(d) in core for d in dists)}
    blocked -= set(sys.stdlib_module_names)
    assert "pytest" in blocked, sorted(blocked)  # the test extras are installed here: blocked

    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, fullname, path=None, target=None):
            if fullname.partition(".")[0] in blocked:
                raise ModuleNotFoundError(f"blocked: {fullname} is not a core dependency",
                                          name=fullname)
            return None

    sys.meta_path.insert(0, Block())
    sys.argv = ["phoid", *sys.argv[2:]]
    from phoid.cli import main
    main()
    """
)


def _run_core_only(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.run(
        [sys.executable, "-c", BLOCK_EXTRAS, str(ROOT / "pyproject.toml"), *args],
        cwd=cwd, env=env, capture_output=True, text=True, timeout=120,
        stdin=subprocess.DEVNULL)


def test_paper_needs_no_extra(tmp_path: Path) -> None:
    """`phoid paper` prints Table 1 and writes Figure 1 with phoid's own dependencies alone."""
    r = _run_core_only("paper", "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "Table 1" in r.stdout
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "figure1a.png", "figure1b.png"]  # the two panels the command says it writes


def test_help_needs_no_extra(tmp_path: Path) -> None:
    """The CLI itself (every command's registration and help) imports no extra."""
    r = _run_core_only("--help", cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "paper" in r.stdout


# --- the Makefile's stamps ---------------------------------------------------------------------

MAKE = shutil.which("make")
needs_make = pytest.mark.skipif(MAKE is None, reason="no `make` on the PATH")


def _checkout(tmp_path: Path) -> Path:
    """A folder with the Makefile and pyproject.toml, the latter an hour old."""
    d = tmp_path / "checkout"
    d.mkdir()
    for name in ("Makefile", "pyproject.toml"):
        shutil.copy2(ROOT / name, d / name)
    old = time.time() - 3600
    os.utime(d / "pyproject.toml", (old, old))
    return d


def _stamp(d: Path, *names: str) -> None:
    (d / ".venv").mkdir(exist_ok=True)
    for name in names:
        (d / ".venv" / name).touch()


def _plan(d: Path, target: str) -> list[str]:
    """The pip install lines `make -n TARGET` would run."""
    r = subprocess.run([MAKE or "make", "-n", "-C", str(d), target], capture_output=True,
                       text=True, timeout=60, stdin=subprocess.DEVNULL)
    assert r.returncode == 0, r.stderr
    return [line for line in r.stdout.splitlines()
            if "pip install" in line and "--upgrade pip" not in line]


@needs_make
def test_fresh_demo_installs_phoid_alone_and_test_the_test_extras(tmp_path: Path) -> None:
    d = _checkout(tmp_path)
    (demo,) = _plan(d, "demo")
    assert demo.endswith("-e '.'"), demo
    (test,) = _plan(d, "test")
    assert test.endswith("-e '.[test]'"), test
    (bench,) = _plan(d, "bench")
    assert bench.endswith("-e '.[test,bench]'"), bench
    for target in ("lint", "readme", "mcu"):  # these need ruff, pytest or the README's extras
        assert [p.rsplit(" ", 1)[-1] for p in _plan(d, target)] == ["'.[test]'"], target


@needs_make
def test_stamps_after_demo_and_after_test(tmp_path: Path) -> None:
    d = _checkout(tmp_path)
    _stamp(d, ".installed")  # after `make demo`
    assert _plan(d, "demo") == []
    (test,) = _plan(d, "test")  # the test extras are still to install
    assert test.endswith("-e '.[test]'"), test
    _stamp(d, ".installed", ".installed-test")  # after `make test`
    assert _plan(d, "demo") == []  # nothing reinstalled, nothing downgraded
    assert _plan(d, "test") == []
    os.utime(d / "pyproject.toml")  # pyproject.toml edited: each target installs again
    assert len(_plan(d, "demo")) == 1
    assert len(_plan(d, "test")) == 1


@needs_make
def test_a_wider_install_satisfies_the_narrower_targets(tmp_path: Path) -> None:
    """`make test` touches make demo's stamp, `make bench` both: the recipes say so."""
    d = _checkout(tmp_path)
    r = subprocess.run([MAKE or "make", "-n", "-C", str(d), "bench"], capture_output=True,
                       text=True, timeout=60, stdin=subprocess.DEVNULL)
    touch = next(line for line in r.stdout.splitlines() if line.startswith("touch"))
    assert set(touch.split()[1:]) == {".venv/.installed", ".venv/.installed-test",
                                      ".venv/.installed-bench"}
    r = subprocess.run([MAKE or "make", "-n", "-C", str(d), "test"], capture_output=True,
                       text=True, timeout=60, stdin=subprocess.DEVNULL)
    touch = next(line for line in r.stdout.splitlines() if line.startswith("touch"))
    assert set(touch.split()[1:]) == {".venv/.installed", ".venv/.installed-test"}
