"""The identification's entry points: one call for every method of the format.

:func:`identify` reads a set's ``method`` and hands it, with its options, to the method's own
pipeline through the one dispatch of :mod:`phoid.methods.registry` (that of ``phoid identify``
and ``phoid batch`` too): PHO sets to :func:`phoid.methods.identification.identify_pho`,
forced and free sets to :func:`phoid.methods.forced.identify_forced` and
:func:`phoid.methods.free.identify_free`, tracking sets to
:func:`phoid.methods.tracking_identification.identify_tracking`.
:func:`identify_data` is the PHO pipeline on records in memory (arrays or pandas objects).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from phoid.io.frames import is_table, table_columns
from phoid.methods.identification import identify_pho_data
from phoid.methods.pho_result import Identification
from phoid.methods.registry import identify_with

if TYPE_CHECKING:
    from phoid.methods.forced import ForcedIdentification
    from phoid.methods.free import FreeIdentification
    from phoid.methods.free_friction import FreeFrictionIdentification
    from phoid.methods.friction import FrictionFit
    from phoid.methods.tracking_identification import TrackingIdentification

__all__ = ["identify", "identify_data"]


def identify(
    experiment: Any,
    *,
    delay: float | None = None,
    estimator: str | None = None,
    compensate: bool = True,
    mass: float | None = None,
    friction: bool = False,
    noise_placement: str | None = None,
) -> Identification | ForcedIdentification | FreeIdentification | FrictionFit | \
        FreeFrictionIdentification | TrackingIdentification:
    """Identify a read experiment set by its ``method``: m, c, k (or what the method gives).

    The one dispatch of :mod:`phoid.methods.registry`, as ``phoid identify`` runs it: the same
    checks, the same exception and message for the same mistake, the options named by their
    keywords here (``compensate=False`` where the command line says ``--no-compensation``).

    Parameters
    ----------
    experiment : phoid.io.ExperimentSet, str or os.PathLike
        The runs and the manifest's settings (``method``, ``[loop] delay``, …), as read by
        :func:`phoid.io.read_experiment`; or the path of a set (its folder or manifest), read
        here by :func:`phoid.io.read_experiment` (whose errors it raises).
    delay : float, optional
        pho: the loop delay Δt (s), overriding the manifest's; tracking: the command delay τ.
    estimator : str, optional
        PHO sets: ``"gls"``, the efficient weighted fit through the exact loop roots (the
        default), or ``"ols"``, the paper's eq. (35) lines by ordinary least squares. Tracking
        sets: ``"idim"``, ``"output-error"`` or ``"auto"`` (default: the set's ``estimator``).
    compensate : bool, default True
        Correct for the delay (eqs. 28–32). False reproduces the paper's uncompensated column
        (only with ``estimator="ols"``).
    mass : float, optional
        Free-decay sets: the known mass, kg (overrides the manifest's ``mass``): c and k too.
    friction : bool, default False
        PHO sets: fit Coulomb friction f_c too, through the stick-slip simulator
        (:func:`phoid.methods.friction.identify_friction_set`); free sets: the decay with
        Coulomb and viscous friction and its stop
        (:func:`phoid.methods.free_friction.identify_free_friction`).
    noise_placement : {"auto", "in-loop", "outside"}, optional
        PHO sets: where the sensor noise enters. ``"in-loop"``: the controller reads the
        recorded position (a digital rig), m, c, k from the output error of the plant driven by
        the applied force; ``"outside"``: from the runs' modes; None or ``"auto"``: the
        manifest's ``[loop] noise``, else chosen by the data (digital loops;
        :mod:`phoid.methods.inloop_route`). The result's ``noise_placement`` says which.

    Returns
    -------
    object
        The result of the set's method (:data:`phoid.methods.registry.METHODS`): PHO sets
        :class:`~phoid.methods.pho_result.Identification`
        (:func:`phoid.methods.identification.identify_pho`; with ``friction=True``
        :func:`phoid.methods.friction.identify_friction_set`'s ``FrictionFit``), forced sets
        :func:`phoid.methods.forced.identify_forced`'s ``ForcedIdentification``, free sets
        :func:`phoid.methods.free.identify_free`'s ``FreeIdentification`` (with
        ``friction=True`` :func:`phoid.methods.free_friction.identify_free_friction`'s
        ``FreeFrictionIdentification``), tracking sets
        :func:`phoid.methods.tracking_identification.identify_tracking`'s
        ``TrackingIdentification``.

    Raises
    ------
    TypeError
        When ``experiment`` is neither an experiment set nor a path.
    IdentificationError
        An option that does not apply to the set's method, an unknown ``estimator``, or data
        that cannot determine the parameters (no usable runs, all gains equal, …).
    """
    if isinstance(experiment, str | os.PathLike):
        from phoid.io import read_experiment

        experiment = read_experiment(experiment)
    elif not hasattr(experiment, "runs"):
        raise TypeError("phoid.identify needs an ExperimentSet (phoid.io.read_experiment) or "
                        f"the path of a set's folder or manifest; got {type(experiment).__name__}")
    return identify_with(experiment, {"delay": delay, "estimator": estimator,
                                      "no_compensation": _no_compensation(compensate),
                                      "mass": mass, "friction": friction,
                                      "noise": noise_placement}, style="api")


def _no_compensation(compensate: Any) -> Any:
    """``compensate`` as the registry's ``no_compensation`` (a non-bool passed on as it is
    given, for the registry to refuse it by the keyword's name)."""
    if isinstance(compensate, bool) or getattr(getattr(compensate, "dtype", None), "kind",
                                               None) == "b":
        return not bool(compensate)
    return compensate


def identify_data(
    data: Sequence[Any],
    P: Any,
    D: Any,
    delay: float | None,
    *,
    files: Sequence[str] | None = None,
    names: Sequence[str] | None = None,
    estimator: str = "gls",
    compensate: bool = True,
    source: str = "",
    digital: Any = None,
    added_mass: Any = None,
    u: Sequence[Any] | None = None,
) -> Identification:
    """The PHO pipeline on records in memory: :func:`identify` without a manifest.

    Records given as arrays carry no ``method``, so there is nothing to dispatch: this is
    :func:`phoid.methods.identification.identify_pho_data`, with each record given either as
    a pair (t, x) of arrays or as a pandas object (:func:`phoid.io.frames.table_columns`): a
    Series (index t, values x) or a DataFrame
    (column ``x``, optionally ``u``; t from a column ``t`` or the index; a datetime or
    timedelta index becomes seconds from the first sample).

    Parameters
    ----------
    data : sequence of (t, x), pandas.Series or pandas.DataFrame
        Each run's record: time (s) and position (m).
    P, D : array_like
        Each run's gains, N/m and N·s/m.
    delay : float or None
        Loop delay Δt, s; None estimates it.
    files, names, estimator, compensate, source, digital, added_mass
        As :func:`phoid.methods.identification.identify_pho_data`.
    u : sequence of ndarray or None, optional
        Each run's recorded feedback force, N; when not given, a DataFrame's ``u`` column.

    Returns
    -------
    Identification

    Raises
    ------
    ValueError
        A table without an ``x`` column, with an unknown column, a non-finite value or a
        time that does not increase (naming ``data[i]`` and the column).
    IdentificationError
        When the data cannot determine m, c, k.
    """
    records = list(data)
    tables = [is_table(r) for r in records]
    if any(tables):
        us: list[Any] = []
        for i, is_tab in enumerate(tables):
            if is_tab:
                ui = u[i] if u is not None and i < len(u) else None
                same = getattr(getattr(ui, "index", None), "equals", None)
                if is_table(ui) and callable(same) and not same(records[i].index):
                    # a Series in u is read by position: its index must be its run's
                    raise ValueError(f"u[{i}] is a Series whose index is not that of data[{i}]; "
                                     f"align it first (reindex) or make it data[{i}]'s column 'u'")
                cols = table_columns(records[i], f"data[{i}]")
                records[i] = (cols["t"], cols["x"])
                us.append(cols.get("u"))
            else:
                us.append(None)
        if u is None and any(one is not None for one in us):
            u = us
    return identify_pho_data(records, P, D, delay, files=files, names=names,
                             estimator=estimator, compensate=compensate, source=source,
                             digital=digital, added_mass=added_mass, u=u)
