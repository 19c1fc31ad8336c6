"""Experiment sets in the ``phoid/1`` format: read, validate and write.

The format is defined in one place, ``docs/format.md`` in the repository: the manifest's keys
(with the extensions ``added_mass``, ``bias``, ``mass`` and the digital ``[loop]`` keys), the
data files, the rules this reader applies, and the JSON that ``phoid identify --json`` prints.
In short: an experiment set is a folder holding one manifest, ``experiment.toml``, and one data
file per run::

    title  = "Linear stage, PHO sweep"   # optional
    format = "phoid/1"                   # optional; when present it must be "phoid/1"
    method = "pho"                       # "pho" (default) | "forced" | "free" | "tracking"

    [loop]
    delay = 0.1                          # s; omitted: to be estimated from the data

    [[run]]
    file = "run01.csv.gz"                # relative to the manifest; .csv or .csv.gz
    P = 0.25                             # N/m
    D = 0.6                              # N·s/m

Each data file is comma-separated text whose first line names the columns: ``t`` (s, strictly
increasing) and ``x`` (m) always, ``u`` (N, the feedback force actually applied) optionally,
``F`` (N, the external force) for forced runs. Extra columns are ignored.

A tracking set (``method = "tracking"``: a sampled PD loop following a reference ``r``) also
reads MATLAB (v5/v7 and v7.3), HDF5 and Parquet files, names the signals of each file in
``[run.columns]``, and takes its gains as numbers or as the names of scalar variables of the
run's file, resolved when the file is read (:mod:`phoid.io.tracking`,
:mod:`phoid.io.containers`; h5py and pyarrow: ``pip install 'phoid[io]'``).

The reader checks what can be checked without knowing the method's model: the keys, their
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
by :func:`read_experiment` reproduces every array bit for bit. Every read is bounded by the
limits ``MAX_*`` exported here (docs/limits.md).

Modules: :mod:`phoid.io.records` (:class:`Run`, :class:`ExperimentSet`,
:func:`run_from_arrays`), :mod:`phoid.io.reading` (:func:`read_experiment`),
:mod:`phoid.io.manifest` (:func:`read_manifest`), :mod:`phoid.io.datafile` (the bounded CSV
reader), :mod:`phoid.io.limits` (the limits), :mod:`phoid.io.writing`
(:func:`write_experiment`), :mod:`phoid.io.tracking` (a tracking set's keys),
:mod:`phoid.io.loop` (a PHO set's ``[loop]`` read: the digital loop and ``noise``),
:mod:`phoid.io.containers` (the MATLAB, HDF5 and Parquet readers); ``_format`` and ``_files``
hold what they share (:func:`open_regular` and :func:`not_regular`, the rule that only regular
files are read, are exported here for the other commands that read a file).
"""

from phoid.io._files import not_regular, open_regular
from phoid.io._format import FORMAT, MANIFEST, METHODS
from phoid.io.containers import CONTAINER_SUFFIXES
from phoid.io.limits import (
    MAX_BLANK_SHARE,
    MAX_DATA_BYTES,
    MAX_LINE_BYTES,
    MAX_LINES,
    MAX_MANIFEST_BYTES,
    MAX_NESTING,
    MAX_RUNS,
    MAX_SET_ROWS,
)
from phoid.io.loop import (
    DIGITAL_KEYS,
    NOISE_PLACEMENTS,
    PHO_LOOP_KEYS,
    read_digital_loop,
    read_noise_placement,
)
from phoid.io.manifest import parse_manifest, read_manifest, read_manifest_bytes
from phoid.io.reading import read_experiment
from phoid.io.records import ExperimentSet, Run, run_from_arrays
from phoid.io.tracking import (
    ESTIMATORS,
    FIXED_KEYS,
    MIN_TRACKING_SAMPLES,
    TRACKING_COLUMNS,
    TRACKING_LOOP_KEYS,
    VELOCITY_PRESETS,
)
from phoid.io.writing import write_experiment

__all__ = [
    "CONTAINER_SUFFIXES",
    "DIGITAL_KEYS",
    "ESTIMATORS",
    "FIXED_KEYS",
    "FORMAT",
    "MANIFEST",
    "MAX_BLANK_SHARE",
    "MAX_DATA_BYTES",
    "MAX_LINES",
    "MAX_LINE_BYTES",
    "MAX_MANIFEST_BYTES",
    "MAX_NESTING",
    "MAX_RUNS",
    "MAX_SET_ROWS",
    "METHODS",
    "MIN_TRACKING_SAMPLES",
    "NOISE_PLACEMENTS",
    "PHO_LOOP_KEYS",
    "TRACKING_COLUMNS",
    "TRACKING_LOOP_KEYS",
    "VELOCITY_PRESETS",
    "ExperimentSet",
    "Run",
    "not_regular",
    "open_regular",
    "parse_manifest",
    "read_digital_loop",
    "read_experiment",
    "read_manifest",
    "read_manifest_bytes",
    "read_noise_placement",
    "run_from_arrays",
    "write_experiment",
]
