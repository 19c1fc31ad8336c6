"""A model-free look at each record of a friction set, and at its recorded force u.

Per run (:func:`survey_run`): the release (:func:`phoid.fits.detect_release`), the held
level x₀ᵢ + bᵢ, the noise sd (the held segment's, or from third differences), the final level
and the end of the motion (the last sample more than 6 noise sd from the final level). Runs set
aside before fitting (with the reason):

* **No motion** after the release (friction holds the mass: |(k + Pᵢ)x₀ᵢ| ≤ f_c).
* **Growing records.** When the loop's damping is negative (σᵢ < 0, c′ᵢ < −c) the oscillation
  grows unless friction bounds it. Friction removes a fixed energy per cycle and negative damping
  feeds one that grows with the amplitude squared, so there is an amplitude A* below which the
  record still decays, with an envelope that steepens as it falls (the seed's "bullet-shaped"
  envelope, Discussion), and above which it grows without bound. A bounded record is modelled
  exactly and is used (it is informative); one whose amplitude in the last quarter of the record
  exceeds 1.5 times that of the first quarter grows without bound (or saturates on a real rig)
  and is set aside.

**The recorded force u**, where given (continuous loops, :func:`check_u`): the gains u implies,
by least squares of u − bᵢ sign(ẋ(t − Δt)) on x(t − Δt), ẋ(t − Δt) and a constant (ẋ a
Savitzky–Golay derivative over a tenth of the dominant period), must agree with (Pᵢ, Dᵢ) to 20 %
of the force swing. Runs that do not are named in a warning with the probable cause: D of the
opposite sign (the sign convention), u of the opposite sign, one factor on both gains (1e−3: x in
mm; or the gains themselves), or — where a delay among whole sample intervals up to 3Δt
reconciles them — the delay u implies.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from phoid.errors import ExperimentError
from phoid.fits import detect_release

__all__ = ["Survey", "check_run", "check_u", "survey_run"]

_MIN_SAMPLES = 32
_MOTION_NSD = 6.0  # motion: more than 6 noise sd away from the record's final level
_GROWTH = 1.5  # last-quarter amplitude / first-quarter amplitude above which a record grows
_U_TOL = 0.2  # u's implied gains off by more than this part of the force swing: a warning
_U_R2 = 0.9  # … when the delayed x, ẋ explain at least this part of u's variance


@dataclass(frozen=True)
class Survey:
    """What one record shows before any model: :func:`survey_run`'s result (t in s, y and
    levels in m)."""

    name: str
    t: np.ndarray
    y: np.ndarray
    release: float
    level: float  # held level (x₀ + b)
    final: float  # final level of the record (median of its last 5 %)
    sd: float  # noise sd
    motion_end: float  # last sample more than 6 sd from the final level, s
    reason: str | None  # why the run is set aside before fitting


def check_run(name: str, t: Any, x: Any) -> tuple[np.ndarray, np.ndarray]:
    """Validate one run's arrays.

    Parameters
    ----------
    name : str
        The run's name, for messages.
    t, x : array_like
        Sample times (s) and measured positions (m).

    Returns
    -------
    t, x : ndarray
        As float arrays.

    Raises
    ------
    ExperimentError
        If they are not 1-D of equal length, not finite, shorter than 32 samples, or t is not
        strictly increasing.
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if t.ndim != 1 or x.ndim != 1 or t.shape != x.shape:
        raise ExperimentError(
            f"{name}: `t` and `x` must be 1-D arrays of equal length; got shapes {t.shape} "
            f"and {x.shape}"
        )
    for field_name, a in (("t", t), ("x", x)):
        if not np.all(np.isfinite(a)):
            j = int(np.flatnonzero(~np.isfinite(a))[0])
            raise ExperimentError(f"{name}: `{field_name}` must be finite; got {a[j]} at row {j}")
    if t.size < _MIN_SAMPLES:
        raise ExperimentError(
            f"{name}: the record needs at least {_MIN_SAMPLES} samples; got {t.size}"
        )
    if not np.all(np.diff(t) > 0):
        j = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise ExperimentError(
            f"{name}: `t` must be strictly increasing; got t[{j}] = {t[j]:.9g} s, "
            f"t[{j + 1}] = {t[j + 1]:.9g} s"
        )
    return t, x


def _third_diff_sd(x: np.ndarray) -> float:
    """White-noise sd from third differences (var Δ³ = 20 s²), robust (MAD): the smooth signal
    contributes (ωh)³A, negligible at practical sample rates."""
    if x.size < 8:
        return 0.0
    d3 = np.diff(x, 3)
    return float(1.4826 * np.median(np.abs(d3 - np.median(d3))) / math.sqrt(20.0))


