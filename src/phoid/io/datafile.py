"""The bounded reader of one ``phoid/1`` CSV data file, plain or gzip-compressed.

The file is read (and decompressed) in blocks of :data:`~phoid.io.limits.BLOCK` bytes, cut into
whole lines, and parsed by :func:`numpy.loadtxt` (C-accelerated, correctly rounded) chunk by
chunk; every limit of :mod:`phoid.io.limits` is checked while reading, so memory stays
proportional to the rows accepted. Errors name the line and the column at fault.
"""

from __future__ import annotations

import bisect
import codecs
import hashlib
import io as _io
import itertools
import re
import zlib
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import BinaryIO

import numpy as np

import phoid.io.limits as limits
from phoid.io._files import open_regular
from phoid.io._format import COLUMNS, fail, show

__all__ = ["read_csv"]

_GZIP_MAGIC = b"\x1f\x8b"
_NUMBER_RE = re.compile(
    # one way to match each number (\d+(?:\.\d*)?, not \d+\.?\d*): a long run of digits that
    # fails to match costs linear, not quadratic, time (docs/design-notes/io.md)
    # ASCII digits only (re.ASCII): numpy refuses the full-width '０.５' that \d would match
    r"[+-]?(?:(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?|inf(?:inity)?|nan)",
    re.IGNORECASE | re.ASCII,
)
_NUMPY_CELL = re.compile(r"could not convert string (.*) to float64 at row (\d+), column (\d+)")
_BLANK_BYTES = tuple(bytes([c]) for c in b" \t\r\v\f")


def _blocks(where: str, real: Path, file: str) -> Iterator[bytes]:
    """The data file's bytes, decompressed, in blocks of at most BLOCK bytes.

    Stops with an error at MAX_DATA_BYTES (decompressed, or stored): never reads or
    decompresses more than one block past the limit. Blank bytes are counted as they come: a
    file more than MAX_BLANK_SHARE blank past its first BLANK_CHECKED_AFTER bytes is refused
    there (gigabytes of blank lines cost no more than that).
    """
    f, st = open_regular(where, real, "data file")
    too_big = (f"the data file is larger than {limits.MAX_DATA_BYTES // 2**30} GiB (after "
               "decompression), phoid's limit for one run (MAX_DATA_BYTES)")
    total = blank = 0
    with f:
        if st.st_size > limits.MAX_DATA_BYTES:
            fail(where, too_big)
        try:
            head = f.peek(2)[:2]
        except OSError as exc:
            fail(where, f"cannot read the data file: {exc.strerror or exc}")
        if not head:
            fail(where, "the data file is empty")
        if head == _GZIP_MAGIC:
            stream = _gunzip(where, f)
        elif file.lower().endswith(".gz"):
            fail(where, "the data file is not a gzip file (it lacks the gzip signature), "
                         "although its name ends in .gz")
        else:
            stream = _plain(where, f)
        for block in stream:
            total += len(block)
            if total > limits.MAX_DATA_BYTES:
                fail(where, too_big)
            blank += sum(map(block.count, _BLANK_BYTES))
            if total > limits.BLANK_CHECKED_AFTER and blank > limits.MAX_BLANK_SHARE * total:
                fail(where, f"the data file is mostly blank: {blank:,} of its first {total:,} "
                             "bytes (after decompression) are spaces, tabs or other blank "
                             f"characters, more than phoid's limit of "
                             f"{limits.MAX_BLANK_SHARE:.0%} (MAX_BLANK_SHARE)")
            yield block


def _plain(where: str, f: BinaryIO) -> Iterator[bytes]:
    while True:
        try:
            block = f.read(limits.BLOCK)
        except OSError as exc:
            fail(where, f"cannot read the data file: {exc.strerror or exc}")
        if not block:
            return
        yield block


