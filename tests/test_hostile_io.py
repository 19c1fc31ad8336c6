"""Hostile input to the readers, through the real command line (issue 15, Part 2, items 2, 3,
4, 7 and 8 on the reading side).

Each case runs ``python -m phoid.cli …`` in a subprocess, as a user would, under an address-space
cap (RLIMIT_AS, where the platform has it) and a wall-clock timeout, and expects what
DEVELOPERS.md promises for bad input: exit status 2 (never 1: that is phoid's own fault), exactly
one line on standard error, printable, naming the file, the run and the key or limit at fault;
never a traceback. Expected words come from the reader's documented limits
(phoid.io.MAX_*,
docs/format-extensions.md "Limits") and from the input each case builds, not from a run of
the code.
"""

from __future__ import annotations

import gzip
import os
import resource
import subprocess
import sys
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import phoid.io as pio
import phoid.io.limits as io_limits
from phoid.errors import ExperimentError

# Address-space cap of each CLI run: the interpreter with numpy, scipy and matplotlib needs
# about 1.0 GB of address space here (measured: identify of a 3-run set passes at 1.2e6 KB);
# 2 GiB leaves room for that while a reader that held the 1.9 GB of the blank-lines bomb
# (the case) or read /dev/zero without bound would fail (MemoryError: exit 1).
AS_CAP = 2 * 2**30
TIMEOUT = 60  # s: a FIFO that blocks the reader would hang forever; a good run takes < 10 s


def _limit() -> None:  # pragma: no cover - runs in the child
    try:
        resource.setrlimit(resource.RLIMIT_AS, (AS_CAP, AS_CAP))
    except (ValueError, OSError):  # platforms without RLIMIT_AS (macOS): the timeout still holds
        pass


def phoid(*args: str | Path, cwd: Path) -> subprocess.CompletedProcess[bytes]:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", PYTHONUTF8="1")
    env.pop("PHOID_DEBUG", None)
    return subprocess.run([sys.executable, "-m", "phoid.cli", *map(str, args)], cwd=cwd,
                          env=env, capture_output=True, timeout=TIMEOUT, preexec_fn=_limit,
                          check=False)


def one_line_error(proc: subprocess.CompletedProcess[bytes], *words: str) -> str:
    """Exit 2, one printable line on stderr holding every word; returns the line."""
    err = proc.stderr.decode("utf-8", "replace")
    assert proc.returncode == 2, (proc.returncode, err)
    assert err.endswith("\n") and err.count("\n") == 1, err
    line = err[:-1]
    assert line.isprintable(), repr(line)
    assert line.startswith("phoid: error: "), line
    assert "Traceback" not in line and "internal error" not in line, line
    for w in words:
        assert w in line, (w, line)
    return line


def csv_bytes(amplitude: float, n: int = 400) -> bytes:
    """A valid t,x,u record: a 1 ms sampled decaying cosine (amplitude in m)."""
    t = np.arange(n) * 1e-3
    x = amplitude * np.exp(-2 * t) * np.cos(30 * t)
    return ("t,x,u\n" + "".join(f"{a!r},{b!r},{-0.5 * b!r}\n" for a, b in
                                zip(t.tolist(), x.tolist(), strict=True))).encode()


MANIFEST = """[loop]
delay = 0.01
[[run]]
file = "run01.csv.gz"
P = 1.0
D = 0.5
[[run]]
file = "run02.csv.gz"
P = 2.0
D = 0.5
"""


def make_set(root: Path, manifest: str | bytes = MANIFEST, **files: bytes) -> Path:
    """A set folder ``root/set``: the manifest, and run01/run02 (distinct, gzipped) unless
    ``files`` (names with '.' written as '_') replaces them."""
    folder = root / "set"
    folder.mkdir()
    data = {"run01.csv.gz": gzip.compress(csv_bytes(0.01), mtime=0),
            "run02.csv.gz": gzip.compress(csv_bytes(0.02), mtime=0)}
    data.update({k.replace("_csv", ".csv").replace("_gz", ".gz"): v for k, v in files.items()})
    for name, content in data.items():
        (folder / name).write_bytes(content)
    m = manifest.encode() if isinstance(manifest, str) else manifest
    (folder / "experiment.toml").write_bytes(m)
    return folder


