"""The identification's entry points: one call for every method of the format.

:func:`identify` reads a set's ``method`` and hands it to the method's own pipeline: PHO sets
to :func:`phoid.methods.identification.identify_pho`, forced and free sets to
:func:`phoid.methods.forced.identify_forced` and :func:`phoid.methods.free.identify_free`,
tracking sets to :func:`phoid.methods.tracking_identification.identify_tracking`.
:func:`identify_data` is the PHO pipeline on plain arrays.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from phoid.errors import IdentificationError
from phoid.methods.identification import check_estimator, identify_pho, identify_pho_data
from phoid.methods.pho_checks import refuse_bias
from phoid.methods.pho_result import Identification

if TYPE_CHECKING:
    from phoid.methods.forced import ForcedIdentification
    from phoid.methods.free import FreeIdentification
    from phoid.methods.tracking_identification import TrackingIdentification

__all__ = ["identify", "identify_data"]


def identify(
    experiment: Any,
    *,
    delay: float | None = None,
    estimator: str | None = None,
    compensate: bool = True,
) -> Identification | ForcedIdentification | FreeIdentification | TrackingIdentification:
    """Identify m, c, k from a PHO experiment set.

    Parameters
    ----------
    experiment : phoid.io.ExperimentSet
        The runs (t, x, P, D) and the loop delay (``[loop] delay``), as read by
        :func:`phoid.io.read_experiment`.
    delay : float, optional
        Loop delay Δt (s), overriding the manifest's (a tracking set: the command delay τ).
    estimator : str, optional
        PHO sets: ``"gls"``, the efficient weighted fit through the exact loop roots (the
        default), or ``"ols"``, the paper's eq. (35) lines by ordinary least squares. Tracking
        sets: ``"idim"``, ``"output-error"`` or ``"auto"`` (default: the set's ``estimator``).
    compensate : bool, default True
        Correct for the delay (eqs. 28–32). False reproduces the paper's uncompensated column
        (only with ``estimator="ols"``).

    Returns
    -------
    Identification
        For ``method = "forced"`` or ``"free"`` sets the result of
        :func:`phoid.methods.forced.identify_forced` or :func:`phoid.methods.free.identify_free`
        (a known mass for a free set: :func:`phoid.methods.free.identify_free` with ``mass=``).

    Raises
    ------
    IdentificationError
        When the data cannot determine m, c, k (no usable runs, all gains equal, …).
    """
    method = getattr(experiment, "method", "pho")
    if method == "tracking":
        if not compensate:
            raise IdentificationError(f"{experiment.path}: `compensate` applies to PHO sets only")
        from phoid.methods.tracking_identification import identify_tracking

        return identify_tracking(experiment, delay=delay, estimator=estimator)
    estimator = "gls" if estimator is None else estimator
    check_estimator(estimator, compensate)
    refuse_bias(experiment, method)
    if method in ("forced", "free"):
        # the other methods of the format, with their own estimators; PHO-only options refused
        if delay is not None or estimator != "gls" or not compensate:
            raise IdentificationError(
                f"{experiment.path}: method = {method!r}: `delay`, `estimator` and "
                "`compensate` apply to PHO sets only"
            )
        if method == "forced":
            from phoid.methods.forced import identify_forced

            return identify_forced(experiment)
        from phoid.methods.free import identify_free

        return identify_free(experiment)
    if method != "pho":
        raise IdentificationError(f"{experiment.path}: method = {method!r} is not known")
    return identify_pho(experiment, delay=delay, estimator=estimator, compensate=compensate)


#: :func:`identify` on plain arrays (``data``: a sequence of (t, x) per run). Records given as
#: arrays carry no ``method``, so there is nothing to dispatch: this is the PHO pipeline itself,
#: :func:`phoid.methods.identification.identify_pho_data`, under its public name.
identify_data = identify_pho_data
