"""The PHO set's checks of its input, made before (or beside) the identification.

Each refuses, or warns of, a set that cannot be what it says: a biased command, a loop delay or
controller sample time far from the records' own time scale (a unit mistake), an added mass far
beyond the plant's, a recorded force that contradicts the gains, records sampled too coarsely
for the release's timing. The manifest's digital loop ([loop] sample_time, …) is read and
checked in io (:func:`phoid.io.loop.read_digital_loop`, re-exported here).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from phoid.errors import IdentificationError
from phoid.io.loop import DIGITAL_KEYS, MAX_DELAY_SAMPLES, read_digital_loop
from phoid.io.units import quantity_unit, unit_hint
from phoid.methods.pho import fit_lines
from phoid.methods.savgol import savgol_filter
from phoid.reports.text import format_ratio

__all__ = [
    "DIGITAL_KEYS",
    "MAX_DELAY_SAMPLES",
    "check_added_mass",
    "check_delay",
    "check_gain_magnitudes",
    "check_sample_time",
    "coarse_sampling",
    "extreme_gain",
    "read_digital_loop",
    "refuse_bias",
    "u_contradicts_gains",
]


def refuse_bias(experiment: Any, method: str) -> None:
    """Refuse runs whose command carries a DC-offset bias (``[[run]] bias``): their decay is not
    a sum of the loop's modes, so the mode fit would return a wrong m, c, k without noticing;
    the friction fit models it (``phoid identify --friction``, :mod:`phoid.methods.friction`)."""
    for r in getattr(experiment, "runs", ()):
        if getattr(r, "bias", 0.0):
            # the public ways only (the CLI's option, phoid's own function)
            hint = (f"; a {method} set has no PD loop to carry it" if method != "pho" else
                    "; fit it with the stick-slip model: phoid identify --friction "
                    "(in Python: phoid.identify(experiment, friction=True))")
            raise IdentificationError(
                f"{experiment.path}: {r.name}: bias = {r.bias:g} N: a biased PD command is not "
                f"a linear loop, so the mode fit does not apply{hint}")


# a given delay shorter than this fraction of the records' sample step is no delay the data can
# tell from 0 (and the release model would step through it in 1e300 steps): a unit mistake
_MIN_DELAY_PER_STEP = 1e-6


def check_delay(delay: float, data: Sequence[tuple[np.ndarray, np.ndarray]], source: str
                ) -> None:
    """Refuse a given loop delay that cannot be right: not finite or negative, far below the
    records' sample step, or so long that the fit's start (3 delays after the release) lies
    beyond every record's end."""
    where = f"{source}: " if source else ""
    what = "the loop delay ([loop] delay, or --delay)"
    if not (math.isfinite(delay) and delay >= 0.0):
        raise IdentificationError(f"{where}{what} must be a finite number ≥ 0 s; got {delay:g}")
    spans, steps = [], []
    for t, _x in data:
        try:
            t = np.asarray(t, dtype=float)
            if t.size >= 2 and np.all(np.isfinite(t[[0, -1]])):
                spans.append(float(t[-1] - t[0]))
                steps.append(float(np.median(np.diff(t[: min(t.size, 64)]))))
        except (TypeError, ValueError):
            continue
    if not spans:
        return
    h = float(np.median(steps))
    if 0.0 < delay < _MIN_DELAY_PER_STEP * h:
        raise IdentificationError(
            f"{where}{what} = {delay:.3g} s is {format_ratio(h, delay)} times shorter than the "
            f"records' sample step ({h:.3g} s): is it in seconds? Give 0 for a loop without delay")
    if 3.0 * delay >= max(spans):
        raise IdentificationError(
            f"{where}{what} = {delay:.4g} s is too long for the records: the fit starts 3 "
            f"delays ({3 * delay:.4g} s) after the release, beyond the longest record "
            f"({max(spans):.4g} s); is it in seconds, and is t (else give its unit as "
            "[units] t, docs/format.md)?")



# is 1; a smoothed derivative of noisy x biases it low by a few per cent and a force sensor's
# calibration is rarely better than a few per cent, so only a scale outside 0.8 … 1.25 (a gain
# or unit mistake, e.g. gains off by 2×: scale 0.5) is reported
_U_SCALE_OK = (0.8, 1.25)