def test_a_good_set_still_reads(tmp_path: Path) -> None:
    """The control: the fixtures below are hostile only where a case makes them so."""
    folder = make_set(tmp_path)
    exp = pio.read_experiment(folder)
    assert [r.n for r in exp.runs] == [400, 400]


# --------------------------------------------------------------------------------------------
# item 2: nesting (tomllib recurses on nested arrays and inline tables: RecursionError)
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("text", [
    "a = " + "[" * 5000 + "]" * 5000 + "\n",               # RecursionError in tomllib
    "a = " + "{b = " * 600 + "1" + "}" * 600 + "\n",        # RecursionError in tomllib
    "[" + ".".join(["a"] * 5000) + "]\n",                   # parses; 5000 levels of tables
    "a = " + "[" * (pio.MAX_NESTING + 1) + "]" * (pio.MAX_NESTING + 1) + "\n",  # just over
], ids=["arrays", "inline-tables", "dotted-header", "just-over"])
def test_deep_nesting(tmp_path: Path, text: str) -> None:
    folder = make_set(tmp_path, text + MANIFEST)
    one_line_error(phoid("identify", folder, cwd=tmp_path), "set/experiment.toml",
                   f"more than {pio.MAX_NESTING} levels", "MAX_NESTING")


def test_nesting_at_the_limit_reads(tmp_path: Path) -> None:
    """MAX_NESTING levels (the document itself is level 1) are accepted and kept."""
    depth = pio.MAX_NESTING - 1
    folder = make_set(tmp_path, "a = " + "[" * depth + "]" * depth + "\n" + MANIFEST)
    assert "a" in pio.read_experiment(folder).extra


# --------------------------------------------------------------------------------------------
# item 3: named pipes and devices (identify, design --check, simulate --schedule hung)
# --------------------------------------------------------------------------------------------
needs_fifo = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")


@needs_fifo
@pytest.mark.parametrize("command", [("identify",), ("design", "--check"),
                                     ("simulate", "OUT", "--schedule")])
def test_fifo_manifest(tmp_path: Path, command: tuple[str, ...]) -> None:
    folder = tmp_path / "set"
    folder.mkdir()
    os.mkfifo(folder / "experiment.toml")
    args = [str(tmp_path / a) if a == "OUT" else a for a in command]
    one_line_error(phoid(*args, folder, cwd=tmp_path), "set/experiment.toml",
                   "named pipe", "not a regular file")
    assert not (tmp_path / "OUT").exists()


@needs_fifo
def test_link_to_a_fifo_as_manifest(tmp_path: Path) -> None:
    folder = tmp_path / "set"
    folder.mkdir()
    os.mkfifo(tmp_path / "pipe")
    (folder / "experiment.toml").symlink_to(tmp_path / "pipe")
    one_line_error(phoid("identify", folder / "experiment.toml", cwd=tmp_path),
                   "set/experiment.toml", "named pipe")


@needs_fifo
def test_fifo_data_file(tmp_path: Path) -> None:
    folder = make_set(tmp_path)
    (folder / "run02.csv.gz").unlink()
    os.mkfifo(folder / "run02.csv.gz")
    one_line_error(phoid("identify", folder, cwd=tmp_path),
                   "set/experiment.toml: run 2 (run02.csv.gz)", "named pipe")


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero here")
def test_dev_zero(tmp_path: Path) -> None:
    """`phoid identify /dev/zero` read without bound; a link to it as a data file too."""
    one_line_error(phoid("identify", "/dev/zero", cwd=tmp_path), "/dev/zero",
                   "character device", "not a regular file")
    folder = make_set(tmp_path)
    (folder / "run02.csv.gz").unlink()
    (folder / "run02.csv.gz").symlink_to("/dev/zero")
    # the link resolves outside the folder: refused before its type is even looked at
    one_line_error(phoid("identify", folder, cwd=tmp_path), "run 2 (run02.csv.gz)", "escapes")
    (folder / "run02.csv.gz").unlink()
    os.symlink("/dev/zero", folder / "zero")
    one_line_error(phoid("identify", folder / "zero", cwd=tmp_path), "set/zero",
                   "character device")


