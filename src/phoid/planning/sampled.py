"""A sampled (digital) loop in the design: exact placement, exact evaluation, margins in samples.

The design's search works on the continuous delayed loop (:mod:`phoid.planning.evaluation`);
for a sampled loop — the digital PD controller of :mod:`phoid.dynamics.digital`, zero-order
hold, d whole samples of command delay — it searches that loop's continuous *surrogate*, whose
delay is :func:`phoid.planning.settings.equivalent_delay`, and then works on the sampled loop
itself, exactly:

* :func:`place_sampled` puts a root of the sampled loop at a target s: χ(e^{sT}) = 0 of the
  characteristic polynomial χ(z) = z^d A_f(z)Δ(z) + [P A_f(z) + D B_f(z)]N(z) (A_f, B_f the
  velocity estimator's polynomials, :meth:`phoid.dynamics.velocity.VelocityFilter.polynomials`)
  is linear in (P, D), so its real and imaginary parts give the gains;
* :func:`evaluate_sampled` evaluates gains on the prior grid from all d + r + 2 roots of χ
  (r the estimator's order: d + 3 for the backward difference)
  (:func:`phoid.dynamics.digital.digital_residues`): stability (every |z| < 1), the dominant
  mode and whether it rings, the separation of the other roots, the release amplitude of the
  dominant mode (its exact residue), the cycles above the noise and the delay margin;
* :func:`delay_margin_samples` is the delay margin in whole samples: the largest d′ ≥ d for
  which the loop stays stable, less d;
* :func:`sampled_information` is the modal Fisher information of (m, c, k) (the dominant
  mode's (σ, ω_d) through the exact ∂s/∂θ of :func:`phoid.dynamics.digital.digital_modes`);
* :func:`predicted_covariance` is the prediction for the noise placement: the in-loop bound
  (:func:`phoid.planning.inloop_bound.inloop_cramer_rao`) when the controller reads the noisy
  record, the modal bound otherwise.

The delay margin in samples
---------------------------
With A(z) = A_f(z)Δ(z) and B(z) = [P A_f(z) + D B_f(z)]N(z), χ_{d′}(z) = z^{d′}A(z) + B(z)
and the loop gain is L = B/A. By the argument principle on the unit circle the number of roots
of χ_{d′} outside it is r + 2 − n_A − W(d′), n_A the roots of A inside and W(d′) the winding
number of 1 + e^{−iθd′}L(e^{iθ}) about 0. Rotating each point of that curve continuously,
e^{−iθτ} for real τ, W changes only where the curve passes through 0: at a frequency θ_j ∈
(0, π) where |L(e^{iθ_j})| = 1, for τ = (arg L(e^{iθ_j}) + π + 2πn)/θ_j, and — only when
|L(−1)| ≥ 1, where the curve's two halves meet at θ = π — where 1 + L(−1)cos(πτ) = 0. Between
these candidate delays the count is constant, so the loop (stable at d) stays stable up to
the first candidate τ* > d; the margin is the last whole d′ before the first candidate at
which the exact roots (:func:`phoid.dynamics.digital.digital_roots`) say unstable: each
candidate's integer is checked exactly (a tangency, where the count does not change, is passed
over). Checked against the exact roots at every d′ from d on (tests/test_design_sampled.py
and, over 90 random loops, to d + 100: docs/design-notes/planning.md). The crossing
frequencies are bracketed on a geometric grid of θ from 10⁻¹² to π with |L| evaluated in
factored form (no cancellation near z = 1) and refined by bisection. For a loop of degree above
:data:`EXACT_ORDER` the candidate is taken without the root check.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from phoid.dynamics.digital import DigitalPD, digital_modes, digital_residues, digital_roots
from phoid.dynamics.zoh import zoh_plant
from phoid.planning.evaluation import Evaluation
from phoid.planning.fisher import mode_information, safe_inverse
from phoid.planning.inloop_bound import inloop_cramer_rao
from phoid.planning.settings import DesignError, DesignSettings, Prior

__all__ = [
    "EXACT_ORDER",
    "delay_margin_samples",
    "evaluate_sampled",
    "place_sampled",
    "predicted_covariance",
    "sampled_information",
]

EXACT_ORDER = 64
"""Highest degree d′ + r + 2 at which a candidate delay is checked on all the loop's roots (an
eigenvalue problem of that order); above it the first candidate is taken as it is (for a loop
stable at d the first crossing destabilises it)."""

_GRID = np.geomspace(1e-12, math.pi, 4000)  # θ, rad per sample: where |L| = 1 is bracketed
_CANDIDATES = 24  # candidate delays tried per crossing frequency (the first destabilises)


def _filter(loop: DigitalPD) -> tuple[np.ndarray, np.ndarray]:
    """The velocity estimator's polynomials A_f(z) (monic) and B̃(z) = B_f(z)/(z − 1) (its
    coefficients sum to 0, so z = 1 is a root of B_f), highest power first."""
    Af, Bf, _ = loop.estimator.polynomials()
    Bq, _ = np.polydiv(Bf, np.array([1.0, -1.0]))
    return Af, np.atleast_1d(Bq)


def _loop_values(z: np.ndarray, zp: Any, P: np.ndarray, D: np.ndarray, filt: tuple
                 ) -> tuple[np.ndarray, np.ndarray]:
    """A(z) = A_f(z)(z − λ₁)(z − λ₂) and B(z) = [P A_f(z) + D (z − 1)B̃(z)]N(z), factored
    (no cancellation near z = 1)."""
    Af, Bq = filt
    l1, l2 = zp.lam
    Afz = np.polyval(Af, z)
    A = Afz * (z - l1) * (z - l2)
    B = (P * Afz + D * (z - 1.0) * np.polyval(Bq, z)) * (zp.b1 * z + zp.b0)
    return A, B


def place_sampled(m: float, c: float, k: float, s: np.ndarray, loop: DigitalPD
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Gains that put a root of the sampled loop at s (1/s): χ(e^{sT}) = 0, linear in (P, D).

    Parameters
    ----------
    m, c, k : float
        The plant, kg, N·s/m, N/m.
    s : ndarray of complex
        Target roots, 1/s, 0 < Im s < π/T.
    loop : DigitalPD
        Sample time, delay and velocity estimator (its gains are ignored).

    Returns
    -------
    P, D : ndarray
        Gains, N/m and N·s/m, solving Re and Im of P·A_f(z)N(z) + D·B_f(z)N(z)
        = −z^d A_f(z)Δ(z), z = e^{sT} (A_f, B_f the velocity estimator's polynomials).
    """
    s = np.asarray(s, dtype=complex)
    T = loop.sample_time
    zp = zoh_plant(m, c, k, T)
    filt = _filter(loop)
    d = loop.delay_samples
    z = np.exp(s * T)
    A, _ = _loop_values(z, zp, np.zeros(s.shape), np.zeros(s.shape), filt)
    N = zp.b1 * z + zp.b0
    alpha = np.polyval(filt[0], z) * N
    beta = (z - 1.0) * np.polyval(filt[1], z) * N
    gamma = z**d * A
    with np.errstate(all="ignore"):
        det = alpha.real * beta.imag - alpha.imag * beta.real
        P = (-gamma.real * beta.imag + gamma.imag * beta.real) / det
        D = (-alpha.real * gamma.imag + alpha.imag * gamma.real) / det
    return P, D


