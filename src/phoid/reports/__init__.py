"""phoid.reports: plain-text reports (:mod:`~phoid.reports.text`) and figures
(:mod:`~phoid.reports.figures` writes them, :mod:`~phoid.reports.runs` and
:mod:`~phoid.reports.lines` draw them; matplotlib imported only when drawing) of results,
and both for a tracking validation (:mod:`~phoid.reports.tracking`).

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
from phoid.reports.text import (
    forced_text,
    format_estimate,
    free_text,
    friction_text,
    identification_text,
)
from phoid.reports.tracking import plot_tracking, tracking_text, validation_lines

__all__ = [
    "figure1",
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
    "tracking_text",
    "validation_lines",
]
