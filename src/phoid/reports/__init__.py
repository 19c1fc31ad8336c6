"""phoid.reports."""

from phoid.reports.text import (
    figure1,
    identification_text,
    plot_identification,
)

__all__ = [
    "figure1",
    "identification_text",
    "plot_identification",
]
