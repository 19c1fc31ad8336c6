"""A batch's output: a journal appended per finished set, Parquet and CSV rewritten whole.

``phoid batch SETS --out results.parquet`` keeps three files side by side:

* ``results.parquet`` — the table (schema :data:`phoid.batch.rows.SCHEMA`, named in the
  file's key-value metadata under ``phoid``), one row per (set, options);
* ``results.csv`` — the same table as CSV;
* ``results.journal.jsonl`` — while a batch runs: one JSON object per finished set, appended
  and flushed to disk as each set ends.

Parquet and CSV are written through :class:`phoid._output.OutputFolder` (inside the folder
named, never through a link, atomically replaced), every few seconds while the batch runs and
at its end; the journal is removed once they hold its rows. A batch killed at any point loses
no finished set: the next run with the same output reads the table and the journal (a last
line cut off by the kill is dropped), writes them into the table, and skips every set whose
checksum and options it already holds. A file in the way that is not a phoid batch output, or
one of another schema, is refused, never replaced.
"""

from __future__ import annotations

import json
import os
import stat
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from phoid._output import OutputFolder
from phoid.batch.rows import BASE_COLUMNS, PARAMETERS, SCHEMA
from phoid.errors import OutputError

__all__ = ["BatchStore", "to_frame"]

_FLOATS = {"seconds", "chi2_dof", *PARAMETERS, *(f"{p}_stderr" for p in PARAMETERS)}
_INTS = {"n_runs", "n_warnings"}
_TIMES = {"time", "finished"}
_REQUIRED = ("set", "checksum", "options", "status")


def _key(row: Mapping[str, Any]) -> tuple[str, str]:
    return (str(row["set"]), str(row["options"]))


def to_frame(rows: Iterable[Mapping[str, Any]]) -> Any:
    """The rows as a pandas DataFrame with the schema's column types.

    The columns of :data:`~phoid.batch.rows.BASE_COLUMNS` first, in that order, then the
    others sorted (further parameters and their ``_stderr``, ``corr_*``, ``meta_*``);
    ``time`` and ``finished`` as UTC timestamps, ``n_runs`` and ``n_warnings`` as nullable
    integers, the numbers as float64, the rest as strings (a ``meta_`` column whose values
    differ in type across sets: as strings).
    """
    import pandas as pd

    rows = list(rows)
    extra = sorted({k for r in rows for k in r} - set(BASE_COLUMNS))
    columns = [*BASE_COLUMNS, *extra]
    frame = pd.DataFrame([[r.get(c) for c in columns] for r in rows], columns=columns)
    for col in columns:
        values = [v for v in frame[col] if v is not None and v == v]
        if col in _TIMES:
            frame[col] = pd.to_datetime(frame[col], utc=True, format="ISO8601").astype(
                "datetime64[us, UTC]")
        elif col in _INTS:
            frame[col] = frame[col].astype("Int64")
        elif col in _FLOATS or col.startswith("corr_") or (
                not col.startswith("meta_") and col not in BASE_COLUMNS):
            frame[col] = pd.to_numeric(frame[col], errors="coerce").astype("float64")
        elif col.startswith("meta_") and values and all(
                isinstance(v, int | float) and not isinstance(v, bool) for v in values):
            frame[col] = frame[col].astype("float64")
        elif col.startswith("meta_") and values and all(isinstance(v, bool) for v in values):
            frame[col] = frame[col].astype("boolean")
        else:
            frame[col] = frame[col].map(lambda v: None if v is None or v != v else str(v)
                                        ).astype("string")
    return frame


def _from_frame_value(value: Any) -> Any:
    """A value read back from the table, as the journal holds it (timestamps as ISO text)."""
    if value is None:
        return None
    if hasattr(value, "isoformat"):
        return value.isoformat()
    if isinstance(value, float) and value != value:
        return None
    return value