def _crossings(zp: Any, P: np.ndarray, D: np.ndarray, filt: tuple) -> list[np.ndarray]:
    """Each run's frequencies θ ∈ (0, π) (rad per sample) where |L(e^{iθ})| = 1."""
    z = np.exp(1j * _GRID)
    A, B = _loop_values(z[None, :], zp, P[:, None], D[:, None], filt)
    with np.errstate(all="ignore"):
        g = np.log(np.abs(B)) - np.log(np.abs(A))  # log |L|
    g = np.where(np.isnan(g), -np.inf, g)  # B = 0 (no feedback): |L| = 0
    above = g > 0
    flips = above[:, 1:] != above[:, :-1]
    ri, ji = np.nonzero(flips)
    lo, hi = _GRID[ji].copy(), _GRID[ji + 1].copy()
    up = above[ri, ji]  # |L| > 1 at the low end
    Pr, Dr = P[ri], D[ri]
    for _ in range(60):  # bisection to rounding (the bracket's ratio is 1.007)
        mid = 0.5 * (lo + hi)
        zm = np.exp(1j * mid)
        Am, Bm = _loop_values(zm, zp, Pr, Dr, filt)
        with np.errstate(all="ignore"):
            gm = np.abs(Bm) > np.abs(Am)
        same = gm == up
        lo = np.where(same, mid, lo)
        hi = np.where(same, hi, mid)
    theta = 0.5 * (lo + hi)
    return [theta[ri == i] for i in range(P.size)]


