"""One experiment set, identified with the command line's options: the dispatch by method.

``phoid identify SET`` (without its --plots and --html) and every set of ``phoid batch`` go
through :func:`identify_set`, so that a batch row holds the very numbers ``phoid identify
--json`` prints for the same set and options. It is :func:`phoid.methods.registry.identify_with`
in the command line's words; :func:`phoid.identify` is the same dispatch in Python's.
"""

from __future__ import annotations

from typing import Any

from phoid.methods.registry import identify_with

__all__ = ["identify_set"]


def identify_set(exp: Any, *, estimator: str | None = None, delay: float | None = None,
                 no_compensation: bool = False, mass: float | None = None,
                 friction: bool = False, noise: str | None = None) -> Any:
    """Identify a read experiment set by its method, with ``phoid identify``'s options.

    Parameters
    ----------
    exp : phoid.io.ExperimentSet
        The set, as read by :func:`phoid.io.read_experiment`.
    estimator : str, optional
        pho: ``"gls"`` (default) or ``"ols"``; tracking: ``"idim"``, ``"output-error"`` or
        ``"auto"`` (default: the manifest's).
    delay : float, optional
        Loop delay Δt, s, overriding the manifest's (tracking: the command delay τ).
    no_compensation : bool, default False
        pho with ``estimator="ols"``: ignore the delay (the paper's uncompensated column).
    mass : float, optional
        Known mass, kg, of a free-decay set (then c and k too).
    friction : bool, default False
        pho: fit Coulomb friction f_c too, through the stick-slip simulator; free: the decay
        with Coulomb and viscous friction and its stop
        (:func:`phoid.methods.free_friction.identify_free_friction`).
    noise : str, optional
        pho: where the sensor noise enters, ``"in-loop"``, ``"outside"`` or ``"auto"``
        (default: the manifest's ``[loop] noise``, else chosen by the data).

    Returns
    -------
    Identification, ForcedIdentification, FreeIdentification, FrictionFit,
    FreeFrictionIdentification or TrackingIdentification
        The method's result (its ``summary()`` is ``phoid identify --json``).

    Raises
    ------
    IdentificationError
        One line naming the set, when an option does not apply to the set's method, or the
        data cannot give the parameters (a ``ValueError``; the options named as the command
        line names them: ``--no-compensation``).
    """
    return identify_with(exp, {"estimator": estimator, "delay": delay,
                               "no_compensation": no_compensation, "mass": mass,
                               "friction": friction, "noise": noise}, style="cli")