def _gunzip(where: str, f: BinaryIO) -> Iterator[bytes]:
    """Decompress a gzip file (one member or several, one after the other) in blocks.

    zlib parses the gzip header and checks the trailer (CRC-32 and length) in C; output is
    bounded by BLOCK per step (max_length), so a bomb is never expanded ahead of the reader.
    """
    bad = "the data file is not a valid gzip file"
    d = zlib.decompressobj(31)
    data = b""
    fed = False
    while True:
        if not data:
            try:
                data = f.read(limits.BLOCK)
            except OSError as exc:
                fail(where, f"cannot read the data file: {exc.strerror or exc}")
            if not data:
                if fed and not d.eof:
                    try:
                        tail = d.flush(limits.BLOCK)
                    except zlib.error as exc:
                        fail(where, f"{bad}: {exc}")
                    if tail:
                        yield tail
                    if not d.eof:
                        fail(where, f"{bad}: it ends before the end of its compressed data "
                                     "(a truncated file?)")
                return
        if d.eof:  # the next member
            d = zlib.decompressobj(31)
        try:
            out = d.decompress(data, limits.BLOCK)
        except zlib.error as exc:
            fail(where, f"{bad}: {exc}")
        fed = True
        data = d.unused_data if d.eof else d.unconsumed_tail
        if out:
            yield out


def _line_chunks(where: str, blocks: Iterable[bytes]) -> Iterator[tuple[int, bytes]]:
    """Whole lines, LF-terminated, in chunks: (number of the chunk's first line, chunk).

    A byte-order mark is dropped and CRLF and CR line ends become LF. Lines are counted as
    they come: more than MAX_LINES lines, or a line longer than MAX_LINE_BYTES, is an error
    before the next block is read.
    """
    carry = b""
    line = 1
    first = True
    for block in blocks:
        buf = carry + block if carry else block
        if first:
            if len(buf) < len(codecs.BOM_UTF8) and codecs.BOM_UTF8.startswith(buf):
                carry = buf
                continue
            first = False
            if buf.startswith(codecs.BOM_UTF8):
                buf = buf[len(codecs.BOM_UTF8):]
        held = b""
        if buf.endswith(b"\r"):  # a CR at the end may be half of a CRLF
            buf, held = buf[:-1], b"\r"
        if b"\r" in buf:
            buf = buf.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        cut = buf.rfind(b"\n") + 1
        chunk, carry = buf[:cut], buf[cut:] + held
        if chunk:
            count = chunk.count(b"\n")
            _check_lines(where, line + count - 1)
            _check_line_lengths(where, chunk, line)
            yield line, chunk
            line += count
        if len(carry) > limits.MAX_LINE_BYTES:
            _long_line(where, line)
    if first and carry.startswith(codecs.BOM_UTF8):
        carry = carry[len(codecs.BOM_UTF8):]
    if carry:
        carry = carry.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        if not carry.endswith(b"\n"):
            carry += b"\n"
        _check_lines(where, line + carry.count(b"\n") - 1)
        yield line, carry


def _check_line_lengths(where: str, chunk: bytes, first: int) -> None:
    """Refuse a line of ``chunk`` (whole LF-terminated lines, the first numbered ``first``)
    longer than MAX_LINE_BYTES, wherever it lies: the line a block began in the middle of
    (its start carried over from the previous block) as well as any other."""
    if len(chunk) <= limits.MAX_LINE_BYTES:
        return  # no line can be longer than the chunk
    ends = np.flatnonzero(np.frombuffer(chunk, dtype=np.uint8) == 10)
    lengths = np.diff(ends, prepend=-1) - 1  # without the LF
    if lengths.max() > limits.MAX_LINE_BYTES:
        _long_line(where, first + int(np.argmax(lengths > limits.MAX_LINE_BYTES)))


def _long_line(where: str, line: int) -> None:
    fail(where, f"line {line} is longer than {limits.MAX_LINE_BYTES // 2**20} MiB, phoid's "
                 "limit for one line (MAX_LINE_BYTES): is this a CSV file with one row per "
                 "line?")


def _check_lines(where: str, last: int) -> None:
    if last > limits.MAX_LINES:
        fail(where, f"the data file has more than {limits.MAX_LINES:,} lines (blank lines "
                     "included), phoid's limit for one run (MAX_LINES)")


def _clean_name(name: str) -> str:
    name = name.strip()
    if len(name) >= 2 and name[0] == name[-1] == '"':
        name = name[1:-1].strip()
    return name


