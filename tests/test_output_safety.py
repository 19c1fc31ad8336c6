"""Everything phoid writes stays in the output folder, is written atomically, and replaces an
existing file only with --overwrite (issue 15, part 2, item 6; rules in phoid._output).

Table-driven through the real command line: for each command that writes, a symbolic link in the
output folder pointing outside (to an existing file and to nothing), a linked subfolder, a FIFO,
a hard link and a user's file in the way.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest
from treesnap import snapshot
from typer.testing import CliRunner

from phoid import OutputError, read_experiment, run_from_arrays, write_experiment
from phoid._output import OutputFolder
from phoid.cli import app
from phoid.errors import ExperimentError

runner = CliRunner()

# small but valid settings, so that a command that is allowed to write runs in about a second
_SIM = ["--P", "1,2", "--D", "0.6,0.9", "--duration", "1", "--fs", "100", "--seed", "1"]
# README's overdamped plant: a design that succeeds with 3 runs on a 1 s record at 500 Hz
_DESIGN = ["design", "--m", "0.5", "--c", "40", "--k", "20", "--delay", "0.005", "--runs", "3",
           "--duration", "1", "--fs", "500"]
_PAPER = ["paper", "--duration", "3", "--fs", "100"]


@dataclass(frozen=True)
class Command:
    """A command that writes: its argv for an output folder, and the files it writes there."""

    argv: Callable[[Path, Path], list[str]]  # (output folder, a recorded set) -> argv
    targets: tuple[str, ...]


COMMANDS = {
    "simulate": Command(lambda out, s: ["simulate", str(out), *_SIM],
                        ("run01.csv.gz", "experiment.toml")),
    "design --out": Command(lambda out, s: [*_DESIGN, "--out", str(out)], ("experiment.toml",)),
    "design --plot": Command(lambda out, s: [*_DESIGN, "--plot", str(out / "design.png")],
                             ("design.png",)),
    "paper --out": Command(lambda out, s: [*_PAPER, "--out", str(out)],
                           ("figure1a.png", "figure1b.png")),
    "identify --plots": Command(lambda out, s: ["identify", str(s), "--plots", str(out)],
                                ("run01.png", "lines.png", "mk-ellipse.png")),
}
CASES = [(name, target) for name, cmd in COMMANDS.items() for target in cmd.targets]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """A small simulated set for `identify --plots` (3 runs, 2 s at 200 Hz, noiseless)."""
    out = tmp_path_factory.mktemp("recorded") / "set"
    r = runner.invoke(app, ["simulate", str(out), "--P", "1,2,3", "--D", "0.6,0.9,1.2",
                            "--duration", "2", "--fs", "200", "--seed", "1"])
    assert r.exit_code == 0, r.output
    return out


def refused(result, *needles: str) -> str:
    """Exit status 2 and exactly one 'phoid: error:' line on stderr naming the needles."""
    assert result.exit_code == 2, (result.exit_code, result.output)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("phoid: error:"), result.stderr
    assert "Traceback" not in result.output
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


def no_temporaries(root: Path) -> None:
    """No temporary file of an atomic write is left anywhere under root."""
    left = [p for p in root.rglob("*") if p.name.endswith(".tmp")]
    assert not left, left


def _layout(tmp_path: Path) -> tuple[Path, Path, Path]:
    """tmp/out (the output folder, existing) and tmp/outside with a victim file."""
    out = tmp_path / "out"
    out.mkdir()
    outside = tmp_path / "outside"
    outside.mkdir()
    victim = outside / "victim.txt"
    victim.write_bytes(b"a file outside the output folder\n")
    return out, outside, victim


@pytest.mark.parametrize("overwrite", [False, True], ids=["plain", "overwrite"])
@pytest.mark.parametrize("dangling", [False, True], ids=["to-file", "dangling"])
@pytest.mark.parametrize(("command", "target"), CASES)
def test_link_in_the_folder_is_refused(tmp_path, recorded, command, target, dangling,
                                       overwrite):
    out, outside, victim = _layout(tmp_path)
    pointee = outside / "created-through-the-link" if dangling else victim
    (out / target).symlink_to(pointee)
    before = snapshot(tmp_path)
    argv = COMMANDS[command].argv(out, recorded) + (["--overwrite"] if overwrite else [])
    refused(runner.invoke(app, argv), str(out / target), "symbolic link")
    assert snapshot(tmp_path) == before  # nothing outside (or inside) written or created
    assert not (outside / "created-through-the-link").exists()
    no_temporaries(tmp_path)


@pytest.mark.parametrize("command", list(COMMANDS))
def test_output_folder_that_is_a_dangling_link_is_refused(tmp_path, recorded, command):
    out, outside, _ = _layout(tmp_path)
    out.rmdir()
    out.symlink_to(outside / "missing")
    before = snapshot(tmp_path)
    refused(runner.invoke(app, COMMANDS[command].argv(out, recorded)), str(out),
            "symbolic link to nothing")
    assert snapshot(tmp_path) == before and not (outside / "missing").exists()


@pytest.mark.parametrize("command", list(COMMANDS))
def test_user_file_is_replaced_only_with_overwrite(tmp_path, recorded, command):
    out, _, victim = _layout(tmp_path)
    cmd = COMMANDS[command]
    user = out / cmd.targets[0]
    user.write_bytes(b"the user's own file\n")
    # the last target is a hard link to a file outside: replaced as a name, the file untouched
    hard = out / cmd.targets[-1]
    if hard != user:
        os.link(victim, hard)
    before = snapshot(tmp_path)
    line = refused(runner.invoke(app, cmd.argv(out, recorded)), str(user), "exists already",
                   "pass --overwrite")
    assert "overwrite=True" not in line  # the CLI's flag, not the Python keyword
    assert snapshot(tmp_path) == before  # checked before anything was written
    r = runner.invoke(app, [*cmd.argv(out, recorded), "--overwrite"])
    assert r.exit_code == 0, r.output
    for name in cmd.targets:
        data = (out / name).read_bytes()
        assert not (out / name).is_symlink() and data != b"the user's own file\n"
        if name.endswith(".png"):
            assert data.startswith(b"\x89PNG\r\n\x1a\n")
    assert victim.read_bytes() == b"a file outside the output folder\n"
    if hard != user:
        assert not os.path.samefile(hard, victim)  # the name now holds a new file
    no_temporaries(tmp_path)


_SCHEDULE = """format = "phoid/1"
method = "pho"

