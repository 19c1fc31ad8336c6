"""Reading an experiment set: the manifest checked key by key, then every data file.

What is checked here is what can be checked without knowing the method's model: the keys,
their types and ranges, their letter case (a key that differs from a known one only in letter
case is an error), the data files' paths (inside the set's folder, regular files, each
recording listed once), compression, text and cells. The whole ``[loop]`` table and every
unknown key are kept (:attr:`ExperimentSet.loop`, :attr:`ExperimentSet.extra`,
:attr:`Run.extra`).
"""

from __future__ import annotations

import os
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any

import numpy as np

import phoid.io.limits as limits
from phoid.errors import ExperimentError
from phoid.io._files import not_regular
from phoid.io._format import (
    FORMAT,
    LOOP_KEYS,
    MANIFEST,
    METHODS,
    RUN_KEYS,
    TOP_KEYS,
    case_clash,
    checked_number,
    fail,
    kind_of,
    optional_number,
    printable,
    show,
    unknown_hint,
)
from phoid.io.containers import CONTAINER_SUFFIXES, container_suffix, read_container
from phoid.io.datafile import read_csv
from phoid.io.manifest import read_manifest
from phoid.io.records import ExperimentSet, Run
from phoid.io.tracking import (
    TRACKING_LOOP_KEYS,
    check_estimator,
    check_fixed,
    check_tracking_loop,
    tracking_run_spec,
)
from phoid.io.units import read_units, to_si

_TRACKING_ONLY_TOP = ("estimator", "fixed")
_TRACKING_ONLY_RUN = ("gain", "command_gain", "columns")

