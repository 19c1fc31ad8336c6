"""One experiment set, identified with the command line's options: the dispatch by method.

``phoid identify SET`` (without its --plots and --html) and every set of ``phoid batch`` go
through :func:`identify_set`, so that a batch row holds the very numbers ``phoid identify
--json`` prints for the same set and options.
"""

from __future__ import annotations

from typing import Any

__all__ = ["identify_set"]


def identify_set(exp: Any, *, estimator: str | None = None, delay: float | None = None,
                 no_compensation: bool = False, mass: float | None = None,
                 friction: bool = False) -> Any:
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
        pho: fit Coulomb friction f_c too, through the stick-slip simulator.

    Returns
    -------
    Identification, ForcedIdentification, FreeIdentification or TrackingIdentification
        The method's result (its ``summary()`` is ``phoid identify --json``).

    Raises
    ------
    ValueError
        One line, when an option does not apply to the set's method or the data cannot give
        the parameters (:class:`~phoid.errors.IdentificationError` is one).
    """
    if exp.method == "tracking":
        if mass is not None or friction or no_compensation:
            raise ValueError("--mass, --friction and --no-compensation do not apply to "
                             f"tracking sets; {exp.path} is one (its [fixed] table holds "
                             "known parameters)")
        from phoid.methods.tracking_identification import identify_tracking

        return identify_tracking(exp, delay=delay, estimator=estimator)
    estimator = "gls" if estimator is None else estimator
    if no_compensation and estimator != "ols":
        raise ValueError("--no-compensation needs --estimator ols (the eq. (35) lines)")
    if friction and (exp.method != "pho" or estimator != "gls" or no_compensation):
        raise ValueError("--friction applies to pho sets, without --estimator ols or "
                         "--no-compensation")
    if not friction:
        from phoid.methods.pho_checks import refuse_bias

        refuse_bias(exp, exp.method)  # a biased command: only the friction fit models it
    if exp.method == "pho":
        if mass is not None:
            raise ValueError("--mass applies to free-decay sets (method = \"free\") only")
        if friction:
            from phoid.methods.friction import identify_friction_set

            return identify_friction_set(exp, delay=delay)
        from phoid.methods.identification import check_estimator, identify_pho

        check_estimator(estimator, not no_compensation)
        return identify_pho(exp, delay=delay, estimator=estimator,
                            compensate=not no_compensation)
    for flag, given in (("--delay", delay is not None),
                        ("--estimator", estimator != "gls"),
                        ("--no-compensation", no_compensation)):
        if given:
            raise ValueError(f"{flag} applies to pho sets only; {exp.path} is a "
                             f"{exp.method} set")
    if exp.method == "forced":
        from phoid.methods.forced import identify_forced

        if mass is not None:
            raise ValueError("--mass applies to free-decay sets only (a forced set gives m)")
        return identify_forced(exp)
    if exp.method != "free":
        from phoid.errors import IdentificationError

        raise IdentificationError(f"{exp.path}: method = {exp.method!r} is not known")
    from phoid.methods.free import identify_free

    return identify_free(exp, mass=mass)