def u_contradicts_gains(data: Sequence[tuple[np.ndarray, np.ndarray]],
                        u: Sequence[np.ndarray | None], P: np.ndarray, D: np.ndarray,
                        delay: float, names: Sequence[str], omega_d: Sequence[float],
                        x_unit: str = "m") -> str | None:
    """A warning naming the runs whose recorded u contradicts the given gains and delay
    (u ≠ −[P x(t − Δt) + D ẋ(t − Δt)] by more than a calibration could explain), or None.

    The warning names x's and u's units by the set's quantities (``x_unit`` ``"rad"``: x in
    rad, u in N m, and the units it suggests are angles and torques: :func:`unit_hint`)."""
    bad = []
    for i, ((t, x), ui) in enumerate(zip(data, u, strict=True)):
        if ui is None or t.size < 32 or not (P[i] or D[i]) or not math.isfinite(omega_d[i]):
            continue
        h = float(np.median(np.diff(t)))
        period = 2 * math.pi / omega_d[i]
        # a dense record is averaged in blocks of k samples down to ~200 per period (noise
        # down by √k; the block mean attenuates the mode by < 1e-4), then ẋ comes from a
        # quadratic Savitzky–Golay fit over 11 samples; with fewer than 10 such windows per
        # period the derivative is not accurate to the band's few per cent: no check
        win = 11
        kb = max(1, int(period / (200 * h)))
        nb = t.size // kb
        if nb < 2 * win or period / (kb * h) < 10 * win:
            continue
        uu = np.asarray(ui, dtype=float)
        t, x, uu = (a[: nb * kb].reshape(nb, kb).mean(axis=1) for a in (t, x, uu))
        with np.errstate(all="ignore"):
            xs = savgol_filter(x, win, 2)
            vs = savgol_filter(x, win, 2, deriv=1, delta=kb * h)
            sel = t - delay >= t[0]
            pred = -(P[i] * np.interp(t[sel] - delay, t, xs)
                     + D[i] * np.interp(t[sel] - delay, t, vs))
            uu = uu[sel]
            pc, uc = pred - pred.mean(), uu - uu.mean()
            den = float(pc @ pc)
            g = float(pc @ uc) / den if den > 0 else math.nan
        if math.isfinite(g) and not _U_SCALE_OK[0] <= g <= _U_SCALE_OK[1]:
            bad.append((names[i], g))
    if not bad:
        return None
    listed = ", ".join(f"{n} ({g:.2g})" for n, g in bad[:5]) + (" …" if len(bad) > 5 else "")
    # a scale near a unit's factor names it: u in kN (or x in mm) reads as g ≈ 1e-3
    g_med = float(np.median([g for _, g in bad]))
    hints = [h for h in (unit_hint("u", g_med, x_unit),
                         unit_hint("x", 1.0 / g_med, x_unit) if g_med else "") if h]
    hint = (f" ({'; or '.join(hints)}; or a [units] entry given for them is the wrong one)"
            if hints else "")
    return (f"the recorded u contradicts the given gains and delay in {len(bad)} run(s): u is "
            f"not -(P x + D x') at t - delay but that times {listed}: check P, D, the units "
            f"of x ({quantity_unit('m', x_unit)}) and u ({quantity_unit('N', x_unit)})"
            f"{hint}, or the delay; m, c, k assume the gains are right")


# a controller sampling more than this many times per recorded sample is no sampled loop phoid
# can model (its z-domain model degenerates as T_s |s| -> 0: JᵀJ singular at 1e-300 s), and no
# rig records that much slower than it controls; such a loop is a continuous one
_MAX_CONTROL_PER_RECORD = 1e4


def check_sample_time(experiment: Any, digital: Any, runs: Sequence[Any]) -> str | None:
    """Refuse a ``[loop] sample_time`` far below the records' own sample step (a unit mistake,
    or a controller so fast it is a continuous loop); return a warning when the records are
    sampled about 1000 (or 10⁶) times more slowly than the controller runs (t in ms, or µs,
    read as s), else None."""
    steps = []
    for r in runs:
        try:
            t = np.asarray(r.t, dtype=float)
            if t.size >= 2:
                steps.append(float(np.median(np.diff(t[: min(t.size, 64)]))))
        except (TypeError, ValueError):
            continue
    steps = [h for h in steps if math.isfinite(h) and h > 0]
    if not steps:
        return None
    h = float(np.median(steps))
    if digital.sample_time * _MAX_CONTROL_PER_RECORD < h:
        hint = unit_hint("t", h / digital.sample_time)
        raise IdentificationError(
            f"{experiment.path}: [loop] sample_time = {digital.sample_time:.3g} s is "
            f"{format_ratio(h, digital.sample_time)} times shorter than the records' sample step "
            f"({h:.3g} s): is it in seconds? {hint + ' ' if hint else ''}A controller that "
            "fast is a continuous loop: give [loop] delay instead of sample_time")
    hint = unit_hint("t", h / digital.sample_time) if h > 20 * digital.sample_time else ""
    if hint:
        return (f"the records are sampled every {h:.3g} s but the controller's period "
                f"([loop] sample_time) is {digital.sample_time:.3g} s, "
                f"{format_ratio(h, digital.sample_time)} times shorter: {hint}")
    return None


