"""Property-based test (hypothesis) of the command line's output options over random layouts
of the output folder: existing files, links leading in and out, dangling links, folders in the
way, subfolders, nested folders still to be created (issue 15, part 2, item 6).

For `simulate`, `simulate --schedule` (files in a subfolder), `design --out` and `paper --out`,
with or without --overwrite, the properties are:

* the exit status is 0 or 2, never 1 (no internal error), and exactly the one the rules of
  phoid._output predict: 0 when every target is absent, or a regular file and --overwrite is
  given, and no subfolder leads out; 2 otherwise;
* an error is one line on standard error;
* nothing outside the output folder is written, changed or created; a refusal changes nothing
  inside it either; other files in it are never touched; no temporary file is left behind.

Derandomized (the same examples every run); about 30 s in all.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from treesnap import snapshot
from typer.testing import CliRunner

from phoid.cli import app

runner = CliRunner()

# file kinds a target can have before the command runs
KINDS = ("absent", "file", "link-out-file", "link-out-missing", "link-out-dir", "link-inside",
         "dir")
# kinds of the subfolder `sub` the schedule's runs are written into
# drawn: absent and existing files twice as often, so that runs that may write are common
# (with these settings about a quarter of the examples exit 0)
DRAWN_KINDS = ("absent", "file") * 2 + KINDS
SUB_KINDS = ("absent", "dir", "link-inside-dir", "link-out-dir", "link-out-missing", "file")
FOLDERS = ("existing", "existing", "absent-nested", "dangling")

_SCHEDULE = """format = "phoid/1"
method = "pho"

[loop]
delay = 0.1
""" + "".join(f"""
[[run]]
file = "sub/run0{i}.csv"
P = {i}.0
D = 0.{5 + i}
""" for i in (1, 2))


@dataclass(frozen=True)
class Spec:
    """A command that writes into a folder: argv builder and the files it writes there."""

    argv: tuple[str, ...]  # OUT stands for the output folder, SCHEDULE for the schedule file
    targets: tuple[str, ...]
    max_examples: int


SPECS = {
    "simulate": Spec(("simulate", "OUT", "--P", "1,2", "--D", "0.6,0.9", "--duration", "1",
                      "--fs", "100", "--seed", "1"), ("run01.csv.gz", "run02.csv.gz",
                                                      "experiment.toml"), 25),
    "simulate --schedule": Spec(("simulate", "OUT", "--schedule", "SCHEDULE", "--duration", "1",
                                 "--fs", "100"),
                                ("sub/run01.csv", "sub/run02.csv", "experiment.toml"), 25),
    # README's overdamped plant: a design that succeeds with 3 runs, 1 s at 500 Hz
    "design --out": Spec(("design", "--m", "0.5", "--c", "40", "--k", "20", "--delay", "0.005",
                          "--runs", "3", "--duration", "1", "--fs", "500", "--out", "OUT"),
                         ("experiment.toml",), 12),
    # the slowest command (about 3 s when it may write): few examples
    "paper --out": Spec(("paper", "--duration", "3", "--fs", "100", "--out", "OUT"),
                        ("figure1a.png", "figure1b.png"), 6),
}

VICTIM = b"a file outside the output folder\n"
NOTES = b"the user's notes, never touched\n"


def _place(path: Path, kind: str, out: Path, outside: Path, n: int) -> None:
    """Put an entry of the given kind at path."""
    if kind == "file":
        path.write_bytes(b"an existing file\n")
    elif kind == "link-out-file":
        path.symlink_to(outside / "victim.txt")
    elif kind == "link-out-missing":
        path.symlink_to(outside / f"missing-{n}")
    elif kind == "link-out-dir":
        path.symlink_to(outside / "dir")
    elif kind == "link-inside":
        path.symlink_to(out / "notes.txt")
    elif kind == "link-inside-dir":
        (out / "real").mkdir()
        path.symlink_to(out / "real")
    elif kind == "dir":
        path.mkdir()


def _build(base: Path, spec: Spec, folder: str, sub: str, kinds: list[str],
           overwrite: bool) -> tuple[Path, int]:
    """Lay out base/outside and the output folder; return the folder and the predicted exit."""
    outside = base / "outside"
    (outside / "dir").mkdir(parents=True)
    (outside / "victim.txt").write_bytes(VICTIM)
    (base / "schedule.toml").write_text(_SCHEDULE, encoding="utf-8")
    if folder == "absent-nested":
        return base / "o" / "a" / "b", 0  # created with its parents
    out = base / "out"
    if folder == "dangling":
        out.symlink_to(outside / "missing-folder")
        return out, 2
    out.mkdir()
    (out / "notes.txt").write_bytes(NOTES)
    ok = True
    has_sub = any("/" in t for t in spec.targets)
    if has_sub:
        _place(out / "sub", sub, out, outside, 99)
        ok = sub in ("absent", "dir", "link-inside-dir")
    for n, (target, kind) in enumerate(zip(spec.targets, kinds, strict=False)):
        if "/" in target and sub not in ("dir", "link-inside-dir"):
            continue  # no folder to put it in
        _place(out / target, kind, out, outside, n)
        ok &= kind == "absent" or (kind == "file" and overwrite)
    return out, 0 if ok else 2


def _check(name: str, tmp_root: Path, folder: str, sub: str, kinds: list[str],
           overwrite: bool) -> None:
    spec = SPECS[name]
    base = Path(tempfile.mkdtemp(dir=tmp_root))
    out, expected = _build(base, spec, folder, sub, kinds, overwrite)
    before = snapshot(base)
    argv = [str(out) if a == "OUT" else str(base / "schedule.toml") if a == "SCHEDULE" else a
            for a in spec.argv] + (["--overwrite"] if overwrite else [])
    r = runner.invoke(app, argv)
    assert r.exit_code in (0, 2), (r.exit_code, r.output)  # never 1: no internal error
    assert r.exit_code == expected, (folder, sub, kinds, overwrite, r.output)
    after = snapshot(base)
    if r.exit_code == 2:
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("phoid: error:"), r.stderr
        assert after == before  # a refusal writes nothing anywhere
    else:
        inside = str(out.relative_to(base))
        changed = {k for k in before.keys() | after.keys() if before.get(k) != after.get(k)}
        assert all(k == inside or k.startswith(inside + os.sep) or k in ("o", "o/a")
                   for k in changed), changed  # nothing outside the output folder
        if folder == "existing":
            assert (out / "notes.txt").read_bytes() == NOTES
        for target in spec.targets:
            assert (out / target).is_file() and not (out / target).is_symlink()
    assert (base / "outside" / "victim.txt").read_bytes() == VICTIM
    assert sorted(p.name for p in (base / "outside").iterdir()) == ["dir", "victim.txt"]
    assert not list((base / "outside" / "dir").iterdir())
    assert not [p for p in base.rglob("*") if p.name.endswith(".tmp")]


@pytest.mark.parametrize("name", list(SPECS))
def test_output_options_never_write_outside(name, tmp_path_factory):
    spec = SPECS[name]
    tmp_root = tmp_path_factory.mktemp("layouts")

    @settings(max_examples=spec.max_examples, derandomize=True, database=None, deadline=None,
              suppress_health_check=[HealthCheck.too_slow])
    @given(folder=st.sampled_from(FOLDERS), sub=st.sampled_from(SUB_KINDS),
           kinds=st.lists(st.sampled_from(DRAWN_KINDS), min_size=len(spec.targets),
                          max_size=len(spec.targets)),
           overwrite=st.booleans())
    def prop(folder, sub, kinds, overwrite):
        _check(name, tmp_root, folder, sub, kinds, overwrite)

    prop()
