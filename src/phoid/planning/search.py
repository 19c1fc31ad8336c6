"""The design search: gain schedules that make a plant ring stably, with the best precision.

:func:`design` proposes the gains (Pᵢ, Dᵢ) of a PHO experiment (seed eq. 23) from a prior guess
of the plant — each of m, c, k a value or a range (:mod:`phoid.planning.settings`) — the loop
delay and the rig's limits; every candidate is checked against the requirements of
:mod:`phoid.planning.evaluation` on the whole prior grid.

Runs are chosen by *pole placement* at the nominal plant: a target dominant root s* fixes the
gains through f(s*) = 0, which is linear in (P, D): D s* + P = −(m s*² + c s* + k) e^{s*Δt}.
Targets are taken on a grid of natural frequencies ω₀ (geometric, from the lowest that gives
``min_cycles`` within the record to the bandwidth limit) and damping ratios in the band (and
above it, for the fallback); every target is checked against the constraints on the whole
prior grid. For each ω₀ the lowest feasible ζ is kept (lighter damping means a slower decay and
more information). The N runs form a **sweep** along that frontier between two ends, spaced as
Chebyshev–Lobatto points in ω₀² (the abscissa of the eq. 35 stiffness line), so that they
cluster towards the ends, where information is greatest, yet spread over the whole range —
distinct runs let the eq. (35) lines be checked for straightness, which replicates at two
optimal points would not. The ends are chosen to minimise the **worst case over the prior
grid** of Σⱼ log Var(θⱼ), θ = (m, c, k), of the Cramér–Rao covariance: a unit-free criterion
(it does not change when a parameter's unit or size changes, so a mass–damper's k ≈ 0 is
handled like any other parameter) that balances the three relative precisions. Overdamped
plants get negative D by the placement itself.

A prior so wide that no run meets the band while staying safe on all of it (e.g. c 20–60 with a
5 ms delay: a run that rings lightly at c = 20 is heavily damped at c = 60) falls back to safe
runs with at least 3 cycles (``phoid.fits.MIN_CYCLES``) at the nominal plant, with a
warning: such a schedule is a first experiment whose identification narrows the prior for a
second design. With so few cycles the prediction is optimistic (docs/design-notes/planning.md).

A **sampled loop** (``sample_time``: the digital controller of :mod:`phoid.dynamics.digital`) is
searched as above on its continuous surrogate, whose delay is the sampled loop's lag
(:func:`phoid.planning.settings.equivalent_delay`); each run's target root is then placed on
the sampled loop itself and the run evaluated on its exact roots over the prior
(:func:`sampled_runs`, :mod:`phoid.planning.sampled`), a run that fails there moved to the
nearest target that passes, or dropped. The schedule is chosen by the modal criterion above;
its prediction is the bound for the noise placement (the in-loop bound by default,
:func:`phoid.planning.inloop_bound.inloop_cramer_rao`), evaluated on the chosen runs.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from phoid._threads import single_blas_thread
from phoid.fits import MIN_CYCLES
from phoid.planning.evaluation import (
    Evaluation,
    evaluate,
    log_var,
    place,
    run_information,
    stack,
)
from phoid.planning.result import Design, assemble, roots_in_range
from phoid.planning.sampled import evaluate_sampled, place_sampled
from phoid.planning.settings import DesignError, DesignSettings, Prior, fmt_range, make_prior

__all__ = ["MAX_RUNS", "design", "sampled_runs"]

MAX_RUNS = 1000
"""Most runs :func:`design` plans (its work and memory grow with the number of runs)."""
_N_OMEGA = 96  # grid of target natural frequencies
_N_ZETA = 10  # grid of target damping ratios in the band
_N_ZETA_ABOVE = 7  # … and above it, up to _ZETA_CAP, for priors too wide for the band
_ZETA_CAP = 0.7
_REPAIR = 64  # grid targets tried for a run whose sampled loop fails the requirements
_REPAIR_BATCH = 16  # … evaluated together


@roots_in_range
@single_blas_thread
def design(
    m: Any,
    c: Any,
    k: Any,
    *,
    delay: float | None = None,
    runs: int = 10,
    pmax: float | None = None,
    dmax: float | None = None,
    max_freq: float | None = None,
    fs: float | None = None,
    duration: float = 10.0,
    noise: float = 1e-5,
    amplitude: float = 0.01,
    zeta: tuple[float, float] = (0.03, 0.2),
    min_cycles: float = 5.0,
    delay_margin: float | None = None,
    separation: float = 2.0,
    tolerance: float = 0.1,
    sample_time: float | None = None,
    delay_samples: int | None = None,
    velocity: str | None = None,
    cutoff: float | None = None,
    noise_in_loop: bool | None = None,
    delay_margin_samples: int | None = None,
) -> Design:
    """Propose the gains of a PHO experiment for a plant known roughly (see the module doc).

    Parameters
    ----------
    m, c, k : float, (lo, hi) or "lo:hi"
        Prior guess of the mass (kg, > 0), damping (N·s/m, ≥ 0) and stiffness (N/m, ≥ 0); a
        range makes the schedule safe for every plant in it.
    delay : float, optional
        Loop delay Δt of a continuous loop, s (required unless ``sample_time`` is given; refused
        with it).
    runs : int, default 10
        Number of runs N (2 ≤ N ≤ :data:`MAX_RUNS` = 1000: the work and memory grow with N).
    pmax, dmax : float, optional
        Limits on |P| (N/m) and |D| (N·s/m).
    max_freq : float, optional
        Highest damped frequency of a run, rad/s (the bandwidth of the rig); the cap 0.2 π f_s
        (10 samples per period) applies in any case.
    fs : float, optional
        Sample rate of the record, Hz: default 1000, or 1/``sample_time`` for a sampled loop
        (a rig records at its loop's rate), where it must be a whole multiple of 1/T.
    duration : float, default 10
        Record length after the release, s.
    noise : float, default 1e-5
        Sensor noise standard deviation, m.
    amplitude : float, default 0.01
        Release position x₀, m.
    zeta : (float, float), default (0.03, 0.2)
        Band of the dominant mode's damping ratio at the nominal plant.
    min_cycles : float, default 5
        Fewest cycles above the noise floor within the record, on the whole prior.
    delay_margin : float, optional
        Least delay margin (s); default max(0.2 Δt, 1/f_s).
    separation : float, default 2
        Other roots must decay at least this many times faster than the dominant one.
    tolerance : float, default 0.1
        Relative width of the safety checks around a prior given as a single value.
    sample_time : float, optional
        A sampled loop: the digital controller's period T, s (:mod:`phoid.dynamics.digital`:
        zero-order hold, the PD law on the sampled position and estimated velocity). The
        runs' modes, stability and margins are then those of the sampled loop, exactly
        (docs/design-notes/planning.md, "Sampled loops").
    delay_samples : int, optional
        The sampled loop's command delay d, whole periods (default 0).
    velocity : {"backward-difference", "filtered"}, optional
        The sampled loop's velocity estimator (default the backward difference).
    cutoff : float, optional
        The filtered velocity's cut-off, rad/s.
    noise_in_loop : bool, optional
        Whether the controller reads the noisy recorded position: default True for a sampled
        loop (as on a rig; the prediction is then the in-loop bound), False for a continuous
        one (True is refused there). False predicts with the modal bound.
    delay_margin_samples : int, optional
        A sampled loop's least delay margin, whole samples (default max(1, ⌈0.2 d⌉)); refused
        for a continuous loop, whose margin is ``delay_margin`` (s).

    Returns
    -------
    Design
        The schedule; ``.summary()`` (JSON), ``.report()`` (text), ``.plot()``, ``.write()``.

    Raises
    ------
    ValueError
        For a bad parameter (named in the message).
    DesignError
        When no gains within the limits make the loop ring stably with the required margins
        on the whole prior (e.g. a delay too long for the bandwidth, limits too tight).

    Examples
    --------
    >>> d = design(0.5, 40.0, 20.0, delay=0.005, runs=6)
    >>> d.safe, bool(d.D[0] < 0)  # overdamped: its slowest run rings by removing damping
    (True, True)
    """
    nruns = _count("runs", runs)
    st = DesignSettings(delay=delay, fs=fs, duration=duration, noise=noise,
                        amplitude=amplitude, zeta=zeta, pmax=pmax, dmax=dmax,
                        max_freq=max_freq, min_cycles=min_cycles, delay_margin=delay_margin,
                        separation=separation, tolerance=tolerance, sample_time=sample_time,
                        delay_samples=delay_samples, velocity=velocity, cutoff=cutoff,
                        noise_in_loop=noise_in_loop, delay_margin_samples=delay_margin_samples)
    prior = make_prior(m, c, k, st.tolerance)
    m0, c0, k0 = prior.nominal
    zlo, zhi = st.zeta
    # target grid: natural frequency of the dominant mode at the nominal plant × damping
    w_lo = 2.0 * math.pi * st.min_cycles / st.duration
    w_hi = st.omega_max / math.sqrt(1.0 - zlo * zlo)
    rate = "--fs" if st.sample_time is None else "shorten --sample-time"
    if not w_hi > w_lo * 1.001:
        raise DesignError(
            f"no room for ringing runs: {st.min_cycles:g} cycles in {st.duration:g} s need "
            f"ω_d ≥ {w_lo:.4g} rad/s, but the bandwidth limit is {st.omega_max:.4g} rad/s "
            f"(raise --max-freq or {rate}, or record longer)"
        )
    W = np.geomspace(w_lo, w_hi, _N_OMEGA)
    Zs = np.unique(np.concatenate([np.geomspace(zlo, zhi, _N_ZETA),
                                   np.geomspace(zhi, max(_ZETA_CAP, zhi), _N_ZETA_ABOVE)]))
    nz = Zs.size
    WW, ZZ = np.meshgrid(W, Zs, indexing="ij")  # (n_w, n_z)
    S = (-ZZ * WW + 1j * WW * np.sqrt(1.0 - ZZ * ZZ)).ravel()
    P, D = place(m0, c0, k0, S, st.model_delay)
    ok_lim = (np.abs(P) <= st.pmax) & (np.abs(D) <= st.dmax)
    idx = np.flatnonzero(ok_lim)
    if idx.size == 0:
        raise DesignError(_why_infeasible(st, prior, ok_lim, None, w_lo))
    ev = evaluate(P[idx], D[idx], S[idx], prior, st)
    safe = np.all(ev.ok, axis=1)
    tier1 = safe & ev.informative(st)
    warnings: list[str] = []
    if np.any(tier1):
        usable = tier1
    else:
        # the band is given up, but each run must still ring for a few cycles at the nominal
        # plant (phoid's decay fit flags fewer than decay.MIN_CYCLES)
        usable = safe & ev.separated[:, 0] & (ev.cycles[:, 0] >= min(st.min_cycles,
                                                                      MIN_CYCLES))
        if not np.any(usable):
            raise DesignError(_why_infeasible(st, prior, ok_lim, ev, w_lo))
        warnings.append(
            "no gains give the nominal plant a mode in the ζ band with "
            f"{st.min_cycles:g} cycles while staying stable with margin over the whole prior: "
            "the runs are more damped than asked (see each run's ζ and cycles) and, with "
            "so few cycles, the predicted stderr is optimistic; narrow the prior (identify "
            "with this schedule, then design again)"
        )
    feasible = np.zeros(S.size, dtype=bool)
    feasible[idx] = usable
    feasible = feasible.reshape(W.size, nz)
    # frontier: lowest feasible ζ at each ω₀
    has = np.any(feasible, axis=1)
    zi = np.argmax(feasible, axis=1)
    cols = np.flatnonzero(has)
    pos = np.full(S.size, -1)
    pos[idx] = np.arange(idx.size)
    ev_front = ev.take(pos[cols * nz + zi[cols]])
    info = run_information(ev_front, prior, st)  # (F, G, 3, 3)
    # contiguous stretches of the frontier (feasible ω₀ in a row)
    seg = np.concatenate([[0], np.cumsum(np.diff(cols) != 1)])
    ends = _best_sweep(W[cols], seg, info, nruns)
    if ends is None:
        raise DesignError(
            "no spread of feasible runs can determine m, c and k: the gains that ring stably "
            "within the limits all give nearly the same mode (widen --pmax/--dmax or "
            "--max-freq, or narrow the prior)"
        )
    a, b = ends
    u = _nodes(nruns)
    w2 = W[cols][a] ** 2 + u * (W[cols][b] ** 2 - W[cols][a] ** 2)
    wr = np.sqrt(w2)
    # each run: the larger frontier ζ of its two neighbouring grid points (conservative)
    fz = Zs[zi[cols]]
    j = np.clip(np.searchsorted(W[cols], wr) - 1, a, max(b - 1, a))
    zr = np.maximum(fz[j], fz[np.minimum(j + 1, b)])
    sr = -zr * wr + 1j * wr * np.sqrt(1.0 - zr * zr)
    Pr, Dr = place(m0, c0, k0, sr, st.model_delay)
    evr = evaluate(Pr, Dr, sr, prior, st)
    good = np.all(evr.ok, axis=1) & evr.ok_limits & (
        evr.informative(st) if np.any(tier1)
        else evr.separated[:, 0] & (evr.cycles[:, 0] >= min(st.min_cycles, MIN_CYCLES)))
    if not np.all(good):
        # snap runs that fall between grid points onto the nearest feasible grid point
        near = np.array([a + int(np.argmin(np.abs(np.log(W[cols][a:b + 1] / x)))) for x in wr])
        Pr = np.where(good, Pr, ev_front.P[near])
        Dr = np.where(good, Dr, ev_front.D[near])
        sr = np.where(good, sr, ev_front.s[near, 0])
    if st.digital is not None:
        # the surrogate's targets, placed and checked on the sampled loop itself
        wa, wb = W[cols][a], W[cols][b]
        span = (W >= wa * (1 - 1e-12)) & (W <= wb * (1 + 1e-12))
        grid = (WW[span].ravel(), ZZ[span].ravel())
        evs, more = sampled_runs(sr, grid, prior, st, informative=bool(np.any(tier1)))
        warnings.extend(more)
        return assemble(evs.P, evs.D, prior, st, "design", warnings, evaluation=evs)
    return assemble(Pr, Dr, prior, st, "design", warnings)


def _meets(ev: Evaluation, st: DesignSettings, informative: bool) -> np.ndarray:
    """Per run: safe on the whole prior, within the limits, and informative at the nominal
    plant (or, for a prior too wide for the band, ringing for a few cycles there)."""
    rings = (ev.informative(st) if informative
             else ev.separated[:, 0] & (ev.cycles[:, 0] >= min(st.min_cycles, MIN_CYCLES)))
    return np.all(ev.ok, axis=1) & ev.ok_limits & rings


def sampled_runs(targets: np.ndarray, grid: tuple[np.ndarray, np.ndarray], prior: Prior,
                 st: DesignSettings, *, informative: bool) -> tuple[Evaluation, list[str]]:
    """The runs of a sampled loop: the surrogate's targets placed exactly, checked exactly.

    Each target root is put on the sampled loop at the nominal plant
    (:func:`phoid.planning.sampled.place_sampled`) and the run evaluated on its exact roots
    over the prior grid (:func:`phoid.planning.sampled.evaluate_sampled`). A run that fails
    there (the surrogate's delay is an approximation) moves to the nearest target of ``grid``
    (natural frequencies ω₀ and damping ratios ζ of the search, within the sweep's span:
    nearest in log ω₀, then the lightest ζ) whose placement meets the requirements, trying at
    most :data:`_REPAIR` of them; a run for which none does is dropped, with a warning.

    Returns
    -------
    Evaluation
        The runs kept (their gains ``P``, ``D``), evaluated exactly on the prior grid.
    warnings : list of str

    Raises
    ------
    DesignError
        Fewer than two runs left.
    """
    m0, c0, k0 = prior.nominal
    loop = st.digital
    P, D = place_sampled(m0, c0, k0, targets, loop)
    rows: list[Evaluation | None] = [None] * P.size  # each run's exact evaluation
    fin = np.flatnonzero(np.isfinite(P) & np.isfinite(D))
    good = np.zeros(P.size, dtype=bool)
    if fin.size:
        ev = evaluate_sampled(P[fin], D[fin], prior, st)
        good[fin] = _meets(ev, st, informative)
        for n, i in enumerate(fin):
            rows[i] = ev.take(np.array([n]))
    gw, gz = grid
    gs = -gz * gw + 1j * gw * np.sqrt(1.0 - gz * gz)
    tried: dict[int, tuple[bool, Evaluation | None]] = {}
    for i in np.flatnonzero(~good):
        order = np.lexsort((gz, np.abs(np.log(gw / abs(targets[i])))))[:_REPAIR]
        for start in range(0, order.size, _REPAIR_BATCH):
            batch = order[start:start + _REPAIR_BATCH]
            new = np.array([j for j in batch if j not in tried], dtype=int)
            if new.size:
                Pc, Dc = place_sampled(m0, c0, k0, gs[new], loop)
                okc = np.flatnonzero(np.isfinite(Pc) & np.isfinite(Dc))
                tried.update({int(j): (False, None) for j in new})
                if okc.size:
                    evc = evaluate_sampled(Pc[okc], Dc[okc], prior, st)
                    for n, (o, j) in enumerate(zip(_meets(evc, st, informative), new[okc],
                                                   strict=True)):
                        tried[int(j)] = (bool(o), evc.take(np.array([n])))
            hit = next((int(j) for j in batch if tried[int(j)][0]), None)
            if hit is not None:
                rows[i] = tried[hit][1]
                good[i] = True
                break
    warnings = []
    if not np.all(good):
        lost = np.abs(targets[~good])
        warnings.append(
            f"{lost.size} of {P.size} runs dropped: near their targets (ω₀ "
            + ", ".join(f"{w:.4g}" for w in lost) + " rad/s) no gains make the sampled loop "
            "ring stably with the margins over the whole prior; the schedule has "
            f"{int(good.sum())} runs")
    if good.sum() < 2:
        raise DesignError(
            f"the sampled loop (sample_time {st.sample_time:g} s, delay_samples "
            f"{st.delay_samples}) leaves fewer than two runs that ring stably with the margins "
            "over the whole prior: narrow the prior, lower the delay or record faster")
    return stack([r for r, g in zip(rows, good, strict=True) if g]), warnings


def _count(name: str, value: Any, most: int = MAX_RUNS) -> int:
    try:
        n = int(value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"`{name}` must be an integer from 2 to {most}; got {value!r}") \
            from None
    if n != value or not 2 <= n <= most:
        raise ValueError(f"`{name}` must be an integer from 2 to {most}; got {value!r}")
    return n


def _nodes(n: int) -> np.ndarray:
    """Chebyshev–Lobatto fractions in [0, 1], denser towards both ends."""
    return 0.5 - 0.5 * np.cos(np.pi * np.arange(n) / (n - 1))


def _best_sweep(w: np.ndarray, seg: np.ndarray, info: np.ndarray, n: int):
    """Ends (a, b) of the frontier sweep minimising the worst-case Σ log Var over the prior.

    ``info`` holds each frontier point's information at every plant, (F, G, 3, 3); a sweep
    between frontier points a < b (same contiguous segment) has its runs at the Chebyshev–Lobatto
    fractions of ω₀², each run's information interpolated linearly (in log ω₀) between its
    neighbouring grid points.
    """
    F = w.size
    ia, ib = np.triu_indices(F, k=1)
    keep = seg[ia] == seg[ib]
    ia, ib = ia[keep], ib[keep]
    if ia.size == 0:
        return None
    u = _nodes(n)
    lw = np.log(w)
    best, best_val = None, np.inf
    for start in range(0, ia.size, 4096):
        a, b = ia[start:start + 4096], ib[start:start + 4096]
        total = np.zeros((a.size, *info.shape[1:]))
        for ur in u:
            x = np.log(np.sqrt(w[a] ** 2 + ur * (w[b] ** 2 - w[a] ** 2)))
            j = np.clip(np.searchsorted(lw, x) - 1, 0, F - 2)
            j = np.maximum(j, a)
            j = np.minimum(j, np.maximum(b - 1, a))
            t = np.clip((x - lw[j]) / (lw[j + 1] - lw[j]), 0.0, 1.0)[:, None, None, None]
            total += (1.0 - t) * info[j] + t * info[j + 1]
        val = np.max(log_var(total), axis=1)
        i = int(np.argmin(val))
        if val[i] < best_val:
            best_val, best = val[i], (int(a[i]), int(b[i]))
    if not np.isfinite(best_val):
        return None
    return best


def _why_infeasible(st: DesignSettings, prior: Prior, ok_lim: np.ndarray, ev: Evaluation | None,
                    w_lo: float) -> str:
    """One line saying which requirement rules out every candidate run (checked in order)."""
    checked = ", ".join(f"{n} {fmt_range(r)}" for n, r in prior.ranges.items())
    band = f"ζ {st.zeta[0]:g}–{st.zeta[1]:g}"
    if ev is None or not np.any(ok_lim):
        return (f"every gain pair that makes the loop ring with {band} exceeds the limits "
                f"|P| ≤ {st.pmax:g} N/m, |D| ≤ {st.dmax:g} N s/m: raise --pmax/--dmax")
    span = (f"ω_d {w_lo:.4g}–{st.omega_max:.4g} rad/s ({st.min_cycles:g} cycles in "
            f"{st.duration:g} s up to the bandwidth limit)")
    rate = "--fs" if st.sample_time is None else "shorten --sample-time"
    loop = (f"a delay of {st.delay:g} s" if st.sample_time is None else
            f"the sampled loop (sample_time {st.sample_time:g} s, delay_samples "
            f"{st.delay_samples}: about {st.model_delay:.3g} s of lag)")
    keep = ev.stable[:, 0] & ev.dominant[:, 0]
    if not np.any(keep):
        return (f"{loop} makes every useful gain unstable: no gains within "
                f"the limits give a stable loop whose slowest mode rings with {band} and "
                f"{span}; shorten the delay, or record longer for slower runs")
    keep = np.all(ev.stable & ev.dominant, axis=1)
    if not np.any(keep):
        return (f"no gains keep the loop stable and ringing for every plant in the prior "
                f"({checked}) with {loop}: narrow the prior")
    keep &= np.all(ev.zeta >= 0.5 * st.zeta[0], axis=1)
    if not np.any(keep):
        return (f"no gains keep the loop damped (ζ ≥ {0.5 * st.zeta[0]:g}) for every plant "
                f"in the prior ({checked}): narrow the prior")
    keep &= np.all(ev.dmargin >= st.delay_margin, axis=1)
    if not np.any(keep):
        need = (f"{st.delay_margin:.3g} s" if st.sample_time is None
                else f"{st.delay_margin_samples} samples")
        lower = "--delay-margin" if st.sample_time is None else "--delay-margin-samples"
        return (f"no gains leave a delay margin of {need} for every plant in "
                f"the prior ({checked}) with {loop}: narrow the prior, or lower "
                f"{lower} only if the delay is well known")
    keep &= np.all(ev.ok_freq, axis=1)
    if not np.any(keep):
        return (f"every safe run rings above the bandwidth limit {st.omega_max:.4g} rad/s for "
                f"some plant of the prior: raise --max-freq or {rate}")
    keep &= ev.separated[:, 0]
    if not np.any(keep):
        return (f"in every safe run another loop mode decays less than {st.separation:g}× "
                "faster than the ringing one, so the decay is not a single mode")
    return (f"no safe run gives {min(st.min_cycles, MIN_CYCLES):g} cycles above the noise "
            f"floor ({st.noise:g} m) in {st.duration:g} s from a release at {st.amplitude:g} "
            "m: record longer, raise --amplitude or lower the noise")

