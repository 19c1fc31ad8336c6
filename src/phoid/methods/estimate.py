"""A physical estimate with its one-standard-deviation uncertainty: the value type every
identification result holds (pho, forced, free, friction, tracking) and the planning reports use.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from phoid._notation import unit_text
from phoid.reports.text import format_estimate

__all__ = ["Estimate"]


# a format spec that pads the whole "value ± stderr unit" text: [[fill]align][width][s]
_TEXT_SPEC = re.compile(r"(.?[<>^])?([1-9]\d*)?s?")


@dataclass(frozen=True)
class Estimate:
    """A physical estimate with its one-standard-deviation uncertainty.

    Attributes
    ----------
    value : float
        The estimate, in ``unit``.
    stderr : float or None
        One standard error, same unit (None when unknown).
    unit : str
        SI unit, as printed in the JSON output (e.g. ``"N s/m"``).
    white_stderr : float or None
        The white-noise least-squares standard error, when ``stderr`` is another one (the
        autocorrelation- and misfit-robust stderr of :mod:`phoid.methods.adequacy`); None when
        ``stderr`` is itself the white-noise one.
    """

    value: float
    stderr: float | None
    unit: str
    white_stderr: float | None = None

    def to_dict(self) -> dict:
        """Plain JSON-ready dict ``{"value", "stderr", "unit"}`` (and ``"stderr_white"`` when
        ``white_stderr`` is set); a value or stderr that is not
        finite (a stderr the data cannot give) is null, never NaN (not JSON)."""

        def num(x):
            return None if x is None or not math.isfinite(float(x)) else float(x)

        out = {"value": num(self.value), "stderr": num(self.stderr), "unit": self.unit}
        if self.white_stderr is not None:
            out["stderr_white"] = num(self.white_stderr)
        return out

    def __float__(self) -> float:
        """The value: ``float(est)`` is ``est.value``."""
        return float(self.value)

    def __format__(self, spec: str) -> str:
        """``format(est, spec)`` / f-strings: an empty ``spec`` gives ``"value ± stderr unit"``,
        rounded to the stderr's first two significant digits
        (:func:`phoid.reports.text.format_estimate`; the value alone when there is no
        stderr); a spec of fill, alignment and width only (``">30"``), or ending in ``s``,
        pads that text; any other spec formats the value (``f"{est:.4f}"`` is
        ``format(est.value, ".4f")``).
        """
        se = None if self.stderr is None else float(self.stderr)
        text = format_estimate(float(self.value), se)
        text = f"{text} {unit_text(self.unit)}" if self.unit else text
        if not spec:
            return text
        if _TEXT_SPEC.fullmatch(spec):
            return format(text, spec)
        return format(float(self.value), spec)