def _candidates(zp: Any, P: float, D: float, filt: tuple, d: int, theta: np.ndarray
                ) -> np.ndarray:
    """Sorted whole delays q > d at which the run's loop may first be unstable."""
    taus: list[float] = []
    if theta.size:
        z = np.exp(1j * theta)
        A, B = _loop_values(z, zp, np.full(theta.shape, P), np.full(theta.shape, D), filt)
        phi = np.mod(np.angle(B) - np.angle(A) + math.pi, 2.0 * math.pi)
        for th, ph in zip(theta, phi, strict=True):
            n0 = max(0, math.floor((d * th - ph) / (2.0 * math.pi)))
            taus.extend((ph + 2.0 * math.pi * n) / th for n in range(n0, n0 + _CANDIDATES))
    A1, B1 = _loop_values(np.array([-1.0 + 0j]), zp, np.array([P]), np.array([D]), filt)
    with np.errstate(all="ignore"):
        L1 = float((B1 / A1)[0].real)
    if math.isfinite(L1) and abs(L1) >= 1.0:  # the halves of the curve meet at θ = π
        ac = math.acos(-1.0 / L1) / math.pi
        n0 = max(0, math.floor((d - 2.0) / 2.0))
        for n in range(n0, n0 + _CANDIDATES):
            taus.extend((2 * n + ac, 2 * n + 2 - ac))
    qs = set()
    for tau in taus:
        if not math.isfinite(tau) or tau > 1e15:
            continue
        q = round(tau) if abs(tau - round(tau)) <= 1e-9 * max(1.0, tau) else math.floor(tau) + 1
        if q > d:
            qs.add(int(q))
    return np.array(sorted(qs), dtype=np.int64)


def _stable_at(m: float, c: float, k: float, P: np.ndarray, D: np.ndarray, loop: DigitalPD,
               q: int) -> np.ndarray:
    """Whether each run's loop is stable with q samples of command delay (all its roots)."""
    lq = DigitalPD(P=0.0, D=0.0, sample_time=loop.sample_time, delay_samples=int(q),
                   velocity=loop.velocity, cutoff=loop.cutoff)
    with np.errstate(all="ignore"):
        return digital_roots(m, c, k, P, D, lq).stable


def delay_margin_samples(m: float, c: float, k: float, P: np.ndarray | float,
                         D: np.ndarray | float, loop: DigitalPD,
                         stable: np.ndarray | None = None) -> np.ndarray:
    """Extra whole samples of command delay each run's sampled loop tolerates (module doc).

    Parameters
    ----------
    m, c, k : float
        The plant, kg, N·s/m, N/m.
    P, D : float or array_like
        Gains of each run, N/m and N·s/m.
    loop : DigitalPD
        Sample time, delay d and velocity estimator (its gains are ignored).
    stable : ndarray of bool, optional
        Whether each run's loop is stable at d, when already known (from all its roots).

    Returns
    -------
    ndarray of float
        d′ − d, d′ the largest delay (whole samples) for which the loop is stable with every
        delay from d to d′; 0 where the loop is unstable at d itself; ``inf`` where no delay
        destabilises it (|L| never reaches 1, or no crossing destabilises).
    """
    P = np.atleast_1d(np.asarray(P, dtype=float))
    D = np.atleast_1d(np.asarray(D, dtype=float))
    P, D = np.broadcast_arrays(P, D)
    T, d = loop.sample_time, loop.delay_samples
    filt = _filter(loop)
    zp = zoh_plant(m, c, k, T)
    out = np.zeros(P.size)
    ok = _stable_at(m, c, k, P, D, loop, d) if stable is None else np.asarray(stable, bool)
    thetas = _crossings(zp, P, D, filt)
    cands = {i: _candidates(zp, float(P[i]), float(D[i]), filt, d, thetas[i])
             for i in np.flatnonzero(ok)}
    pos = dict.fromkeys(cands, 0)
    first_bad: dict[int, int] = {}
    for i, q in cands.items():
        if q.size == 0:
            out[i] = math.inf
    pending = [i for i in cands if cands[i].size]
    while pending:
        groups: dict[int, list[int]] = {}
        for i in pending:
            groups.setdefault(int(cands[i][pos[i]]), []).append(i)
        pending = []
        for q, idx in groups.items():
            sel = np.array(idx)
            stab = (np.zeros(sel.size, dtype=bool) if q + loop.order - d > EXACT_ORDER
                    else _stable_at(m, c, k, P[sel], D[sel], loop, q))
            for i, st in zip(idx, stab, strict=True):
                if not st:
                    first_bad[i] = q
                else:
                    pos[i] += 1
                    if pos[i] < cands[i].size:
                        pending.append(i)
                    else:  # no candidate destabilises the loop
                        out[i] = math.inf
    for i, q in first_bad.items():
        out[i] = float(q - 1 - d)
    return out