__all__ = ["read_experiment"]


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
        The runs in manifest order; arrays in SI units (s, m, N), read-only: columns that the
        manifest's ``[units]`` table gives in other units (``t = "ms"``, ``x = "mm"``, …) are
        converted (:func:`phoid.io.units.check_units`), so a set written back is SI.

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
            fail(where, f"manifest not found: the folder has no {MANIFEST}")
        fail(where, "no such file or folder")
    if manifest.is_dir():
        fail(where, "the manifest is a folder, not a file")
    doc = read_manifest(where, manifest)

    case_clash(where, doc, TOP_KEYS, "the manifest")
    fmt = doc.get("format", FORMAT)
    if fmt != FORMAT:
        fail(where, f"key 'format' must be {FORMAT!r}; got {show(fmt)} "
                     "(this phoid reads only phoid/1 sets)")
    method = doc.get("method", "pho")
    if method not in METHODS:
        fail(where, f"key 'method' must be one of {', '.join(map(repr, METHODS))}; "
                     f"got {show(method)}")
    title = doc.get("title")
    if title is not None and not isinstance(title, str):
        fail(where, f"key 'title' must be a string; got {show(title)} ({kind_of(title)})")
    tracking = method == "tracking"
    for key in _TRACKING_ONLY_TOP:
        if key in doc and not tracking:
            fail(where, _tracking_only(key, method))
    if tracking and "mass" in doc:
        fail(where, "key 'mass' is not read in a tracking set: give the known mass as "
                     "[fixed] m")
    units, x_unit = read_units(where, doc.get("units"), method)
    if tracking and "sample_rate" in doc:
        fail(where, _NO_RATE_IN_TRACKING)
    rate = _sample_rate(where, doc.get("sample_rate"))
    estimator = check_estimator(where, doc.get("estimator")) if tracking else None
    fixed = check_fixed(where, doc.get("fixed")) if tracking else {}
    mass = optional_number(where, "mass", doc.get("mass"), minimum=0.0, strict=True)
    if mass is not None and x_unit not in ("m", "rad"):
        fail(where, f"key 'mass' cannot be used with [units] x = {show(x_unit)} (a sensor "
                     "unit): c and k need x in a length or an angle unit; a free decay in "
                     "sensor units gives only σ, ω₀, ζ, c/m and k/m (remove 'mass', or give "
                     "x calibrated)")
    loop = doc.get("loop", {})
    if not isinstance(loop, dict):
        fail(where, f"'loop' must be a table ([loop]); got {kind_of(loop)}")
    case_clash(f"{where}: [loop]", loop, TRACKING_LOOP_KEYS if tracking else LOOP_KEYS,
               "[loop]")
    loop_gains = check_tracking_loop(where, loop)[1] if tracking else {}
    delay = optional_number(f"{where}: [loop]", "delay", loop.get("delay"), minimum=0.0)

    tables = doc.get("run")
    if tables is None:
        hint = unknown_hint(doc, TOP_KEYS)
        fail(where, f"no runs: the manifest has no [[run]] tables{hint}")
    if not isinstance(tables, list) or not all(isinstance(r, dict) for r in tables):
        fail(where, "'run' must be an array of tables ([[run]] … [[run]])")
    if not tables:
        fail(where, "no runs: 'run' is empty")

    specs = [_run_spec(where, i, table, method, loop_gains)
             for i, table in enumerate(tables, start=1)]
    folder = manifest.parent
    root = _resolve(where, folder)
    seen: dict[Any, str] = {}
    inodes: dict[Any, dict[str, Any]] = {}
    for spec in specs:
        rwhere = f"{where}: {spec['name']}"
        real, st = _data_path(rwhere, folder, root, spec["file"], tracking)
        # one container file may hold several runs, each under its own variable names
        part = tuple(spec["columns"].items()) if spec["container"] else ()
        if (real, part) in seen:
            fail(rwhere, f"file {show(spec['file'], 100)} is already used by "
                          f"{seen[(real, part)]}" + (" with the same [run.columns]" if part
                                                     else ""))
        other = inodes.get((st.st_dev, st.st_ino, part))
        if other is not None:
            fail(rwhere, f"file {show(spec['file'], 100)} is a hard link to "
                          f"{show(other['file'], 100)} of {other['name']}: the same recording "
                          "would be counted twice; list each recording once")
        seen[(real, part)] = spec["name"]
        inodes[(st.st_dev, st.st_ino, part)] = spec
        spec["where"], spec["real"] = rwhere, real

    runs = []
    notes: list[str] = []
    digests: dict[bytes, dict[str, Any]] = {}
    budget = limits.MAX_SET_ROWS
    for spec in specs:
        fs = spec["sample_rate"] if spec["sample_rate"] is not None else rate
        cols, digest = _read_data(spec, method, budget, clock=fs is None)
        cols = to_si(cols, units, spec["where"])  # [units]: the columns in s, m, N from here on
        if fs is not None:
            cols, note = _rebuild_time(spec["where"], spec["name"], cols, fs)
            notes.extend(note)
        budget -= cols["t"].size
        other = digests.get(digest)
        if other is not None:
            fail(spec["where"], f"the data file has the same content, byte for byte, as "
                                 f"{other['name']}'s: a copy (or a noise-free repeat of a "
                                 "simulated run) would be counted twice; list each recording "
                                 "once")
        digests[digest] = spec
        try:
            runs.append(Run(file=spec["file"], index=spec["index"], extra=spec["extra"],
                            P=spec["P"], D=spec["D"], B=spec["B"], omega=spec["omega"],
                            added_mass=spec["added_mass"], bias=spec["bias"],
                            gain=spec["gain"], command_gain=spec["command_gain"], **cols))
        except ExperimentError as exc:  # pragma: no cover - the reader checks first
            fail(where, str(exc))
    try:
        # the set checks what needs every run: a tracking run's samples against its loop
        return ExperimentSet(path=manifest, runs=tuple(runs), method=method, delay=delay,
                             title=title, mass=mass, loop=loop,
                             extra={k: v for k, v in doc.items() if k not in TOP_KEYS},
                             estimator=estimator, fixed=fixed, x_unit=x_unit,
                             notes=tuple(notes))
    except ExperimentError as exc:
        raise ExperimentError(str(exc)) from None


_NO_RATE_IN_TRACKING = (
    "key 'sample_rate' is not read in a tracking set: its t is the controller's clock, "
    "checked against [loop] sample_time")