# --------------------------------------------------------------------------------------------
# item 4: sizes (a 1.8 MB gzip of blank lines read to 1.9 GB; the caps hold while reading)
# --------------------------------------------------------------------------------------------
def gzip_of(head: bytes, fill: bytes, count: int) -> bytes:
    """gzip of ``head`` + ``fill`` × ``count`` (about; rounded up to 16 MiB of fill).

    Built as gzip members (a gzip file may hold several, read one after the other), one member
    of 16 MiB of fill repeated: cheap to make however large the content."""
    per = 2**24 // len(fill)
    member = gzip.compress(fill * per, compresslevel=9, mtime=0)
    return gzip.compress(head, mtime=0) + member * -(-count // per)


def test_gzip_of_blank_lines(tmp_path: Path) -> None:
    """The issue's case: 1.9e9 blank lines after a valid start. Refused at MAX_LINES (5e7)
    lines, i.e. after decompressing 50 MB, not 1.9 GB (the AS cap would stop the latter)."""
    bomb = gzip_of(b"t,x\n0,0\n1,1\n", b"\n", 1_900_000_000)
    assert len(bomb) < 2 * 2**20  # deflate's ratio limit is ~1032:1: 1.9 GB in a 1.8 MB file
    folder = make_set(tmp_path, run02_csv_gz=bomb)
    one_line_error(phoid("identify", folder, cwd=tmp_path),
                   "set/experiment.toml: run 2 (run02.csv.gz)",
                   f"more than {pio.MAX_LINES:,} lines (blank lines included)", "MAX_LINES")


def test_blank_lines_count_toward_the_line_cap_uncompressed_too(tmp_path: Path) -> None:
    """A blank header line followed by MAX_LINES blank lines (not gzip: the plain path)."""
    folder = make_set(tmp_path, MANIFEST.replace("run02.csv.gz", "run02.csv"),
                      run02_csv=b"\r\n" * (pio.MAX_LINES + 1))
    one_line_error(phoid("identify", folder, cwd=tmp_path), "run 2 (run02.csv)", "MAX_LINES")


def test_line_longer_than_the_cap(tmp_path: Path) -> None:
    """One endless line (a header, then 2 MiB without a line end)."""
    body = b"t,x\n0,1\n" + b"1" * (2 * pio.MAX_LINE_BYTES)
    folder = make_set(tmp_path, run02_csv_gz=gzip.compress(body, mtime=0))
    one_line_error(phoid("identify", folder, cwd=tmp_path), "run 2 (run02.csv.gz)",
                   "line 3 is longer than 1 MiB", "MAX_LINE_BYTES")


def test_manifest_larger_than_the_cap(tmp_path: Path) -> None:
    pad = "# " + "x" * 98 + "\n"
    text = MANIFEST + pad * (pio.MAX_MANIFEST_BYTES // len(pad) + 1)
    folder = make_set(tmp_path, text)
    one_line_error(phoid("identify", folder, cwd=tmp_path), "set/experiment.toml",
                   "larger than 2 MiB", "MAX_MANIFEST_BYTES")


def test_too_many_runs(tmp_path: Path) -> None:
    """MAX_RUNS + 1 [[run]] tables are refused before any data file is looked for."""
    text = "".join(f'[[run]]\nfile = "r{i}.csv"\nP = 1\nD = 1\n'
                   for i in range(pio.MAX_RUNS + 1))
    folder = make_set(tmp_path, text)
    one_line_error(phoid("identify", folder, cwd=tmp_path), "set/experiment.toml",
                   f"{pio.MAX_RUNS + 1:,} [[run]] tables", "MAX_RUNS")


@pytest.mark.parametrize(("limit", "setting", "fill", "words"), [
    # blank lines: a repeated data row would be refused first, at its repeated t
    ("MAX_DATA_BYTES", 3 * 2**20, b" " * 127 + b"\n",
     ("larger than", "after decompression", "MAX_DATA_BYTES")),
    ("MAX_SET_ROWS", 600, b"0.5,1,2" + b" " * 120 + b"\n",
     ("more than 600 data rows in all", "MAX_SET_ROWS")),
])
def test_byte_and_row_caps(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, limit: str,
                           setting: int, fill: bytes, words: tuple[str, ...]) -> None:
    """The caps too large to reach in a test (4 GiB, 2e8 rows) enforced at a lowered value:
    the same code path, the limit read at call time. In-process (a CLI run cannot lower it)."""
    monkeypatch.setattr(io_limits, limit, setting)  # where the reader reads it
    big = gzip_of(csv_bytes(0.02, 2), fill, 40_000)  # 16 MiB of lines of 128 bytes
    folder = make_set(tmp_path, run02_csv_gz=big)
    with pytest.raises(ExperimentError) as info:
        pio.read_experiment(folder)
    msg = str(info.value)
    assert "run 2 (run02.csv.gz)" in msg and all(w in msg for w in words), msg


def test_memory_is_proportional_to_the_rows_kept(tmp_path: Path) -> None:
    """Blank lines cost no memory: a 100 MB file of which 400 rows are data is read in a
    bounded working set (tracemalloc counts numpy's buffers), not in 100 MB or a multiple."""
    import tracemalloc

    filler = gzip_of(csv_bytes(0.02), b" " * 7 + b"\n", 12_500_000)  # 100 MB, 1.3e7 lines
    folder = make_set(tmp_path, run02_csv_gz=filler)
    tracemalloc.start()
    try:
        exp = pio.read_experiment(folder)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert exp.runs[1].n == 400
    # the reader holds one 1 MiB block, its chunk of whole lines and, for a chunk with blank
    # lines, the vectorised structure check's arrays (8-byte line starts, ends and counts per
    # line, bytes-sized masks: ~16 MiB measured for this file); 32 MiB bounds that with a 2x
    # margin and is a third of the 100 MB that a reader holding the file would need
    assert peak < 32 * 2**20, peak


# --------------------------------------------------------------------------------------------
# item 7: the same recording listed twice
# --------------------------------------------------------------------------------------------
def test_hard_link(tmp_path: Path) -> None:
    folder = make_set(tmp_path)
    (folder / "run02.csv.gz").unlink()
    os.link(folder / "run01.csv.gz", folder / "run02.csv.gz")
    one_line_error(phoid("identify", folder, cwd=tmp_path), "run 2 (run02.csv.gz)",
                   "hard link", "run 1 (run01.csv.gz)")


@pytest.mark.parametrize("how", ["copy", "recompressed", "uncompressed"])
def test_byte_identical_copy(tmp_path: Path, how: str) -> None:
    """A copy is caught by the content of the data (decompressed), however it is stored."""
    data = csv_bytes(0.01)
    copy = {"copy": gzip.compress(data, mtime=0),
            "recompressed": gzip.compress(data, compresslevel=1, mtime=7),
            "uncompressed": data}[how]
    name = "run02.csv" if how == "uncompressed" else "run02.csv.gz"
    folder = make_set(tmp_path, MANIFEST.replace("run02.csv.gz", name),
                      **{name.replace(".", "_"): copy})
    one_line_error(phoid("identify", folder, cwd=tmp_path), f"run 2 ({name})",
                   "same content, byte for byte", "run 1 (run01.csv.gz)")


# --------------------------------------------------------------------------------------------
# item 8: what messages quote from the input is escaped and length-capped
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("manifest", "files", "words"), [
    (MANIFEST.replace('"run02.csv.gz"', '"run\\u0000.csv"'), {},
     ("run 2 (run\\x00.csv)", "NUL")),
    (MANIFEST.replace('"run02.csv.gz"', '"\\u001b[2J\\u0007.csv"'), {},
     ("run 2 (\\x1b[2J\\x07.csv)", "data file not found")),
    ('method = "pho\\u0000\\r\\n"\n' + MANIFEST, {}, ("key 'method'", "'pho\\x00\\r\\n'")),
    ('format = "' + "x" * 10**6 + '"\n' + MANIFEST, {}, ("key 'format'", "…")),
    (MANIFEST, {"run02_csv_gz": gzip.compress(b"t,x\x00,u\n0,1,2\n1,2,3\n", mtime=0)},
     ("run 2 (run02.csv.gz)", "missing column 'x'", "'x\\x00'")),
    (MANIFEST, {"run02_csv_gz": gzip.compress(b"t,x\n0,1\n1,\x00\x1b[31m\n", mtime=0)},
     ("run 2 (run02.csv.gz)", "column 'x'", "line 3", "'\\x00\\x1b[31m'")),
    (MANIFEST, {"run02_csv_gz": gzip.compress(b"t,x\n0,1\n1," + b"9" * 500_000 + b"x\n",
                                              mtime=0)},
     ("run 2 (run02.csv.gz)", "column 'x'", "line 3", "…")),
], ids=["nul-in-file", "escape-in-file", "control-in-value", "long-value", "nul-in-header",
        "control-in-cell", "long-cell"])
def test_quoted_input_is_escaped(tmp_path: Path, manifest: str, files: dict[str, bytes],
                                 words: tuple[str, ...]) -> None:
    folder = make_set(tmp_path, manifest, **files)
    proc = phoid("identify", folder, cwd=tmp_path)
    line = one_line_error(proc, "set/experiment.toml", *words)
    assert b"\x00" not in proc.stderr and b"\x1b" not in proc.stderr
    assert len(line) < 1000, len(line)


# --------------------------------------------------------------------------------------------
# the same refusals through the Python API (the CLI relays them; read_schedule shares them)
# --------------------------------------------------------------------------------------------
CASES: list[tuple[str, Callable[[Path], Path], str]] = [
    ("deep", lambda d: make_set(d, "a = " + "[" * 900 + "]" * 900 + "\n"), "MAX_NESTING"),
    ("big", lambda d: make_set(d, "#" * (pio.MAX_MANIFEST_BYTES + 1)), "MAX_MANIFEST_BYTES"),
]


@pytest.mark.parametrize(("name", "build", "word"), CASES, ids=[c[0] for c in CASES])
def test_read_schedule_shares_the_manifest_checks(tmp_path: Path, name: str,
                                                  build: Callable[[Path], Path],
                                                  word: str) -> None:
    from phoid.planning import DesignError, read_schedule

    folder = build(tmp_path)
    with pytest.raises(DesignError, match=word):
        read_schedule(folder)


# --------------------------------------------------------------------------------------------
# gzip details the streaming decompressor handles (found while replacing gzip.GzipFile)
# --------------------------------------------------------------------------------------------
def test_gzip_members_and_a_long_header_name(tmp_path: Path) -> None:
    """Several gzip members are one file (as gzip(1) and Python's gzip read them); a header
    with a 20 MiB file name (FNAME) is skipped in C: gzip.GzipFile read it a byte at a time
    (2.6 s CPU per 5 MiB measured), so 3 s of CPU for the whole read bounds the new path
    (about 0.2 s measured) and fails the old one."""
    import time

    data = csv_bytes(0.02)
    cut = data.index(b"\n", len(data) // 2) + 1
    members = gzip.compress(data[:cut], mtime=0) + gzip.compress(data[cut:], mtime=0)
    folder = make_set(tmp_path, run02_csv_gz=members)
    assert pio.read_experiment(folder).runs[1].n == 400
    deflated = zlib.compressobj(6, zlib.DEFLATED, -15)
    body = deflated.compress(data) + deflated.flush()
    named = (b"\x1f\x8b\x08\x08" + b"\x00" * 6 + b"n" * 20 * 2**20 + b"\x00" + body
             + (zlib.crc32(data)).to_bytes(4, "little") + len(data).to_bytes(4, "little"))
    (folder / "run02.csv.gz").write_bytes(named)
    start = time.process_time()
    exp = pio.read_experiment(folder)
    assert time.process_time() - start < 3.0
    assert exp.runs[1].n == 400
    (folder / "run02.csv.gz").write_bytes(members + b"trailing junk")
    with pytest.raises(ExperimentError, match=r"run 2 \(run02.csv.gz\): the data file is "
                                                  "not a valid gzip file"):
        pio.read_experiment(folder)
