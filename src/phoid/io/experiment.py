"""Experiment sets in the ``phoid/1`` format: read, validate and write.

The format is defined in one place, ``docs/format.md`` in the repository: the manifest's keys
(with the extensions ``added_mass``, ``bias``, ``mass`` and the digital ``[loop]`` keys), the
data files, the rules this reader applies, and the JSON that ``phoid identify --json`` prints.
In short: an experiment set is a folder holding one manifest, ``experiment.toml``, and one data
file per run::

    title  = "Linear stage, PHO sweep"   # optional
    format = "phoid/1"                   # optional; when present it must be "phoid/1"
    method = "pho"                       # "pho" (default) | "forced" | "free"

    [loop]
    delay = 0.1                          # s; omitted: to be estimated from the data

    [[run]]
    file = "run01.csv.gz"                # relative to the manifest; .csv or .csv.gz
    P = 0.25                             # N/m
    D = 0.6                              # N·s/m

Each data file is comma-separated text whose first line names the columns: ``t`` (s, strictly
increasing) and ``x`` (m) always, ``u`` (N, the feedback force actually applied) optionally,
``F`` (N, the external force) for forced runs. Extra columns are ignored.

This module checks what can be checked without knowing the method's model: the keys, their
types and ranges, their letter case (a key that differs from a known one only in letter case is
an error), the data files' paths, compression, text and cells. It keeps the whole ``[loop]`` table
(:attr:`ExperimentSet.loop`; only ``delay`` is checked here, the identification checks the
rest) and every unknown key (:attr:`ExperimentSet.extra`, :attr:`Run.extra`), so that tools can
store their own information in a set.

Every problem raises :class:`phoid.errors.ExperimentError` (a ``ValueError``) with a one-line
message naming the manifest, the run and the key, column or line, e.g.
``paper-sample/experiment.toml: run 3 (run03.csv.gz): column 'x' has a non-numeric cell at
line 57: 'abc'``.

Numbers are parsed by :func:`numpy.loadtxt` (C-accelerated, correctly rounded) and written in
the shortest form that reads back to the same double, so that :func:`write_experiment` followed
by :func:`read_experiment` reproduces every array bit for bit.
"""

from __future__ import annotations

import bisect
import codecs
import dataclasses
import gzip as _gzip
import hashlib
import io as _io
import itertools
import math
import numbers
import os
import re
import stat
import tomllib
import zlib
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any, BinaryIO, NoReturn

import numpy as np
import tomli_w

from phoid._output import OutputFolder
from phoid.errors import ExperimentError

__all__ = [
    "FORMAT",
    "MANIFEST",
    "METHODS",
    "ExperimentSet",
    "Run",
    "read_experiment",
    "read_manifest",
    "run_from_arrays",
    "write_experiment",
]

FORMAT = "phoid/1"
"""The value of the manifest's ``format`` key."""
MANIFEST = "experiment.toml"
"""The manifest's file name inside an experiment-set folder."""
METHODS = ("pho", "forced", "free")
"""The values of the manifest's ``method`` key."""

_TOP_KEYS = ("title", "format", "method", "loop", "run", "mass")
_RUN_KEYS = ("file", "P", "D", "B", "omega", "added_mass", "bias")
_LOOP_KEYS = ("delay",)
_COLUMNS = ("t", "x", "u", "F")
_UNITS = {"P": "N/m", "D": "N·s/m", "B": "N", "omega": "rad/s", "added_mass": "kg",
          "bias": "N", "delay": "s", "mass": "kg"}
_GZIP_MAGIC = b"\x1f\x8b"
_MAX_MESSAGE = 2000  # characters of one error message

# Limits of the reader (docs/limits.md): every read stops at the limit (at most one
# block of _BLOCK bytes past it), so that no input can make phoid read, decompress or hold
# without bound. Generous for real recordings: a 10 kHz, 1-hour run is 3.6e7 rows.
MAX_MANIFEST_BYTES = 2 * 2**20
"""Largest manifest (``experiment.toml``) read, bytes (2 MiB: about 40 000 ``[[run]]`` tables;
Python's TOML parser needs up to about 10 s for 2 MiB of dense arrays)."""
MAX_NESTING = 32
"""Deepest nesting of tables and arrays in a manifest."""
MAX_RUNS = 20_000
"""Most ``[[run]]`` tables in one set."""
MAX_LINES = 50_000_000
"""Most lines in one data file: the header, the data rows and the blank lines (5e7)."""
MAX_LINE_BYTES = 2**20
"""Longest line of a data file, bytes (1 MiB)."""
MAX_DATA_BYTES = 4 * 2**30
"""Largest data file, bytes after decompression (4 GiB)."""
MAX_SET_ROWS = 200_000_000
"""Most data rows in all the runs of one set together (2e8: 4.8 GB as t, x, u doubles)."""
_BLOCK = 2**20  # bytes read (or decompressed) at a time: memory while reading is this + the data
_NUMBER_RE = re.compile(
    # one way to match each number (\d+(?:\.\d*)?, not \d+\.?\d*): a long run of digits that
    # fails to match costs linear, not quadratic, time (a 1 MiB cell took minutes)
    r"[+-]?(?:(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?|inf(?:inity)?|nan)", re.IGNORECASE
)


# --------------------------------------------------------------------------------------------
# small helpers
# --------------------------------------------------------------------------------------------
def _fail(where: str, message: str) -> NoReturn:
    """Raise ExperimentError("where: message") on one printable line."""
    text = f"{where}: {message}" if where else message
    raise ExperimentError(_printable(text, _MAX_MESSAGE)) from None


def _printable(text: str, limit: int = 120) -> str:
    """``text`` with every non-printable character escaped as ``repr`` does, length-capped.

    Messages quote file names, keys and cells from the input: a NUL byte, a terminal escape
    sequence or a line break in them must not reach the user's terminal raw, and a 10 MB cell
    must not make a 10 MB message.
    """
    if not text.isprintable():
        text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _show(value: Any, limit: int = 60) -> str:
    """A short, one-line rendering of a (TOML or cell) value for messages."""
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, str | bytes):
        text = repr(value[: 4 * limit])
    elif isinstance(value, numbers.Real):
        text = repr(float(value)) if isinstance(value, float) else repr(value)
    elif isinstance(value, Mapping | list | tuple):
        text = f"{_kind(value)} of {len(value)} item(s)"
    else:
        text = repr(value)
    return _printable(text, limit)


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, Mapping):
        return "a table"
    if isinstance(value, list | tuple):
        return "an array"
    return f"a {type(value).__name__}"