#: the sample rates phoid accepts, Hz (as every other number of the format: 1e-30 … 1e30)
_RATE_RANGE = (1e-30, 1e30)


def _sample_rate(where: str, value: Any) -> float | None:
    """``sample_rate`` (Hz): None, or a finite number within :data:`_RATE_RANGE`."""
    rate = optional_number(where, "sample_rate", value, minimum=0.0, strict=True)
    lo, hi = _RATE_RANGE
    if rate is not None and not lo <= rate <= hi:
        fail(where, f"key 'sample_rate' must be between {lo:g} and {hi:g} Hz; got {rate!r}")
    return rate


def _rebuild_time(where: str, name: str, cols: dict[str, Any], fs: float
                  ) -> tuple[dict[str, Any], list[str]]:
    """t = t₀ + n/fs for a run read with ``sample_rate``: t₀ the t column's first value (0
    without one); a note when a t column was there (it is replaced), saying how it compares."""
    n = cols["x"].size
    given = cols.get("t")
    t0 = float(given[0]) if given is not None else 0.0
    t = t0 + np.arange(n) / fs
    step = np.diff(t)
    if not (np.isfinite(t).all() and (step > 0).all()):
        fail(where, f"sample_rate = {fs!r} Hz does not make usable times from t₀ = {t0!r} s "
                     f"over {n} samples: t₀ + n/fs is not finite and strictly increasing in "
                     "double precision")
    t.flags.writeable = False
    notes: list[str] = []
    if given is not None:
        span = float(t[-1] - t[0])
        d = np.diff(given)
        bad = int(np.count_nonzero(~(d > 0)))
        if bad:
            how = (f"it is not strictly increasing: {bad} of its {d.size} steps are zero or "
                   "backward")
        else:
            gspan = float(given[-1] - given[0])
            off = abs(gspan - span) / span
            how = (f"it spans {gspan:.6g} s, {off:.2%} off the rebuilt {span:.6g} s"
                   if off > 1e-3 else "it agrees with the rebuilt t to 0.1 %")
        notes.append(f"{name}: t rebuilt from sample_rate = {fs:g} Hz as t₀ + n/fs (t₀ = "
                     f"{t0:g} s, the file's first t); the file's t column was not used "
                     f"beyond its first value ({how})")
    return {**cols, "t": t}, notes


def _tracking_only(key: str, method: str) -> str:
    return (f"key {key!r} belongs to tracking sets (method = \"tracking\"); this set's "
            f"method is {method!r}")


def _read_data(spec: dict[str, Any], method: str, budget: int, clock: bool = True
               ) -> tuple[dict[str, Any], bytes]:
    """Read one run's data file; for a tracking run, resolve its gains (into ``spec``)."""
    if method != "tracking":
        return read_csv(spec["where"], spec["real"], spec["file"], need_F=(method == "forced"),
                        max_rows=budget, clock=clock)
    required = ("t", "x", "r", *spec["explicit"])
    gains = spec["gains"]
    if spec["container"]:
        names = {k: v[0] for k, v in gains.items() if isinstance(v, tuple)}
        cols, values, digest = read_container(
            spec["where"], spec["real"], spec["file"], columns=spec["columns"],
            required=required, scalars=names, max_rows=budget)
    else:
        cols, digest = read_csv(spec["where"], spec["real"], spec["file"], max_rows=budget,
                                columns=spec["columns"], required=required)
        values = {}
    for key in ("P", "D", "gain", "command_gain"):
        value = gains.get(key, 1.0)
        spec[key] = values[key] if isinstance(value, tuple) else value
    return cols, digest

