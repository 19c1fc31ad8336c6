"""Hostile edges of the readers, `phoid batch`, `phoid trend` and `phoid design` (a probe's
groups 9-11): messages that named the wrong thing, batch and identify disagreeing on links,
warnings beside one-line errors, a line over the limit and a gzip bomb.

Each test is the regression test of one finding: bad input gives one line naming the file or
the option, and exit status 2 (DEVELOPERS standards).
"""

from __future__ import annotations

import contextlib
import gzip
import io
import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import phoid.io as pio
from phoid.cli import app
from phoid.errors import ExperimentError, PhoidError

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "examples" / "paper-sample"
runner = CliRunner()


def one_line_error(result, *needles: str) -> str:
    """The one stderr line of a CliRunner result that failed with status 2."""
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("phoid: error: "), result.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def phoid_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """The installed command line in a subprocess (main(), as a user runs it); a hang guard of
    120 s, far above the seconds each call takes."""
    code = "import sys; from phoid.cli import main; sys.argv[0] = 'phoid'; main()"
    env = {k: v for k, v in os.environ.items() if k != "PHOID_DEBUG"}
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          cwd=cwd, timeout=120, env=env)


# --- 9: a compressed MATLAB file cut short is damaged, not missing a variable ---------------


TRACKING = """format = "phoid/1"
method = "tracking"
[loop]
delay = 0.001
[[run]]
file = "rec.mat"
P = 1.0
D = 0.1
[run.columns]
t = "t"
x = "qm"
r = "qg"
u = "vir"
"""


def _compressed_mat() -> bytes:
    import scipy.io

    t = np.arange(2000) * 1e-3
    data = {"t": t, "qm": np.sin(t), "qg": np.cos(t), "vir": np.sin(2 * t)}
    buf = io.BytesIO()
    scipy.io.savemat(buf, {k: v.reshape(-1, 1) for k, v in data.items()}, do_compression=True)
    return buf.getvalue()


def _elements(raw: bytes) -> list[tuple[int, int]]:
    """(offset, byte count) of each top-level element of a little-endian MAT v5 file (the
    format: a 128-byte header, then 8-byte tags each giving its element's size)."""
    out, pos = [], 128
    while pos + 8 <= len(raw):
        nbytes = struct.unpack("<I", raw[pos + 4:pos + 8])[0]
        out.append((pos, nbytes))
        pos += 8 + nbytes
    return out


def _last_recompressed(raw: bytes, inner: bytes) -> bytes:
    """The file with its last compressed element (vir, savemat's order) replaced by ``inner``
    compressed, under a tag of the right size: only the stream's content is wrong."""
    import zlib

    pos, _ = _elements(raw)[-1]
    z = zlib.compress(inner)
    return raw[:pos] + struct.pack("<II", 15, len(z)) + z


def _vir(raw: bytes) -> bytes:
    import zlib

    pos, nbytes = _elements(raw)[-1]
    return zlib.decompress(raw[pos + 8:pos + 8 + nbytes])