#: the largest gain magnitude (N/m, N·s/m) a run may give: beyond any loop a rig closes, and
#: where a gain times a record's positions and rates (and the loop's squared rates) would leave
#: the floating-point range
MAX_GAIN = 1e30
# a run's gain this many times the others' median magnitude is named when the fit fails
_EXTREME_GAIN = 1e3


def check_gain_magnitudes(P: np.ndarray, D: np.ndarray, names: Sequence[str], source: str
                          ) -> None:
    """Refuse a run whose gain P or D exceeds :data:`MAX_GAIN` in magnitude (one line naming
    the set, the run and the key)."""
    where = f"{source}: " if source else ""
    for key, gains, unit in (("P", P, "N/m"), ("D", D, "N·s/m")):
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(~(np.abs(gains) <= MAX_GAIN))
        if bad.size:
            i = int(bad[0])
            raise IdentificationError(
                f"{where}{names[i]}: {key} = {float(gains[i]):.6g} {unit} is beyond any loop's "
                f"gain (|{key}| ≤ {MAX_GAIN:g} {unit}): check its value and unit")


def extreme_gain(P: np.ndarray, D: np.ndarray, names: Sequence[str]) -> str:
    """A hint for a failed fit: the run whose gain is farthest (over 1000×) from the others'
    median magnitude, or the general advice to check the gains and the delay."""
    best = (1.0, "", "", 0.0)
    n = len(names)
    for key, gains in (("P", np.asarray(P, dtype=float)), ("D", np.asarray(D, dtype=float))):
        mags = np.abs(gains)
        for i in range(n if n >= 2 else 0):
            others = np.delete(mags, i)
            ref = float(np.median(others[others > 0])) if np.any(others > 0) else 0.0
            if ref > 0 and mags[i] / ref > max(best[0], _EXTREME_GAIN):
                best = (float(mags[i] / ref), names[i], key, float(gains[i]))
    if best[1]:
        return (f"; {best[1]} has {best[2]} = {best[3]:.6g}, {best[0]:.3g} times the other runs' "
                f"(median magnitude): check its gains")
    return "; check the runs' gains P, D and the loop delay"


_MAX_ADDED_RATIO = 1e6


def check_added_mass(first: Sequence[tuple[Any, str | None]], P: np.ndarray, D: np.ndarray,
                     delay: float, dm: np.ndarray, names: Sequence[str], source: str) -> None:
    """Refuse an added mass far beyond the plant's own mass, as the runs without added mass
    give it roughly (the eq. (35) lines of their first-pass modes); no check when fewer than
    two of them, with distinct gains, oscillate."""
    free = [i for i, (st, _e) in enumerate(first)
            if dm[i] == 0 and st is not None and st.oscillating]
    if len({(float(P[i]), float(D[i])) for i in free}) < 2:
        return
    try:
        with np.errstate(all="ignore"):
            m0 = fit_lines([first[i][0].sigma for i in free], [first[i][0].omega_d for i in free],
                           P[free], D[free], delay).m
    except (ValueError, np.linalg.LinAlgError):
        return
    if not (math.isfinite(m0) and m0 > 0):
        return
    i = int(np.argmax(dm))
    if dm[i] > _MAX_ADDED_RATIO * m0:
        where = f"{source}: " if source else ""
        raise IdentificationError(
            f"{where}{names[i]}: added_mass = {float(dm[i]):.3g} kg is {float(dm[i]) / m0:.3g} "
            f"times the mass the runs without added mass give ({m0:.3g} kg): check its value "
            "(kg)")


# ω_d·h above this (fewer than ~30 samples per period) leaves the release's sub-sample timing
# unresolved: a release between two samples biases c by several stderr (measured: fs 12 Hz,
# ω_d ≈ 6–9 rad/s, ω_d·h ≈ 0.5–0.75; exact when the release falls on a sample)
_COARSE_WD_H = 0.2


def coarse_sampling(data: Sequence[tuple[np.ndarray, np.ndarray]], fits: Sequence[Any]
                    ) -> str | None:
    """A warning when the runs are sampled too coarsely for the release's timing, or None."""
    worst, wmax = 0.0, 0.0
    for (t, _x), f in zip(data, fits, strict=False):
        if f is None or not math.isfinite(f.omega_d) or np.size(t) < 2:
            continue
        h = float(np.median(np.diff(np.asarray(t[: min(np.size(t), 64)], dtype=float))))
        worst, wmax = max(worst, f.omega_d * h), max(wmax, f.omega_d)
    if worst <= _COARSE_WD_H:
        return None
    return (f"the records are sampled coarsely ({2 * math.pi / worst:.3g} samples per period of "
            "the fastest run): a release that falls between two samples is not resolved, which "
            "can bias c (and k) by several standard errors; record at "
            f"{wmax / _COARSE_WD_H:.3g} Hz or more")