def read_csv(where: str, real: Path, file: str, *, need_F: bool = False,
              max_rows: int = limits.MAX_SET_ROWS, columns: Mapping[str, str] | None = None,
              required: Sequence[str] = (), clock: bool = True
              ) -> tuple[dict[str, np.ndarray], bytes]:
    """Read, decompress and parse one phoid/1 CSV data file, streaming.

    Returns the known columns it has (read-only float64 arrays) and a BLAKE2b digest of its
    decompressed content. At most ``max_rows`` data rows are accepted. ``clock=False`` (the
    manifest gives ``sample_rate``, from which the reader rebuilds t): the ``t`` column is
    optional and, when there, read as numbers but not required to increase.

    ``columns`` (a tracking set's ``[run.columns]``) maps each phoid name to the header name
    that holds it, in the order the columns are kept; the columns in ``required`` and ``t``,
    ``x`` must be there, the others are read when present. ``None``: the known columns
    :data:`~phoid.io._format.COLUMNS` under their own names.
    """
    digest = hashlib.blake2b(digest_size=32)

    def hashed() -> Iterator[bytes]:
        for block in _blocks(where, real, file):
            digest.update(block)
            yield block

    try:
        cols = _parse_csv(where, _line_chunks(where, hashed()), need_F=need_F,
                          max_rows=max_rows, columns=columns, required=required, clock=clock)
    except MemoryError:
        fail(where, "not enough memory to hold the data file's columns")
    return cols, digest.digest()


def _parse_csv(where: str, chunks: Iterator[tuple[int, bytes]], *, need_F: bool = False,
               max_rows: int = limits.MAX_SET_ROWS, columns: Mapping[str, str] | None = None,
               required: Sequence[str] = (), clock: bool = True) -> dict[str, np.ndarray]:
    """Parse a phoid/1 CSV, given as chunks of whole LF-terminated lines, into the known
    columns it has (``clock=False``: ``t`` optional, not checked to increase)."""
    first = next(chunks, None)
    if first is None:
        fail(where, "the data file is empty")
    start, chunk = first
    cut = chunk.find(b"\n")
    head, body = chunk[:cut], chunk[cut + 1:]
    if not head.strip():
        rest = body
        while not rest.strip():  # all blank so far: an empty file, or a blank header line
            nxt = next(chunks, None)
            if nxt is None:
                fail(where, "the data file is empty")
            rest = nxt[1]
        fail(where, "line 1 is blank; the first line must be a header naming the columns")
    try:
        header = head.decode("utf-8")
    except UnicodeDecodeError:
        fail(where, "the header (line 1) is not UTF-8 text")
    names = [_clean_name(n) for n in header.split(",")]
    if all(_NUMBER_RE.fullmatch(n) for n in names):
        fail(where, f"line 1 looks like data ({show(header.strip())}); the first line must "
                     "be a header naming the columns, e.g. 't,x,u'")
    position: dict[str, int] = {}
    for j, n in enumerate(names):
        if n and n in position:
            fail(where, f"the header names column {show(n)} twice "
                         f"(columns {position[n] + 1} and {j + 1})")
        position[n] = j
    mapping = dict(columns) if columns is not None else {k: k for k in COLUMNS}
    needed = (("t", "x") if clock else ("x",)) + (("F",) if need_F else ()) + tuple(required)
    for key in dict.fromkeys(needed):
        if mapping[key] not in position:
            fail(where, _missing_column(key, names, header, need_F, mapping[key]))
    keys = [k for k in mapping if mapping[k] in position]
    usecols = [position[mapping[k]] for k in keys]
    # messages name a column as the header does, and its phoid name where that differs
    wanted = [show(k) if mapping[k] == k else f"{show(mapping[k], 40)} ({k})" for k in keys]
    ncols = len(names)

    parts: list[np.ndarray] = []   # per chunk: rows × wanted columns
    where_rows: list[tuple[int, int, np.ndarray | None]] = []  # (first row, first line, lines)
    n = 0
    it = keys.index("t") if clock else -1  # no clock to check: t rebuilt from sample_rate
    last_t: tuple[float, int] | None = None  # the previous chunk's last t and its line

    def line_of(row: int) -> int:
        i = bisect.bisect_right([w[0] for w in where_rows], row) - 1
        first_row, line0, lines = where_rows[i]
        return int(lines[row - first_row]) if lines is not None else line0 + row - first_row

    bodies = itertools.chain([(start + 1, body)], ((s, c) for s, c in chunks))
    for line0, text in bodies:
        if not text:
            continue
        table, lines = _parse_chunk(where, text, line0, ncols, position, wanted, usecols)
        if not table.shape[0]:
            continue
        if n + table.shape[0] > max_rows:
            fail(where, f"the set's data files hold more than {limits.MAX_SET_ROWS:,} data rows in "
                         "all (this one included), phoid's limit for one set (MAX_SET_ROWS)")
        where_rows.append((n, line0, lines))
        parts.append(table)
        n += table.shape[0]
        # t is checked chunk by chunk, so that a file that repeats one row (a gzip bomb of
        # 60 million '0,0' lines is 233 kB) is refused at its first block, not after
        # MAX_LINES rows have been parsed and held
        if it < 0:
            continue
        t = table[:, it]
        if last_t is not None and not t[0] > last_t[0]:
            _not_increasing(where, wanted[it], float(t[0]), line_of(n - t.size), *last_t)
        up = t[1:] > t[:-1]
        if not up.all():
            j = int(np.argmin(up)) + 1  # in this chunk; row n - t.size + j of the file
            _not_increasing(where, wanted[it], float(t[j]), line_of(n - t.size + j),
                            float(t[j - 1]), line_of(n - t.size + j - 1))
        last_t = (float(t[-1]), line_of(n - 1))
    if n == 0:
        fail(where, "the data file has a header but no data rows")
    if n < 2:
        fail(where, f"only {n} data row; at least 2 are needed")

    cols: dict[str, np.ndarray] = {}
    for i, key in enumerate(keys):
        col = np.concatenate([p[:, i] for p in parts]) if len(parts) > 1 \
            else np.ascontiguousarray(parts[0][:, i])
        col.flags.writeable = False
        cols[key] = col
    parts.clear()
    return cols