def _number(
    where: str, key: str, value: Any, *, minimum: float | None = None, strict: bool = False
) -> float:
    """Check a manifest/run number: a real, finite, and ≥ (or >) ``minimum`` when given."""
    unit = _UNITS.get(key, "")
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        _fail(where, f"key '{key}' must be a number; got {_show(value)} ({_kind(value)})")
    v = float(value)
    if not math.isfinite(v):
        _fail(where, f"key '{key}' must be finite; got {v}")
    if minimum is not None:
        ok = v > minimum if strict else v >= minimum
        if not ok:
            rel = ">" if strict else "≥"
            _fail(where, f"key '{key}' must be {rel} {minimum:g}{' ' + unit if unit else ''}; "
                         f"got {v!r}")
    return v


def _optional_number(where: str, key: str, value: Any, **kw: Any) -> float | None:
    return None if value is None else _number(where, key, value, **kw)


def _checked_extra(where: str, extra: Any, known: Any, what: str) -> Mapping[str, Any]:
    """Validate the unknown keys kept beside a table's known ones and freeze them."""
    extra = extra if extra is not None else {}
    if not isinstance(extra, Mapping):
        _fail(where, f"`extra` must be a mapping; got {_kind(extra)}")
    for k in extra:
        if not isinstance(k, str) or k in known:
            _fail(where, f"`extra` may not hold the key {_show(k)}: it is not an extra key")
    _case_clash(where, extra, known, what)
    return _freeze(extra)


def _case_clash(where: str, keys: Iterable[str], known: Sequence[str], table: str) -> None:
    """Reject keys that differ from a known key only by letter case."""
    lower = {k.lower(): k for k in known}
    for k in keys:
        if k not in known and k.lower() in lower:
            _fail(where, f"unknown key '{k}' in {table}: keys are case-sensitive; "
                         f"did you mean '{lower[k.lower()]}'?")


def _unknown_hint(keys: Iterable[str], known: Sequence[str]) -> str:
    unknown = [k for k in keys if k not in known]
    return f" (the table has unknown keys {', '.join(map(repr, unknown))})" if unknown else ""


class _FrozenMap(Mapping[str, Any]):
    """A read-only, picklable mapping (nested tables frozen, arrays turned into tuples)."""

    __slots__ = ("_data",)

    def __init__(self, data: Mapping[str, Any] | None = None) -> None:
        self._data = {str(k): _freeze(v) for k, v in (data or {}).items()}

    def __getitem__(self, key: str) -> Any:
        return self._data[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)

    def __repr__(self) -> str:
        return repr(self._data)

    def __reduce__(self) -> tuple[Any, ...]:
        return (_FrozenMap, (self._data,))


def _freeze(value: Any) -> Any:
    if isinstance(value, Mapping):
        return value if isinstance(value, _FrozenMap) else _FrozenMap(value)
    if isinstance(value, list | tuple):
        return tuple(_freeze(v) for v in value)
    return value


