"""Each run's dominant mode, measured past the delayed loop's fast transient (two passes).

Right after the release the delayed loop also rings in its fast non-dominant modes, which would
bias a single-mode fit. A first pass (:func:`phoid.fits.start_decays`, the record after
3Δt) gives a rough plant through eq. (35)'s lines; its exact loop roots give each run's next two
modes, which the second pass fits alongside the dominant one (free amplitudes, rates fixed)
right from the release. The fit starts as soon as the first mode left out — whose amplitude
follows from its residue x₀N(s)/f′(s), N(s) = ms + c + De^{−sΔt} − P(1 − e^{−sΔt})/s
(:func:`phoid.methods.loop_modes.mode_residue`) — is below 0.3 noise sd (or 1e−12 of the
amplitude for noise-free data). This keeps the information of the first instants, which
skipping the transient would throw away (docs/design-notes/pho.md, "fast modes fitted from
the release"). Because the second pass fits from the release on, the release time is refitted
there with the rough loop's own response from rest
(:func:`phoid.methods.pho_release.model_releases`), not taken from the data-only detection alone.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from phoid.dynamics import rightmost_roots_many
from phoid.fits import (
    DecayFit,
    FitJob,
    detect_release,
    fit_checked,
    fit_decays,
    start_decay,
    start_decays,
)
from phoid.methods.loop_modes import distinct_modes, mode_residue
from phoid.methods.pho import fit_lines
from phoid.methods.pho_release import model_releases

__all__ = ["N_FAST", "measure_modes", "measure_runs", "start_run"]

N_FAST = 2  # non-dominant loop modes fitted alongside the dominant one
_OMIT_NOISE_FRACTION = 0.3  # the fit starts once the first omitted mode is below 0.3 noise sd
_OMIT_FLOOR = 1e-12  # … or below 1e-12 of the release amplitude (noise-free records)
# a loop mode that decays by more than e² from one sample to the next is no column a fit can
# hold (it lives in the first sample or two: a tiny delay's fast modes, |Re s| ~ 1/Δt); it is
# left out and skipped instead, like the modes beyond the fitted ones
_FAST_MAX_DECAY_PER_SAMPLE = 2.0


def _fit_run(t, x, skip, release, fast_roots=None, guess=None):
    try:
        # the record passed start_decay's checks in the first pass (identify_pho_data made it
        # a float array), and identify_pho_data already runs with one BLAS thread
        fit = fit_checked(t, x, release=release, skip=skip, fast_roots=fast_roots,
                           guess=guess)
        return fit, None
    except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
        return None, str(exc)


def _unusable(fit: DecayFit) -> str | None:
    """Reason to set a run aside, or None. Runs with few cycles are kept (weighted).

    A run is set aside for growth only when it surely grows (σ < −2 stderr: an unstable loop,
    whose record on a real rig ends in saturation or nonlinearity). A barely damped run whose σ
    comes out negative but within 2 stderr of 0 is kept: it is consistent with a decay, it is
    usually the most precise run of the set, and dropping it whenever noise makes σ̂ < 0 would
    discard it half the time when σ ≈ 0. Its "growing oscillation … marginally stable" warning
    stays in the result.
    """
    surely_grows = fit.sigma < -2.0 * fit.sigma_stderr
    for w in fit.warnings:
        lw = w.lower()
        if "grow" in lw and not surely_grows:
            continue
        if any(key in lw for key in ("clip", "saturat", "grow", "unstable", "not converge",
                                     "no oscillation", "not oscillat")):
            return w
    if not (np.all(np.isfinite(fit.cov)) and fit.cov[0, 0] > 0 and fit.cov[1, 1] > 0):
        return "the decay fit has no usable covariance"
    if not fit.omega_d > 0:
        return "no oscillation found"
    return None


def measure_modes(
    data: Sequence[tuple[np.ndarray, np.ndarray]],
    P: np.ndarray,
    D: np.ndarray,
    delay: float,
    *,
    names: Sequence[str] | None = None,
) -> tuple[list[DecayFit | None], list[str | None], list[float]]:
    """Fit each run's dominant mode, skipping the loop's fast transient (two passes).

    Parameters
    ----------
    data : sequence of (t, x)
        Each run's time (s) and position (m) arrays.
    P, D : array_like
        Gains, N/m and N·s/m.
    delay : float
        Loop delay Δt, s.
    names : sequence of str, optional
        Run names for messages.

    Returns
    -------
    fits : list of DecayFit or None
    reasons : list of str or None
        Why a run was set aside (None if usable).
    skips : list of float
        The skip (s after release) used for each run.
    """
    _first, fits, reasons, skips, _rough = measure_runs(data, P, D, delay)
    return fits, reasons, skips


def start_run(t: np.ndarray, x: np.ndarray, skip: float, coarse_release: bool = False
              ) -> tuple[Any, str | None]:
    """One run's first look (:func:`phoid.fits.start_decay`) and None, or None and why
    it failed.

    Parameters
    ----------
    t, x : ndarray
        Time (s) and position (m).
    skip : float
        Time after the release left out, s.
    coarse_release : bool
        Stop the data-only release detection at its first stage (refined later).
    """
    try:
        return start_decay(t, x, skip=skip, coarse_release=coarse_release,
                           refine="auto" if coarse_release else True), None
    except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
        return None, str(exc)


def _digital_modes_of(rough, P, D, digital, dm):
    """Per run: the sampled loop's finite roots (decreasing real part) and their amplitudes
    for a unit release (phoid.dynamics.digital.digital_residues), from the rough plant with each
    run's added mass ``dm`` (one call per distinct added mass)."""
    from phoid.dynamics.digital import digital_residues, digital_roots

    m, c, k = rough
    roots: list[Any] = [None] * P.size
    s_res: list[Any] = [None] * P.size
    amp: list[Any] = [None] * P.size
    for added in np.unique(dm):
        idx = np.flatnonzero(dm == added)
        r = digital_roots(m + added, c, k, P[idx], D[idx], digital).s
        sr, a = digital_residues(m + added, c, k, P[idx], D[idx], digital)
        for j, i in enumerate(idx.tolist()):
            roots[i], s_res[i], amp[i] = r[j], sr[j], a[j]
    return roots, s_res, amp