def _not_increasing(where: str, name: str, value: float, line: int, before: float,
                    line_before: int) -> None:
    fail(where, f"column {name} is not strictly increasing at line {line}: {value!r} s "
                 f"follows {before!r} s (line {line_before}) (if the logger's clock is "
                 "unusable, give `sample_rate` = <Hz> in the manifest to rebuild t = t₀ + n/fs "
                 "from the sample count, docs/format.md)")


def _parse_chunk(where: str, body: bytes, line0: int, ncols: int, position: dict[str, int],
                 wanted: list[str], usecols: list[int]
                 ) -> tuple[np.ndarray, np.ndarray | None]:
    """Parse whole lines (LF-terminated) starting at line ``line0`` into rows × wanted.

    Returns the table and the physical line number of each row (None when the rows are the
    consecutive lines from ``line0``: no blank line among them).
    """
    table = None
    lines: np.ndarray | None = None
    if not body.strip():
        return np.empty((0, len(wanted))), None
    if not body.startswith(b"\n") and b"\n\n" not in body:
        # fast path: every line a row, every column numeric
        try:
            table = np.loadtxt(_io.StringIO(body.decode("utf-8", "replace")), delimiter=",",
                               comments=None, ndmin=2, dtype=np.float64)
        except ValueError:
            table = None
        if table is not None and table.shape[1] != ncols:
            table = None
        if table is not None:
            table = table[:, usecols]
    if table is None:
        body, lines = _check_structure(where, body, ncols, line0)
        if not lines.size:
            return np.empty((0, len(wanted))), None
        try:
            table = np.loadtxt(_io.StringIO(body.decode("utf-8", "replace")), delimiter=",",
                               comments=None, ndmin=2, dtype=np.float64, usecols=usecols)
        except ValueError as exc:
            _diagnose_cells(where, body, lines, wanted, usecols)
            _numpy_cell(where, str(exc), lines, wanted, usecols)
            fail(where, f"cannot parse the data of lines {int(lines[0])}–{int(lines[-1])}: "
                         f"{show(str(exc), 120)}")
    finite = np.isfinite(table)
    if not finite.all():
        bad = ~finite.all(axis=0)
        i = int(np.argmax(bad))
        r = int(np.argmin(finite[:, i]))
        line = int(lines[r]) if lines is not None else line0 + r
        cell = _cell_text(body, r, usecols[i])
        fail(where, f"column {wanted[i]} has a non-finite value at line {line}: "
                     f"{show(cell)}")
    return table, lines