[loop]
delay = 0.1

[[run]]
file = "sub/run01.csv"
P = 1.0
D = 0.6

[[run]]
file = "sub/run02.csv"
P = 2.0
D = 0.9
"""


@pytest.mark.parametrize("overwrite", [False, True], ids=["plain", "overwrite"])
@pytest.mark.parametrize("link", ["to-folder", "dangling", "file-in-the-way"])
def test_schedule_does_not_write_through_a_linked_subfolder(tmp_path, link, overwrite):
    out, outside, _ = _layout(tmp_path)
    schedule = tmp_path / "schedule.toml"
    schedule.write_text(_SCHEDULE, encoding="utf-8")
    if link == "to-folder":
        (out / "sub").symlink_to(outside)
        words = ("leading outside the output folder",)
    elif link == "dangling":
        (out / "sub").symlink_to(outside / "made-through-the-link")
        words = ("leading outside the output folder",)
    else:
        (out / "sub").write_text("a file, not a folder\n")
        words = ("not a folder",)
    before = snapshot(tmp_path)
    argv = ["simulate", str(out), "--schedule", str(schedule), "--duration", "1", "--fs", "100"]
    refused(runner.invoke(app, argv + (["--overwrite"] if overwrite else [])),
            str(out / "sub"), *words)
    assert snapshot(tmp_path) == before
    assert not (outside / "made-through-the-link").exists()


def test_schedule_subfolders_inside_are_created_and_links_inside_followed(tmp_path):
    """Ordinary layouts work as before: subfolders are created; a link that stays inside the
    folder (sub -> real) is no way out."""
    out, outside, _ = _layout(tmp_path)
    schedule = tmp_path / "schedule.toml"
    schedule.write_text(_SCHEDULE, encoding="utf-8")
    argv = ["simulate", str(out / "new" / "set"), "--schedule", str(schedule), "--duration",
            "1", "--fs", "100"]
    r = runner.invoke(app, argv)
    assert r.exit_code == 0, r.output
    assert [run.file for run in read_experiment(out / "new" / "set").runs] == \
        ["sub/run01.csv", "sub/run02.csv"]
    (out / "real").mkdir()
    (out / "sub").symlink_to(out / "real")
    r = runner.invoke(app, ["simulate", str(out), "--schedule", str(schedule), "--duration",
                            "1", "--fs", "100"])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (out / "real").iterdir()) == ["run01.csv", "run02.csv"]
    assert list(outside.iterdir()) == [outside / "victim.txt"]


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_fifo_in_the_way_is_refused_without_blocking(tmp_path):
    out, _, _ = _layout(tmp_path)
    os.mkfifo(out / "experiment.toml")
    refused(runner.invoke(app, ["simulate", str(out), *_SIM, "--overwrite"]),
            str(out / "experiment.toml"), "not a regular file")


def test_folder_in_the_way_is_refused(tmp_path):
    out, _, _ = _layout(tmp_path)
    (out / "run01.csv.gz").mkdir()
    refused(runner.invoke(app, ["simulate", str(out), *_SIM, "--overwrite"]),
            str(out / "run01.csv.gz"), "is a folder")


# ------------------------------------------------------------------------------------------
# the Python API: same rules, its own wording, atomic writes


def test_python_api_says_overwrite_true(tmp_path):
    run = run_from_arrays([0.0, 1.0], [0.0, 1.0], P=1.0, D=1.0)
    write_experiment(tmp_path / "s", [run])
    # a CLI call in between must not leave its wording behind
    refused(runner.invoke(app, ["simulate", str(tmp_path / "s"), *_SIM]), "pass --overwrite")
    with pytest.raises(ExperimentError, match=r"exists already \(pass overwrite=True"):
        write_experiment(tmp_path / "s", [run])
    (tmp_path / "t").mkdir()
    (tmp_path / "t" / "run01.csv.gz").symlink_to(tmp_path / "elsewhere")
    with pytest.raises(ExperimentError, match="symbolic link"):
        write_experiment(tmp_path / "t", [run], overwrite=True)
    assert not (tmp_path / "elsewhere").exists()


def test_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    out = OutputFolder(tmp_path, overwrite=True)
    (tmp_path / "a.txt").write_bytes(b"old\n")

    def half_then_fail(fh):
        fh.write(b"half of the new cont")
        raise RuntimeError("the renderer failed midway")

    with pytest.raises(RuntimeError, match="midway"):
        out.write("a.txt", half_then_fail)
    assert (tmp_path / "a.txt").read_bytes() == b"old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]
    with pytest.raises(RuntimeError):
        out.write("new/b.txt", half_then_fail)
    assert not (tmp_path / "new" / "b.txt").exists()
    no_temporaries(tmp_path)
    assert out.write("a.txt", b"new\n") == tmp_path / "a.txt"
    assert (tmp_path / "a.txt").read_bytes() == b"new\n"


@pytest.mark.parametrize("name", ["../x.txt", "/abs.txt", "a/../../x.txt", ""])
def test_names_outside_the_folder_are_refused(tmp_path, name):
    with pytest.raises(OutputError, match="relative path inside the output folder"):
        OutputFolder(tmp_path / "o").check([name])
    assert not (tmp_path / "o").exists()


def test_output_folder_named_through_a_link_is_the_users_choice(tmp_path):
    """The folder the user names may itself be a link to a folder: only links *inside* it are
    refused."""
    real = tmp_path / "real"
    real.mkdir()
    (tmp_path / "named").symlink_to(real)
    r = runner.invoke(app, ["simulate", str(tmp_path / "named"), *_SIM])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in real.iterdir()) == ["experiment.toml", "run01.csv.gz",
                                                       "run02.csv.gz"]


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0,
                    reason="needs a user whom file permissions bind (not root)")
def test_unwritable_folder_is_one_line_naming_the_file(tmp_path):
    out = tmp_path / "ro"
    out.mkdir()
    out.chmod(0o555)
    try:
        refused(runner.invoke(app, ["simulate", str(out), *_SIM]), str(out / "run01.csv.gz"),
                "cannot be written")
        assert not list(out.iterdir())
    finally:
        out.chmod(0o755)