def evaluate_sampled(P: np.ndarray, D: np.ndarray, prior: Prior, st: DesignSettings
                     ) -> Evaluation:
    """The requirements of :mod:`phoid.planning.evaluation` on the sampled loop, exactly.

    Parameters
    ----------
    P, D : array_like, shape (R,)
        Gains of the runs, N/m and N·s/m.
    prior : Prior
        The prior grid (G plants, row 0 nominal).
    st : DesignSettings
        The requirements, with the sampled loop (``st.digital``).

    Returns
    -------
    Evaluation
        Per run and plant: the dominant root s (the rightmost of all d + r + 2, Im ≥ 0) and its
        release amplitude w = 2·residue (the record's Re[w e^{sτ}]), stability (all |z| < 1),
        ``dominant`` (the rightmost root is a complex pair below the Nyquist rate π/T: the run
        rings), ``separated`` (every other root left of ``separation``·Re s), ζ, cycles above
        the noise, ``dsamples`` (the delay margin in whole samples, 0 where unstable) and
        ``dmargin`` = ``dsamples``·T; ``ok`` requires at least ``delay_margin_samples``.
    """
    loop = st.digital
    T = loop.sample_time
    P = np.atleast_1d(np.asarray(P, dtype=float))
    D = np.atleast_1d(np.asarray(D, dtype=float))
    R, G = P.size, prior.plants.shape[0]
    s = np.full((R, G), np.nan + 0j)
    w = np.full((R, G), np.nan + 0j)
    stable = np.zeros((R, G), dtype=bool)
    rings = np.zeros((R, G), dtype=bool)
    separated = np.zeros((R, G), dtype=bool)
    dsamples = np.zeros((R, G))
    nyquist = math.pi / T
    for g, (m, c, k) in enumerate(prior.plants):
        with np.errstate(all="ignore"):
            S, amp = digital_residues(float(m), float(c), float(k), P, D, loop,
                                      x0=st.amplitude)
        s0 = S[:, 0]
        stab = np.all(S.real < 0.0, axis=1)  # |z| < 1 for every root (z = 0: s = −inf)
        with np.errstate(invalid="ignore"):
            ring = (np.isfinite(s0) & (s0.imag > 1e-12 * np.abs(s0))
                    & (s0.imag < nyquist * (1.0 - 1e-9))
                    & (np.abs(S[:, 1] - np.conj(s0)) <= 1e-6 * np.abs(s0)))
            tiny = 1e-9 * np.abs(s0) + 1e-12
            sep = ring & (S[:, 2].real < st.separation * s0.real - tiny) if S.shape[1] > 2 \
                else ring
        s[:, g] = np.where(ring, s0.real + 1j * np.abs(s0.imag), s0.real + 0j)
        w[:, g] = np.where(ring, 2.0 * amp[:, 0], np.nan)
        stable[:, g], rings[:, g], separated[:, g] = stab, ring, sep
        if np.any(stab):
            dsamples[stab, g] = delay_margin_samples(float(m), float(c), float(k), P[stab],
                                                     D[stab], loop, stable=stab[stab])
    found = rings
    s = np.where(found, s, np.nan + 0j)
    zeta = np.where(found, -s.real / np.abs(s), np.nan)
    sig = -s.real
    with np.errstate(all="ignore"):
        t_above = np.where(np.abs(w) > st.noise,
                           np.minimum(st.duration, np.log(np.abs(w) / st.noise) / sig), 0.0)
        cycles = np.where(found & (sig > 0), s.imag * t_above / (2 * np.pi), 0.0)
    dmargin = dsamples * T
    in_band = (zeta[:, 0] >= st.zeta[0] * (1 - 1e-9)) & (zeta[:, 0] <= st.zeta[1] * (1 + 1e-9))
    ok_freq = found & (s.imag <= st.omega_max * (1 + 1e-9))
    ok_limits = (np.abs(P) <= st.pmax * (1 + 1e-12)) & (np.abs(D) <= st.dmax * (1 + 1e-12))
    with np.errstate(invalid="ignore"):
        ok = (stable & rings & (zeta >= 0.5 * st.zeta[0])
              & (dsamples >= st.delay_margin_samples) & ok_freq)
    return Evaluation(P=P, D=D, s=s, w=w, stable=stable, dominant=rings, separated=separated,
                      zeta=zeta, cycles=cycles, dmargin=dmargin, in_band=in_band,
                      ok_freq=ok_freq, ok_limits=ok_limits, ok=ok, dsamples=dsamples)


