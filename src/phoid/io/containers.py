"""Reading a tracking run's signals and scalars from a MATLAB, HDF5 or Parquet file.

Formats (docs/format.md, "Tracking sets"), recognised by content, the name's suffix being the
user's claim (a mismatch is an error that says what the content is):

* ``.mat``: MATLAB v5/v7 (a 128-byte header, "MATLAB 5.0 MAT-file …"; listed by
  :func:`scipy.io.whosmat`, values read by :mod:`phoid.io._mat5`) or MATLAB v7.3 (HDF5
  behind a 512-byte header; read by h5py);
* ``.h5``, ``.hdf5``: HDF5 (the signature ``\\x89HDF\\r\\n\\x1a\\n`` at offset 0, 512, 1024, …;
  read by h5py); datasets by name, nested paths ``"group/name"`` allowed;
* ``.parquet``: Apache Parquet (``PAR1`` at both ends; read by pyarrow); signals are columns,
  scalars are entries of the file's key-value metadata whose value is a number as text.

A signal is a real numeric vector, stored N×1, 1×N or 1-D; a matrix is refused, naming it.
A scalar (a gain) is a real number stored 1×1 (or with one element, any shape). The sizes are
checked before anything is read (:data:`~phoid.io.limits.MAX_DATA_BYTES` for the file and for
the values read, :data:`~phoid.io.limits.MAX_LINES` samples per run, the set's remaining
:data:`~phoid.io.limits.MAX_SET_ROWS`). Values are then read piece by piece (about a MiB at a
time) into float64 arrays of the declared size, ``t`` first, each piece checked as it comes
(finite; ``t`` strictly increasing): a file of zeros declared huge is refused at its first
piece, and memory is the signals kept (8 bytes per value) plus one piece. HDF5 links and
storage that lead outside the file (external links, external or virtual datasets) are
refused. h5py and pyarrow are optional
(``pip install 'phoid[io]'``) and imported only when such a file is read.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

import phoid.io.limits as limits
from phoid.errors import ExperimentError
from phoid.io._files import open_regular
from phoid.io._format import fail, show
from phoid.io._mat5 import check_mat5, read_values

__all__ = ["CONTAINER_SUFFIXES", "container_suffix", "read_container"]

CONTAINER_SUFFIXES = (".mat", ".h5", ".hdf5", ".parquet")
"""The data-file suffixes read by this module (tracking sets only)."""

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_PARQUET_MAGIC = b"PAR1"
_GZIP_MAGIC = b"\x1f\x8b"
_MAT5_VERSION = (b"\x00\x01IM", b"\x01\x00MI")  # bytes 124–127 of a v5 header
_NUMERIC = re.compile(r"\s*[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?\s*", re.ASCII)
_MAT_NUMERIC = ("double", "single", "int8", "uint8", "int16", "uint16", "int32", "uint32",
                "int64", "uint64")
_LISTED = 30  # names shown in a message
_WALKED = 10_000  # HDF5 objects visited to list a file's datasets
_PIECE = limits.BLOCK // 8  # samples read at a time (8 MiB of float64 at most per piece)

_DESCRIPTION = {"mat5": "a MATLAB v5 file", "mat73": "a MATLAB v7.3 file (HDF5)",
                "hdf5": "an HDF5 file", "parquet": "a Parquet file", "gzip": "a gzip file"}


def container_suffix(file: str) -> str | None:
    """The suffix of :data:`CONTAINER_SUFFIXES` that ``file`` ends in (any case), else None."""
    lower = file.lower()
    return next((s for s in CONTAINER_SUFFIXES if lower.endswith(s)), None)


def read_container(
    where: str,
    real: Path,
    file: str,
    *,
    columns: Mapping[str, str],
    required: Sequence[str],
    scalars: Mapping[str, str],
    max_rows: int = limits.MAX_SET_ROWS,
) -> tuple[dict[str, np.ndarray], dict[str, float], bytes]:
    """Read a run's signals and scalars from a ``.mat``, ``.h5``/``.hdf5`` or ``.parquet`` file.

    Parameters
    ----------
    where : str
        Prefix of the one-line :class:`~phoid.errors.ExperimentError` messages (manifest and
        run).
    real : pathlib.Path
        The file's resolved path (a regular file inside the set's folder).
    file : str
        The file's name as the manifest gives it (its suffix is the claimed format).
    columns : Mapping[str, str]
        Phoid name → variable name of each signal, in the order they are kept; ``t`` first.
    required : sequence of str
        The phoid names that must be in the file; the others are read when present.
    scalars : Mapping[str, str]
        Key (``"P"``, …) → variable name of each scalar to read.
    max_rows : int
        Most samples accepted (what the set's :data:`~phoid.io.limits.MAX_SET_ROWS` leaves).

    Returns
    -------
    signals : dict
        Phoid name → read-only float64 vector; every one of the same length, ``t`` strictly
        increasing, all finite.
    values : dict
        Key → the scalar's value (finite float).
    digest : bytes
        BLAKE2b digest of the signals read (to refuse one recording listed twice).
    """
    suffix = container_suffix(file) or ""
    f, st = open_regular(where, real, "data file")
    with f:
        if st.st_size > limits.MAX_DATA_BYTES:
            fail(where, f"the data file is larger than {limits.MAX_DATA_BYTES // 2**30} GiB, "
                         "phoid's limit for one run (MAX_DATA_BYTES)")
        if st.st_size == 0:
            fail(where, "the data file is empty")
        kind = _sniff(where, f, st.st_size)
        _check_claim(where, suffix, kind)
        try:
            if kind == "mat5":
                source: _Source = _Mat5(where, f, st.st_size)
            elif kind == "parquet":
                source = _Parquet(where, f)
            else:
                source = _Hdf5(where, f, matlab=(kind == "mat73"))
            with source:
                return _read(where, source, columns, required, scalars, max_rows)
        except MemoryError:
            fail(where, "not enough memory to hold the data file's variables")
        except ExperimentError:
            raise
        except Exception as exc:  # hostile input: what the libraries raise unforeseen
            fail(where, f"cannot read the data file: {_exc(exc)}")


def _sniff(where: str, f: BinaryIO, size: int) -> str | None:
    """What the file is by its content: mat5, mat73, hdf5, parquet, gzip or None."""
    try:
        head = f.read(128)
        if head.startswith(b"MATLAB 7.3") or _hdf5_at(f, 0, size, head):
            kind = "mat73" if head.startswith(b"MATLAB") else "hdf5"
            if kind == "hdf5" or _hdf5_at(f, 512, size):
                return kind
        if head.startswith(b"MATLAB 5.0") or head[124:128] in _MAT5_VERSION:
            return "mat5"
        if head.startswith(_PARQUET_MAGIC) and size >= 12:
            f.seek(size - 4)
            if f.read(4) == _PARQUET_MAGIC:
                return "parquet"
        if head.startswith(_GZIP_MAGIC):
            return "gzip"
        offset = 512
        while offset + 8 <= size and offset <= limits.BLOCK:
            if _hdf5_at(f, offset, size):
                return "hdf5"
            offset *= 2
        return None
    except OSError as exc:
        fail(where, f"cannot read the data file: {exc.strerror or exc}")
    finally:
        f.seek(0)


def _hdf5_at(f: BinaryIO, offset: int, size: int, head: bytes | None = None) -> bool:
    if head is not None and offset == 0:
        return head.startswith(HDF5_SIGNATURE)
    if offset + 8 > size:
        return False
    f.seek(offset)
    return f.read(8) == HDF5_SIGNATURE


def _check_claim(where: str, suffix: str, kind: str | None) -> None:
    """The content must be what the name's suffix claims."""
    fits = {".mat": ("mat5", "mat73", "hdf5"), ".h5": ("hdf5", "mat73"),
            ".hdf5": ("hdf5", "mat73"), ".parquet": ("parquet",)}[suffix]
    if kind in fits:
        return
    if kind is not None:
        fail(where, f"the data file is {_DESCRIPTION[kind]} by its content, although its name "
                     f"ends in {suffix}; rename it to what it is")
    if suffix == ".mat":
        fail(where, "the data file is not a MATLAB v5/v7 or v7.3 file (no 'MATLAB 5.0' or "
                     "HDF5 header); MAT v4 and other content are not read: save it with "
                     "save(..., '-v7') or '-v7.3'")
    if suffix == ".parquet":
        fail(where, "the data file is not a Parquet file (it lacks 'PAR1' at its start and "
                     "end)")
    fail(where, f"the data file is not an HDF5 file (it lacks the HDF5 signature), although "
                 f"its name ends in {suffix}")


# --------------------------------------------------------------------------------------------
# what the three formats share


class _Source:
    """A data file's variables: names, shapes before reading, values."""

    what = "variable"

    def __enter__(self) -> _Source:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:  # pragma: no cover - overridden where there is something to close
        pass

    def listing(self) -> str:
        names = sorted(self.names())
        text = ", ".join(show(n, 40)[1:-1] for n in names[:_LISTED])
        return (text + (", …" if len(names) > _LISTED else "")) or "nothing"

    def names(self) -> list[str]:
        raise NotImplementedError

    def shape(self, name: str, role: str) -> tuple[int, ...] | None:
        """The variable's shape (None: absent), after checking it holds real numbers."""
        raise NotImplementedError

    def pieces(self, name: str, n: int) -> Iterator[np.ndarray]:
        """The ``n`` values of a vector (its shape checked before), in order, in pieces of
        about :data:`_PIECE` values (any real type; one-dimensional or not, each piece is
        read in order): memory is one piece, not the variable."""
        raise NotImplementedError

    def scalar(self, name: str, key: str) -> float:
        """A scalar for the gain ``key`` (the variable must exist: checked before)."""
        shape = self.shape(name, key)
        assert shape is not None
        if int(np.prod(shape)) != 1:
            fail(self.where, f"{self.what} {show(name, 60)} for {key} is "
                              f"{_shape_text(shape)}, not a scalar (1×1)")
        out = np.empty(1)
        _fill(self, name, key, out, increasing=False, finite=False)
        value = float(out[0])
        if not np.isfinite(value):
            fail(self.where, f"{self.what} {show(name, 60)} for {key} is not finite: {value}")
        return value

    def has_scalar(self, name: str, key: str) -> bool:
        return self.shape(name, key) is not None

    def missing_scalar(self, name: str, key: str) -> str:
        return f"no {self.what} {show(name, 60)} for {key}; the file has: {self.listing()}"

    where: str


def _shape_text(shape: tuple[int, ...]) -> str:
    if not shape:
        return "a scalar"
    dims = "×".join(map(str, shape))
    return f"an empty {dims} array" if 0 in shape else f"a {dims} array"


def _read(where: str, source: _Source, columns: Mapping[str, str], required: Sequence[str],
          scalars: Mapping[str, str], max_rows: int
          ) -> tuple[dict[str, np.ndarray], dict[str, float], bytes]:
    """Check every variable's presence, type and shape, then read them."""
    lengths: dict[str, int] = {}
    for key, name in columns.items():
        shape = source.shape(name, key)
        if shape is None:
            if key in required or key == "t":
                fail(where, f"no {source.what} {show(name, 60)} for {key}; the file has: "
                             f"{source.listing()}")
            continue
        big = [d for d in shape if d != 1]
        if len(big) > 1 or 0 in shape or not shape:
            fail(where, f"{source.what} {show(name, 60)} for {key} is {_shape_text(shape)}, "
                         "not a vector (N×1 or 1×N)")
        lengths[key] = big[0] if big else 1
    n = lengths["t"]
    for key, m in lengths.items():
        if m != n:
            fail(where, f"{source.what} {show(columns[key], 60)} for {key} has {m} samples but "
                         f"{show(columns['t'], 60)} for t has {n}")
    if n > limits.MAX_LINES:
        fail(where, f"the data file's signals have {n:,} samples, more than phoid's limit for "
                     f"one run ({limits.MAX_LINES:,}, MAX_LINES)")
    if n > max_rows:
        fail(where, f"the set's data files hold more than {limits.MAX_SET_ROWS:,} data rows in "
                     "all (this one included), phoid's limit for one set (MAX_SET_ROWS)")
    if 8 * n * len(lengths) > limits.MAX_DATA_BYTES:
        fail(where, f"the signals read would take more than {limits.MAX_DATA_BYTES // 2**30} "
                     "GiB, phoid's limit for one run (MAX_DATA_BYTES)")
    values: dict[str, float] = {}
    for key, name in scalars.items():
        if not source.has_scalar(name, key):
            fail(where, source.missing_scalar(name, key))
        values[key] = source.scalar(name, key)
    digest = hashlib.blake2b(digest_size=32)
    signals: dict[str, np.ndarray] = {}
    for key in lengths:  # t first: a t that does not increase is refused at its first piece
        a = np.empty(n)
        _fill(source, columns[key], key, a, increasing=(key == "t"))
        a.flags.writeable = False
        signals[key] = a
        digest.update(f"{key}:{a.size};".encode())
        digest.update(memoryview(a).cast("B"))
    return signals, values, digest.digest()


def _fill(source: _Source, name: str, key: str, out: np.ndarray, *, increasing: bool,
          finite: bool = True) -> None:
    """Read a variable's values into ``out`` (float64, its declared size) piece by piece,
    checking each piece as it comes: finite, strictly increasing (``t``), no more values
    than declared. Nothing is held but ``out`` and one piece."""
    what, where, n = source.what, source.where, out.size
    at = 0
    for piece in source.pieces(name, n):
        piece = np.ravel(piece)
        if at + piece.size > n:  # the content contradicts the shape it declared
            fail(where, f"{what} {show(name, 60)} for {key}: it holds more values than its "
                         f"shape says ({n})")
        chunk = out[at:at + piece.size]
        with np.errstate(over="ignore", invalid="ignore"):  # a float128 beyond float64: inf
            np.copyto(chunk, piece, casting="unsafe")
        bad = ~np.isfinite(chunk) if finite else None
        if bad is not None and bad.any():
            i = int(np.argmax(bad))
            fail(where, f"{what} {show(name, 60)} for {key} has a non-finite value at index "
                         f"{at + i}: {chunk[i]}")
        if increasing and chunk.size:
            up = chunk[1:] > chunk[:-1]
            if at and not chunk[0] > out[at - 1]:
                _not_increasing(where, what, name, at, out)
            if not up.all():
                _not_increasing(where, what, name, at + int(np.argmin(up)) + 1, out)
        at += piece.size
    if at != n:
        fail(where, f"{what} {show(name, 60)} for {key}: read {at} values, its shape says {n}")


def _not_increasing(where: str, what: str, name: str, i: int, t: np.ndarray) -> None:
    fail(where, f"{what} {show(name, 60)} for t is not strictly increasing at index {i}: "
                 f"{float(t[i])!r} s follows {float(t[i - 1])!r} s")


def _exc(exc: BaseException) -> str:
    """A library's exception, for a message: its type and its text on one line."""
    return f"{type(exc).__name__}: {' '.join(str(exc).split())}"


def _missing_package(package: str, what: str) -> str:
    return (f"reading {what} needs the Python package {package}, which is not installed: "
            "pip install 'phoid[io]'")


# --------------------------------------------------------------------------------------------
# MATLAB v5/v7 (scipy.io)


class _Mat5(_Source):
    """A MATLAB v5/v7 file, listed and read by :mod:`phoid.io._mat5` (names, shapes and
    classes before any value; the values of the variables asked for, in blocks)."""

    def __init__(self, where: str, f: BinaryIO, size: int) -> None:
        self.where, self.f = where, f
        listed, self.located = check_mat5(where, f, size)
        self.vars = {name: (tuple(int(d) for d in shape), cls) for name, shape, cls in listed}
        names = [name for name, _, _ in listed]
        self.twice = {name for name in self.vars if names.count(name) > 1} \
            if len(self.vars) < len(names) else set()

    def names(self) -> list[str]:
        return list(self.vars)

    def shape(self, name: str, role: str) -> tuple[int, ...] | None:
        if name not in self.vars:
            return None
        if name in self.twice:
            fail(self.where, f"the MATLAB file holds two variables named {show(name, 60)}")
        shape, cls = self.vars[name]
        if cls not in _MAT_NUMERIC or name not in self.located:
            fail(self.where, f"variable {show(name, 60)} for {role} is a MATLAB {cls} array, "
                              "not real numbers")
        if self.located[name].complex:
            fail(self.where, f"variable {show(name, 60)} for {role} is complex, not real "
                              "numbers")
        return shape

    def pieces(self, name: str, n: int) -> Iterator[np.ndarray]:
        return read_values(self.where, self.f, self.located[name], name)


# --------------------------------------------------------------------------------------------
# HDF5 and MATLAB v7.3 (h5py)


class _Hdf5(_Source):
    """An HDF5 file (a MATLAB v7.3 file is one: its shapes are shown as MATLAB shows them,
    N×1 for what HDF5 stores 1×N)."""

    what = "dataset"

    def __init__(self, where: str, f: BinaryIO, *, matlab: bool) -> None:
        try:
            import h5py
        except ImportError:
            fail(where, _missing_package("h5py", "HDF5 and MATLAB v7.3 files"))
        self.where, self.matlab, self.h5py = where, matlab, h5py
        if matlab:
            self.what = "variable"
        try:
            self.file = h5py.File(f, "r")
        except Exception as exc:  # hostile input: HDF5 raises many kinds
            fail(where, f"cannot open the HDF5 file: {_exc(exc)}")

    def close(self) -> None:
        self.file.close()

    def names(self) -> list[str]:
        out: list[str] = []
        visited = 0
        stack = [("", self.file)]
        while stack and visited < _WALKED:
            prefix, group = stack.pop()
            try:
                items = list(group.items())
            except Exception:  # a broken or external member: not listed
                continue
            for key, obj in items:
                visited += 1
                if key.startswith("#"):  # MATLAB's #refs#, #subsystem#
                    continue
                if isinstance(obj, self.h5py.Group):
                    stack.append((f"{prefix}{key}/", obj))
                else:
                    out.append(prefix + key)
        return out

    def _dataset(self, name: str) -> Any:
        h5py = self.h5py
        path = name.strip("/")
        if not path:
            return None
        group = self.file
        parts = path.split("/")
        for i, part in enumerate(parts):
            try:
                link = group.get(part, getlink=True)
            except Exception:
                return None
            if link is None:
                return None
            if isinstance(link, h5py.ExternalLink):
                fail(self.where, f"{show(name, 60)} is an external link (to "
                                  f"{show(link.filename, 60)}): phoid reads only what is inside "
                                  "the data file")
            try:
                obj = group[part]
            except Exception as exc:
                fail(self.where, f"cannot open {show(name, 60)}: {_exc(exc)}")
            if i < len(parts) - 1:
                if not isinstance(obj, h5py.Group):
                    return None
                group = obj
        if isinstance(obj, h5py.Group):
            fail(self.where, f"{show(name, 60)} is a group, not a dataset; name a dataset "
                              "inside it, e.g. \"group/name\"")
        if not isinstance(obj, h5py.Dataset):  # pragma: no cover - committed datatypes
            fail(self.where, f"{show(name, 60)} is not a dataset")
        return obj

    def shape(self, name: str, role: str) -> tuple[int, ...] | None:
        ds = self._dataset(name)
        if ds is None:
            return None
        where = self.where
        if ds.is_virtual or ds.external:
            fail(where, f"{self.what} {show(name, 60)} for {role} keeps its data in other "
                         "files (a virtual or external dataset): phoid reads only what is "
                         "inside the data file")
        cls = ds.attrs.get("MATLAB_class") if self.matlab else None
        if isinstance(cls, bytes):
            cls = cls.decode("ascii", "replace")
        if cls is not None and str(cls) not in _MAT_NUMERIC:
            fail(where, f"variable {show(name, 60)} for {role} is a MATLAB {show(str(cls))} "
                         "array, not real numbers")
        if ds.dtype.kind not in "fiu" or ds.dtype.kind == "b":
            fail(where, f"{self.what} {show(name, 60)} for {role} holds {ds.dtype}, not real "
                         "numbers")
        if self.matlab and ds.attrs.get("MATLAB_empty", 0):
            return (0, 0)
        shape = tuple(int(d) for d in ds.shape)
        return shape[::-1] if self.matlab else shape

    def pieces(self, name: str, n: int) -> Iterator[np.ndarray]:
        ds = self._dataset(name)
        dims = ds.shape
        if not dims or n == 1:
            yield self._read(name, ds, ())
            return
        axis = next(i for i, d in enumerate(dims) if d != 1)
        step = _PIECE
        if ds.chunks:  # whole chunks per read: each decompressed once, whatever its shape
            size = ds.chunks[axis]
            step = max(size, step // size * size)
        for start in range(0, n, step):
            stop = min(start + step, n)
            yield self._read(name, ds, tuple(slice(start, stop) if i == axis else 0
                                             for i in range(len(dims))))

    def _read(self, name: str, ds: Any, index: tuple[Any, ...]) -> np.ndarray:
        try:
            return np.asarray(ds[index])
        except Exception as exc:  # hostile input: a corrupt chunk, a failing filter
            fail(self.where, f"cannot read {self.what} {show(name, 60)}: {_exc(exc)}")


# --------------------------------------------------------------------------------------------
# Parquet (pyarrow)


class _Parquet(_Source):
    """A Parquet file: signals are columns, scalars key-value metadata entries."""

    what = "column"

    def __init__(self, where: str, f: BinaryIO) -> None:
        try:
            import pyarrow.parquet as pq
        except ImportError:
            fail(where, _missing_package("pyarrow", "Parquet files"))
        self.where = where
        try:
            self.file = pq.ParquetFile(f)
            self.schema = self.file.schema_arrow
            meta = self.file.metadata
            self.rows = int(meta.num_rows)
            groups = [int(meta.row_group(i).num_rows) for i in range(meta.num_row_groups)]
            raw = meta.metadata or {}
        except Exception as exc:  # hostile input: pyarrow raises many kinds
            fail(where, f"cannot read the Parquet file: {_exc(exc)}")
        if sum(groups) != self.rows or min(groups, default=0) < 0:
            fail(where, f"the Parquet file declares {self.rows} rows, but its row groups "
                         f"{sum(groups)}: the file is damaged")
        self.meta = {k.decode("utf-8", "replace"): v for k, v in raw.items()
                     if k not in (b"ARROW:schema", b"pandas")}

    def close(self) -> None:
        self.file.close()

    def names(self) -> list[str]:
        return list(self.schema.names)

    def shape(self, name: str, role: str) -> tuple[int, ...] | None:
        import pyarrow as pa

        count = self.schema.names.count(name)
        if count > 1:
            fail(self.where, f"the file has {count} columns named {show(name, 60)}")
        if not count:
            return None
        kind = self.schema.field(name).type
        if not (pa.types.is_floating(kind) or pa.types.is_integer(kind)):
            fail(self.where, f"column {show(name, 60)} for {role} holds {kind}, not real "
                              "numbers")
        return (self.rows,)

    def pieces(self, name: str, n: int) -> Iterator[np.ndarray]:
        at = 0
        batches = self.file.iter_batches(batch_size=_PIECE, columns=[name], use_threads=False)
        while True:
            try:
                batch = next(batches, None)
            except Exception as exc:  # hostile input
                fail(self.where, f"cannot read column {show(name, 60)}: {_exc(exc)}")
            if batch is None:
                return
            column = batch.column(0)
            if column.null_count:
                i = int(np.flatnonzero(column.is_null().to_numpy(zero_copy_only=False))[0])
                fail(self.where, f"column {show(name, 60)} has a missing (null) value at index "
                                  f"{at + i}")
            at += len(column)
            yield column.to_numpy(zero_copy_only=False)

    def scalar(self, name: str, key: str) -> float:
        text = self.meta[name].decode("utf-8", "replace")
        if not _NUMERIC.fullmatch(text):
            fail(self.where, f"metadata entry {show(name, 60)} for {key} is {show(text)}, not "
                              "a finite number")
        return float(text)

    def missing_scalar(self, name: str, key: str) -> str:
        listed = ", ".join(show(k, 40)[1:-1] for k in sorted(self.meta)[:_LISTED]) or "nothing"
        note = (f" ({show(name, 60)} is a column, not a scalar)"
                if name in self.schema.names else "")
        return (f"no scalar {show(name, 60)} for {key} in the file's key-value metadata, where "
                f"a Parquet file keeps its scalars{note}; the metadata has: {listed}")

    def has_scalar(self, name: str, key: str) -> bool:
        return name in self.meta
