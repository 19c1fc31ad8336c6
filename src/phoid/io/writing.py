"""Writing an experiment set in the ``phoid/1`` format.

Numbers are written in the shortest form that reads back to the same double, so that
:func:`write_experiment` followed by :func:`~phoid.io.reading.read_experiment` reproduces every
array bit for bit.
"""

from __future__ import annotations

import dataclasses
import gzip as _gzip
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any

import numpy as np
import tomli_w

from phoid._output import OutputFolder
from phoid.errors import ExperimentError
from phoid.io._format import FORMAT, MANIFEST, fail, kind_of, show, thaw
from phoid.io.records import ExperimentSet, Run
from phoid.io.units import SIGNAL_UNITS

__all__ = ["write_experiment"]


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
    estimator: str | None = None,
    fixed: Mapping[str, float] | None = None,
    x_unit: str | None = None,
) -> Path:
    """Write an experiment set in the ``phoid/1`` format.

    Writes one data file per run (columns ``t,x`` and, where the run has them, ``r``, ``u``,
    ``w`` and ``F``; every number in the shortest form that reads back to the same double) and
    then the manifest ``experiment.toml``. :func:`read_experiment` on the result gives
    bitwise-equal arrays.

    Parameters
    ----------
    folder : str or os.PathLike
        The set's folder; created if missing. Files are never written through a symbolic link
        (a link in the folder, or a subfolder that leads outside it, is refused) and each file
        is written atomically (a temporary file beside it, then renamed).
    runs : iterable of Run, or ExperimentSet
        The runs, in manifest order. With an :class:`ExperimentSet`, every keyword left at
        None below is taken from the set.
    method : {"pho", "forced", "free", "tracking"}, optional
        Default ``"pho"``. A tracking set is written with CSV data files and every run's
        resolved gains (``P``, ``D``, ``gain``, ``command_gain``) in its ``[[run]]`` table;
        ``[loop]`` keeps the loop's other keys.
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
    estimator : {"auto", "idim", "output-error"}, optional
        Tracking sets: the top-level ``estimator``.
    fixed : Mapping, optional
        Tracking sets: the ``[fixed]`` table (known ``m``, ``c``, ``k``, ``fc``, ``offset``).
    x_unit : str, optional
        What x is in (:attr:`ExperimentSet.x_unit`; default ``"m"``): ``"rad"`` writes
        ``[units] x = "rad"`` (a rotational set), a sensor unit ``[units] x = "V"`` (or
        ``x = {signal = "NAME"}`` for a name not in
        :data:`~phoid.io.units.SIGNAL_UNITS`), so that the set reads back as it was.

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
        estimator = src.estimator if estimator is None else estimator
        fixed = src.fixed if fixed is None else fixed
        x_unit = src.x_unit if x_unit is None else x_unit
        runs = src.runs
    run_list = list(runs)
    for r in run_list:
        if not isinstance(r, Run):
            fail(where, f"`runs` must hold Run objects; got {kind_of(r)}")
    method = "pho" if method is None else method
    # a tracking set's runs carry their gains resolved: the loop's (maybe variable names of
    # another file format) are not written
    dropped = ("delay", "P", "D", "gain", "command_gain") if method == "tracking" else ("delay",)
    loop_table = {k: v for k, v in (loop or {}).items() if k not in dropped}
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
            fail(where, f"`names` has {len(files)} entries for {n} runs")
    root = Path(os.path.abspath(folder))
    targets: list[Path] = []
    for i, name in enumerate(files, start=1):
        rwhere = f"{where}: run {i}"
        if not isinstance(name, str) or not name.strip():
            fail(rwhere, f"the file name must be a non-empty string; got {show(name)}")
        rwhere = f"{where}: run {i} ({name})"
        if "\\" in name or "\x00" in name:
            fail(rwhere, f"file name {name!r} must use '/' separators and no NUL")
        posix = PurePosixPath(name)
        if posix.is_absolute() or PureWindowsPath(name).drive or ".." in posix.parts:
            fail(rwhere, f"file name {name!r} must be a relative path inside the folder")
        if not name.lower().endswith((".csv", ".csv.gz")):
            fail(rwhere, f"file name {name!r} must end in .csv or .csv.gz")
        target = Path(os.path.normpath(root / name))
        if target in targets:
            fail(rwhere, f"file name {name!r} is used twice")
        targets.append(target)
    # the runs as they will be read back, checked as a read set is
    placed = tuple(dataclasses.replace(r, file=f, index=i)
                   for i, (r, f) in enumerate(zip(run_list, files, strict=True), start=1))
    exp = ExperimentSet(path=manifest, runs=placed, method=method, delay=None,
                        title=title, mass=mass, loop=loop_table, extra=extra or {},
                        estimator=estimator, fixed=fixed or {},
                        x_unit="m" if x_unit is None else x_unit)
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
    if exp.estimator is not None:
        doc["estimator"] = exp.estimator
    if exp.fixed:
        doc["fixed"] = thaw(exp.fixed)
    if exp.x_unit != "m":  # the columns are SI (rad) or the sensor's own: say which
        doc["units"] = {"x": exp.x_unit if exp.x_unit in ("rad", *SIGNAL_UNITS)
                        else {"signal": exp.x_unit}}
    doc.update(thaw(exp.extra))
    if exp.loop:
        doc["loop"] = thaw(exp.loop)
    tables = []
    for run in exp.runs:
        table: dict[str, Any] = {"file": run.file}
        for key in ("P", "D", "B", "omega", "gain", "command_gain"):
            if getattr(run, key) is not None:
                table[key] = getattr(run, key)
        if run.added_mass != 0.0:
            table["added_mass"] = run.added_mass
        if run.bias != 0.0:
            table["bias"] = run.bias
        table.update(thaw(run.extra))
        tables.append(table)
    try:
        text = _dump_manifest(doc, tables)
    except (TypeError, ValueError) as exc:
        fail(where, f"cannot write the manifest as TOML: {exc}")

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
    """The run's data file: header ``t,x[,r][,u][,w][,F]``, shortest round-trip numbers."""
    names = ["t", "x"] + [k for k in ("r", "u", "w", "F") if getattr(run, k) is not None]
    table = np.column_stack([getattr(run, k) for k in names])
    cells = table.astype(str)  # numpy's shortest repr: parses back to the same double
    lines = "\n".join(map(",".join, cells.tolist()))
    return (",".join(names) + "\n" + lines + "\n").encode("ascii")