def measure_runs(data: Sequence[tuple[np.ndarray, np.ndarray]], P: np.ndarray, D: np.ndarray,
                 delay: float, *, rough: tuple[float, float, float] | None = None,
                 first: list | None = None, noise: Sequence[float | None] | None = None,
                 digital: Any = None, added_mass: np.ndarray | None = None,
                 ) -> tuple[list, list[DecayFit | None], list[str | None], list[float], Any]:
    """Both passes of :func:`measure_modes`.

    The first pass is only the starting stage of the decay fit
    (:func:`phoid.fits.start_decay`: release, noise, window, and (σ, ω_d) from ESPRIT on
    the record after 3Δt): it is within about one standard error of a full fit, which is all
    the rough plant needs. Each run is then fitted once, in full: from the release with the
    loop's fast modes where the rough plant gives them, else a single mode after 3Δt.

    Parameters
    ----------
    data, P, D, delay
        As in :func:`measure_modes` (``data`` as float arrays).
    rough : (m, c, k), optional
        The plant the loop modes come from (kg, N·s/m, N/m); None: from the first pass.
    first : list of (start or None, error or None), optional
        The first pass's starts; given, that pass is not redone.
    noise : sequence of float or None, optional
        Per run, a noise level (m) that replaces the first pass's when smaller.
    digital : phoid.dynamics.digital.DigitalPD, optional
        A sampled loop (its gains ignored).
    added_mass : ndarray, optional
        Per run, the known added mass, kg.

    Returns
    -------
    first, fits, reasons, skips, rough
        The first pass's (start, error) per run, the fits, why each run was set aside (None if
        usable), the skips (s), and the rough plant used (None if none).
    """
    n = len(data)
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    dm = np.zeros(n) if added_mass is None else np.asarray(added_mass, dtype=float)
    skip0 = 3.0 * delay
    if first is None:
        # the release is refined below with the loop's own response, so the data-only
        # detection may stop at its first stage; where that refit is not made, the full
        # data-only detection is run then
        first = [(st, None) if not isinstance(st, str) else (None, st)
                 for st in start_decays(data, skip=skip0, refine="auto", coarse_release=True)]
    starts = [st for st, _err in first]
    fits: list[DecayFit | None] = [None] * n
    reasons: list[str | None] = [err for _st, err in first]
    skips = [skip0] * n
    ok = [i for i in range(n) if starts[i] is not None and starts[i].oscillating]
    if rough is None and len({(P[i], D[i]) for i in ok}) >= 2:
        try:
            lines = fit_lines([starts[i].sigma for i in ok], [starts[i].omega_d for i in ok],
                              P[ok], D[ok], delay, added_mass=dm[ok])
            if lines.m > 0:
                rough = (lines.m, lines.c, lines.k)
        except (ValueError, np.linalg.LinAlgError):
            rough = None
    releases = ([None] * n if not rough
                else model_releases(data, starts, rough, P, D, delay, dm, digital))
    all_roots: list[np.ndarray | None] = [None] * n
    todo = [i for i in range(n) if starts[i] is not None]
    amps: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    if rough is not None and todo and digital is not None:
        try:
            roots, s_res, amp = _digital_modes_of(rough, P[todo], D[todo], digital, dm[todo])
            for j, i in enumerate(todo):
                r = roots[j][np.isfinite(roots[j])]
                all_roots[i] = r
                amps[i] = (s_res[j], amp[j])
        except (RuntimeError, ValueError, np.linalg.LinAlgError):
            pass
    elif rough is not None and todo and delay > 0.0:
        try:
            # one continuation per added mass (usually one group: no mass added)
            for added in np.unique(dm[todo]):
                grp = [i for i in todo if dm[i] == added]
                rm, rc, rk = rough
                for i, r in zip(grp, rightmost_roots_many(rm + added, rc, rk, P[grp], D[grp],
                                                           delay, count=2 * N_FAST + 4),
                                strict=True):
                    all_roots[i] = r
        except (RuntimeError, ValueError):
            pass
    # every run's fit is planned first and made in one batch (phoid.fits.modal); a run whose
    # planned fit fails, or that has none, then gets the plain single-mode fit after 3Δt
    plans: dict[int, tuple[FitJob, bool]] = {}  # run: (fit, made with fast modes)
    rel_of: dict[int, float] = {}
    for i in range(n):
        st = starts[i]
        if st is None:
            continue
        t, x = data[i]
        release = releases[i] if releases[i] is not None else detect_release(t, x)
        rel_of[i] = release
        if st.oscillating and releases[i] is not None and delay == 0.0:
            # no delay: the closed loop is exactly second order; fit from the refined release
            plans[i] = (FitJob(t, x, release, 0.0, None, (st.sigma, st.omega_d)), False)
            skips[i] = 0.0
        elif all_roots[i] is not None and (
            len(modes := distinct_modes(all_roots[i])) >= N_FAST + 2
            or (digital is not None and len(modes) >= 1)
        ):
            rest = modes[1:]
            if digital is not None:
                # a root on the negative real z axis rings at the controller's Nyquist rate,
                # (−1)ⁿ: not a column the decay fit can hold; it can only be skipped
                nyq = 0.99 * math.pi / digital.sample_time
                fitted = [q for q in rest if abs(q.imag) < nyq][:N_FAST]
            else:
                step = float(np.median(np.diff(t[: min(t.size, 64)])))
                fitted = [q for q in rest if -q.real * step <= _FAST_MAX_DECAY_PER_SAMPLE]
                fitted = fitted[:N_FAST]
            fast = np.array(fitted, dtype=complex)
            left = [q for q in rest if q not in fitted]
            omitted = left[0] if left else None
            # release amplitude scale and the first omitted mode's share of it (its residue)
            x0 = max(float(x.max()) - st.offset, st.offset - float(x.min()))  # max |x − offset|
            if omitted is None:
                a_omit = 0.0
            elif digital is not None:
                s_res, amp = amps[i]
                a_omit = 2.0 * float(np.max(np.abs(amp[np.abs(s_res - omitted) <= 1e-9 * max(
                    1.0, abs(omitted))]), initial=0.0)) * x0
            else:
                a_omit = 2.0 * abs(mode_residue(omitted, rough[0] + dm[i], rough[1], rough[2],
                                            float(P[i]), float(D[i]), delay)) * x0
            nsd = st.noise_sd if noise is None or noise[i] is None else min(st.noise_sd, noise[i])
            nsd = nsd if math.isfinite(nsd) else 0.0
            level = max(_OMIT_NOISE_FRACTION * nsd, _OMIT_FLOOR * x0)
            skip = (max(0.0, math.log(a_omit / level) / -omitted.real)
                    if omitted is not None and a_omit > level else 0.0)
            # never skip so much that fewer than ~3 cycles remain
            period = 2 * math.pi / st.omega_d if st.omega_d > 0 else math.inf
            skip = min(skip, max(skip0, (st.t_end - st.release) - 3 * period))
            # start from the run's own mode, or where the data gave none, the rough loop's
            guess = (st.sigma, st.omega_d) if st.oscillating else (-modes[0].real, modes[0].imag)
            if guess[1] > 0:
                plans[i] = (FitJob(t, x, release, skip, fast, guess), True)
                skips[i] = skip
    done = dict(zip(plans, fit_decays([job for job, _fast in plans.values()]), strict=True))
    for i in rel_of:
        g = done.get(i)
        if isinstance(g, str) or (g is not None and plans[i][1] and not math.isfinite(g.sigma)):
            g = None  # the model with these modes could not be evaluated anywhere
        if g is None:
            # no loop modes (no rough plant, a non-oscillating start, or that fit failed): one
            # mode after 3Δt from the data-only start, as a plain fit_decay would do
            skips[i] = skip0
            t, x = data[i]
            g, err = _fit_run(t, x, skip0, rel_of[i])
            if g is None:
                reasons[i] = err
                continue
        fits[i], reasons[i] = g, _unusable(g)
    return first, fits, reasons, skips, rough