def _thaw(value: Any) -> Any:
    """Back to plain dicts and lists (for tomli_w)."""
    if isinstance(value, Mapping):
        return {str(k): _thaw(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_thaw(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _frozen_array(where: str, name: str, value: Any, n: int | None) -> np.ndarray:
    """A read-only, 1-D, finite float64 array (copied unless it already is one)."""
    if (isinstance(value, np.ndarray) and value.dtype == np.float64 and value.ndim == 1
            and not value.flags.writeable and value.flags.c_contiguous):
        a = value
    else:
        try:
            a = np.array(value, dtype=np.float64, copy=True)
        except (TypeError, ValueError):
            _fail(where, f"column '{name}' must be an array of real numbers")
        if a.ndim != 1:
            _fail(where, f"column '{name}' must be 1-dimensional; got shape {a.shape}")
        a.flags.writeable = False
    if n is not None and a.size != n:
        _fail(where, f"column '{name}' has {a.size} samples but 't' has {n}")
    if not np.isfinite(a).all():
        i = int(np.flatnonzero(~np.isfinite(a))[0])
        _fail(where, f"column '{name}' has a non-finite value at index {i}: {a[i]}")
    return a


# --------------------------------------------------------------------------------------------
# the values
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False, repr=False)
class Run:
    """One recorded run: a free decay (``pho``, ``free``) or a forced response (``forced``).

    Arrays are stored as read-only float64 copies (an array that already is read-only, 1-D,
    C-contiguous float64 is kept as it is). Construction validates everything it can check
    without knowing the set's method (see :func:`run_from_arrays`); raises
    :class:`~phoid.errors.ExperimentError`.

    Attributes
    ----------
    file : str
        Path of the data file relative to the manifest, as written there ("" for a run made
        in memory).
    t : numpy.ndarray
        Sample times (s), finite and strictly increasing; at least 2 samples.
    x : numpy.ndarray
        Position of the mass (m), same length as ``t``.
    u : numpy.ndarray or None
        Feedback force actually applied (N), optional column.
    F : numpy.ndarray or None
        External (forcing) force (N); required for forced runs.
    P : float or None
        Proportional gain of the run (N/m); required for ``pho`` runs.
    D : float or None
        Derivative gain of the run (N·s/m); required for ``pho`` runs.
    B : float or None
        Forcing amplitude (N), forced runs, optional (else taken from ``F``).
    omega : float or None
        Forcing angular frequency (rad/s, > 0), forced runs, optional.
    added_mass : float
        Known mass added for this run (kg, ≥ 0); format extension, default 0.
    bias : float
        Known DC offset b (N, ≥ 0) added to the run's command in the direction of the
        controller's velocity, +b·sign(ẋ(t − Δt)); format extension, default 0.
    index : int
        1-based position of the run in the manifest (0: not from a manifest).
    extra : Mapping[str, Any]
        Keys of the run's table that phoid/1 does not define, kept as read.
    """

    file: str
    t: np.ndarray
    x: np.ndarray
    u: np.ndarray | None = None
    F: np.ndarray | None = None
    P: float | None = None
    D: float | None = None
    B: float | None = None
    omega: float | None = None
    added_mass: float = 0.0
    bias: float = 0.0
    index: int = 0
    extra: Mapping[str, Any] = field(default_factory=_FrozenMap)

    def __post_init__(self) -> None:
        if not isinstance(self.file, str):
            raise ExperimentError(f"run: `file` must be a string; got {_show(self.file)}")
        if isinstance(self.index, bool) or not isinstance(self.index, numbers.Integral) \
                or self.index < 0:
            raise ExperimentError(f"run: `index` must be an integer ≥ 0; got {_show(self.index)}")
        object.__setattr__(self, "index", int(self.index))
        where = self.name
        t = _frozen_array(where, "t", self.t, None)
        if t.size < 2:
            _fail(where, f"column 't' has {t.size} sample(s); at least 2 are needed")
        d = np.diff(t)
        if not (d > 0).all():
            i = int(np.flatnonzero(~(d > 0))[0])
            _fail(where, f"column 't' is not strictly increasing at index {i + 1}: "
                         f"{float(t[i + 1])!r} s follows {float(t[i])!r} s")
        set_ = object.__setattr__
        set_(self, "t", t)
        set_(self, "x", _frozen_array(where, "x", self.x, t.size))
        for name in ("u", "F"):
            value = getattr(self, name)
            if value is not None:
                set_(self, name, _frozen_array(where, name, value, t.size))
        set_(self, "P", _optional_number(where, "P", self.P))
        set_(self, "D", _optional_number(where, "D", self.D))
        set_(self, "B", _optional_number(where, "B", self.B))
        set_(self, "omega", _optional_number(where, "omega", self.omega, minimum=0.0,
                                             strict=True))
        set_(self, "added_mass", _number(where, "added_mass", self.added_mass, minimum=0.0))
        set_(self, "bias", _number(where, "bias", self.bias, minimum=0.0))
        set_(self, "extra", _checked_extra(where, self.extra, _RUN_KEYS, "the run's table"))

    @property
    def name(self) -> str:
        """How messages name the run, e.g. ``"run 3 (run03.csv.gz)"``."""
        text = "run" + (f" {self.index}" if self.index else "")
        return text + (f" ({_printable(self.file, 80)})" if self.file else "")

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.t.size)

    def __repr__(self) -> str:
        gains = ", ".join(f"{k}={getattr(self, k)!r}" for k in ("P", "D", "B", "omega")
                          if getattr(self, k) is not None)
        cols = "t,x" + (",u" if self.u is not None else "") + (",F" if self.F is not None else "")
        return (f"Run({self.name}: {self.n} samples of {cols}, t = {self.t[0]:g}…{self.t[-1]:g}"
                f" s{', ' + gains if gains else ''})")


@dataclass(frozen=True, eq=False, repr=False)
class ExperimentSet:
    """An experiment set: the manifest's settings and its runs, in manifest order.

    Construction checks the settings and what the method requires of every run (``pho``:
    ``P`` and ``D``; ``forced``: an ``F`` column); raises
    :class:`~phoid.errors.ExperimentError`.

    Attributes
    ----------
    path : pathlib.Path
        The manifest's path (as given, not resolved).
    runs : tuple of Run
        The runs, at least one.
    method : {"pho", "forced", "free"}
        How the runs were excited.
    delay : float or None
        Feedback-loop delay Δt (s, ≥ 0) from ``[loop] delay``; None when omitted (to be
        estimated). When ``loop`` holds ``delay`` too, the two must agree.
    title : str or None
        The set's title.
    mass : float or None
        Known mass (kg, > 0), top-level ``mass`` key (format extension, for free decays).
    loop : Mapping[str, Any]
        The whole ``[loop]`` table as read (future keys kept).
    extra : Mapping[str, Any]
        Unknown top-level keys of the manifest, kept as read.
    """

    path: Path
    runs: tuple[Run, ...]
    method: str = "pho"
    delay: float | None = None
    title: str | None = None
    mass: float | None = None
    loop: Mapping[str, Any] = field(default_factory=_FrozenMap)
    extra: Mapping[str, Any] = field(default_factory=_FrozenMap)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "path", Path(self.path))
        where = str(self.path)
        if self.method not in METHODS:
            _fail(where, f"key 'method' must be one of {', '.join(map(repr, METHODS))}; "
                         f"got {_show(self.method)}")
        if self.title is not None and not isinstance(self.title, str):
            _fail(where, f"key 'title' must be a string; got {_show(self.title)} "
                         f"({_kind(self.title)})")
        loop = self.loop if self.loop is not None else {}
        if not isinstance(loop, Mapping):
            _fail(where, f"'loop' must be a table ([loop]); got {_kind(loop)}")
        delay = _optional_number(where, "delay", self.delay, minimum=0.0)
        if "delay" in loop:
            in_loop = _number(f"{where}: [loop]", "delay", loop["delay"], minimum=0.0)
            if delay is None:
                delay = in_loop
            elif delay != in_loop:
                _fail(where, f"`delay` = {delay!r} s disagrees with [loop] delay = "
                             f"{in_loop!r} s")
        set_(self, "delay", delay)
        set_(self, "mass", _optional_number(where, "mass", self.mass, minimum=0.0,
                                            strict=True))
        set_(self, "loop", _freeze(loop))
        set_(self, "extra", _checked_extra(where, self.extra, _TOP_KEYS, "the manifest"))
        runs = tuple(self.runs) if isinstance(self.runs, Iterable) else self.runs
        if not isinstance(runs, tuple) or not runs:
            _fail(where, "no runs: the manifest needs at least one [[run]] table")
        for r in runs:
            if not isinstance(r, Run):
                _fail(where, f"`runs` must hold Run objects; got {_kind(r)}")
            _check_method_needs(f"{where}: {r.name}", r, self.method)
        set_(self, "runs", runs)

    @property
    def folder(self) -> Path:
        """The set's folder (the manifest's parent)."""
        return self.path.parent

    def __len__(self) -> int:
        return len(self.runs)

    def __repr__(self) -> str:
        return (f"ExperimentSet({str(self.path)!r}, method={self.method!r}, "
                f"delay={self.delay!r}, {len(self.runs)} runs"
                f"{', title=' + repr(self.title) if self.title else ''})")


def _check_method_needs(where: str, run: Run, method: str) -> None:
    if method == "pho":
        for key in ("P", "D"):
            if getattr(run, key) is None:
                hint = _unknown_hint(run.extra, ())
                _fail(where, f"missing key '{key}': a pho run needs the gains P (N/m) and "
                             f"D (N·s/m){hint}")
    elif method == "forced" and run.F is None:
        _fail(where, "missing column 'F': a forced run needs the external force F (N)")


