"""The base every identification result shares: warnings, adequacy, fit statistics, report.

A method's result is a frozen dataclass that lists :class:`ResultBase` (or, for a result of
m, c, k, :class:`PlantResult`) among its bases. The base holds what every result carries —
its ``warnings``, the ``source`` it came from, the records it was fitted to (``data``, for the
figures and the residual/noise ratios) and an ``adequacy`` slot (the model-adequacy checks of
:mod:`phoid.methods.adequacy`, or None where they were not made) — as keyword-only fields,
so that a subclass's own fields keep their order, and the pieces of ``summary()`` that every
method writes the same way: the ``runs`` with each run's ``residual_noise_ratio``, the
``adequacy`` block and the ``covariance``, ``correlation`` and ``statistics`` blocks
(:meth:`ResultBase.fit_statistics`). Its ``report()`` and ``plot()`` call the functions of
:mod:`phoid.reports` that its class names (``REPORT``, ``FIGURES``), imported when called;
its one-line ``repr`` and notebook display are :class:`~phoid.reports.display.NotebookDisplay`.

A subclass supplies :meth:`ResultBase.statistics_of` (which parameters, their covariance and
χ²) and its own ``summary()``, built from these pieces in the order of docs/format.md. The
estimates themselves stay the subclass's fields (``m``, ``c``, ``k``; a free decay's ``sigma``,
``omega0``, …; a tracking result's ``estimates`` mapping, which :mod:`phoid.interop` reads
as the mark of a tracking result): the base defines no attribute a subclass might make a
field, so that none of them becomes a property here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from phoid.interop.exports import PlantExports
from phoid.io.units import quantity_unit, relabel
from phoid.methods.estimate import Estimate
from phoid.methods.fit_statistics import fit_blocks
from phoid.methods.pho import open_loop_omega0, open_loop_zeta
from phoid.methods.registry import load
from phoid.reports.display import NotebookDisplay

__all__ = ["PlantResult", "ResultBase"]


@dataclass(frozen=True, repr=False, kw_only=True)
class ResultBase(NotebookDisplay):
    """What every identification result carries, and the parts of its summary they share.

    Attributes
    ----------
    warnings : tuple of str
        What the data cannot support, in the user's words (text report, ``--json``, HTML,
        notebook and batch rows show them).
    source : str
        Where the data came from (a path or a description).
    data : tuple
        Each run's record as arrays (t, x, …), for the figures and the residual/noise ratios
        (empty when the result carries none).
    adequacy : object or None
        The model-adequacy checks of the fit (an object with ``to_dict()``; its dict is
        ``summary()["adequacy"]``), None where they were not made.
    """

    warnings: tuple[str, ...] = ()
    source: str = ""
    data: tuple[Any, ...] = field(default=(), repr=False)
    adequacy: Any = None

    #: ``method`` in ``summary()`` ("pho", "forced", …)
    METHOD: ClassVar[str] = ""
    #: the text report, ``"module:function"`` taking the result (phoid.reports)
    REPORT: ClassVar[str] = ""
    #: the figures, ``"module:function"`` taking (result, folder, overwrite=) (phoid.reports)
    FIGURES: ClassVar[str] = ""

    def statistics_of(self) -> tuple[Sequence[str], Sequence[str], np.ndarray,
                                     float | None, int | None, str]:
        """The fit's parameters, their units, covariance, χ², dof and what the fit was
        (the arguments of :func:`phoid.methods.fit_statistics.fit_blocks`)."""
        raise NotImplementedError(f"{type(self).__name__} does not define statistics_of()")

    def fit_statistics(self) -> dict[str, Any]:
        """The ``covariance``, ``correlation`` and ``statistics`` blocks of ``summary()``
        (docs/format.md, "Fit statistics"), from :meth:`statistics_of`; the units read as the
        set's x makes them (:func:`phoid.io.units.quantity_unit` of the result's ``x_unit``,
        where it has one: J in kg m^2 for x in rad)."""
        names, units, cov, chi2, dof, of = self.statistics_of()
        return fit_blocks(names, [self.unit_of(u) for u in units], cov, chi2, dof, of=of)

    def unit_of(self, unit: str) -> str:
        """One of phoid's SI unit strings (``"N/m"``, ``"m"`` …) as the result's x makes it
        (:func:`phoid.io.units.quantity_unit` of its ``x_unit``, where it has one; the reports
        label their columns by it)."""
        return quantity_unit(unit, str(getattr(self, "x_unit", "m")))

    def residual_noise_ratios(self) -> list[float | None]:
        """Per run: its fit's residual RMS over the record's own noise level (≈ 1 when the
        model explains the record to its noise); None where not known. The base knows no
        runs: a subclass with runs overrides it."""
        return []

    def run_entries(self) -> list[dict[str, Any]]:
        """``summary()["runs"]``: each run's ``to_dict()`` with its ``residual_noise_ratio``."""
        runs = getattr(self, "runs", ())
        return [r.to_dict() | {"residual_noise_ratio": q}
                for r, q in zip(runs, self.residual_noise_ratios(), strict=True)]

    def adequacy_entry(self) -> dict[str, Any]:
        """``{"adequacy": …}`` when the adequacy checks were made, else nothing (its units
        read as the result's ``x_unit`` makes them)."""
        if self.adequacy is None:
            return {}
        return {"adequacy": relabel(self.adequacy.to_dict(),
                                    str(getattr(self, "x_unit", "m")))}

    def summary_tail(self) -> dict[str, Any]:
        """The last keys of every ``summary()``: ``warnings``, the ``adequacy`` block (when
        made) and the fit statistics."""
        return {"warnings": list(self.warnings), **self.adequacy_entry(),
                **self.fit_statistics()}

    def report(self) -> str:
        """The plain-text report (the function of :mod:`phoid.reports` named by ``REPORT``),
        no line wider than 100 columns (:func:`phoid._notation.fit_width`)."""
        from phoid._notation import fit_width

        return fit_width(load(self.REPORT)(self))

    def plot(self, out_dir: str | Path, *, overwrite: bool = False) -> list[Path]:
        """Write the result's figures as PNG files into ``out_dir`` (the function of
        :mod:`phoid.reports` named by ``FIGURES``): created if needed, existing files replaced
        only with ``overwrite``, links refused (:mod:`phoid._output`). Returns the paths."""
        return load(self.FIGURES)(self, out_dir, overwrite=overwrite)


