"""Exceptions raised by phoid.

Every exception subclasses a builtin (``ValueError``), so callers can catch either the phoid class
or the builtin, as in python-control's ``control.exception``.
"""

from __future__ import annotations

__all__ = ["ExperimentError", "IdentificationError", "OutputError", "PhoidError"]


class PhoidError(ValueError):
    """Base class of phoid's errors: bad input or data that cannot support an answer."""


class ExperimentError(PhoidError):
    """An experiment set (manifest or data file) is missing, malformed or inconsistent."""


class IdentificationError(PhoidError):
    """The data cannot determine the requested parameters (e.g. too few usable runs)."""


class OutputError(PhoidError):
    """A file cannot be written safely: a link in the way, a file that exists, a write failure."""
