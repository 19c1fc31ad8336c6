"""The export methods results share: ``to_control``, ``to_lti``, ``sample_plants``,
``to_pandas`` and, for results with feedback runs, ``closed_loop``.

A result class lists :class:`PlantExports` (or :class:`LoopExports`) among its bases and gets
the methods, each a one-line delegation to :mod:`phoid.interop`: the functions read the result
by duck typing (:func:`phoid.interop.plant.linear_plant`), so the methods carry no state and
the dataclass fields of the result are untouched. python-control and pandas are imported only
when a method is called.
"""

from __future__ import annotations

from typing import Any

__all__ = ["LoopExports", "PlantExports"]


class PlantExports:
    """The identified plant G(s) = 1/(m s² + c s + k) exported (a mixin of result classes)."""

    __slots__ = ()

    def to_control(self, *, form: str = "tf") -> Any:
        """The identified plant G(s) = 1/(m s² + c s + k), force (N) → position (m), as a
        python-control system (:func:`phoid.interop.control.to_control`).

        ``form="tf"`` gives a TransferFunction, ``"ss"`` a StateSpace with states x (m) and
        v (m/s); the covariance of (m, c, k) travels as ``.phoid.cov``.
        """
        from phoid.interop.control import to_control

        return to_control(self, form=form)

    def to_lti(self, *, form: str = "tf") -> Any:
        """The identified plant as a :class:`scipy.signal.lti` (no python-control needed;
        :func:`phoid.interop.control.to_lti`)."""
        from phoid.interop.control import to_lti

        return to_lti(self, form=form)

    def sample_plants(self, n: int, rng: Any = None, *, form: str = "plant") -> list:
        """``n`` Monte Carlo plants: (m, c, k) drawn from the estimates' normal with this
        result's covariance, draws with m ≤ 0, c < 0 or k < 0 rejected
        (:func:`phoid.interop.sampling.sample_plants`; ``form`` "plant", "tf", "ss", "lti")."""
        from phoid.interop.sampling import sample_plants

        return sample_plants(self, n, rng, form=form)

    def to_pandas(self) -> Any:
        """``Frames(estimates, runs)``: the estimates (rows m, c, k, …; columns value, stderr,
        unit) and the runs (one row per run) as pandas DataFrames
        (:func:`phoid.interop.tables.to_pandas`)."""
        from phoid.interop.tables import to_pandas

        return to_pandas(self)


class LoopExports(PlantExports):
    """:class:`PlantExports` and each feedback run's closed loop (a mixin of result classes)."""

    __slots__ = ()

    def closed_loop(self, run: int | str, *, pade_order: int | None = None,
                    form: str = "tf") -> Any:
        """One run's closed loop, external force (N) → position (m), as a python-control
        system (:func:`phoid.interop.control.closed_loop`): exact without a delay, the delay
        as a Padé approximant (``pade_order``; by default the lowest that matches the loop's
        certified dominant root), or the exact discrete-time loop of a sampled controller.
        ``.phoid`` carries the run, the Padé order and its error."""
        from phoid.interop.control import closed_loop

        return closed_loop(self, run, pade_order=pade_order, form=form)