def run_from_arrays(
    t: Any,
    x: Any,
    *,
    u: Any = None,
    F: Any = None,
    P: float | None = None,
    D: float | None = None,
    B: float | None = None,
    omega: float | None = None,
    added_mass: float = 0.0,
    bias: float = 0.0,
    file: str = "",
    index: int = 0,
    extra: Mapping[str, Any] | None = None,
) -> Run:
    """Make a :class:`Run` from arrays, checked as the reader checks a data file.

    Parameters
    ----------
    t : array_like
        Sample times (s), finite, strictly increasing, at least 2.
    x : array_like
        Position (m), same length as ``t``.
    u, F : array_like, optional
        Applied feedback force and external force (N), same length as ``t``.
    P, D : float, optional
        Gains (N/m, N·s/m); needed for a ``pho`` set.
    B, omega : float, optional
        Forcing amplitude (N) and angular frequency (rad/s, > 0).
    added_mass : float, default 0
        Known added mass (kg, ≥ 0).
    bias : float, default 0
        Known DC offset of the command in the direction of the velocity (N, ≥ 0).
    file : str, default ""
        Data-file name, used in messages (and kept by :func:`write_experiment` only when
        passed as ``names``).
    index : int, default 0
        1-based position in a set, for messages.
    extra : Mapping, optional
        Unknown run keys to keep.

    Returns
    -------
    Run

    Raises
    ------
    ExperimentError
        On NaN/inf, unequal lengths, non-increasing ``t``, bad gains.

    Examples
    --------
    >>> import numpy as np
    >>> run = run_from_arrays(np.arange(3) * 1e-3, [0.0, 1e-3, 2e-3], P=1.0, D=0.5)
    >>> run.x.dtype, run.x.flags.writeable
    (dtype('float64'), False)
    """
    return Run(file=file, t=t, x=x, u=u, F=F, P=P, D=D, B=B, omega=omega,
               added_mass=added_mass, bias=bias, index=index,
               extra=_FrozenMap() if extra is None else extra)


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------
def read_experiment(path: str | os.PathLike[str]) -> ExperimentSet:
    """Read an experiment set in the ``phoid/1`` format.

    Every file is read in blocks and checked against the reader's limits while it is read
    (:data:`MAX_MANIFEST_BYTES`, :data:`MAX_NESTING`, :data:`MAX_RUNS`, :data:`MAX_LINES`,
    :data:`MAX_LINE_BYTES`, :data:`MAX_DATA_BYTES`, :data:`MAX_SET_ROWS`): memory stays
    proportional to the rows accepted, whatever the input. Only regular files are opened
    (a named pipe or a device is refused before it is read).

    Parameters
    ----------
    path : str or os.PathLike
        The set's folder (holding ``experiment.toml``) or the manifest's path.

    Returns
    -------
    ExperimentSet
        The runs in manifest order; arrays in SI units (s, m, N), read-only.

    Raises
    ------
    ExperimentError
        For every problem with the manifest or a data file; the one-line message names the
        manifest, the run (``run 3 (run03.csv.gz)``) and the key, column or line at fault.

    Examples
    --------
    >>> exp = read_experiment("examples/paper-sample")  # the repository's example  # doctest: +SKIP
    >>> exp.runs[2].name, exp.runs[2].P, exp.delay  # doctest: +SKIP
    ('run 3 (run03.csv.gz)', 3.0, 0.1)
    """
    given = Path(path)
    manifest = given / MANIFEST if given.is_dir() else given
    where = str(manifest)
    if not manifest.exists():
        if given.is_dir():
            _fail(where, f"manifest not found: the folder has no {MANIFEST}")
        _fail(where, "no such file or folder")
    if manifest.is_dir():
        _fail(where, "the manifest is a folder, not a file")
    doc = read_manifest(where, manifest)

    _case_clash(where, doc, _TOP_KEYS, "the manifest")
    fmt = doc.get("format", FORMAT)
    if fmt != FORMAT:
        _fail(where, f"key 'format' must be {FORMAT!r}; got {_show(fmt)} "
                     "(this phoid reads only phoid/1 sets)")
    method = doc.get("method", "pho")
    if method not in METHODS:
        _fail(where, f"key 'method' must be one of {', '.join(map(repr, METHODS))}; "
                     f"got {_show(method)}")
    title = doc.get("title")
    if title is not None and not isinstance(title, str):
        _fail(where, f"key 'title' must be a string; got {_show(title)} ({_kind(title)})")
    mass = _optional_number(where, "mass", doc.get("mass"), minimum=0.0, strict=True)
    loop = doc.get("loop", {})
    if not isinstance(loop, dict):
        _fail(where, f"'loop' must be a table ([loop]); got {_kind(loop)}")
    _case_clash(f"{where}: [loop]", loop, _LOOP_KEYS, "[loop]")
    delay = _optional_number(f"{where}: [loop]", "delay", loop.get("delay"), minimum=0.0)

    tables = doc.get("run")
    if tables is None:
        hint = _unknown_hint(doc, _TOP_KEYS)
        _fail(where, f"no runs: the manifest has no [[run]] tables{hint}")
    if not isinstance(tables, list) or not all(isinstance(r, dict) for r in tables):
        _fail(where, "'run' must be an array of tables ([[run]] … [[run]])")
    if not tables:
        _fail(where, "no runs: 'run' is empty")

    specs = [_run_spec(where, i, table, method) for i, table in enumerate(tables, start=1)]
    folder = manifest.parent
    root = _resolve(where, folder)
    seen: dict[Path, str] = {}
    inodes: dict[tuple[int, int], dict[str, Any]] = {}
    for spec in specs:
        rwhere = f"{where}: {spec['name']}"
        real, st = _data_path(rwhere, folder, root, spec["file"])
        if real in seen:
            _fail(rwhere, f"file {_show(spec['file'], 100)} is already used by {seen[real]}")
        other = inodes.get((st.st_dev, st.st_ino))
        if other is not None:
            _fail(rwhere, f"file {_show(spec['file'], 100)} is a hard link to "
                          f"{_show(other['file'], 100)} of {other['name']}: the same recording "
                          "would be counted twice; list each recording once")
        seen[real] = spec["name"]
        inodes[(st.st_dev, st.st_ino)] = spec
        spec["where"], spec["real"] = rwhere, real

    runs = []
    digests: dict[bytes, dict[str, Any]] = {}
    budget = MAX_SET_ROWS
    for spec in specs:
        cols, digest = _read_csv(spec["where"], spec["real"], spec["file"],
                                 need_F=(method == "forced"), max_rows=budget)
        budget -= cols["t"].size
        other = digests.get(digest)
        if other is not None:
            _fail(spec["where"], f"the data file has the same content, byte for byte, as "
                                 f"{other['name']}'s: a copy (or a noise-free repeat of a "
                                 "simulated run) would be counted twice; list each recording "
                                 "once")
        digests[digest] = spec
        try:
            runs.append(Run(file=spec["file"], index=spec["index"], extra=spec["extra"],
                            P=spec["P"], D=spec["D"], B=spec["B"], omega=spec["omega"],
                            added_mass=spec["added_mass"], bias=spec["bias"], **cols))
        except ExperimentError as exc:  # pragma: no cover - the reader checks first
            _fail(where, str(exc))
    try:
        return ExperimentSet(path=manifest, runs=tuple(runs), method=method, delay=delay,
                             title=title, mass=mass, loop=loop,
                             extra={k: v for k, v in doc.items() if k not in _TOP_KEYS})
    except ExperimentError as exc:  # pragma: no cover - the reader checks first
        raise ExperimentError(str(exc)) from None