@pytest.mark.parametrize(("damage", "needles"), [
    # finding: "no variable 'vir' for u; the file has: qg, qm, t"
    ("cut in half", ("cut short (truncated)", "the file is damaged")),
    ("stream cut, tag fixed", ("variable 'vir'", "zlib stream does not end")),
    ("stream longer than its variable", ("variable 'vir'", "more than the")),
    ("stream shorter than its variable", ("variable 'vir'", "fewer than its variable")),
])
def test_a_damaged_compressed_mat_file_is_called_damaged(tmp_path: Path, damage: str,
                                                         needles: tuple[str, ...]) -> None:
    raw = _compressed_mat()
    pos, nbytes = _elements(raw)[-1]
    bad = {
        "cut in half": lambda: raw[:len(raw) // 2],
        "stream cut, tag fixed": lambda: (raw[:pos] + struct.pack("<II", 15, nbytes - 40)
                                          + raw[pos + 8:pos + 8 + nbytes - 40]),
        "stream longer than its variable": lambda: _last_recompressed(raw, _vir(raw) + bytes(64)),
        "stream shorter than its variable": lambda: _last_recompressed(raw, _vir(raw)[:-64]),
    }[damage]()
    (tmp_path / "experiment.toml").write_text(TRACKING)
    (tmp_path / "rec.mat").write_bytes(raw)
    pio.read_experiment(tmp_path)  # the undamaged file reads
    (tmp_path / "rec.mat").write_bytes(bad)
    with pytest.raises(ExperimentError) as info:
        pio.read_experiment(tmp_path)
    msg = str(info.value)
    assert "run 1 (rec.mat)" in msg and "no variable" not in msg, msg
    for needle in needles:
        assert needle in msg, msg


# --- 9: trend on a device or a named pipe says what it is -----------------------------------


def test_trend_on_a_device_or_a_named_pipe_says_what_it_is(tmp_path: Path) -> None:
    # finding: `phoid trend /dev/zero`, or a FIFO: "no such file" (and a FIFO must never be
    # opened for reading: it would block)
    os.mkfifo(tmp_path / "pipe")
    cases = [(tmp_path / "pipe", "is a named pipe (FIFO)")]
    if Path("/dev/zero").exists():
        cases.append((Path("/dev/zero"), "is a character device"))
    for path, words in cases:
        res = phoid_cli("trend", str(path), cwd=tmp_path)
        assert res.returncode == 2, res.stderr
        lines = res.stderr.strip().splitlines()
        assert len(lines) == 1 and str(path) in lines[0] and words in lines[0], res.stderr


# --- 9: each design option's range error names that option ----------------------------------


@pytest.mark.parametrize(("option", "value", "named"), [
    ("--duration", "1e300", "`duration`"),  # finding: it blamed the delay
    ("--duration", "1e-300", "`duration`"),
    ("--fs", "1e300", "`fs`"),  # a RuntimeWarning and "Singular matrix"
    ("--fs", "1e-300", "`fs`"),
    ("--noise", "1e-300", "`noise`"),  # a RuntimeWarning from numpy's det
    ("--amplitude", "1e300", "`amplitude`"),
    ("--delay", "1e-300", "`delay`"),  # a RuntimeWarning, "the loop's roots cannot be ..."
    ("--delay-margin", "1e300", "`delay_margin`"),  # "no spread of feasible runs"
    ("--min-cycles", "1e-300", "`min_cycles`"),  # it blamed the delay
    ("--zeta", "1e-300:0.5", "`zeta`"),  # it blamed the noise floor
])
def test_a_design_option_out_of_range_is_named(option: str, value: str, named: str) -> None:
    args = {"--m": "1", "--c": "0.5", "--k": "10", "--delay": "0.01", "--runs": "3"}
    args[option] = value
    res = runner.invoke(app, ["design", *(f"{k}={v}" for k, v in args.items())])
    one_line_error(res, named)


# --- 9: a scheduler address that answers with garbage ---------------------------------------


@contextlib.contextmanager
def _server(reply: bytes):
    """A TCP port on 127.0.0.1 that sends ``reply`` to each connection: another service
    on the scheduler's port."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    server.settimeout(0.2)
    stop = threading.Event()
    held: list[socket.socket] = []

    def serve() -> None:
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            held.append(conn)
            with contextlib.suppress(OSError):
                conn.sendall(reply)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    finally:
        stop.set()
        thread.join(5)
        for conn in held:
            conn.close()
        server.close()


# a frame count of 1 and one empty frame: framed as distributed frames its messages, but
# no msgpack map (a Dask scheduler's handshake is one)
_FRAMED_NOT_MSGPACK = struct.pack("<QQQ", 16, 1, 0)


@pytest.mark.parametrize("reply", [
    bytes(range(256)) * 16,  # random-looking bytes: 7 EiB declared by the first 8
    b"HTTP/1.0 400 Bad Request\r\n\r\n",
    _FRAMED_NOT_MSGPACK,
], ids=["bytes", "http", "framed-not-msgpack"])
def test_a_scheduler_that_answers_garbage_is_not_a_dask_scheduler(reply: bytes) -> None:
    # finding: a MemoryError allocating 7 EiB (the length distributed read first)
    pytest.importorskip("distributed", reason="the batch extra is not installed")
    from phoid.batch.cluster import cluster_client

    with _server(reply) as address, pytest.raises(PhoidError) as info:
        with cluster_client(address, timeout=5.0):
            pass
    msg = str(info.value)
    assert "answers, but not as a Dask scheduler" in msg and address in msg, msg
    assert "MemoryError" not in msg and "\n" not in msg, msg


# --- 10: batch reads a set exactly as identify does ------------------------------------------


def test_batch_reads_a_linked_manifest_and_data_file_as_identify_does(tmp_path: Path) -> None:
    # finding: experiment.toml a link to another file of the same folder: identify read it,
    # batch wrote an error row "Too many levels of symbolic links"
    pd = pytest.importorskip("pandas", reason="the batch extra is not installed")
    pytest.importorskip("pyarrow", reason="the batch extra is not installed")
    folder = tmp_path / "linked"
    shutil.copytree(SAMPLE, folder)
    (folder / "experiment.toml").rename(folder / "manifest-v2.toml")
    (folder / "experiment.toml").symlink_to("manifest-v2.toml")
    (folder / "data").mkdir()
    (folder / "run02.csv.gz").rename(folder / "data" / "run02.csv.gz")
    (folder / "run02.csv.gz").symlink_to("data/run02.csv.gz")
    ident = runner.invoke(app, ["identify", str(folder), "--json"])
    assert ident.exit_code == 0, ident.output
    import json

    expected = json.loads(ident.stdout)["m"]["value"]
    for given in (folder, folder / "experiment.toml"):  # the folder, or the link itself
        out = tmp_path / f"r-{given.name}.parquet"
        res = runner.invoke(app, ["batch", str(given), "--out", str(out), "--workers", "0"])
        assert res.exit_code == 0, res.output
        row = pd.read_parquet(out).iloc[0]
        assert row["status"] == "ok", row["error"]
        assert row["set"] == str(folder.resolve())
        assert row["m"] == expected  # the same reader, the same code path: equal


def test_batch_and_identify_refuse_a_named_pipe_manifest_alike(tmp_path: Path) -> None:
    pd = pytest.importorskip("pandas", reason="the batch extra is not installed")
    pytest.importorskip("pyarrow", reason="the batch extra is not installed")
    folder = tmp_path / "piped"
    folder.mkdir()
    os.mkfifo(folder / "experiment.toml")
    ident = one_line_error(runner.invoke(app, ["identify", str(folder)]),
                           "the manifest is a named pipe (FIFO)")
    res = runner.invoke(app, ["batch", str(folder), "--out", str(tmp_path / "r.parquet"),
                              "--workers", "0"])
    assert res.exit_code == 0, res.output
    row = pd.read_parquet(tmp_path / "r.parquet").iloc[0]
    assert row["status"] == "error" and ident.endswith(row["error"]), (ident, row["error"])


# --- 11: no Python warning beside a one-line error -------------------------------------------


def _free_set(folder: Path, scale: float) -> Path:
    """A free-decay set whose positions are ``scale`` × a decaying cosine."""
    folder.mkdir()
    t = np.arange(2000) * 1e-3
    x = scale * np.exp(-t) * np.cos(30 * t)
    lines = "".join(f"{a!r},{b!r}\n" for a, b in zip(t.tolist(), x.tolist(), strict=True))
    (folder / "run01.csv").write_text("t,x\n" + lines)
    (folder / "experiment.toml").write_text('method = "free"\n[[run]]\nfile = "run01.csv"\n')
    return folder


def test_units_that_overflow_a_column_are_one_error_naming_it(tmp_path: Path) -> None:
    # finding: "RuntimeWarning: overflow encountered in multiply" beside "column 'F' has a
    # non-finite value"; in-process, where a warning fails the test (filterwarnings=error)
    t = np.arange(3) * 1e-3
    rows = "".join(f"{a!r},0.5,1,1e308\n" for a in t.tolist())
    (tmp_path / "run01.csv").write_text("t,x,u,F\n" + rows)
    (tmp_path / "experiment.toml").write_text(
        'method = "forced"\n[units]\nF = "kN"\n[[run]]\nfile = "run01.csv"\n')
    with pytest.raises(ExperimentError) as info:
        pio.read_experiment(tmp_path)
    assert "run 1 (run01.csv)" in str(info.value) and "'F' overflows" in str(info.value)


def test_the_command_line_prints_no_python_warning_beside_an_error(tmp_path: Path) -> None:
    # findings: numpy RuntimeWarnings (overflow, invalid value) printed beside the one-line
    # error; each case below printed at least one before
    big = _free_set(tmp_path / "big", 1e308)  # the free-decay fit overflows
    units = tmp_path / "units"
    units.mkdir()
    (units / "run01.csv").write_text("t,x,u,F\n0,0.5,1,1e308\n0.001,0.5,1,1e308\n")
    (units / "experiment.toml").write_text(
        'method = "forced"\n[units]\nF = "kN"\n[[run]]\nfile = "run01.csv"\n')
    cases = [("identify", str(big)), ("identify", str(units)),
             ("design", "--m=1", "--c=0.5", "--k=10", "--delay=0.01", "--noise=1e-300")]
    for args in cases:
        res = phoid_cli(*args, cwd=tmp_path)
        assert res.returncode == 2, (args, res.stderr)
        lines = res.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("phoid: error: "), (args, res.stderr)


# --- 11: every line's length is checked; a gzip bomb is refused at once ----------------------


def _two_run_set(folder: Path, run02: bytes, name: str = "run02.csv") -> Path:
    folder.mkdir()
    t = np.arange(400) * 1e-3
    x = 0.01 * np.exp(-2 * t) * np.cos(30 * t)
    rows = "".join(f"{a!r},{b!r}\n" for a, b in zip(t.tolist(), x.tolist(), strict=True))
    (folder / "run01.csv").write_text("t,x\n" + rows)
    (folder / name).write_bytes(run02)
    (folder / "experiment.toml").write_text(
        f'[loop]\ndelay = 0.01\n[[run]]\nfile = "run01.csv"\nP = 1.0\nD = 0.5\n'
        f'[[run]]\nfile = "{name}"\nP = 2.0\nD = 0.5\n')
    return folder


def test_a_line_over_the_limit_is_refused_where_a_block_ends_inside_it(tmp_path: Path) -> None:
    # finding: a line of 1.9 MiB (the limit: 1 MiB) was read: only the part of a line left
    # at a block's end was checked, and this one ends inside the next block
    assert pio.MAX_LINE_BYTES == 2**20 and 2**20 < 1.9 * 2**20 < 2 * 2**20
    long_line = b"0.002," + b"0" * int(1.9 * 2**20) + b"1\n"
    data = b"t,x\n0,0\n0.001,1\n" + long_line + b"0.003,1\n"
    folder = _two_run_set(tmp_path / "set", data)
    with pytest.raises(ExperimentError) as info:
        pio.read_experiment(folder)
    msg = str(info.value)
    assert "run 2 (run02.csv)" in msg and "line 4 is longer than 1 MiB" in msg, msg


def test_a_gzip_bomb_of_one_repeated_row_is_refused_at_its_first_block(tmp_path: Path) -> None:
    # finding: 233 kB of gzip (60 million lines '0,0') cost 17 s and 0.8 GB: all the rows
    # parsed and held until MAX_LINES refused them. t is checked block by block now, so the
    # error is the repeated t of line 3, not the line limit (which would need 5e7 lines read)
    member = gzip.compress(b"0,0\n" * (4 * 2**20), compresslevel=9, mtime=0)  # 16 MiB each
    bomb = gzip.compress(b"t,x\n", mtime=0) + member * 15  # 240 MiB, 6.3e7 lines
    assert len(bomb) < 300_000
    folder = _two_run_set(tmp_path / "set", bomb, "run02.csv.gz")
    with pytest.raises(ExperimentError) as info:
        pio.read_experiment(folder)
    msg = str(info.value)
    assert "run 2 (run02.csv.gz)" in msg
    assert "not strictly increasing at line 3" in msg and "MAX_LINES" not in msg, msg


# --- container bombs: sizes declared huge, values read piece by piece, t first ---------------
# findings (a second probe): the MATLAB, HDF5 and Parquet readers loaded every variable whole
# before checking t: 4.8 kB of HDF5 declaring 45e6 never-written samples cost 1.8 GB and 8 s,
# 784 kB of Parquet zeros 2.3 GB, 1.4 MB of compressed MATLAB zeros 3.2 GB and 27 s, all to
# say "t is not strictly increasing at index 1"


CONTAINER_SET = """format = "phoid/1"
method = "tracking"
[loop]
delay = 0.0
sample_time = 0.001
[[run]]
file = "{file}"
P = 4000.0
D = 60.0
[run.columns]
t = "tt"
x = "qm"
r = "qg"
u = "vir"
"""
SIGNALS = ("tt", "qm", "qg", "vir")


def _read_measured(folder: Path) -> dict:
    """read_experiment(folder) in a fresh interpreter: its error (or "ok"), its seconds, and
    the process's peak resident memory (MB) before and after the read (ru_maxrss)."""
    code = (
        "import json, resource, sys, time\n"
        "import h5py, pyarrow.parquet, scipy.io\n"  # the readers' imports, before the baseline
        "import phoid.io as pio\n"
        "from phoid.errors import ExperimentError\n"
        "peak = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024\n"
        "base, t0 = peak(), time.perf_counter()\n"
        "try:\n"
        "    pio.read_experiment(sys.argv[1]); error = 'ok'\n"
        "except ExperimentError as e:\n"
        "    error = str(e)\n"
        "print(json.dumps({'error': error, 'seconds': time.perf_counter() - t0,\n"
        "                  'base': base, 'peak': peak()}))\n"
    )
    done = subprocess.run([sys.executable, "-c", code, str(folder)], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def _bomb_refused(folder: Path, file: str, *, declared_mb: float) -> None:
    got = _read_measured(folder)
    assert f"run 1 ({file})" in got["error"], got
    assert "'tt' for t is not strictly increasing at index 1: 0.0 s follows 0.0 s" \
        in got["error"], got
    # the old reader held every declared value (declared_mb, 300 MB or more here) before it
    # checked t; the new one holds one piece (1 MiB of values) beside the pages it touched of
    # the preallocated columns: 100 MB is room for the libraries' buffers
    assert got["peak"] - got["base"] < 100 < declared_mb, got
    # seconds: the old reader took 8-27 s on these; 10 s is room for a loaded machine
    assert got["seconds"] < 10, got


def test_an_hdf5_file_declaring_huge_never_written_datasets_is_refused_at_its_first_piece(
        tmp_path: Path) -> None:
    import h5py

    n = 45_000_000  # under MAX_LINES: only the values can refuse it
    with h5py.File(tmp_path / "d.h5", "w") as f:
        for name in SIGNALS:  # never written: every value is the fill value, 0
            f.create_dataset(name, shape=(1, n), dtype="f8", chunks=(1, 1 << 20))
    assert (tmp_path / "d.h5").stat().st_size < 10_000
    (tmp_path / "experiment.toml").write_text(CONTAINER_SET.format(file="d.h5"))
    _bomb_refused(tmp_path, "d.h5", declared_mb=4 * 8 * n / 2**20)


def test_a_parquet_file_of_constant_columns_is_refused_at_its_first_batch(
        tmp_path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    zeros = pa.array(np.zeros(1 << 20))
    table = pa.concat_tables([pa.table({k: zeros for k in SIGNALS})] * 10)  # 10 Mi rows
    pq.write_table(table, tmp_path / "d.parquet", row_group_size=table.num_rows,
                   compression="zstd")  # one row group: dictionary pages, 2 kB per column
    (tmp_path / "experiment.toml").write_text(CONTAINER_SET.format(file="d.parquet"))
    _bomb_refused(tmp_path, "d.parquet", declared_mb=4 * 8 * table.num_rows / 2**20)


def _mat_zeros(path: Path, n: int, names: Sequence[str]) -> None:
    """A MATLAB v5 file (header, then per name a compressed n×1 double of zeros), written by
    hand as the MAT-file format lays it out (a 128-byte header; elements tag, flags, dims,
    name, values): zlib of zeros is a thousand times smaller than the zeros."""
    import zlib

    def tag(kind: int, nbytes: int) -> bytes:
        return struct.pack("<II", kind, nbytes)

    header = b"MATLAB 5.0 MAT-file, hand-written by phoid's tests".ljust(116) + bytes(8) \
        + b"\x00\x01IM"
    with open(path, "wb") as f:
        f.write(header)
        for name in names:
            raw = name.encode()
            body = (tag(6, 8) + struct.pack("<II", 6, 0) + tag(5, 8) + struct.pack("<ii", n, 1)
                    + tag(1, len(raw)) + raw + bytes(-len(raw) % 8) + tag(9, 8 * n))
            z = zlib.compressobj(1)
            parts = [z.compress(tag(14, len(body) + 8 * n) + body)]
            block, left = bytes(1 << 24), 8 * n
            while left:
                parts.append(z.compress(block[:min(left, len(block))]))
                left -= min(left, len(block))
            parts.append(z.flush())
            stream = b"".join(parts)
            f.write(tag(15, len(stream)) + stream)


def test_a_compressed_mat_file_of_zeros_is_refused_at_its_first_block(tmp_path: Path) -> None:
    n = 10_000_000
    _mat_zeros(tmp_path / "d.mat", n, SIGNALS)
    assert (tmp_path / "d.mat").stat().st_size < 2_000_000
    (tmp_path / "experiment.toml").write_text(CONTAINER_SET.format(file="d.mat"))
    _bomb_refused(tmp_path, "d.mat", declared_mb=4 * 8 * n / 2**20)


def test_mat_variables_not_asked_for_are_listed_without_being_decompressed(
        tmp_path: Path) -> None:
    # scipy's whosmat (the old listing) decompressed each compressed element in unbounded
    # steps: 20 variables of 128 MB of zeros (2.4 MB of file) cost it ~10 s and 300 MB
    import scipy.io

    t = np.arange(1000) * 1e-3
    buf = io.BytesIO()
    scipy.io.savemat(buf, {"tt": t, "qm": np.sin(t), "qg": np.sin(t), "vir": np.cos(t)})
    junk = tmp_path / "junk.mat"
    _mat_zeros(junk, 16_000_000, ["junk"])
    element = junk.read_bytes()[128:]
    (tmp_path / "d.mat").write_bytes(buf.getvalue() + element * 20)
    (tmp_path / "experiment.toml").write_text(CONTAINER_SET.format(file="d.mat"))
    got = _read_measured(tmp_path)
    assert got["error"] == "ok", got
    assert got["peak"] - got["base"] < 100 and got["seconds"] < 10, got


def test_a_valid_record_is_read_into_its_columns_with_little_more_memory(
        tmp_path: Path) -> None:
    # finding: 542 kB of HDF5 (a real t, signals declared and never written) took 4.6 GB
    # to identify; the reader's part is now the columns kept (8 bytes a value) and a piece
    import h5py

    n = 4_000_000
    with h5py.File(tmp_path / "d.h5", "w") as f:
        f.create_dataset("tt", data=(np.arange(n) * 1e-3).reshape(1, -1), chunks=(1, 1 << 20),
                         compression="gzip", shuffle=True)
        for name in SIGNALS[1:]:
            f.create_dataset(name, shape=(1, n), dtype="f8", chunks=(1, 1 << 20))
    (tmp_path / "experiment.toml").write_text(CONTAINER_SET.format(file="d.h5"))
    got = _read_measured(tmp_path)
    assert got["error"] == "ok", got
    kept = 4 * 8 * n / 2**20  # 122 MB: the four float64 columns returned
    # 40 MB: a piece of each read (8 MiB), a decompressed chunk, the library's chunk cache
    assert got["peak"] - got["base"] < kept + 40, (got, kept)


def test_a_force_of_zeros_is_refused_naming_the_run_and_its_file(tmp_path: Path) -> None:
    # finding: "force: the force to fit is zero at every sample (…)", naming no run or file
    t = np.arange(3000) * 1e-3
    table = "tt,qm,qg,vir\n" + "".join(f"{v!r},0,0,0\n" for v in t.tolist())
    (tmp_path / "rec.csv").write_text(table)
    (tmp_path / "experiment.toml").write_text(
        CONTAINER_SET.replace("{file}", "rec.csv").replace('method = "tracking"',
                                                           'method = "tracking"\n'
                                                           'estimator = "idim"'))
    result = runner.invoke(app, ["identify", str(tmp_path)])
    one_line_error(result, "run 1 (rec.csv)", "zero at every sample")


# --- CSV: a cell numpy cannot read is named by line and column; a blank bomb ---------------


def test_a_full_width_digit_is_named_by_its_line_and_column(tmp_path: Path) -> None:
    # finding: '０.５' (full-width digits, which Python's \d matches and numpy refuses) said
    # "could not convert … at row 500, column 1": line 502 and column t
    rows = [f"{i * 1e-3!r},{float(np.sin(i * 1e-3))!r}" for i in range(1000)]
    rows[500] = "０.５," + rows[500].split(",")[1]
    folder = _two_run_set(tmp_path / "set", ("t,x\n" + "\n".join(rows) + "\n").encode())
    with pytest.raises(ExperimentError) as info:
        pio.read_experiment(folder)
    msg = str(info.value)
    # line 502: the header is line 1, row i is line i + 2
    assert "run 2 (run02.csv): column 't' has a non-numeric cell at line 502: '０.５'" in msg, msg


def test_a_gzip_of_gigabytes_of_blank_lines_is_refused_within_seconds(tmp_path: Path) -> None:
    # finding: 4.9 MB of gzip, 4 GiB of lines of 1 MiB of spaces, was refused only at
    # MAX_DATA_BYTES, after 21.6 s of decompression (4096 lines: far under MAX_LINES)
    import time

    line = b" " * (2**20 - 2) + b"\n"
    member = gzip.compress(line * 16, compresslevel=9, mtime=0)  # 16 MiB each
    bomb = gzip.compress(b"t,x\n0,0\n", mtime=0) + member * 300  # 4.7 GiB
    assert len(bomb) < 6_000_000
    folder = _two_run_set(tmp_path / "set", bomb, "run02.csv.gz")
    start = time.perf_counter()
    with pytest.raises(ExperimentError) as info:
        pio.read_experiment(folder)
    seconds = time.perf_counter() - start
    msg = str(info.value)
    assert "run 2 (run02.csv.gz): the data file is mostly blank" in msg
    assert "MAX_BLANK_SHARE" in msg and "MAX_DATA_BYTES" not in msg, msg
    # refused after BLANK_CHECKED_AFTER (64 MiB, well under a second), not after 4 GiB (20 s);
    # 8 s is room for a loaded machine
    assert seconds < 8, seconds


def test_a_small_mat_element_claiming_more_than_four_bytes_is_damaged() -> None:
    # the MAT-file format's small data element keeps ≤ 4 bytes in its tag; a tag claiming 160
    # was read from the bytes after it (scipy refuses it: "Error in SDE format data")
    import io

    import scipy.io

    from phoid.io._mat5 import check_mat5

    buf = io.BytesIO()
    scipy.io.savemat(buf, {"t": np.array([[7]], dtype=np.uint8)}, do_compression=False)
    raw = buf.getvalue()
    tag = b"\x02\x00\x01\x00"  # miUINT8 (2), 1 byte, little-endian small element: the value
    assert raw.count(tag) == 1
    bad = raw.replace(tag, b"\x02\x00\xa0\x00")
    check_mat5("ok.mat", io.BytesIO(raw), len(raw))  # the valid file lists
    with pytest.raises(ExperimentError, match="damaged"):
        check_mat5("bad.mat", io.BytesIO(bad), len(bad))