@dataclass(frozen=True, repr=False, kw_only=True)
class PlantResult(ResultBase, PlantExports):
    """A result of the plant's m, c, k (fields ``m``, ``c``, ``k`` and ``fit`` with its
    ``cov``; no ``estimates`` mapping, which marks a tracking result): ω₀ and ζ derived with
    their stderr, and the exports of :class:`~phoid.interop.exports.PlantExports`
    (python-control, scipy.signal, pandas)."""

    @property
    def cov(self) -> np.ndarray:
        """(3, 3) covariance of (m, c, k)."""
        return self.fit.cov  # type: ignore[attr-defined]

    @property
    def omega0(self) -> Estimate:
        """Open-loop natural frequency ω₀ = √(k/m), rad/s (eq. 5), delta-method stderr."""
        return open_loop_omega0(self.m.value, self.k.value, self.cov)  # type: ignore[attr-defined]

    @property
    def zeta(self) -> Estimate:
        """Open-loop damping ratio ζ = c/(2√(mk)) (eq. 10), delta-method stderr."""
        return open_loop_zeta(self.m.value, self.c.value,  # type: ignore[attr-defined]
                              self.k.value, self.cov)  # type: ignore[attr-defined]

    def estimate_entries(self) -> dict[str, Any]:
        """``m``, ``c``, ``k`` of ``summary()``, each ``{value, stderr, unit}``."""
        return {name: getattr(self, name).to_dict() for name in ("m", "c", "k")}

    def derived_entries(self) -> dict[str, Any]:
        """``omega0`` and ``zeta`` of ``summary()``, each where it is defined (finite)."""
        out: dict[str, Any] = {}
        for key in ("omega0", "zeta"):
            est = getattr(self, key)
            if math.isfinite(est.value):
                out[key] = est.to_dict()
        return out