_FILE_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a named pipe (FIFO)"),
               (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
               (stat.S_ISSOCK, "a socket"))


def _not_regular(mode: int) -> str | None:
    """What a non-regular file is ("a named pipe (FIFO)", …); None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    return next((name for test, name in _FILE_KINDS if test(mode)), "not a regular file")


def _open_regular(where: str, path: Path, what: str) -> tuple[BinaryIO, os.stat_result]:
    """Open a regular file for reading, refusing anything else before it is read.

    A named pipe would block the read forever and a device (``/dev/zero``) would never end:
    the file's type is checked (after symbolic links are resolved) before it is opened, and
    again on the open file (non-blocking open, so that a pipe swapped in meanwhile cannot
    block either).
    """
    try:
        kind = _not_regular(os.stat(path).st_mode)
    except OSError as exc:
        _fail(where, f"cannot read the {what}: {exc.strerror or exc}")
    if kind is not None:
        _fail(where, f"the {what} is {kind}, not a regular file; phoid reads only regular "
                     "files")
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) \
        | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        _fail(where, f"cannot read the {what}: {exc.strerror or exc}")
    try:
        st = os.fstat(fd)
        kind = _not_regular(st.st_mode)
        if kind is not None:
            _fail(where, f"the {what} is {kind}, not a regular file; phoid reads only "
                         "regular files")
        return os.fdopen(fd, "rb"), st
    except BaseException:
        os.close(fd)
        raise


def read_manifest(where: str, manifest: Path) -> dict[str, Any]:
    """Read and parse a manifest: a regular file of at most MAX_MANIFEST_BYTES, UTF-8 TOML,
    nested at most MAX_NESTING levels deep (docs/limits.md).

    The one manifest reader: :func:`read_experiment` and :func:`phoid.planning.sweep.read_schedule`
    both read through it. ``where`` prefixes the one-line :class:`ExperimentError` it raises.
    """
    f, st = _open_regular(where, manifest, "manifest")
    with f:
        if st.st_size > MAX_MANIFEST_BYTES:
            raw = b""
        else:
            try:
                raw = f.read(MAX_MANIFEST_BYTES + 1)
            except OSError as exc:
                _fail(where, f"cannot read the manifest: {exc.strerror or exc}")
    if st.st_size > MAX_MANIFEST_BYTES or len(raw) > MAX_MANIFEST_BYTES:
        _fail(where, f"the manifest is larger than {MAX_MANIFEST_BYTES // 2**20} MiB, phoid's "
                     "limit for experiment.toml (MAX_MANIFEST_BYTES)")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        _fail(where, f"the manifest is not UTF-8 text (bad byte at line {line})")
    too_deep = (f"the manifest nests tables or arrays more than {MAX_NESTING} levels deep, "
                "phoid's limit (MAX_NESTING)")
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        _fail(where, f"not valid TOML, TOML syntax error: {exc}")
    except RecursionError:  # tomllib parses nested arrays and inline tables recursively
        _fail(where, too_deep)
    if _depth(doc) > MAX_NESTING:
        _fail(where, too_deep)
    tables = doc.get("run")
    if isinstance(tables, list) and len(tables) > MAX_RUNS:
        _fail(where, f"the manifest has {len(tables):,} [[run]] tables; phoid reads at most "
                     f"{MAX_RUNS:,} runs per set (MAX_RUNS)")
    return doc


def _depth(doc: Any) -> int:
    """Nesting depth of tables and arrays (iterative: no recursion limit to hit)."""
    deepest = 0
    stack = [(doc, 1)]
    while stack:
        value, level = stack.pop()
        if level > deepest:
            deepest = level
            if deepest > MAX_NESTING:
                break
        children = value.values() if isinstance(value, dict) else value
        stack.extend((v, level + 1) for v in children if isinstance(v, dict | list))
    return deepest


def _run_spec(where: str, index: int, table: dict[str, Any], method: str) -> dict[str, Any]:
    """Check one [[run]] table (before any data is read)."""
    file = table.get("file")
    name = f"run {index}" + (f" ({_printable(file, 80)})" if isinstance(file, str) and file
                             else "")
    rwhere = f"{where}: {name}"
    _case_clash(rwhere, table, _RUN_KEYS, "the run's table")
    if file is None:
        _fail(rwhere, f"missing key 'file'{_unknown_hint(table, _RUN_KEYS)}")
    if not isinstance(file, str):
        _fail(rwhere, f"key 'file' must be a string; got {_show(file)} ({_kind(file)})")
    if not file.strip():
        _fail(rwhere, "key 'file' is empty")
    if method == "pho":
        for key in ("P", "D"):
            if key not in table:
                _fail(rwhere, f"missing key '{key}': a pho run needs the gains P (N/m) and "
                              f"D (N·s/m){_unknown_hint(table, _RUN_KEYS)}")
    spec: dict[str, Any] = {"file": file, "index": index, "name": name}
    for key in ("P", "D", "B"):
        spec[key] = _optional_number(rwhere, key, table.get(key))
    spec["omega"] = _optional_number(rwhere, "omega", table.get("omega"), minimum=0.0,
                                     strict=True)
    spec["added_mass"] = _number(rwhere, "added_mass", table.get("added_mass", 0.0),
                                 minimum=0.0)
    spec["bias"] = _number(rwhere, "bias", table.get("bias", 0.0), minimum=0.0)
    spec["extra"] = {k: v for k, v in table.items() if k not in _RUN_KEYS}
    return spec


def _resolve(where: str, path: Path) -> Path:
    try:
        return path.resolve()
    except (OSError, RuntimeError, ValueError) as exc:
        _fail(where, f"cannot resolve {_show(str(path), 200)}: {exc}")


def _data_path(where: str, folder: Path, root: Path, file: str) -> tuple[Path, os.stat_result]:
    """The data file's resolved path and status, after checking that it stays inside the set's
    folder and is a regular file."""
    shown = _show(file, 100)
    if "\x00" in file:
        _fail(where, "key 'file' contains a NUL character")
    if "\\" in file:
        _fail(where, f"key 'file' must use '/' as the path separator; got {shown}")
    posix = PurePosixPath(file)
    if posix.is_absolute() or PureWindowsPath(file).drive:
        _fail(where, f"key 'file' must be a path relative to the manifest's folder; "
                     f"got the absolute path {shown}")
    if ".." in posix.parts:
        _fail(where, f"file {shown} escapes the set's folder ('..' is not allowed)")
    if not file.lower().endswith((".csv", ".csv.gz")):
        _fail(where, f"file {shown} must end in .csv or .csv.gz")
    real = _resolve(where, folder / file)
    if not real.is_relative_to(root):
        _fail(where, f"file {shown} escapes the set's folder (it resolves to "
                     f"{_show(str(real), 200)})")
    try:
        st = os.stat(real)
    except FileNotFoundError:
        _fail(where, f"data file not found: {_show(str(folder / file), 200)}")
    except OSError as exc:
        _fail(where, f"cannot read the data file: {exc.strerror or exc}")
    kind = _not_regular(st.st_mode)
    if kind is not None:
        _fail(where, f"data file {shown} is {kind}, not a regular file; phoid reads only "
                     "regular files")
    return real, st


def _blocks(where: str, real: Path, file: str) -> Iterator[bytes]:
    """The data file's bytes, decompressed, in blocks of at most _BLOCK bytes.

    Stops with an error at MAX_DATA_BYTES (decompressed, or stored): never reads or
    decompresses more than one block past the limit.
    """
    f, st = _open_regular(where, real, "data file")
    too_big = (f"the data file is larger than {MAX_DATA_BYTES // 2**30} GiB (after "
               "decompression), phoid's limit for one run (MAX_DATA_BYTES)")
    total = 0
    with f:
        if st.st_size > MAX_DATA_BYTES:
            _fail(where, too_big)
        try:
            head = f.peek(2)[:2]
        except OSError as exc:
            _fail(where, f"cannot read the data file: {exc.strerror or exc}")
        if not head:
            _fail(where, "the data file is empty")
        if head == _GZIP_MAGIC:
            stream = _gunzip(where, f)
        elif file.lower().endswith(".gz"):
            _fail(where, "the data file is not a gzip file (it lacks the gzip signature), "
                         "although its name ends in .gz")
        else:
            stream = _plain(where, f)
        for block in stream:
            total += len(block)
            if total > MAX_DATA_BYTES:
                _fail(where, too_big)
            yield block


def _plain(where: str, f: BinaryIO) -> Iterator[bytes]:
    while True:
        try:
            block = f.read(_BLOCK)
        except OSError as exc:
            _fail(where, f"cannot read the data file: {exc.strerror or exc}")
        if not block:
            return
        yield block


def _gunzip(where: str, f: BinaryIO) -> Iterator[bytes]:
    """Decompress a gzip file (one member or several, one after the other) in blocks.

    zlib parses the gzip header and checks the trailer (CRC-32 and length) in C; output is
    bounded by _BLOCK per step (max_length), so a bomb is never expanded ahead of the reader.
    """
    bad = "the data file is not a valid gzip file"
    d = zlib.decompressobj(31)
    data = b""
    fed = False
    while True:
        if not data:
            try:
                data = f.read(_BLOCK)
            except OSError as exc:
                _fail(where, f"cannot read the data file: {exc.strerror or exc}")
            if not data:
                if fed and not d.eof:
                    try:
                        tail = d.flush(_BLOCK)
                    except zlib.error as exc:
                        _fail(where, f"{bad}: {exc}")
                    if tail:
                        yield tail
                    if not d.eof:
                        _fail(where, f"{bad}: it ends before the end of its compressed data "
                                     "(a truncated file?)")
                return
        if d.eof:  # the next member
            d = zlib.decompressobj(31)
        try:
            out = d.decompress(data, _BLOCK)
        except zlib.error as exc:
            _fail(where, f"{bad}: {exc}")
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
            yield line, chunk
            line += count
        if len(carry) > MAX_LINE_BYTES:
            _fail(where, f"line {line} is longer than {MAX_LINE_BYTES // 2**20} MiB, phoid's "
                         "limit for one line (MAX_LINE_BYTES): is this a CSV file with one row "
                         "per line?")
    if first and carry.startswith(codecs.BOM_UTF8):
        carry = carry[len(codecs.BOM_UTF8):]
    if carry:
        carry = carry.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        if not carry.endswith(b"\n"):
            carry += b"\n"
        _check_lines(where, line + carry.count(b"\n") - 1)
        yield line, carry


def _check_lines(where: str, last: int) -> None:
    if last > MAX_LINES:
        _fail(where, f"the data file has more than {MAX_LINES:,} lines (blank lines "
                     "included), phoid's limit for one run (MAX_LINES)")


def _clean_name(name: str) -> str:
    name = name.strip()
    if len(name) >= 2 and name[0] == name[-1] == '"':
        name = name[1:-1].strip()
    return name


def _read_csv(where: str, real: Path, file: str, *, need_F: bool = False,
              max_rows: int = MAX_SET_ROWS) -> tuple[dict[str, np.ndarray], bytes]:
    """Read, decompress and parse one phoid/1 CSV data file, streaming.

    Returns the known columns it has (read-only float64 arrays) and a BLAKE2b digest of its
    decompressed content. At most ``max_rows`` data rows are accepted.
    """
    digest = hashlib.blake2b(digest_size=32)

    def hashed() -> Iterator[bytes]:
        for block in _blocks(where, real, file):
            digest.update(block)
            yield block

    try:
        cols = _parse_csv(where, _line_chunks(where, hashed()), need_F=need_F,
                          max_rows=max_rows)
    except MemoryError:
        _fail(where, "not enough memory to hold the data file's columns")
    return cols, digest.digest()


def _parse_csv(where: str, chunks: Iterator[tuple[int, bytes]], *, need_F: bool = False,
               max_rows: int = MAX_SET_ROWS) -> dict[str, np.ndarray]:
    """Parse a phoid/1 CSV, given as chunks of whole LF-terminated lines, into the known
    columns it has."""
    first = next(chunks, None)
    if first is None:
        _fail(where, "the data file is empty")
    start, chunk = first
    cut = chunk.find(b"\n")
    head, body = chunk[:cut], chunk[cut + 1:]
    if not head.strip():
        rest = body
        while not rest.strip():  # all blank so far: an empty file, or a blank header line
            nxt = next(chunks, None)
            if nxt is None:
                _fail(where, "the data file is empty")
            rest = nxt[1]
        _fail(where, "line 1 is blank; the first line must be a header naming the columns")
    try:
        header = head.decode("utf-8")
    except UnicodeDecodeError:
        _fail(where, "the header (line 1) is not UTF-8 text")
    names = [_clean_name(n) for n in header.split(",")]
    if all(_NUMBER_RE.fullmatch(n) for n in names):
        _fail(where, f"line 1 looks like data ({_show(header.strip())}); the first line must "
                     "be a header naming the columns, e.g. 't,x,u'")
    position: dict[str, int] = {}
    for j, n in enumerate(names):
        if n and n in position:
            _fail(where, f"the header names column {_show(n)} twice "
                         f"(columns {position[n] + 1} and {j + 1})")
        position[n] = j
    for key in ("t", "x") + (("F",) if need_F else ()):
        if key not in position:
            _fail(where, _missing_column(key, names, header, need_F))
    wanted = [k for k in _COLUMNS if k in position]
    usecols = [position[k] for k in wanted]
    ncols = len(names)

    parts: list[np.ndarray] = []   # per chunk: rows × wanted columns
    where_rows: list[tuple[int, int, np.ndarray | None]] = []  # (first row, first line, lines)
    n = 0
    bodies = itertools.chain([(start + 1, body)], ((s, c) for s, c in chunks))
    for line0, text in bodies:
        if not text:
            continue
        table, lines = _parse_chunk(where, text, line0, ncols, position, wanted, usecols)
        if not table.shape[0]:
            continue
        if n + table.shape[0] > max_rows:
            _fail(where, f"the set's data files hold more than {MAX_SET_ROWS:,} data rows in "
                         "all (this one included), phoid's limit for one set (MAX_SET_ROWS)")
        where_rows.append((n, line0, lines))
        parts.append(table)
        n += table.shape[0]
    if n == 0:
        _fail(where, "the data file has a header but no data rows")
    if n < 2:
        _fail(where, f"only {n} data row; at least 2 are needed")

    def line_of(row: int) -> int:
        i = bisect.bisect_right([w[0] for w in where_rows], row) - 1
        first_row, line0, lines = where_rows[i]
        return int(lines[row - first_row]) if lines is not None else line0 + row - first_row

    cols: dict[str, np.ndarray] = {}
    for i, key in enumerate(wanted):
        col = np.concatenate([p[:, i] for p in parts]) if len(parts) > 1 \
            else np.ascontiguousarray(parts[0][:, i])
        col.flags.writeable = False
        cols[key] = col
    parts.clear()
    t = cols["t"]
    up = t[1:] > t[:-1]
    if not up.all():
        r = int(np.argmin(up)) + 1
        _fail(where, f"column 't' is not strictly increasing at line {line_of(r)}: "
                     f"{float(t[r])!r} s follows {float(t[r - 1])!r} s (line {line_of(r - 1)})")
    return cols


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
            _fail(where, f"cannot parse the data: {exc}")
    finite = np.isfinite(table)
    if not finite.all():
        bad = ~finite.all(axis=0)
        i = int(np.argmax(bad))
        r = int(np.argmin(finite[:, i]))
        line = int(lines[r]) if lines is not None else line0 + r
        cell = _cell_text(body, r, usecols[i])
        _fail(where, f"column {wanted[i]!r} has a non-finite value at line {line}: "
                     f"{_show(cell)}")
    return table, lines


def _missing_column(key: str, names: list[str], header: str, need_F: bool) -> str:
    shown = ", ".join(_show(n, 40) for n in names[:12]) + (", …" if len(names) > 12 else "")
    text = f"missing column {key!r}"
    if key == "F" and need_F:
        text += " (a forced run needs the external force F)"
    text += f"; the header names {shown}"
    if any(n.lower() == key.lower() for n in names):
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
        _fail(where, f"line {i + line0} has {commas[i] + 1} fields but the header names "
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
                _fail(where, f"column {key!r} has an empty cell at line {int(rows[r])}")
            if not _NUMBER_RE.fullmatch(cell):
                _fail(where, f"column {key!r} has a non-numeric cell at line {int(rows[r])}: "
                             f"{_show(cell)}")


def _cell_text(body: bytes, row: int, col: int) -> str:
    """Text of one cell of the (blank-line free) body; error path only."""
    line = body.split(b"\n", row + 1)[row].decode("utf-8", "replace")
    return line.split(",")[col].strip()


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------
def write_experiment(
    folder: str | os.PathLike[str],
    runs: Iterable[Run] | ExperimentSet,
    *,
    method: str | None = None,
    delay: float | None = None,
    title: str | None = None,
    mass: float | None = None,
    loop: Mapping[str, Any] | None = None,
    extra: Mapping[str, Any] | None = None,
    gzip: bool = True,
    names: Sequence[str] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write an experiment set in the ``phoid/1`` format.

    Writes one data file per run (columns ``t,x`` and, where the run has them, ``u`` and
    ``F``; every number in the shortest form that reads back to the same double) and then the
    manifest ``experiment.toml``. :func:`read_experiment` on the result gives bitwise-equal
    arrays.

    Parameters
    ----------
    folder : str or os.PathLike
        The set's folder; created if missing. Files are never written through a symbolic link
        (a link in the folder, or a subfolder that leads outside it, is refused) and each file
        is written atomically (a temporary file beside it, then renamed).
    runs : iterable of Run, or ExperimentSet
        The runs, in manifest order. With an :class:`ExperimentSet`, every keyword left at
        None below is taken from the set.
    method : {"pho", "forced", "free"}, optional
        Default ``"pho"``.
    delay : float, optional
        Loop delay Δt (s, ≥ 0), written as ``[loop] delay``; omitted when None.
    title : str, optional
        The set's title.
    mass : float, optional
        Known mass (kg, > 0), top-level ``mass`` (format extension).
    loop : Mapping, optional
        Further ``[loop]`` keys to write (``delay`` overrides ``loop["delay"]``).
    extra : Mapping, optional
        Further top-level keys to write.
    gzip : bool, default True
        Name the data files ``runNN.csv.gz`` (gzip-compressed) rather than ``runNN.csv``.
    names : sequence of str, optional
        The data files' names (relative paths inside ``folder``, ending in ``.csv`` or
        ``.csv.gz``; the suffix decides compression), instead of ``run01.csv[.gz]``, … . Pass
        ``[r.file for r in runs]`` to keep the names of a set that was read.
    overwrite : bool, default False
        Replace existing regular files; otherwise an existing manifest or data file is an
        error. Links are refused either way.

    Returns
    -------
    pathlib.Path
        The manifest's path.

    Raises
    ------
    ExperimentError
        For an invalid set (no runs, a pho run without gains, bad names, …) or files in the
        way (an existing file without ``overwrite``, a symbolic link); nothing is written then.
        A write that fails midway (disk full) raises it too, leaving whole files only (the
        manifest is written last).
    """
    folder = Path(folder)
    manifest = folder / MANIFEST
    where = str(manifest)
    if isinstance(runs, ExperimentSet):
        src = runs
        method = src.method if method is None else method
        delay = src.delay if delay is None else delay
        title = src.title if title is None else title
        mass = src.mass if mass is None else mass
        loop = src.loop if loop is None else loop
        extra = src.extra if extra is None else extra
        runs = src.runs
    run_list = list(runs)
    for r in run_list:
        if not isinstance(r, Run):
            _fail(where, f"`runs` must hold Run objects; got {_kind(r)}")
    method = "pho" if method is None else method
    loop_table = {k: v for k, v in (loop or {}).items() if k != "delay"}
    if delay is not None:
        loop_table["delay"] = delay
    elif loop is not None and "delay" in loop:
        loop_table["delay"] = loop["delay"]

    n = len(run_list)
    if names is None:
        width = max(2, len(str(n)))
        suffix = ".csv.gz" if gzip else ".csv"
        files = [f"run{i:0{width}d}{suffix}" for i in range(1, n + 1)]
    else:
        files = list(names)
        if len(files) != n:
            _fail(where, f"`names` has {len(files)} entries for {n} runs")
    root = Path(os.path.abspath(folder))
    targets: list[Path] = []
    for i, name in enumerate(files, start=1):
        rwhere = f"{where}: run {i}"
        if not isinstance(name, str) or not name.strip():
            _fail(rwhere, f"the file name must be a non-empty string; got {_show(name)}")
        rwhere = f"{where}: run {i} ({name})"
        if "\\" in name or "\x00" in name:
            _fail(rwhere, f"file name {name!r} must use '/' separators and no NUL")
        posix = PurePosixPath(name)
        if posix.is_absolute() or PureWindowsPath(name).drive or ".." in posix.parts:
            _fail(rwhere, f"file name {name!r} must be a relative path inside the folder")
        if not name.lower().endswith((".csv", ".csv.gz")):
            _fail(rwhere, f"file name {name!r} must end in .csv or .csv.gz")
        target = Path(os.path.normpath(root / name))
        if target in targets:
            _fail(rwhere, f"file name {name!r} is used twice")
        targets.append(target)
    # the runs as they will be read back, checked as a read set is
    placed = tuple(dataclasses.replace(r, file=f, index=i)
                   for i, (r, f) in enumerate(zip(run_list, files, strict=True), start=1))
    exp = ExperimentSet(path=manifest, runs=placed, method=method, delay=None,
                        title=title, mass=mass, loop=loop_table, extra=extra or {})
    # every target checked before the first is written: no links followed, nothing replaced
    # without `overwrite` (phoid._output)
    out = OutputFolder(folder, overwrite=overwrite, error=ExperimentError)
    out.check([*files, MANIFEST])

    doc: dict[str, Any] = {}
    if exp.title is not None:
        doc["title"] = exp.title
    doc["format"] = FORMAT
    doc["method"] = exp.method
    if exp.mass is not None:
        doc["mass"] = exp.mass
    doc.update(_thaw(exp.extra))
    if exp.loop:
        doc["loop"] = _thaw(exp.loop)
    tables = []
    for run in exp.runs:
        table: dict[str, Any] = {"file": run.file}
        for key in ("P", "D", "B", "omega"):
            if getattr(run, key) is not None:
                table[key] = getattr(run, key)
        if run.added_mass != 0.0:
            table["added_mass"] = run.added_mass
        if run.bias != 0.0:
            table["bias"] = run.bias
        table.update(_thaw(run.extra))
        tables.append(table)
    try:
        text = _dump_manifest(doc, tables)
    except (TypeError, ValueError) as exc:
        _fail(where, f"cannot write the manifest as TOML: {exc}")

    # data files first, the manifest last: a set is complete once its manifest is there
    for run, name in zip(exp.runs, files, strict=True):
        data = _csv_bytes(run)
        if name.lower().endswith(".gz"):
            data = _gzip.compress(data, compresslevel=6, mtime=0)
        out.write(name, data)
    out.write(MANIFEST, text.encode("utf-8"))
    return manifest


def _dump_manifest(doc: dict[str, Any], tables: list[dict[str, Any]]) -> str:
    """TOML text with one ``[[run]]`` block per run (tomli_w would inline short ones)."""
    nested = any(isinstance(v, dict) or (isinstance(v, list) and v and isinstance(v[0], dict))
                 for table in tables for v in table.values())
    if nested:  # rare: let tomli_w lay out tables inside runs
        return tomli_w.dumps({**doc, "run": tables})
    parts = [tomli_w.dumps(doc)]
    for table in tables:
        parts.append("\n[[run]]\n")
        parts.extend(tomli_w.dumps({k: v}) for k, v in table.items())
    return "".join(parts)


def _csv_bytes(run: Run) -> bytes:
    """The run's data file: header ``t,x[,u][,F]``, shortest round-trip numbers."""
    names = ["t", "x"] + [k for k in ("u", "F") if getattr(run, k) is not None]
    table = np.column_stack([getattr(run, k) for k in names])
    cells = table.astype(str)  # numpy's shortest repr: parses back to the same double
    lines = "\n".join(map(",".join, cells.tolist()))
    return (",".join(names) + "\n" + lines + "\n").encode("ascii")
