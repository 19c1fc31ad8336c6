"""The records of an experiment set: :class:`Run` and :class:`ExperimentSet`.

Both are frozen and validate on construction everything that can be checked without knowing
the method's model; :func:`run_from_arrays` makes a run from arrays in memory.
"""

from __future__ import annotations

import numbers
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from phoid.errors import ExperimentError
from phoid.io._format import (
    METHODS,
    RUN_KEYS,
    TOP_KEYS,
    FrozenMap,
    checked_extra,
    checked_number,
    fail,
    freeze,
    frozen_array,
    kind_of,
    optional_number,
    printable,
    show,
    unknown_hint,
)
from phoid.io.frames import is_table, table_columns
from phoid.io.tracking import check_estimator, check_fixed, check_tracking_loop, min_samples
from phoid.io.units import check_x_unit

__all__ = ["ExperimentSet", "Run", "run_from_arrays"]


@dataclass(frozen=True, eq=False, repr=False)
class Run:
    """One recorded run: a free decay (``pho``, ``free``), a forced response (``forced``) or a
    record of a loop tracking a reference (``tracking``).

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
        Proportional gain of the run (N/m); required for ``pho`` runs. In a tracking run, the
        controller's P (command units per m), resolved to a number; required.
    D : float or None
        Derivative gain of the run (N·s/m); required for ``pho`` runs. In a tracking run, the
        controller's D (command units per m/s), resolved to a number; required.
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
    r : numpy.ndarray or None
        Tracking runs: the reference position (m) at the samples; required there.
    w : numpy.ndarray or None
        Tracking runs: the additive command input (command units), optional.
    gain : float or None
        Tracking runs: the controller's gain K (u = K·(P·(r − x) − D·v̂)), finite, non-zero;
        the reader gives 1.0 when the manifest does not. None in other sets.
    command_gain : float or None
        Tracking runs: G, the force per command unit (N per command unit; F = G·(sat(u) + w)),
        finite, non-zero; the reader gives 1.0 when the manifest does not. None in other sets.
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
    extra: Mapping[str, Any] = field(default_factory=FrozenMap)
    r: np.ndarray | None = None
    w: np.ndarray | None = None
    gain: float | None = None
    command_gain: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.file, str):
            raise ExperimentError(f"run: `file` must be a string; got {show(self.file)}")
        if isinstance(self.index, bool) or not isinstance(self.index, numbers.Integral) \
                or self.index < 0:
            raise ExperimentError(f"run: `index` must be an integer ≥ 0; got {show(self.index)}")
        object.__setattr__(self, "index", int(self.index))
        where = self.name
        t = frozen_array(where, "t", self.t, None)
        if t.size < 2:
            fail(where, f"column 't' has {t.size} sample(s); at least 2 are needed")
        d = np.diff(t)
        if not (d > 0).all():
            i = int(np.flatnonzero(~(d > 0))[0])
            fail(where, f"column 't' is not strictly increasing at index {i + 1}: "
                         f"{float(t[i + 1])!r} s follows {float(t[i])!r} s")
        set_ = object.__setattr__
        set_(self, "t", t)
        set_(self, "x", frozen_array(where, "x", self.x, t.size))
        for name in ("u", "F", "r", "w"):
            value = getattr(self, name)
            if value is not None:
                set_(self, name, frozen_array(where, name, value, t.size))
        set_(self, "P", optional_number(where, "P", self.P))
        set_(self, "D", optional_number(where, "D", self.D))
        set_(self, "B", optional_number(where, "B", self.B))
        set_(self, "omega", optional_number(where, "omega", self.omega, minimum=0.0,
                                             strict=True))
        for name in ("gain", "command_gain"):
            value = optional_number(where, name, getattr(self, name))
            if value == 0.0:
                fail(where, f"key {name!r} is 0: the command would not reach the plant")
            set_(self, name, value)
        set_(self, "added_mass", checked_number(where, "added_mass", self.added_mass, minimum=0.0))
        set_(self, "bias", checked_number(where, "bias", self.bias, minimum=0.0))
        set_(self, "extra", checked_extra(where, self.extra, RUN_KEYS, "the run's table"))

    @property
    def name(self) -> str:
        """How messages name the run, e.g. ``"run 3 (run03.csv.gz)"``."""
        text = "run" + (f" {self.index}" if self.index else "")
        return text + (f" ({printable(self.file, 80)})" if self.file else "")

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.t.size)

    def __repr__(self) -> str:
        gains = ", ".join(f"{k}={getattr(self, k)!r}" for k in ("P", "D", "B", "omega", "gain",
                                                                 "command_gain")
                          if getattr(self, k) is not None)
        cols = "t,x" + "".join(f",{k}" for k in ("r", "u", "w", "F")
                               if getattr(self, k) is not None)
        return (f"Run({self.name}: {self.n} samples of {cols}, t = {self.t[0]:g}…{self.t[-1]:g}"
                f" s{', ' + gains if gains else ''})")


@dataclass(frozen=True, eq=False, repr=False)
class ExperimentSet:
    """An experiment set: the manifest's settings and its runs, in manifest order.

    Construction checks the settings and what the method requires of every run (``pho``:
    ``P`` and ``D``; ``forced``: an ``F`` column; ``tracking``: ``P``, ``D``, an ``r`` column,
    the ``[loop]`` keys and enough samples for the velocity estimator); raises
    :class:`~phoid.errors.ExperimentError`.

    Attributes
    ----------
    path : pathlib.Path
        The manifest's path (as given, not resolved).
    runs : tuple of Run
        The runs, at least one.
    method : {"pho", "forced", "free", "tracking"}
        How the runs were excited.
    delay : float or None
        Feedback-loop delay Δt (s, ≥ 0) from ``[loop] delay``; None when omitted (to be
        estimated). When ``loop`` holds ``delay`` too, the two must agree.
    title : str or None
        The set's title.
    mass : float or None
        Known mass (kg, > 0), top-level ``mass`` key (format extension, for free decays).
    loop : Mapping[str, Any]
        The whole ``[loop]`` table as read (future keys kept; a tracking set's gains as given,
        numbers or variable names: each run carries them resolved).
    extra : Mapping[str, Any]
        Unknown top-level keys of the manifest, kept as read.
    estimator : {"auto", "idim", "output-error"} or None
        Tracking sets: the top-level ``estimator`` (default ``"auto"``); None in other sets.
    fixed : Mapping[str, float]
        Tracking sets: the ``[fixed]`` table, parameters known rather than estimated (any of
        ``m`` (kg, > 0), ``c`` (N·s/m), ``k`` (N/m), ``fc`` (N, ≥ 0), ``offset`` (N)); empty
        otherwise.
    x_unit : str
        What x (and a tracking set's r) is in: ``"m"`` (default), ``"rad"`` (an angle, from
        ``[units] x = "deg"``, …: the set is rotational, its mass a moment of inertia J in
        kg m², its gains N m/rad and N m s/rad, its forces torques in N m) or a sensor unit's
        name (``"V"``, ``"counts"``, …: x not calibrated, only a ``free`` set without a
        ``mass``; :func:`phoid.io.units.check_x_unit`).
    notes : tuple of str
        What the reader did that a result should say (``run 1 (…): t rebuilt from
        sample_rate = … Hz …``, where a data file's t column was replaced).
    """

    path: Path
    runs: tuple[Run, ...]
    method: str = "pho"
    delay: float | None = None
    title: str | None = None
    mass: float | None = None
    loop: Mapping[str, Any] = field(default_factory=FrozenMap)
    extra: Mapping[str, Any] = field(default_factory=FrozenMap)
    estimator: str | None = None
    fixed: Mapping[str, float] = field(default_factory=FrozenMap)
    x_unit: str = "m"
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "path", Path(self.path))
        where = str(self.path)
        if self.method not in METHODS:
            fail(where, f"key 'method' must be one of {', '.join(map(repr, METHODS))}; "
                         f"got {show(self.method)}")
        if self.title is not None and not isinstance(self.title, str):
            fail(where, f"key 'title' must be a string; got {show(self.title)} "
                         f"({kind_of(self.title)})")
        loop = self.loop if self.loop is not None else {}
        if not isinstance(loop, Mapping):
            fail(where, f"'loop' must be a table ([loop]); got {kind_of(loop)}")
        delay = optional_number(where, "delay", self.delay, minimum=0.0)
        if "delay" in loop:
            in_loop = checked_number(f"{where}: [loop]", "delay", loop["delay"], minimum=0.0)
            if delay is None:
                delay = in_loop
            elif delay != in_loop:
                fail(where, f"`delay` = {delay!r} s disagrees with [loop] delay = "
                             f"{in_loop!r} s")
        set_(self, "delay", delay)
        set_(self, "mass", optional_number(where, "mass", self.mass, minimum=0.0,
                                            strict=True))
        set_(self, "loop", freeze(loop))
        check_x_unit(where, self.x_unit, self.method, self.mass)
        notes = self.notes
        if not isinstance(notes, tuple | list) or not all(isinstance(n, str) for n in notes):
            fail(where, f"`notes` must be a tuple of strings; got {kind_of(notes)}")
        set_(self, "notes", tuple(notes))
        set_(self, "extra", checked_extra(where, self.extra, TOP_KEYS, "the manifest"))
        runs = tuple(self.runs) if isinstance(self.runs, Iterable) else self.runs
        if not isinstance(runs, tuple) or not runs:
            fail(where, "no runs: the manifest needs at least one [[run]] table")
        for r in runs:
            if not isinstance(r, Run):
                fail(where, f"`runs` must hold Run objects; got {kind_of(r)}")
            _check_method_needs(f"{where}: {r.name}", r, self.method)
        set_(self, "runs", runs)
        if self.method == "tracking":
            self._check_tracking(where)
        else:
            for key, empty in (("estimator", self.estimator is None),
                               ("fixed", not self.fixed)):
                if not empty:
                    fail(where, f"key {key!r} belongs to tracking sets (method = "
                                 f"\"tracking\"); this set's method is {self.method!r}")

    def _check_tracking(self, where: str) -> None:
        set_ = object.__setattr__
        set_(self, "estimator", check_estimator(where, self.estimator))
        set_(self, "fixed", freeze(check_fixed(where, self.fixed)))
        if self.mass is not None:
            fail(where, "key 'mass' is not read in a tracking set: give the known mass as "
                         "[fixed] m")
        taps, _gains = check_tracking_loop(where, self.loop)
        need = min_samples(taps)
        for r in self.runs:
            rwhere = f"{where}: {r.name}"
            if r.n < need:
                fail(rwhere, f"{r.n} samples; a tracking run needs at least {need}: the "
                              f"velocity estimator uses {taps} earlier sample(s), so one "
                              f"estimate takes {taps + 1}, and phoid reads no tracking run "
                              f"shorter than {min_samples(0)}")
            if self.estimator == "idim" and r.u is None:
                fail(rwhere, "estimator = 'idim' needs the recorded command u in every run; "
                              "this run has none (map it in [run.columns], or use "
                              "'output-error')")

    @property
    def folder(self) -> Path:
        """The set's folder (the manifest's parent)."""
        return self.path.parent

    def __len__(self) -> int:
        return len(self.runs)

    def _repr_html_(self) -> str:
        """HTML for notebooks (:func:`phoid.io.display.experiment_html`)."""
        from phoid.io.display import experiment_html

        return experiment_html(self)

    def __repr__(self) -> str:
        return (f"ExperimentSet({str(self.path)!r}, method={self.method!r}, "
                f"delay={self.delay!r}, {len(self.runs)} runs"
                f"{'' if self.x_unit == 'm' else ', x_unit=' + repr(self.x_unit)}"
                f"{', title=' + repr(self.title) if self.title else ''})")


def _check_method_needs(where: str, run: Run, method: str) -> None:
    if method != "tracking":
        for key in ("r", "w", "gain", "command_gain"):
            if getattr(run, key) is not None:
                fail(where, f"{key!r} belongs to tracking runs (method = \"tracking\"); this "
                             f"set's method is {method!r}")
    if method == "tracking":
        for key in ("P", "D"):
            if getattr(run, key) is None:
                fail(where, f"missing key '{key}': a tracking run needs the gains P and D")
        if run.r is None:
            fail(where, "missing column 'r': a tracking run needs the reference r (m)")
        for key, unset in (("B", run.B is None), ("omega", run.omega is None),
                           ("added_mass", run.added_mass == 0.0), ("bias", run.bias == 0.0)):
            if not unset:
                fail(where, f"key {key!r} has no meaning in a tracking set (method = "
                             "\"tracking\")")
    elif method == "pho":
        for key in ("P", "D"):
            if getattr(run, key) is None:
                hint = unknown_hint(run.extra, ())
                fail(where, f"missing key '{key}': a pho run needs the gains P (N/m) and "
                             f"D (N·s/m){hint}")
    elif method == "forced" and run.F is None:
        fail(where, "missing column 'F': a forced run needs the external force F (N)")


def run_from_arrays(
    t: Any,
    x: Any = None,
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
    r: Any = None,
    w: Any = None,
    gain: float | None = None,
    command_gain: float | None = None,
) -> Run:
    """Make a :class:`Run` from arrays, checked as the reader checks a data file.

    Parameters
    ----------
    t : array_like, pandas.Series or pandas.DataFrame
        Sample times (s), finite, strictly increasing, at least 2. Or the whole record as a
        table (``x`` then omitted; :func:`phoid.io.frames.table_columns`): a Series (index
        t, values x) or a DataFrame (columns ``x`` and optionally ``u``, ``F``, ``r``,
        ``w``; t from a column ``t`` or the index). A datetime or timedelta index becomes
        seconds from the first sample.
    x : array_like
        Position (m), same length as ``t``; required unless ``t`` is a table.
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
    r, w : array_like, optional
        Tracking runs: the reference (m) and the additive command input (command units),
        same length as ``t``.
    gain, command_gain : float, optional
        Tracking runs: the controller's gain K and the force per command unit G (N per
        command unit), finite and non-zero.

    Returns
    -------
    Run

    Raises
    ------
    ExperimentError
        On NaN/inf, unequal lengths, non-increasing ``t``, bad gains; for a table also a
        missing ``x`` or an unknown column (the message names the argument and the column).

    Examples
    --------
    >>> import numpy as np
    >>> run = run_from_arrays(np.arange(3) * 1e-3, [0.0, 1e-3, 2e-3], P=1.0, D=0.5)
    >>> run.x.dtype, run.x.flags.writeable
    (dtype('float64'), False)
    """
    if is_table(t):
        if x is not None:
            raise ExperimentError("run_from_arrays: `t` is a table (Series/DataFrame) holding "
                                  "x already; do not pass `x` as well")
        cols = table_columns(t, "t")
        given = {"u": u, "F": F, "r": r, "w": w}
        both = [k for k, value in given.items() if k in cols and value is not None]
        if both:
            raise ExperimentError(f"run_from_arrays: column(s) {', '.join(map(repr, both))} "
                                  "of `t` also given as argument(s); give each once")
        for k, value in given.items():  # a Series beside the table: read by position, so
            # its index must be the table's (else its samples would silently be misplaced)
            same = getattr(getattr(value, "index", None), "equals", None)
            if is_table(value) and callable(same) and not same(t.index):
                raise ExperimentError(
                    f"run_from_arrays: `{k}` is a Series whose index is not that of `t`; "
                    f"align it first ({k}.reindex(t.index)) or make it a column of `t`")
        t, x = cols["t"], cols["x"]
        u, F, r, w = (cols.get(k, value) for k, value in given.items())
    elif x is None:
        raise ExperimentError("run_from_arrays: `x` (the position, m) is missing")
    return Run(file=file, t=t, x=x, u=u, F=F, P=P, D=D, B=B, omega=omega,
               added_mass=added_mass, bias=bias, index=index,
               extra=FrozenMap() if extra is None else extra, r=r, w=w, gain=gain,
               command_gain=command_gain)
