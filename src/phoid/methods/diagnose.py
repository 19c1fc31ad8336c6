"""What is probably wrong with a PHO set whose runs do not fit one plant.

When the identification fails, or its runs disagree far beyond their noise, the cause is
usually a mistake in the set rather than in the rig: gains given with the other sign
convention, a loop delay that is not the rig's, one run's time column in milliseconds, one
run's gain mistyped. Each of these leaves a mark on the runs' rough modes (σᵢ, ω_dᵢ from the
decay fits' starting stage) that the straight lines of eq. (35) show cheaply:

- the runs' points are collinear with one positive slope m on both lines only with the right
  gains and delay (:func:`phoid.methods.pho.delay_profile` measures the misfit);
- a time column in ms makes one run's sample step 1000× the others', and a whole set's makes
  every rate 1000× too slow: its runs fit one plant once the rates are scaled back.

:func:`probable_cause` tries the usual mistakes in turn and names the one that makes the runs
agree, in the command line's words (a manifest field, or a flag).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from phoid.methods.pho import delay_profile, fit_lines

__all__ = ["SIGN_CONVENTION", "probable_cause"]

#: phoid's sign convention for the gains, as the messages state it
SIGN_CONVENTION = (
    "phoid's convention is u = -(P x(t - delay) + D x'(t - delay)), so P > 0 stiffens and "
    "D > 0 damps the loop"
)

# a run whose sample step differs from the set's median by more than this factor has another
# time unit (ms against s is 1000; a rig's sample rates differ by far less than 20)
_STEP_RATIO = 20.0
# an alternative (other signs, another delay, one run left out) is the probable cause when it
# lowers the lines' scaled misfit this much and leaves it small per point: a set that fits one
# plant has a misfit per point ~ (relative noise of σ, ω_d)², below 1e-4 even for noisy runs,
# while each of these mistakes gives 1e-1 … 1 per point
_BETTER = 1e-2
_AGREE = 1e-3
# a whole set's time axis in another unit: the unit, and the factor its rates σ, ω_d are read
# too slow by (t in ms read as s: 1000)
_TIME_UNITS = {"ms": 1e3, "us": 1e6, "min": 1.0 / 60.0}


def _misfit(sig, wd, P, D, delay, dm) -> float:
    """The lines' scaled misfit per point at one delay (None: at the best delay in
    0 … π/max ω_d), ∞ when either line's slope (the mass) is not positive."""
    if delay is None:
        grid = np.linspace(0.0, math.pi / float(np.max(wd)), 401)
        with np.errstate(all="ignore"):
            delay = float(grid[int(np.argmin(delay_profile(sig, wd, P, D, grid,
                                                           added_mass=dm)))])
    with np.errstate(all="ignore"):
        prof = float(delay_profile(sig, wd, P, D, [delay], added_mass=dm)[0])
        lines = fit_lines(sig, wd, P, D, delay, added_mass=dm)
    if not (lines.m > 0 and lines.c_line is not None and lines.c_line.slope > 0):
        return math.inf
    return prof / (2 * sig.size) if math.isfinite(prof) else math.inf