def survey_run(name: str, t: np.ndarray, y: np.ndarray) -> Survey:
    """Release, held level, noise, end of motion and growth of one record, from the data.

    Parameters
    ----------
    name : str
        The run's name.
    t, y : ndarray
        Sample times (s, strictly increasing) and measured positions (m), held segment
        included.

    Returns
    -------
    Survey
        With ``reason`` set when the run is to be set aside (no motion, a growing record:
        module docstring).
    """
    amp = float(np.ptp(y))
    if not amp > 0:
        return Survey(name, t, y, float(t[0]), float(y[0]), float(y[0]), 0.0, float(t[0]),
                      "the record is constant: no motion")
    release = detect_release(t, y)
    j = int(np.searchsorted(t, release, side="right")) - 1
    held = y[: j + 1]
    level = float(np.median(held)) if held.size >= 5 else float(y[0])
    sd = float(np.std(held, ddof=1)) if held.size >= 20 else 0.0
    if not sd > 0:
        sd = _third_diff_sd(y)
    sd = max(sd, 1e-9 * amp, 1e-15)
    post = y[j + 1 :]
    tp = t[j + 1 :]
    n_tail = max(20, y.size // 20)
    final = float(np.median(y[-n_tail:]))
    moving = np.flatnonzero(np.abs(post - final) > _MOTION_NSD * sd)
    if post.size < 8 or moving.size == 0 or abs(level - final) <= _MOTION_NSD * sd:
        return Survey(name, t, y, release, level, final, sd, float(t[-1]),
                      "no motion after the release (friction holds the mass, or the record "
                      "has no release)")
    motion_end = float(tp[moving[-1]])
    q = max(post.size // 4, 1)
    centre = float(np.median(post))
    a_first = float(np.max(np.abs(post[:q] - centre)))
    a_last = float(np.max(np.abs(post[-q:] - centre)))
    reason = None
    if a_last > _GROWTH * a_first and a_last > 10.0 * sd:
        reason = (
            f"the oscillation grows (amplitude ×{a_last / a_first:.3g} from the first to the "
            "last quarter of the record): an unstable loop that friction does not bound"
        )
    return Survey(name, t, y, release, level, final, sd, motion_end, reason)


# --------------------------------------------------------------------------------------------
# the recorded force u against the gains and x (model-free)


def _u_gains(t: np.ndarray, x: np.ndarray, u: np.ndarray, delay: float,
             bias: float) -> tuple[float, float, float, float, float] | None:
    """Gains that the recorded u implies: least squares of u − b sign(ẋ(t − Δt)) on
    x(t − Δt), ẋ(t − Δt) and a constant (the sensor offset times P).

    ẋ is a Savitzky–Golay derivative (cubic, over a tenth of the dominant period) of x; both
    are read at t − Δt by linear interpolation. Returns (P̂, D̂, R², sd of x(t − Δt), sd of
    ẋ(t − Δt)), or None when the record is too short or u is constant.
    """
    from scipy import signal

    sel = t - delay >= t[0]
    if np.count_nonzero(sel) < _MIN_SAMPLES or not np.ptp(u[sel]) > 0:
        return None
    dt = float(np.median(np.diff(t)))
    # the window: a tenth of the record's dominant period (its spectrum's peak), at least 5
    # samples: it smooths the noise out of ẋ (a noisy regressor would bias D̂ low)
    spec = np.abs(np.fft.rfft(x - x.mean()))
    f_peak = max(int(np.argmax(spec[1:])) + 1, 1) / (x.size * dt)
    win = max(5, min(round(0.1 / (f_peak * dt)), x.size // 4))
    win += 1 - win % 2
    v = signal.savgol_filter(x, win, 3, deriv=1, delta=dt)
    td = t[sel] - delay
    xd = np.interp(td, t, x)
    vd = np.interp(td, t, v)
    target = u[sel] - bias * np.sign(vd)
    A = np.c_[xd, vd, np.ones(xd.size)]
    coef, *_ = np.linalg.lstsq(A, target, rcond=None)
    res = target - A @ coef
    tss = float(np.sum((target - target.mean()) ** 2))
    r2 = 1.0 - float(res @ res) / tss if tss > 0 else 0.0
    return -float(coef[0]), -float(coef[1]), r2, float(np.std(xd)), float(np.std(vd))


def _u_diagnosis(P: float, D: float, Ph: float, Dh: float, sx: float,
                 sv: float) -> tuple[str, str] | None:
    """What the gains (P̂, D̂) implied by u say about the given (P, D): None when they agree
    within 20 % of the force swing, else (kind, the probable cause in words)."""
    F = math.hypot(P * sx, D * sv)
    Fh = math.hypot(Ph * sx, Dh * sv)
    scale = max(F, Fh)
    if not scale > 0 or math.hypot((Ph - P) * sx, (Dh - D) * sv) <= _U_TOL * scale:
        return None
    if D != 0 and math.hypot((Ph - P) * sx, (Dh + D) * sv) <= _U_TOL * scale:
        return "sign D", ("D has the opposite sign to the one u implies (phoid/1's convention: "
                          "u = -P x(t - delay) - D x'(t - delay))")
    if F > 0:  # one factor g for both gains?
        g = (Ph * P * sx * sx + Dh * D * sv * sv) / (F * F)
        if 1e-4 < abs(g) < 1e4 and \
                math.hypot((Ph - g * P) * sx, (Dh - g * D) * sv) <= _U_TOL * scale:
            if g < 0:
                return "sign u", ("u has the opposite sign to the force the gains imply "
                                  "(recorded as +P x + D x'?)")
            for factor, what in ((1e-3, "x in mm instead of m, or u in mN instead of N"),
                                 (1e-2, "x in cm instead of m"),
                                 (1e3, "x in km, or u in kN instead of N")):
                if abs(g / factor - 1.0) <= _U_TOL:
                    return f"units {factor:g}", (
                        f"u is {g:.3g} times the force the gains and x imply: {what}?")
            return "scale", (f"u is {g:.3g} times the force the gains and x imply: check the "
                             "gains (all off by one factor?) and the units of x and u")
    return "gains", (f"u implies P = {Ph:.4g} N/m, D = {Dh:.4g} N s/m where the set gives "
                     f"P = {P:.4g}, D = {D:.4g}: check the loop delay, the gains and their "
                     "sign convention")


def _u_delay(t, x, u, P, D, delay, bias) -> float | None:
    """The delay at which u agrees with the given gains (:func:`_u_diagnosis`), searched over
    whole sample intervals up to max(3Δt, 20 samples) (at most 200 trials); None if none."""
    dt = float(np.median(np.diff(t)))
    top = min(max(3.0 * delay, 20.0 * dt), 200.0 * dt, 0.25 * float(t[-1] - t[0]))
    best, best_err = None, math.inf
    for lag in np.arange(0.0, top + 0.5 * dt, dt):
        got = _u_gains(t, x, u, float(lag), bias)
        if got is None or not got[2] >= _U_R2:
            continue
        Ph, Dh, _, sx, sv = got
        err = math.hypot((Ph - P) * sx, (Dh - D) * sv)
        if err < best_err:
            best, best_err = float(lag), err
    if best is None or _u_diagnosis(P, D, *_u_gains(t, x, u, best, bias)[:2],
                                    *_u_gains(t, x, u, best, bias)[3:]) is not None:
        return None
    return best


def check_u(names: Sequence[str], surveys: Sequence[Survey], u: Sequence[Any],
            P: np.ndarray, D: np.ndarray, delay: float, bias: np.ndarray) -> list[str]:
    """Warnings for the runs whose recorded u contradicts the gains and x (one per probable
    cause, naming the runs; the text of the first such run).

    Parameters
    ----------
    names : sequence of str
        Run names.
    surveys : sequence of Survey
        The runs' records.
    u : sequence of array_like or None
        Each run's recorded feedback force, N, on its sample times (None: not recorded; a run
        whose u has the wrong shape or is not finite is skipped).
    P, D : ndarray
        Gains of each run, N/m and N s/m.
    delay : float
        Loop delay Δt, s.
    bias : ndarray
        Known DC offset of each run's command, N.

    Returns
    -------
    list of str
    """
    groups: dict[str, list[tuple[str, str]]] = {}
    lags: dict[str, float] = {}
    for i, s in enumerate(surveys):
        ui = None if u is None else u[i]
        if ui is None:
            continue
        ui = np.asarray(ui, dtype=float)
        if ui.shape != s.t.shape or not np.all(np.isfinite(ui)):
            continue
        got = _u_gains(s.t, s.y, ui, delay, float(bias[i]))
        if got is None or not got[2] >= _U_R2:  # u not a linear function of delayed x, ẋ
            continue
        found = _u_diagnosis(float(P[i]), float(D[i]), *got[:2], *got[3:])
        if found is not None and found[0] == "gains":
            lag = _u_delay(s.t, s.y, ui, float(P[i]), float(D[i]), delay, float(bias[i]))
            if lag is not None:
                lags[names[i]] = lag
                found = "delay", (f"u implies a loop delay of about {lag:.3g} s, not the "
                                  f"{delay:.3g} s given")
        if found is not None:
            groups.setdefault(found[0], []).append((names[i], found[1]))
    out = []
    for kind, runs in groups.items():
        text = runs[0][1]
        if kind == "delay":  # the runs' median
            lag = float(np.median([lags[n] for n, _ in runs]))
            text = f"u implies a loop delay of about {lag:.3g} s, not the {delay:.3g} s given"
        out.append(f"{', '.join(n for n, _ in runs)}: the recorded u contradicts the gains "
                   f"and x: {text}")
    return out
