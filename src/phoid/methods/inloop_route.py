r"""Which route identifies a PHO set: the modes (noise outside the loop) or the output error
of the plant driven by the applied force (noise in the loop), and the in-loop result.

Where the sensor noise enters decides the likelihood. Outside the loop (the controller acts on
the true position) each run's record is its loop's free decay plus white noise, and the modal
route (per-run decay fits → :func:`phoid.methods.pho.fit_modes`) is efficient. Inside the
loop (a digital rig's controller reads the recorded, noisy encoder) the noise becomes a force
on the plant; given the record that force is known, and the output error of the plant driven
by it (:mod:`phoid.methods.inloop`) is the likelihood (docs/design-notes/inloop.md).

The choice (:func:`identify_digital`)
-------------------------------------
- An option (``noise_placement`` / ``--noise``) of ``"in-loop"`` or ``"outside"`` decides;
  where it contradicts the manifest's ``[loop] noise`` a warning says so.
- Else the manifest's ``[loop] noise`` decides.
- Else the data (``"auto"``): both routes are computed and D = RSS_modal − RSS_in-loop over
  the samples both fit (each run's decay-fit window ∩ its in-loop window; the modal model is
  each run's fitted decay with its fast modes) is compared with the white noise σ̂² of the
  in-loop fit. Under the wrong placement each route's residual carries the loop's filtered
  noise T·e; D's mean is then ±‖Te‖² and its cross term with the white noise has sd
  2σ‖Te‖, so z = sign(D)√|D|/(2σ̂). A digital controller reads its sensor (a rig has the
  noise in the loop), so the in-loop route is the default and the modal route is chosen only
  where the data say outside: z < −3 (D < −36σ̂²). Noise-free records have no placement to
  choose (the in-loop route, exact for them).
- A stated placement the data contradict by the same margin is used, with a warning.
- An in-loop fit whose residual is more than :data:`FAR` times the records' model-free noise
  is never reported (a one-line refusal where asked for, else the modal route with a
  warning); a set whose runs all share one gain pair has no in-loop fit (only the closed-loop
  family is fixed); runs the modal route set aside get no window.
- A continuous loop (no ``sample_time``) has no in-loop route: the modal one, reported as
  ``"outside"`` from ``"continuous loop"``; ``"in-loop"`` asked for by the option is refused.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from phoid.errors import IdentificationError
from phoid.fits import detect_release
from phoid.io.loop import read_noise_placement
from phoid.methods.estimate import Estimate
from phoid.methods.fit_statistics import difference_noise
from phoid.methods.inloop import InLoopFit, equation_error_starts, fit_inloop
from phoid.methods.inloop_adequacy import assess_inloop
from phoid.methods.inloop_model import (
    PATTERN_FLOOR,
    Layout,
    RunWindow,
    applied_force,
    live_patterns,
    record_layout,
    window_start,
)
from phoid.methods.pho import MCKFit
from phoid.methods.pho_result import Identification, RunMode

__all__ = ["MARGIN", "MARGIN_DETECTED", "MAX_SAMPLES", "MIN_WINDOW", "PLACEMENTS",
           "Z_THRESHOLD", "PlacementTest", "check_placement", "identify_digital",
           "inloop_windows", "placement_source", "placement_test", "read_stated_placement"]

#: the values of the option (``noise_placement``, ``--noise``)
PLACEMENTS = ("auto", "in-loop", "outside")
#: z = √D/(2σ̂) above which the data choose the in-loop route
Z_THRESHOLD = 3.0
#: samples after the release before the window starts: the modal route's model-fitted
#: release is placed to a fraction of a sample (3), the data-only detection
#: (:func:`phoid.fits.detect_release`) was measured up to 19 samples early at 1e-5 m noise on
#: the overdamped plant's slow departure (32: the span phoid's model-fitted release searches
#: about it, :data:`phoid.methods.pho_release.REL_HALF`); a held sample inside the window is
#: a misfit that biases c by several stderr
MARGIN = 3
MARGIN_DETECTED = 32
#: fewest samples of a run's window
MIN_WINDOW = 16
#: most samples of all windows together: the fit holds a few (runs × samples × 3) arrays
#: (≈ 24 MB each at this size); longer windows are cut to their first samples
MAX_SAMPLES = 1 << 20
#: σ̂ within this factor of the records' own noise: a fit good enough to stop trying starts
_GOOD = 1.25
#: an in-loop fit whose residual is more than this many times its records' model-free noise
#: (the noise check's statistic) is no fit of them: never reported. A wrong model (a delay off
#: by one sample, friction) leaves a misfit that grows as the noise shrinks (10.7× for a delay
#: off by one at 1 µm noise on the overdamped plant: reported, with robust stderr and the
#: delay's warning); a start stuck on the closed-loop family, or gains in other units, leave
#: 3.6e2–1e21× (measured on the prober's sets)
FAR = 100.0
#: where the modal route cannot be made, the in-loop fit stands alone: a residual this many
#: times the records' noise is a loop the records contradict (a delay off by hundreds of
#: samples: 47×), not a misfit to report with widened stderr (a delay off by one at 1 µm: 10.7×
#: — reported, with the modes beside it, under FAR)
FAR_ALONE = 20.0
#: a residual below this fraction of the motion's RMS is rounding (noise-free records)
_EXACT = 1e-5
#: why a set whose runs all have one gain pair has no in-loop fit (measured: docs/design-notes/
#: inloop.md, "One gain pair")
_SAME_GAINS = (
    "all its runs have the same gains (P, D): their ringing fixes only the closed-loop family "
    "(λm, λ(c + D) − D, λ(k + P) − P), and what singles one out — the noise the controller "
    "feeds back — leaves m, c, k biased by tens of stderr (measured on simulated sets of one "
    "gain pair); record runs with at least two different gain pairs")
#: the closed-loop family's scale factors tried as starts (:func:`_family`)
_LAMBDAS = tuple(2.0 ** (0.5 * i) for i in range(-8, 25))


@dataclass(frozen=True)
class PlacementTest:
    """The data's test of the noise placement (module docstring).

    Attributes
    ----------
    z : float or None
        sign(D)·√|D|/(2σ̂); None where not computed (``reason`` says why).
    threshold : float
        The in-loop route is chosen for z above it (3).
    rss_outside, rss_in_loop : float or None
        The modal and the in-loop residual sums of squares over the samples both fit.
    sigma : float or None
        σ̂ of the in-loop fit, x's unit.
    samples : int
        The samples both routes fit.
    reason : str or None
        Why the test was not made (the in-loop fit could not be made, no common samples).
    """

    z: float | None
    threshold: float = Z_THRESHOLD
    rss_outside: float | None = None
    rss_in_loop: float | None = None
    sigma: float | None = None
    samples: int = 0
    reason: str | None = None
    noise_free: bool = False

    def words(self, placement: str) -> str:
        """Why ``placement`` was used where the data decided (the report's words)."""
        if self.noise_free:
            return "the records are noise-free: no noise placement to choose"
        if self.reason is not None and self.z is None:
            if placement == "outside":
                return f"the modal route: {self.reason}"
            return f"the digital loop's default ({self.reason})"
        z = self.z if self.z is not None else math.nan
        if placement == "in-loop" and z > self.threshold:
            return f"chosen by the data: z = {z:.3g} > {self.threshold:g}"
        if placement == "in-loop":
            return (f"the digital loop's default: the data do not say outside "
                    f"(z = {z:.3g} ≥ −{self.threshold:g})")
        if z < -self.threshold:
            return f"chosen by the data: z = {z:.3g} < −{self.threshold:g}"
        # a route that keeps the modal one unless z > 3 (the friction fit's)
        return f"chosen by the data: z = {z:.3g} ≤ {self.threshold:g}"

    def to_dict(self) -> dict[str, Any]:
        """The ``noise_placement_test`` object of ``--json`` (non-finite numbers as null)."""
        def num(v: float | None) -> float | None:
            return None if v is None or not math.isfinite(v) else float(v)
        return {"z": num(self.z), "threshold": float(self.threshold),
                "rss_outside": num(self.rss_outside), "rss_in_loop": num(self.rss_in_loop),
                "sigma": num(self.sigma), "samples": int(self.samples), "reason": self.reason}


def check_placement(value: Any) -> str | None:
    """The option's value, None for ``"auto"`` or not given.

    Raises
    ------
    IdentificationError
        For a value that is not one of :data:`PLACEMENTS` (one line).
    """
    if value is None or value == "auto":
        return None
    if not isinstance(value, str) or value not in PLACEMENTS:
        text = repr(value)
        raise IdentificationError(
            f"the noise placement must be one of {', '.join(map(repr, PLACEMENTS))}; got "
            f"{text if len(text) <= 60 else text[:57] + '...'}")
    return value


def read_stated_placement(experiment: Any) -> str | None:
    """The manifest's ``[loop] noise``: ``"in-loop"``, ``"outside"`` or None (not stated)
    (:func:`phoid.io.loop.read_noise_placement`, which refuses any other value in one line)."""
    return read_noise_placement(experiment)


# --------------------------------------------------------------------------------------------
# the windows


def _release_index(t: np.ndarray, x: np.ndarray, fit: Any) -> int:
    """The first sample of the window that the release allows: :data:`MARGIN` samples after
    the modal route's model-fitted release, else :data:`MARGIN_DETECTED` after the data-only
    one (:func:`phoid.fits.detect_release`; the modal route falls back on it, to the bit,
    where its model fit of the release fails) — :data:`MARGIN` where that is the record's
    first sample (a record from its release on, as ``phoid run`` writes)."""
    h = float(t[1] - t[0]) if t.size > 1 else 1.0
    try:
        detected = float(detect_release(t, x))
        # no held level at all: the record starts at its release (as `phoid run` writes it),
        # so no held sample can come into the window
        at_start = abs(detected - float(t[0])) <= 1e-9 * h
    except (ValueError, IdentificationError):
        detected, at_start = float(t[0]), False
    rel = getattr(fit, "release", None)
    if rel is None or not math.isfinite(rel) or abs(rel - detected) <= 1e-9 * h:
        rel, margin = detected, MARGIN if at_start else MARGIN_DETECTED
    else:
        margin = MARGIN
    return int(np.searchsorted(t, rel - 1e-6 * h, side="left")) + margin


def inloop_windows(data: Sequence[tuple[np.ndarray, np.ndarray]], P: np.ndarray,
                   D: np.ndarray, digital: Any, *, names: Sequence[str],
                   added_mass: np.ndarray, fits: Sequence[Any] = (),
                   aside: Any = ()) -> tuple[list[RunWindow], list[str]]:
    """Each run's window of the in-loop fit (:mod:`phoid.methods.inloop_model`), and why the
    others have none (``"<run>: not in the in-loop fit: <reason>"``).

    Parameters
    ----------
    data : sequence of (t, x)
        The runs' records (float arrays).
    P, D : ndarray
        Their gains.
    digital : phoid.dynamics.digital.DigitalPD
        The loop (its gains ignored).
    names : sequence of str
        The runs' names.
    added_mass : ndarray
        Each run's known added mass, kg.
    fits : sequence of DecayFit or None
        The modal route's decay fits (their releases), where made.
    aside : collection of int
        The runs the modal route set aside (a glitch, a non-physical record): no window (its
        warning says why).
    """
    windows: list[RunWindow] = []
    notes: list[str] = []
    T = digital.sample_time
    for i, (t, x) in enumerate(data):
        if i in aside:
            continue
        lay = record_layout(t, T)
        if not isinstance(lay, Layout):
            notes.append(f"{names[i]}: not in the in-loop fit: {lay}")
            continue
        force, patterns, first = applied_force(x, lay, float(P[i]), float(D[i]),
                                               digital.estimator, digital.delay_samples)
        fit = fits[i] if i < len(fits) else None
        start = window_start(first, _release_index(t, x, fit), 0)
        if x.size - start < MIN_WINDOW:
            notes.append(f"{names[i]}: not in the in-loop fit: fewer than {MIN_WINDOW} samples "
                         "after its release have a known applied force (the delay and the "
                         "velocity estimator need the samples before)")
            continue
        # a start state of the estimator that has decayed out of every command is left out
        pat = live_patterns(None if patterns is None else patterns[:, start:],
                            PATTERN_FLOOR * abs(D[i]))
        windows.append(RunWindow(i, start, x[start:].copy(), force[start:].copy(), pat,
                                 lay.step, float(added_mass[i])))
    total = sum(w.size for w in windows)
    if total > MAX_SAMPLES:
        cap = MAX_SAMPLES // len(windows)
        notes.append(f"the in-loop fit uses each run's first {cap} samples after its release "
                     f"({total} in all would exceed its limit of {MAX_SAMPLES})")
        windows = [w.part(0, min(w.size, cap)) for w in windows]
    return windows, notes


def _same_gains(P: np.ndarray, D: np.ndarray) -> bool:
    """True when every run has the same gains (P, D), to 1e-9 relative."""
    return bool(P.size and np.all(np.abs(P - P[0]) <= 1e-9 * max(abs(P[0]), 1e-300))
                and np.all(np.abs(D - D[0]) <= 1e-9 * max(abs(D[0]), 1e-300)))


def _family(starts: Sequence[np.ndarray], P: float, D: float) -> list[np.ndarray]:
    """The closed-loop family through each start: (λm, λ(c + D) − D, λ(k + P) − P) for λ on
    :data:`_LAMBDAS` — the loops with the same closed-loop modes (m x'' + (c + D) x' + (k + P) x
    scaled), which the ringing alone cannot tell apart and on which the equation error's starts
    lie (its force is nearly the gains' law on the smoothed record)."""
    out = []
    for th in starts:
        for lam in _LAMBDAS:
            out.append(np.array([lam * th[0], lam * (th[1] + D) - D, lam * (th[2] + P) - P]))
    return out


def _noise_ratio(fit: InLoopFit) -> float:
    """The noise check's statistic of a fit: the worst window's residual RMS over its records'
    model-free noise (third differences); nan where no window has a noise level."""
    ratios = [r for r in fit.noise_ratios(max(fit.runs, default=-1) + 1) if r is not None]
    return max(ratios) if ratios else math.nan


def _fit(windows: list[RunWindow], start: np.ndarray | None, P: np.ndarray,
         D: np.ndarray, enough: Callable[[InLoopFit], bool] | None = None) -> InLoopFit:
    """The in-loop fit from the modal estimate, from the equation error's starts where that
    does not reach the records' noise, and from the closed-loop family through them where
    none does; the one of lowest RSS. ``enough``: a fit that settles the question asked
    (the data's test already says outside), after which no other start is tried."""
    noise = [s for s in (difference_noise(w.y, rounding=True) for w in windows) if s > 0]
    good = _GOOD * float(np.median(noise)) if noise else None
    runs = [w.run for w in windows]
    best: InLoopFit | None = None

    def attempt(starts: Sequence[np.ndarray], tries: int) -> bool:
        nonlocal best
        try:
            with np.errstate(all="ignore"):
                f = fit_inloop(windows, starts, tries=tries, good_sigma=good)
        except (IdentificationError, np.linalg.LinAlgError):
            return False
        if best is None or f.rss < best.rss:
            best = f
        return (good is not None and best.sigma <= good) or (enough is not None
                                                             and enough(best))

    if start is not None and attempt([start], 1):
        return best  # type: ignore[return-value]
    others = equation_error_starts(windows)
    if others and attempt(others, 3):
        return best  # type: ignore[return-value]
    bases = ([] if start is None else [start]) + others
    if best is not None:
        bases.append(best.theta)
    Pm, Dm = float(np.mean(P[runs])), float(np.mean(D[runs]))
    family = [th for th in _family(bases, Pm, Dm) if th[0] > 0]
    if family:
        attempt(family, 3)
    if best is None:
        raise IdentificationError("the in-loop fit found no starting point (the equation "
                                  "error gives no positive mass)")
    return best


# --------------------------------------------------------------------------------------------
# the test


def placement_test(modal: Identification, fit: InLoopFit,
                   windows: Sequence[RunWindow]) -> PlacementTest:
    """D = RSS_modal − RSS_in-loop over the samples both routes fit, and z (module
    docstring)."""
    rss_o = rss_i = 0.0
    n = 0
    for w, e in zip(windows, fit.residuals, strict=True):
        run = modal.runs[w.run] if w.run < len(modal.runs) else None
        f = None if run is None or not run.used else run.fit
        if f is None or w.run >= len(modal.data):
            continue
        t = np.asarray(modal.data[w.run][0], dtype=float)[w.start: w.start + w.size]
        sel = (t >= f.t_start) & (t <= f.t_end)
        if not np.any(sel):
            continue
        em = w.y[sel] - f.model(t[sel], fast=True)
        rss_o += float(em @ em)
        rss_i += float(e[sel] @ e[sel])
        n += int(np.count_nonzero(sel))
    if n == 0:
        return PlacementTest(None, sigma=fit.sigma,
                             reason="no sample is fitted by both routes")
    diff = rss_o - rss_i
    s = fit.sigma
    if s > 0:
        z = math.copysign(math.sqrt(abs(diff)) / (2.0 * s), diff)
    else:
        z = math.inf if diff > 0 else (0.0 if diff == 0 else -math.inf)
    return PlacementTest(z, Z_THRESHOLD, rss_o, rss_i, s, n)


# --------------------------------------------------------------------------------------------
# the result


def _skeleton(data, P, D, digital, names, files, added_mass, source) -> Identification:
    """A modal-less result to fill with the in-loop fit (the modal route failed)."""
    nan = math.nan
    runs = tuple(RunMode(file=files[i], P=float(P[i]), D=float(D[i]), sigma=nan, omega_d=nan,
                         sigma_stderr=nan, omega_d_stderr=nan, c_prime=nan, k_prime=nan,
                         cycles=nan, residual_rms=nan, used=False, fit=None,
                         added_mass=float(added_mass[i])) for i in range(len(data)))
    n = len(data)
    fit = MCKFit(nan, nan, nan, np.full((3, 3), nan), "output-error", True, np.full(n, nan),
                 np.full(n, nan))
    return Identification(m=Estimate(nan, None, "kg"), c=Estimate(nan, None, "N s/m"),
                          k=Estimate(nan, None, "N/m"), delay=digital.delay,
                          delay_source="given", runs=runs, fit=fit, digital=digital,
                          source=source, data=tuple(data))


def _in_loop_result(base: Identification, fit: InLoopFit, windows: list[RunWindow],
                    names: Sequence[str], notes: list[str], x_unit: str) -> Identification:
    """``base`` with the in-loop fit's m, c, k, covariance, adequacy and warnings."""
    labels = [names[w.run] for w in windows]
    ad = assess_inloop(fit, windows, labels, x_unit=x_unit)
    cov = 0.5 * (ad.robust_cov + ad.robust_cov.T)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    robust = ad.stderr == "robust"
    wse = np.sqrt(np.clip(np.diag(ad.white_cov), 0.0, None))

    def est(value: float, j: int, unit: str) -> Estimate:
        return Estimate(value, float(se[j]), unit,
                        white_stderr=float(wse[j]) if robust else None)

    mck = replace(base.fit, m=fit.m, c=fit.c, k=fit.k, cov=cov, estimator="output-error",
                  chi2=fit.chi2, dof=fit.samples - fit.parameters, warnings=(), delay=None,
                  delay_stderr=None, cov_full=None)
    warnings = list(notes)
    if not fit.converged:
        warnings.append(f"the in-loop fit did not converge in {fit.iterations} iterations: "
                        "m, c, k may not be at the output error's minimum")
    warnings += [w for w in ad.warnings if w not in warnings]
    rms = {w.run: float(np.sqrt(np.mean(e * e))) for w, e in zip(windows, fit.residuals,
                                                                   strict=True)}
    runs = tuple(replace(r, residual_rms=rms.get(i, math.nan))
                 for i, r in enumerate(base.runs))
    return replace(base, m=est(fit.m, 0, "kg"), c=est(fit.c, 1, "N s/m"),
                   k=est(fit.k, 2, "N/m"), fit=mck, runs=runs, adequacy=ad,
                   warnings=tuple(warnings), delay_stderr=None, delay_source="given",
                   inloop=fit, noise_placement="in-loop")



def placement_source(requested: str | None, stated: str | None
                     ) -> tuple[str | None, str, list[str]]:
    """(placement, source, notes): the option wins, then the manifest's ``[loop] noise``, else
    the data decide (placement None); an option that contradicts the manifest is noted."""
    if requested is not None:
        notes = [] if stated is None or stated == requested else [
            f"the noise placement {requested!r} asked for contradicts the manifest's [loop] "
            f"noise = {stated!r}; {requested!r} is used"]
        return requested, "option", notes
    if stated is not None:
        return stated, "manifest", []
    return None, "data", []

def identify_digital(modal: Callable[[], Identification], data: Sequence[tuple[Any, Any]],
                     P: Any, D: Any, digital: Any, *, option: Any = None,
                     stated: str | None = None, names: Sequence[str], files: Sequence[str],
                     added_mass: Any = None, source: str = "", estimator: str = "gls",
                     x_unit: str = "m") -> Identification:
    """Identify a PHO set by the route its noise placement calls for (module docstring).

    Parameters
    ----------
    modal : callable
        The modal route (with its adequacy): called at most once.
    data : sequence of (t, x)
        The runs' records.
    P, D : array_like
        The runs' gains.
    digital : phoid.dynamics.digital.DigitalPD or None
        The sampled loop (None: a continuous loop, the modal route only).
    option : str or None
        ``noise_placement``: ``"auto"`` (or None), ``"in-loop"`` or ``"outside"``.
    stated : str or None
        The manifest's ``[loop] noise`` (None: not stated).
    names, files : sequence of str
        The runs' names and files.
    added_mass : array_like, optional
        Each run's added mass, kg.
    source : str
        The set, for messages.
    estimator : str
        The modal route's estimator (the in-loop route needs the default, ``"gls"``).
    x_unit : str
        x's unit, for the words.

    Returns
    -------
    Identification
        With ``noise_placement``, ``noise_placement_source`` and ``placement_test`` set.

    Raises
    ------
    IdentificationError
        One line: an option that is not a placement, ``"in-loop"`` asked of a continuous loop
        or of records the in-loop route cannot fit, and whatever the routes refuse.
    """
    where = f"{source}: " if source else ""
    requested = check_placement(option)
    if digital is None:
        if requested == "in-loop":
            raise IdentificationError(
                f"{where}the noise placement 'in-loop' needs a digital loop ([loop] "
                "sample_time): a continuous loop is identified from its runs' modes")
        res = modal()
        extra = () if stated != "in-loop" else (
            "[loop] noise = 'in-loop', but the loop is continuous (no [loop] sample_time): "
            "phoid's in-loop route needs the sampled loop, so m, c, k come from the runs' "
            "modes, whose stderr assume the noise outside the loop",)
        return replace(res, noise_placement="outside", noise_placement_source="continuous loop",
                       warnings=(*res.warnings, *extra))
    placement, how, notes = placement_source(requested, stated)
    named = "--noise / noise_placement" if how == "option" else "[loop] noise"
    res: Identification | None
    try:
        res = modal()
        arrays = [(np.asarray(t, dtype=float), np.asarray(x, dtype=float))
                  for t, x in res.data]
    except IdentificationError as exc:
        cleaned = _clean(data)
        if placement == "outside" or estimator != "gls" or cleaned is None:
            raise
        res, arrays, modal_error = None, cleaned, exc
    if placement == "outside":
        assert res is not None
        extra = _contradiction(res, how, named, data=arrays, P=P, D=D, digital=digital,
                               names=names, added_mass=added_mass)
        return replace(res, noise_placement="outside", noise_placement_source=how,
                       warnings=(*res.warnings, *notes, *extra))
    n = len(arrays)
    dm = np.zeros(n) if added_mass is None else np.asarray(added_mass, dtype=float)
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    fits = [] if res is None else [r.fit if r.used else None for r in res.runs]
    aside = set() if res is None else {i for i, r in enumerate(res.runs) if not r.used}
    windows, skipped = inloop_windows(arrays, P, D, digital, names=names, added_mass=dm,
                                      fits=fits, aside=aside)
    if aside and res is not None:
        skipped = [w for w in res.warnings if any(w.startswith(f"{names[i]}: set aside")
                                                  for i in aside)] + skipped
    start = None if res is None else np.array([res.m.value, res.c.value, res.k.value])
    fit = None
    reason = None
    if not windows:
        reason = "no run has a window for it" + (f" ({skipped[0]})" if skipped else "")
    elif _same_gains(P[[w.run for w in windows]], D[[w.run for w in windows]]):
        reason = _SAME_GAINS
    else:
        says_outside = None
        if placement is None and res is not None:
            modal_res = res

            def says_outside(f: InLoopFit) -> bool:
                z = placement_test(modal_res, f, windows).z
                return z is not None and z < -Z_THRESHOLD
        try:
            fit = _fit(windows, start if start is not None and np.all(np.isfinite(start))
                       else None, P, D, says_outside)
        except (IdentificationError, np.linalg.LinAlgError) as exc:
            reason = str(exc)
        if fit is not None and says_outside is not None and says_outside(fit):
            pass  # the data say outside: the test below chooses the modal route
        elif fit is not None and res is None and _noise_ratio(fit) > FAR_ALONE:
            reason = (f"its best residual is {_noise_ratio(fit):.3g}× the records' own noise, "
                      f"and the modes cannot be fitted either: no m, c, k found that explain "
                      "the records; check the loop's delay_samples, velocity and the gains")
            fit = None
        elif fit is not None and _noise_ratio(fit) > FAR:
            reason = (f"its best residual is {_noise_ratio(fit):.3g}× the records' own noise "
                      f"(more than {FAR:g}×: no m, c, k found that explain the records; check "
                      "the runs' gains (units, sign) and the loop's delay_samples and velocity)")
            fit = None
    if fit is None:
        if placement == "in-loop" and (how == "option" or res is None):
            raise IdentificationError(f"{where}the in-loop fit cannot be made: {reason}")
        if res is None:  # neither route: the modes' own reason, which names the set's fault
            raise IdentificationError(f"{modal_error} (nor can the in-loop fit be made: "
                                      f"{reason})") from None
        test = PlacementTest(None, reason=f"the in-loop fit cannot be made: {reason}")
        extra = () if placement is None else (
            f"[loop] noise = 'in-loop', but the in-loop fit cannot be made ({reason}): m, c, "
            "k come from the runs' modes, whose stderr assume the noise outside the loop",)
        if placement is None:
            extra = (f"the in-loop fit cannot be made ({reason}): m, c, k come from the runs' "
                     "modes, whose stderr assume the noise outside the loop (a digital "
                     "loop's controller that reads the recorded sensor puts its noise in the "
                     "loop)",)
        return replace(res, noise_placement="outside", noise_placement_source=how,
                       placement_test=test, warnings=(*res.warnings, *notes, *extra))
    if _noise_free(fit, windows):
        test = PlacementTest(None, sigma=fit.sigma, noise_free=True,
                             reason="the records are noise-free: no noise placement to choose")
    elif res is not None:
        test = placement_test(res, fit, windows)
    else:
        test = PlacementTest(None, sigma=fit.sigma, reason="the modal route failed")
    if placement is None and test.z is not None and test.z < -Z_THRESHOLD:
        assert res is not None
        return replace(res, noise_placement="outside", noise_placement_source="data",
                       placement_test=test)
    contra: list[str] = []
    if how != "data" and test.z is not None and test.z < -Z_THRESHOLD:
        contra.append(
            f"the data contradict {named} = 'in-loop': the runs' modes explain the records "
            f"better than the in-loop model by more than their noise (z = {test.z:.3g} < "
            f"−{Z_THRESHOLD:g}), as when the controller acts on the true position (noise "
            "outside the loop); m, c, k come from the in-loop route as stated")
    base = res if res is not None else _skeleton(arrays, P, D, digital, names, files, dm,
                                                 source)
    out = _in_loop_result(base, fit, windows, names, [*notes, *skipped], x_unit)
    checked = _delay_check(out, fit, arrays, P, D, digital, names, dm, fits, aside)
    # a wrong delay misfits the in-loop model too: then its warning says why, not the placement
    if checked is out:
        checked = replace(out, warnings=(*contra, *out.warnings))
    return replace(checked, noise_placement_source=how, placement_test=test)


def _noise_free(fit: InLoopFit, windows: Sequence[RunWindow]) -> bool:
    """True when every window's residual is rounding (below 1e-5 of its motion's RMS): the
    records are noise-free (:mod:`phoid.methods.inloop_adequacy`'s test)."""
    for w, e in zip(windows, fit.residuals, strict=True):
        mot = w.y - e - fit.offset
        if not float(np.sqrt(np.mean(e * e))) <= _EXACT * float(np.sqrt(np.mean(mot * mot))):
            return False
    return True


def _contradiction(res: Identification, how: str, named: str, **kw: Any) -> tuple[str, ...]:
    """A stated ``"outside"`` the data contradict (z > 3), tested only where the modal
    route's adequacy fails (the in-loop fit costs a second route)."""
    ad = getattr(res, "adequacy", None)
    failed = ad is not None and any(c.passed is False for c in ad.checks)
    if not failed:
        return ()
    data, P, D = kw["data"], np.asarray(kw["P"], dtype=float), np.asarray(kw["D"], dtype=float)
    n = len(data)
    dm = np.zeros(n) if kw["added_mass"] is None else np.asarray(kw["added_mass"], dtype=float)
    fits = [r.fit if r.used else None for r in res.runs]
    aside = {i for i, r in enumerate(res.runs) if not r.used}
    try:
        windows, _ = inloop_windows(data, P, D, kw["digital"], names=kw["names"],
                                    added_mass=dm, fits=fits, aside=aside)
        start = np.array([res.m.value, res.c.value, res.k.value])
        fit = _fit(windows, start if np.all(np.isfinite(start)) else None, P, D)
    except (IdentificationError, np.linalg.LinAlgError, ValueError, ZeroDivisionError):
        return ()
    if _noise_ratio(fit) > FAR or _noise_free(fit, windows):
        return ()
    test = placement_test(res, fit, windows)
    if test.z is None or not test.z > Z_THRESHOLD:
        return ()
    return (f"the data contradict {named} = 'outside': the in-loop model explains the "
            f"records better than the runs' modes by more than their noise (z = {test.z:.3g} "
            f"> {Z_THRESHOLD:g}), as when the controller reads the recorded sensor (noise in "
            "the loop; `--noise in-loop` fits it); m, c, k come from the runs' modes as "
            "stated",)


def _delay_check(out: Identification, fit: InLoopFit, arrays, P, D, digital, names, dm, fits,
                 aside) -> Identification:
    """Where the in-loop fit's noise or whiteness check fails, the fit at delay_samples ± 1:
    a warning naming ``[loop] delay_samples`` where one fits markedly better (its RSS, over
    as many samples, lower by more than the noise explains: √ΔRSS/(2σ̂) > 3, the placement
    test's margin). The result stays at the stated delay."""
    ad = out.adequacy
    if ad is None or not any(c.name in ("noise", "whiteness") and c.passed is False
                             for c in ad.checks):
        return out
    d0 = int(digital.delay_samples)
    best: tuple[float, int] | None = None
    for d in (d0 - 1, d0 + 1):
        if d < 0:
            continue
        try:
            alt_digital = replace(digital, delay_samples=d)
            windows, _ = inloop_windows(arrays, P, D, alt_digital, names=names,
                                        added_mass=dm, fits=fits, aside=aside)
            if not windows:
                continue
            alt = _fit(windows, fit.theta, P, D)
        except (IdentificationError, np.linalg.LinAlgError, ValueError, TypeError):
            continue
        dof0 = fit.samples - fit.parameters
        dof1 = alt.samples - alt.parameters
        if dof0 <= 0 or dof1 <= 0 or not alt.sigma > 0:
            continue
        drop = (fit.sigma ** 2 - alt.sigma ** 2) * dof1
        z = math.sqrt(drop) / (2.0 * alt.sigma) if drop > 0 else 0.0
        if z > Z_THRESHOLD and (best is None or z > best[0]):
            best = (z, d)
    if best is None:
        return out
    z, d = best
    key = "delay_samples"
    return replace(out, warnings=(*out.warnings, (
        f"[loop] {key} = {d0} does not fit the records as well as {d}: the in-loop fit at "
        f"{key} = {d} lowers the residual by more than the noise explains (z = {z:.3g} > "
        f"{Z_THRESHOLD:g}); check the loop's delay (m, c, k are at the stated {d0})")))


def _clean(data: Sequence[tuple[Any, Any]]) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """The records as float arrays when each is a 1-d, finite, increasing (t, x) pair of one
    length (≥ 2); None otherwise (the modal route's first pass names what is wrong)."""
    out = []
    for run in data:
        try:
            t, x = run
            t = np.asarray(t, dtype=float)
            x = np.asarray(x, dtype=float)
        except (TypeError, ValueError):
            return None
        if t.ndim != 1 or x.shape != t.shape or t.size < 2 or not (
                np.all(np.isfinite(t)) and np.all(np.isfinite(x)) and np.all(np.diff(t) > 0)):
            return None
        out.append((t, x))
    return out
