"""Many experiment sets at once, on a Dask cluster: ``phoid batch`` and ``identify_many``.

Modules: :mod:`phoid.batch.cluster` (a client to a running scheduler or a local cluster, a
map over items with a progress bar, the check for the ``phoid[batch]`` extra),
:mod:`phoid.batch.engine` (the batch), :mod:`phoid.batch.drift` (the trend) and
:mod:`phoid.batch.rehearsal` (a design rehearsed). The names of ``__all__`` are imported from
their modules on first use (:mod:`phoid._lazy`), so that ``phoid --help``, which registers
``phoid batch`` and ``phoid trend``, loads none of them; dask, distributed, pandas and pyarrow
are imported inside functions.
"""

from typing import TYPE_CHECKING

from phoid._lazy import lazy_exports

if TYPE_CHECKING:  # the real imports, for type checkers; at run time see __getattr__
    from phoid.batch.cluster import cluster_client, map_unordered, require_batch
    from phoid.batch.drift import (
        ChartPoint,
        ParameterChart,
        Trend,
        UnitTrend,
        control_chart,
        read_results,
        trend,
    )
    from phoid.batch.drift_plot import plot_trend
    from phoid.batch.engine import BatchReport, identify_many, run_batch
    from phoid.batch.rehearsal import ParameterRehearsal, Rehearsal, rehearse
    from phoid.batch.rows import SCHEMA
    from phoid.batch.sets import SetDigest, expand_sets, set_digest

_EXPORTS = {
    **dict.fromkeys(("cluster_client", "map_unordered", "require_batch"), "phoid.batch.cluster"),
    **dict.fromkeys(("ChartPoint", "ParameterChart", "Trend", "UnitTrend", "control_chart",
                     "read_results", "trend"), "phoid.batch.drift"),
    "plot_trend": "phoid.batch.drift_plot",
    **dict.fromkeys(("BatchReport", "identify_many", "run_batch"), "phoid.batch.engine"),
    **dict.fromkeys(("ParameterRehearsal", "Rehearsal", "rehearse"), "phoid.batch.rehearsal"),
    "SCHEMA": "phoid.batch.rows",
    **dict.fromkeys(("SetDigest", "expand_sets", "set_digest"), "phoid.batch.sets"),
}

__getattr__, __dir__ = lazy_exports(__name__, globals(), _EXPORTS)

__all__ = [
    "SCHEMA",
    "BatchReport",
    "ChartPoint",
    "ParameterChart",
    "ParameterRehearsal",
    "Rehearsal",
    "SetDigest",
    "Trend",
    "UnitTrend",
    "cluster_client",
    "control_chart",
    "expand_sets",
    "identify_many",
    "map_unordered",
    "plot_trend",
    "read_results",
    "rehearse",
    "require_batch",
    "run_batch",
    "set_digest",
    "trend",
]