def probable_cause(
    sigma: np.ndarray,
    omega_d: np.ndarray,
    P: np.ndarray,
    D: np.ndarray,
    delay: float | None,
    *,
    steps: Sequence[float],
    names: Sequence[str],
    added_mass: np.ndarray | None = None,
    delay_flag: str = "[loop] delay (or phoid identify --delay)",
) -> str | None:
    """Name the mistake in a set that makes its runs disagree, or None if none is found.

    Parameters
    ----------
    sigma, omega_d : array_like
        Each run's rough decay rate (1/s) and damped frequency (rad/s); NaN for a run without
        one (it is left out of the line checks).
    P, D : array_like
        The gains as given, N/m and N·s/m.
    delay : float or None
        The loop delay as given, s (None: being estimated; the delay check is skipped).
    steps : sequence of float
        Each run's sample step, s (median of its first intervals).
    names : sequence of str
        Run names for the message.
    added_mass : array_like, optional
        Known mass added per run, kg.
    delay_flag : str
        How the message names the delay setting.

    Returns
    -------
    str or None
        One sentence saying what is probably wrong and how to put it right.
    """
    sigma = np.asarray(sigma, dtype=float)
    omega_d = np.asarray(omega_d, dtype=float)
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    n = sigma.size
    dm = np.zeros(n) if added_mass is None else np.asarray(added_mass, dtype=float)
    # 1. units of t: one run's sample step far from the others'
    st = np.asarray(steps, dtype=float)
    good = np.isfinite(st) & (st > 0)
    if np.count_nonzero(good) >= 2:
        med = float(np.median(st[good]))
        odd = [i for i in np.flatnonzero(good).tolist()
               if not 1 / _STEP_RATIO <= st[i] / med <= _STEP_RATIO]
        if odd and len(odd) < np.count_nonzero(good) / 2:
            i = odd[0]
            return (f"{names[i]}: its sample step ({st[i]:.3g} s) is {st[i] / med:.3g} times "
                    f"the other runs' ({med:.3g} s): t must be in seconds (is it in ms?)")
    ok = np.flatnonzero(np.isfinite(sigma) & np.isfinite(omega_d) & (omega_d > 0)
                        & np.isfinite(P) & np.isfinite(D))
    if ok.size < 3 or len({(float(P[i]), float(D[i])) for i in ok}) < 3:
        return None
    sig, wd, Pk, Dk, dmk = sigma[ok], omega_d[ok], P[ok], D[ok], dm[ok]
    tau = None if delay is None else float(delay)
    base = _misfit(sig, wd, Pk, Dk, tau, dmk)
    if base <= _AGREE:
        return None
    # 1b. units of t for the whole set: the runs fit one plant with every mode rescaled
    # (t read in s but written in ms: every rate σ, ω_d comes out 1000× too slow)
    for unit, factor in _TIME_UNITS.items():
        if tau is not None and factor * float(np.max(wd)) * tau >= math.pi:
            continue  # rates that fast would not be the loop's dominant mode at this delay
        try:
            alt = _misfit(factor * sig, factor * wd, Pk, Dk, tau, dmk)
        except (np.linalg.LinAlgError, ValueError, ArithmeticError):
            continue  # rates so far off that the lines cannot even be fitted: not this unit
        if alt <= _AGREE and alt <= _BETTER * base:
            return (f"the runs' time axis looks like it is in {unit}, not s: with t read as "
                    f"{unit} the runs fit one plant; give [units] t = \"{unit}\" in the "
                    "manifest (docs/format.md), or write t in seconds")
    # 2. the sign convention of the gains (every run alike: the usual mistake)
    flips = {"D": (1.0, -1.0), "P and D": (-1.0, -1.0), "P": (-1.0, 1.0)}
    for what, (a, b) in flips.items():
        alt = _misfit(sig, wd, a * Pk, b * Dk, tau, dmk)
        if alt <= _AGREE and alt <= _BETTER * base:
            plural = "s" if what == "P and D" else ""
            return (f"the gains look like they have the other sign: with every run's {what} "
                    f"negated the runs fit one plant; {SIGN_CONVENTION}: give {what} with "
                    f"th{'ose' if plural else 'at'} sign{plural}")
    # 3. one run that does not fit with the others (a mistyped gain, another unit)
    if ok.size >= 4:
        loo = []
        for j in range(ok.size):
            keep = np.arange(ok.size) != j
            if len({(float(p), float(d)) for p, d in zip(Pk[keep], Dk[keep], strict=True)}) < 3:
                loo.append(math.inf)
                continue
            loo.append(_misfit(sig[keep], wd[keep], Pk[keep], Dk[keep], tau, dmk[keep]))
        j = int(np.argmin(loo))
        if loo[j] <= _AGREE and loo[j] <= _BETTER * base:
            i = int(ok[j])
            return (f"{names[i]} does not fit with the other runs, which agree: check its gains "
                    f"(P = {float(P[i]):.6g} N/m, D = {float(D[i]):.6g} N s/m) and the units "
                    "of its t (s) and x (m)")
    # 4. the delay: the one that makes the runs agree
    if delay is not None:
        hi = math.pi / float(np.max(wd))
        grid = np.linspace(0.0, hi, 401)
        with np.errstate(all="ignore"):
            prof = delay_profile(sig, wd, Pk, Dk, grid, added_mass=dmk) / (2 * sig.size)
        j = int(np.argmin(prof))
        best = float(grid[j])
        if (prof[j] <= _AGREE and prof[j] <= _BETTER * base and j < grid.size - 1
                and _misfit(sig, wd, Pk, Dk, best, dmk) <= _AGREE):
            how = "too long" if tau > best else "too short"
            return (f"the loop delay {tau:.4g} s looks {how} for the data: the runs fit one "
                    f"plant with a delay near {best:.3g} s; check {delay_flag}, or leave it out "
                    "to have it estimated")
    return None
