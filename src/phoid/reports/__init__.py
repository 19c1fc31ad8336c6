"""phoid.reports: plain-text reports (:mod:`~phoid.reports.text`) and figures
(:mod:`~phoid.reports.figures` writes them, :mod:`~phoid.reports.runs` and
:mod:`~phoid.reports.lines` draw them; matplotlib imported only when drawing) of results,
both for a tracking validation (:mod:`~phoid.reports.tracking`), the fit statistics' blocks
(:mod:`~phoid.reports.statistics`: covariance → correlation, JSON and text) and HTML views
(:mod:`~phoid.reports.html`: the notebook display and the single-file report). The notation
and its ASCII spelling for a stream that cannot show it are phoid's base (``phoid._notation``):
the error line every command prints uses them too.

Results are taken by duck typing: nothing here imports the methods, planning or paper modules.
"""

from phoid.reports.figures import (
    figure1,
    plot_forced,
    plot_free,
    plot_friction,
    plot_identification,
    save_png,
)
from phoid.reports.statistics import (
    correlation,
    correlation_json,
    correlation_lines,
    covariance_json,
    statistics_json,
    statistics_lines,
)
from phoid.reports.text import (
    fit_statistics_lines,
    forced_text,
    format_estimate,
    free_text,
    friction_text,
    identification_text,
)
from phoid.reports.tracking import plot_tracking, tracking_text, validation_lines

__all__ = [
    "correlation",
    "correlation_json",
    "correlation_lines",
    "covariance_json",
    "figure1",
    "fit_statistics_lines",
    "forced_text",
    "format_estimate",
    "free_text",
    "friction_text",
    "identification_text",
    "plot_forced",
    "plot_free",
    "plot_friction",
    "plot_identification",
    "plot_tracking",
    "save_png",
    "statistics_json",
    "statistics_lines",
    "tracking_text",
    "validation_lines",
]