class BatchStore:
    """The output files of a batch (see the module's description), checked on creation.

    Parameters
    ----------
    out : str or Path
        The Parquet file, e.g. ``results.parquet``; the CSV and the journal are the same
        name with ``.csv`` and ``.journal.jsonl`` for its last suffix.

    Raises
    ------
    OutputError
        One line naming the file: ``out`` ending in ``.csv`` (any case), an existing file
        that is a link, not a regular file, not a phoid batch output, or a phoid batch output
        of another schema.
    """

    def __init__(self, out: str | os.PathLike[str]) -> None:
        self.parquet = Path(out)
        self.csv = self.parquet.with_suffix(".csv")
        self.journal = self.parquet.with_suffix(".journal.jsonl")
        if self.parquet.suffix.lower() == ".csv":  # .CSV too: x.CSV and x.csv are one file
            # on a case-insensitive file system
            raise OutputError(f"{self.parquet}: the output must not end in "
                              f"{self.parquet.suffix}; name the Parquet file, e.g. "
                              "results.parquet")
        self._folder = OutputFolder(self.parquet.parent, overwrite=True)
        self._rows: dict[tuple[str, str], dict[str, Any]] = {}
        for path in (self.parquet, self.csv, self.journal):
            self._check_regular(path)
        if self.csv.exists():
            self._check_csv()
        if self.parquet.exists():
            self._read_parquet()
        if self.journal.exists():
            self._read_journal()

    # -- reading what is there ------------------------------------------------------------
    @staticmethod
    def _check_regular(path: Path) -> None:
        if path.is_symlink():
            raise OutputError(f"{path}: is a symbolic link; phoid batch never writes through "
                              "one (remove it or choose another output)")
        if path.exists() and not stat.S_ISREG(path.stat().st_mode):
            raise OutputError(f"{path}: exists and is not a regular file")

    def _refuse(self, path: Path, why: str) -> OutputError:
        return OutputError(f"{path}: {why}; phoid batch does not replace it (choose another "
                           "--out or move the file)")

    def _read_parquet(self) -> None:
        import pyarrow.parquet as pq

        try:
            schema = pq.read_schema(self.parquet)
        except Exception as exc:  # pyarrow's errors: not a Parquet file, cut off, ...
            raise self._refuse(self.parquet, f"not a Parquet file ({type(exc).__name__})"
                               ) from None
        found = (schema.metadata or {}).get(b"phoid")
        if found is None:
            raise self._refuse(self.parquet, "not a phoid batch output (no 'phoid' key in its "
                                             "Parquet metadata)")
        if found.decode("utf-8", "replace") != SCHEMA:
            name = found.decode("utf-8", "replace")
            raise self._refuse(self.parquet, f"a table of schema {name!r}, not {SCHEMA!r}")
        missing = [c for c in BASE_COLUMNS if c not in schema.names]
        if missing:
            raise self._refuse(self.parquet, f"schema {SCHEMA} without the column {missing[0]!r}")
        table = pq.read_table(self.parquet)
        for row in table.to_pylist():
            row = {k: _from_frame_value(v) for k, v in row.items()}
            self._rows[_key(row)] = {k: v for k, v in row.items()
                                     if v is not None or k in BASE_COLUMNS}

    def _check_csv(self) -> None:
        with open(self.csv, "rb") as fh:
            head = fh.readline(1 << 16).decode("utf-8", "replace").strip().split(",")
        missing = [c for c in BASE_COLUMNS if c not in head]
        if missing:
            raise self._refuse(self.csv, f"not a phoid batch output (no column {missing[0]!r})")

    def _read_journal(self) -> None:
        lines = self.journal.read_bytes().split(b"\n")
        complete = lines[:-1]  # the part after the last newline: empty, or cut off by a kill
        for n, line in enumerate(complete, 1):
            try:
                row = json.loads(line)
            except ValueError:
                raise self._refuse(self.journal, f"line {n} is not JSON: not a phoid batch "
                                                 "journal") from None
            if not isinstance(row, dict) or any(k not in row for k in _REQUIRED):
                raise self._refuse(self.journal, f"line {n} is not a row of {SCHEMA}")
            self._rows[_key(row)] = row

    # -- what is done ---------------------------------------------------------------------
    def done(self) -> dict[tuple[str, str], dict[str, Any]]:
        """The rows held, by (set, options)."""
        return dict(self._rows)

    # -- writing --------------------------------------------------------------------------
    def begin(self) -> None:
        """Write the table (what an earlier table and a journal left by a killed batch hold,
        or no row), creating the folder; start a new journal."""
        self.write()
        if self.journal.exists():
            os.unlink(self.journal)

    def append(self, row: Mapping[str, Any]) -> None:
        """Add a finished set's row: appended to the journal and flushed to disk."""
        self._rows[_key(row)] = dict(row)
        line = (json.dumps(dict(row), ensure_ascii=False, allow_nan=False) + "\n").encode()
        flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0)
        try:
            fd = os.open(self.journal, flags, 0o666)
            try:
                os.write(fd, line)
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError as exc:
            raise OutputError(f"{self.journal}: cannot be written: {exc.strerror or exc}"
                              ) from None

    def write(self) -> None:
        """Rewrite the Parquet and CSV files with every row held (atomically, each)."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        rows = [self._rows[k] for k in sorted(self._rows)]
        frame = to_frame(rows)
        table = pa.Table.from_pandas(frame, preserve_index=False)
        table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                               b"phoid": SCHEMA.encode()})
        self._folder.write(self.parquet.name, lambda fh: pq.write_table(table, fh))
        self._folder.write(self.csv.name, frame.to_csv(index=False).encode("utf-8"))

    def finish(self) -> None:
        """Write the table, then remove the journal (its rows are in the table)."""
        self.write()
        if self.journal.exists():
            os.unlink(self.journal)