def _missing_column(key: str, names: list[str], header: str, need_F: bool,
                    name: str | None = None) -> str:
    shown = ", ".join(show(n, 40) for n in names[:12]) + (", …" if len(names) > 12 else "")
    name = key if name is None else name
    text = f"missing column {show(name, 40)}" + (f" for {key}" if name != key else "")
    if key == "F" and need_F:
        text += " (a forced run needs the external force F)"
    text += f"; the header names {shown}"
    if any(n.lower() == name.lower() for n in names):
        text += " (column names are case-sensitive)"
    elif len(names) == 1 and any(c in header for c in ";\t "):
        text += " (columns must be separated by commas)"
    return text


def _check_structure(where: str, body: bytes, ncols: int, line0: int
                     ) -> tuple[bytes, np.ndarray]:
    """Find ragged rows and blank lines (vectorised); drop the blank lines.

    ``body`` holds whole LF-terminated lines, the first of them line ``line0``. Returns the
    body without blank lines and the physical line number of each data row.
    """
    b = np.frombuffer(body, dtype=np.uint8)
    ends = np.flatnonzero(b == 10)  # body ends with "\n": every line has one
    starts = np.empty_like(ends)
    starts[0] = 0
    starts[1:] = ends[:-1] + 1
    blanks = (b == 32) | (b == 9) | (b == 10) | (b == 11) | (b == 12)
    # each segment [start, next start) holds its "\n", so none is empty for reduceat
    filled = np.add.reduceat(~blanks, starts, dtype=np.intp)
    commas = np.add.reduceat(b == 44, starts, dtype=np.intp)
    data = filled > 0
    bad = np.flatnonzero(data & (commas != ncols - 1))
    if bad.size:
        i = int(bad[0])
        fail(where, f"line {i + line0} has {commas[i] + 1} fields but the header names "
                     f"{ncols} columns")
    lines = np.flatnonzero(data) + line0
    if not data.all():
        keep = np.repeat(data, ends - starts + 1)
        body = b[keep].tobytes()
    return body, lines


def _diagnose_cells(where: str, body: bytes, rows: np.ndarray, wanted: list[str],
                    usecols: list[int]) -> None:
    """Find the first bad cell of the known columns (error path only: a loop per row)."""
    text = body.decode("utf-8", "replace")
    for r, line in enumerate(text.split("\n")[:-1]):
        cells = line.split(",")
        for key, j in zip(wanted, usecols, strict=True):
            cell = cells[j].strip()
            if not cell:
                fail(where, f"column {key} has an empty cell at line {int(rows[r])}")
            if not _NUMBER_RE.fullmatch(cell):
                fail(where, f"column {key} has a non-numeric cell at line {int(rows[r])}: "
                             f"{show(cell)}")


def _numpy_cell(where: str, message: str, rows: np.ndarray, wanted: list[str],
                usecols: list[int]) -> None:
    """Name the line and column of a cell numpy could not convert (its message counts rows
    of the chunk from 0 and the file's columns from 1) where _diagnose_cells found none."""
    found = _NUMPY_CELL.search(message)
    if found is None:
        return
    cell, row, column = found[1].strip("'"), int(found[2]), int(found[3]) - 1
    if row < rows.size and column in usecols:
        fail(where, f"column {wanted[usecols.index(column)]} has a non-numeric cell at line "
                     f"{int(rows[row])}: {show(cell, 60)}")


def _cell_text(body: bytes, row: int, col: int) -> str:
    """Text of one cell of the (blank-line free) body; error path only."""
    line = body.split(b"\n", row + 1)[row].decode("utf-8", "replace")
    return line.split(",")[col].strip()
