"""How a result shows itself: a one-line ``repr`` and the notebook's ``_repr_html_``.

A result or design class lists :class:`NotebookDisplay` among its bases (a dataclass with
``repr=False``, so that the generated field dump does not replace the mixin's ``__repr__``);
both methods delegate to :mod:`phoid.reports.html`, which reads the object by duck typing
(its ``summary()``, ``warnings``, …) and is imported only when an object is shown.
"""

from __future__ import annotations

__all__ = ["NotebookDisplay"]


class NotebookDisplay:
    """A one-line ``repr`` and a notebook ``_repr_html_`` (a mixin of result classes)."""

    __slots__ = ()

    def __repr__(self) -> str:
        """One line: the class, its estimates ± stderr with units, runs and warnings
        (:func:`phoid.reports.html.short_repr`)."""
        from phoid.reports.html import short_repr

        return short_repr(self)

    def _repr_html_(self) -> str:
        """HTML for notebooks (:func:`phoid.reports.html.result_html`)."""
        from phoid.reports.html import result_html

        return result_html(self)