def _run_spec(where: str, index: int, table: dict[str, Any], method: str,
              loop_gains: dict[str, Any]) -> dict[str, Any]:
    """Check one [[run]] table (before any data is read)."""
    file = table.get("file")
    name = f"run {index}" + (f" ({printable(file, 80)})" if isinstance(file, str) and file
                             else "")
    rwhere = f"{where}: {name}"
    case_clash(rwhere, table, RUN_KEYS, "the run's table")
    if file is None:
        fail(rwhere, f"missing key 'file'{unknown_hint(table, RUN_KEYS)}")
    if not isinstance(file, str):
        fail(rwhere, f"key 'file' must be a string; got {show(file)} ({kind_of(file)})")
    if not file.strip():
        fail(rwhere, "key 'file' is empty")
    if method == "tracking":
        if "sample_rate" in table:
            fail(rwhere, _NO_RATE_IN_TRACKING)
        container = container_suffix(file) is not None
        spec = tracking_run_spec(rwhere, table, loop_gains, container)
        spec.update(file=file, index=index, name=name, container=container, B=None,
                    omega=None, added_mass=0.0, bias=0.0, sample_rate=None)
        return spec
    for key in _TRACKING_ONLY_RUN:
        if key in table:
            fail(rwhere, _tracking_only(key, method))
    if method == "pho":
        for key in ("P", "D"):
            if key not in table:
                fail(rwhere, f"missing key '{key}': a pho run needs the gains P (N/m) and "
                              f"D (N·s/m){unknown_hint(table, RUN_KEYS)}")
    spec: dict[str, Any] = {"file": file, "index": index, "name": name, "container": False,
                            "gain": None, "command_gain": None}
    for key in ("P", "D", "B"):
        spec[key] = optional_number(rwhere, key, table.get(key))
    spec["omega"] = optional_number(rwhere, "omega", table.get("omega"), minimum=0.0,
                                     strict=True)
    spec["added_mass"] = checked_number(rwhere, "added_mass", table.get("added_mass", 0.0),
                                 minimum=0.0)
    spec["bias"] = checked_number(rwhere, "bias", table.get("bias", 0.0), minimum=0.0)
    spec["sample_rate"] = _sample_rate(rwhere, table.get("sample_rate"))
    spec["extra"] = {k: v for k, v in table.items() if k not in RUN_KEYS}
    return spec


def _resolve(where: str, path: Path) -> Path:
    try:
        return path.resolve()
    except (OSError, RuntimeError, ValueError) as exc:
        fail(where, f"cannot resolve {show(str(path), 200)}: {exc}")


def _data_path(where: str, folder: Path, root: Path, file: str, tracking: bool = False
               ) -> tuple[Path, os.stat_result]:
    """The data file's resolved path and status, after checking that it stays inside the set's
    folder and is a regular file (a tracking set's may be a container, .mat/.h5/.parquet)."""
    shown = show(file, 100)
    if "\x00" in file:
        fail(where, "key 'file' contains a NUL character")
    if "\\" in file:
        fail(where, f"key 'file' must use '/' as the path separator; got {shown}")
    posix = PurePosixPath(file)
    if posix.is_absolute() or PureWindowsPath(file).drive:
        fail(where, f"key 'file' must be a path relative to the manifest's folder; "
                     f"got the absolute path {shown}")
    if ".." in posix.parts:
        fail(where, f"file {shown} escapes the set's folder ('..' is not allowed)")
    if tracking and container_suffix(file) is None \
            and not file.lower().endswith((".csv", ".csv.gz")):
        fail(where, f"file {shown} must end in .csv, .csv.gz, "
                     f"{', '.join(CONTAINER_SUFFIXES)} (the format it holds)")
    if not tracking and not file.lower().endswith((".csv", ".csv.gz")):
        hint = (" (MATLAB, HDF5 and Parquet files are read in tracking sets only)"
                if container_suffix(file) else "")
        fail(where, f"file {shown} must end in .csv or .csv.gz{hint}")
    real = _resolve(where, folder / file)
    if not real.is_relative_to(root):
        fail(where, f"file {shown} escapes the set's folder (it resolves to "
                     f"{show(str(real), 200)})")
    try:
        st = os.stat(real)
    except FileNotFoundError:
        fail(where, f"data file not found: {show(str(folder / file), 200)}")
    except OSError as exc:
        fail(where, f"cannot read the data file: {exc.strerror or exc}")
    kind = not_regular(st.st_mode)
    if kind is not None:
        fail(where, f"data file {shown} is {kind}, not a regular file; phoid reads only "
                     "regular files")
    return real, st
