"""phoid.reports: plain-text reports (:mod:`~phoid.reports.text`) and figures
(:mod:`~phoid.reports.figures`, matplotlib imported only when drawing) of results.

Results are taken by duck typing: nothing here imports the methods, planning or paper modules.
"""

from phoid.reports.figures import (
    figure1,
    plot_identification,
    save_png,
)
from phoid.reports.text import (
    format_estimate,
    friction_text,
    identification_text,
)

__all__ = [
    "figure1",
    "format_estimate",
    "friction_text",
    "identification_text",
    "plot_identification",
    "save_png",
]