def sampled_information(ev: Evaluation, prior: Prior, st: DesignSettings) -> np.ndarray:
    """Modal Fisher information of (m, c, k) of every run at every plant, (R, G, 3, 3).

    The dominant mode's (σ, ω_d) information (:func:`phoid.planning.fisher.mode_information`,
    its exact release amplitude) mapped through ∂s/∂(m, c, k) of the sampled loop
    (:func:`phoid.dynamics.digital.digital_modes`); 0 for a run that does not ring stably there.
    """
    loop = st.digital
    R, G = ev.s.shape
    out = np.zeros((R, G, 3, 3))
    good = np.isfinite(ev.s) & (ev.s.imag > 0) & (ev.s.real < 0) & np.isfinite(ev.w)
    for g in range(G):
        ri = np.flatnonzero(good[:, g])
        if ri.size == 0:
            continue
        m, c, k = (float(x) for x in prior.plants[g])
        s = ev.s[ri, g]
        info = mode_information(s, ev.w[ri, g], fs=st.fs, duration=st.duration,
                                noise=st.noise)
        with np.errstate(all="ignore"):
            _, ds = digital_modes(m, c, k, ev.P[ri], ev.D[ri], loop, s_guess=s)
        Gm = np.stack([-ds.real, ds.imag], axis=1)  # (n, 2, 3)
        val = np.einsum("nai,nab,nbj->nij", Gm, info, Gm)
        out[ri, g] = np.where(np.isfinite(val), val, 0.0)
    return out


def predicted_covariance(plant: tuple[float, float, float], P: np.ndarray, D: np.ndarray,
                         st: DesignSettings, modal: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, str]:
    """The prediction's covariance of (m, c, k) at one plant, for the noise placement.

    Parameters
    ----------
    plant : (m, c, k)
        Where the bound is evaluated.
    P, D : ndarray
        The runs' gains (those that ring stably there).
    st : DesignSettings
        The record and the sampled loop; ``st.noise_in_loop`` picks the bound.
    modal : ndarray, shape (R, 3, 3)
        The runs' modal information there (:func:`sampled_information`).

    Returns
    -------
    cov : ndarray, shape (3, 3)
        The covariance bound (``inf`` on the diagonal where undetermined).
    run_information : ndarray, shape (R, 3, 3)
        Each run's information (to share the set's among the runs).
    bound : str
        ``"in-loop"`` (:func:`phoid.planning.inloop_bound.inloop_cramer_rao`: the output error
        of the plant driven by the applied command, the noise read by the controller) or
        ``"modal"`` (the dominant modes' bound, for noise outside the loop: the model of
        ``inloop_cramer_rao(..., noise_in_loop=False)``, from ``modal`` as given).

    Raises
    ------
    DesignError
        Where the in-loop bound refuses the record (too many samples, …), saying so.
    """
    if not st.noise_in_loop or P.size == 0:
        return safe_inverse(modal.sum(axis=0)), modal, "modal"
    m, c, k = plant
    try:
        b = inloop_cramer_rao(m, c, k, P, D, st.digital, fs=st.fs, duration=st.duration,
                              noise=st.noise, x0=st.amplitude, noise_in_loop=True)
    except ValueError as exc:
        raise DesignError(f"the in-loop bound cannot be evaluated for this design ({exc}); "
                          "predict with the noise outside the loop (--noise-outside, "
                          "noise_in_loop=False) or change the record") from None
    return np.asarray(b.cov, dtype=float), np.asarray(b.run_information, dtype=float), "in-loop"
