"""Evaluation of gains on the prior grid, vectorised over runs × plants.

What a run must satisfy (:func:`phoid.planning.search.design` only proposes such runs;
:func:`phoid.planning.checking.check` reports which fail):

*Safety*, on **every** plant of the prior grid:

* *stable and ringing:* the rightmost characteristic roots of
  f(s) = m s² + c s + k + (D s + P) e^{−sΔt} (seed eq. 23) are a complex pair s = −σ + iω_d
  whose damping ratio ζ = σ/|s| is at least half the band's lower edge;
* *stability margins:* the **decay margin** is the distance σ of the rightmost root from the
  imaginary axis (1/s, reported); the **delay margin** is the extra loop delay (s) the loop
  tolerates before it loses stability, which must be at least ``delay_margin`` (default
  max(0.2 Δt, 1/f_s): a misjudged delay, or one more sample of latency in a digital loop, must
  not drive the rig unstable);
* *bandwidth:* ω_d ≤ ``max_freq`` and ≤ 0.2 of the Nyquist rate π f_s (10 samples per period);
* *limits:* |P| ≤ ``pmax``, |D| ≤ ``dmax``.

*Information*, at the nominal plant (elsewhere in the prior reported as warnings):

* ζ in the ``zeta`` band (default 0.03–0.2: lightly damped enough for many cycles above the
  noise floor, damped enough to die out within the record);
* at least ``min_cycles`` (default 5) oscillation cycles while the envelope |w|e^{−σt} is above
  the noise sd, within the record length (|w| the release amplitude of the dominant mode,
  :func:`phoid.planning.fisher.release_amplitude`);
* every other root left of ``separation``·Re s (default 2: the other modes die at least twice
  as fast, so the record is a single-mode decay after a short transient).

Roots are counted exactly by :mod:`phoid.planning.margins`; the information of a run is that of
:mod:`phoid.planning.fisher`. A sampled loop is searched on this module's continuous surrogate
(the delay :attr:`DesignSettings.model_delay`) and evaluated exactly by
:mod:`phoid.planning.sampled`, into the same :class:`Evaluation`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from phoid.dynamics import characteristic
from phoid.planning.fisher import mode_information, release_amplitude
from phoid.planning.margins import count_roots_right, delay_margin
from phoid.planning.settings import DesignSettings, Prior

__all__ = ["Evaluation", "evaluate", "log_var", "place", "run_information", "stack"]


@dataclass(frozen=True)
class Evaluation:
    """Constraint evaluation of runs (axis 0) on the plants of the prior grid (axis 1)."""

    P: np.ndarray
    D: np.ndarray
    s: np.ndarray  # dominant roots (Im ≥ 0), NaN where not found
    w: np.ndarray  # release amplitudes
    stable: np.ndarray
    dominant: np.ndarray  # tracked root is the rightmost, complex, separated
    separated: np.ndarray
    zeta: np.ndarray
    cycles: np.ndarray
    dmargin: np.ndarray
    in_band: np.ndarray  # at the nominal plant (axis 1 index 0)
    ok_freq: np.ndarray
    ok_limits: np.ndarray  # per run
    ok: np.ndarray  # per run and plant: safe (stable, ringing, margins, bandwidth)
    # a sampled loop's delay margin in whole samples (``dmargin`` is it × T); None: continuous
    dsamples: np.ndarray | None = None

    def informative(self, st: DesignSettings) -> np.ndarray:
        """Per run: at the nominal plant, ζ in the band, enough cycles, separated modes."""
        return self.in_band & self.separated[:, 0] & (self.cycles[:, 0] >= st.min_cycles)

    def take(self, sel: np.ndarray) -> Evaluation:
        """The runs ``sel`` only."""
        return Evaluation(**{f: None if getattr(self, f) is None else getattr(self, f)[sel]
                             for f in self.__dataclass_fields__})


def stack(parts: list[Evaluation]) -> Evaluation:
    """The runs of several evaluations (on the same prior grid), in order, as one."""
    out = {}
    for f in Evaluation.__dataclass_fields__:
        vals = [getattr(e, f) for e in parts]
        out[f] = None if any(x is None for x in vals) else np.concatenate(vals, axis=0)
    return Evaluation(**out)


def place(m: float, c: float, k: float, s: np.ndarray, delay: float
          ) -> tuple[np.ndarray, np.ndarray]:
    """Gains that put a root at s: D s + P = −(m s² + c s + k) e^{sΔt} (f(s) = 0, eq. 23).

    Parameters
    ----------
    m, c, k : float
        The plant, kg, N·s/m, N/m.
    s : ndarray of complex
        Target roots (1/s), Im s ≠ 0.
    delay : float
        Loop delay Δt, s.

    Returns
    -------
    P, D : ndarray
        Gains (N/m, N·s/m): the real and imaginary parts of the linear equation in (P, D).
    """
    q = -(m * s * s + c * s + k) * np.exp(s * delay)
    D = q.imag / s.imag
    P = q.real - D * s.real
    return P, D


def _newton_masked(s, m, c, k, P, D, delay, iters):
    """Newton on f (eq. 23 characteristic) for flat arrays, iterating only unconverged entries."""
    s = s.copy()
    active = np.flatnonzero(np.isfinite(s))
    for _ in range(iters):
        if active.size == 0:
            break
        sa = s[active]
        with np.errstate(all="ignore"):
            f, df = characteristic(sa, m[active], c[active], k[active], P[active], D[active],
                                   delay)
            step = f / df
        s[active] = sa - step
        done = ~(np.abs(step) > 1e-14 * np.maximum(np.abs(sa), 1.0))  # NaN counts as done
        active = active[~done]
    return s


def _track(s0, plants, P, D, delay):
    """Continue the nominal roots s0 (per run) to every plant of the grid by Newton homotopy.

    Returns (R, G) roots with Im ≥ 0; NaN where Newton did not converge to a root.
    """
    R, G = s0.size, plants.shape[0]
    m0, c0, k0 = plants[0]
    s = np.repeat(s0[:, None], G, axis=1).ravel()
    PP = np.repeat(P[:, None], G, axis=1).ravel()
    DD = np.repeat(D[:, None], G, axis=1).ravel()
    for t in (0.25, 0.5, 0.75, 1.0):
        m = np.tile(m0 + t * (plants[:, 0] - m0), R)
        c = np.tile(c0 + t * (plants[:, 1] - c0), R)
        k = np.tile(k0 + t * (plants[:, 2] - k0), R)
        s = _newton_masked(s, m, c, k, PP, DD, delay, 8 if t < 1.0 else 40)
    with np.errstate(all="ignore"):
        f, _ = characteristic(s, m, c, k, PP, DD, delay)
        scale = m * np.abs(s) ** 2 + np.abs(c * s) + np.abs(k) + np.abs(DD * s) + np.abs(PP)
        good = np.isfinite(s) & (np.abs(f) <= 1e-9 * scale)
    s = np.where(good, s.real + 1j * np.abs(s.imag), np.nan + 0j)
    return s.reshape(R, G)


def evaluate(P: np.ndarray, D: np.ndarray, s0: np.ndarray, prior: Prior, st: DesignSettings,
             *, s_grid: np.ndarray | None = None) -> Evaluation:
    """Check gains (P, D) with nominal dominant roots s0 on all plants of the prior grid.

    Parameters
    ----------
    P, D : array_like, shape (R,)
        Gains of the runs, N/m and N·s/m.
    s0 : array_like of complex, shape (R,)
        Each run's dominant root at the nominal plant, 1/s; continued to the other plants by
        Newton homotopy.
    prior : Prior
        The prior grid (G plants, row 0 nominal).
    st : DesignSettings
        The requirements.
    s_grid : ndarray of complex, shape (R, G), optional
        The dominant roots on the whole grid, when already known (then ``s0`` is not used).

    Returns
    -------
    Evaluation
        The requirements of the module docstring, per run and plant.
    """
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    plants = prior.plants
    s = _track(np.asarray(s0, dtype=complex), plants, P, D, st.model_delay) if s_grid is None \
        else s_grid
    m, c, k = (plants[:, j][None, :] for j in range(3))
    PP, DD = P[:, None], D[:, None]
    re = s.real
    with np.errstate(invalid="ignore"):
        tiny = 1e-9 * np.abs(s) + 1e-12
        n_right = count_roots_right(np.where(np.isfinite(re), re + tiny, 0.0), m, c, k, PP, DD,
                                    st.model_delay)
        n_sep = count_roots_right(np.where(np.isfinite(re), st.separation * re - tiny, 0.0),
                                  m, c, k, PP, DD, st.model_delay)
        n_unstable = count_roots_right(np.zeros_like(re), m, c, k, PP, DD, st.model_delay)
    found = np.isfinite(re) & (s.imag > 0)
    rightmost = found & (n_right == 0)
    stable = (n_unstable == 0) & ~np.isnan(n_unstable)
    separated = rightmost & (n_sep == 2)
    zeta = np.where(found, -re / np.abs(s), np.nan)
    w = np.where(found, release_amplitude(np.where(found, s, -1.0 + 1j), m, c, k, PP, DD,
                                          st.model_delay, st.amplitude), np.nan)
    sig = -re
    with np.errstate(all="ignore"):
        t_above = np.where(np.abs(w) > st.noise,
                           np.minimum(st.duration, np.log(np.abs(w) / st.noise) / sig), 0.0)
        cycles = np.where(found & (sig > 0), s.imag * t_above / (2 * np.pi), 0.0)
    dmargin = delay_margin(m, c, k, PP, DD, st.model_delay)
    dmargin = np.where(stable, dmargin, 0.0)
    in_band = (zeta[:, 0] >= st.zeta[0] * (1 - 1e-9)) & (zeta[:, 0] <= st.zeta[1] * (1 + 1e-9))
    ok_freq = found & (s.imag <= st.omega_max * (1 + 1e-9))
    ok_limits = (np.abs(P) <= st.pmax * (1 + 1e-12)) & (np.abs(D) <= st.dmax * (1 + 1e-12))
    with np.errstate(invalid="ignore"):
        # safety, on every plant of the prior grid
        ok = (stable & rightmost & (zeta >= 0.5 * st.zeta[0]) & (dmargin >= st.delay_margin)
              & ok_freq)
    return Evaluation(P=P, D=D, s=s, w=w, stable=stable, dominant=rightmost, separated=separated,
                 zeta=zeta, cycles=cycles, dmargin=dmargin, in_band=in_band, ok_freq=ok_freq,
                 ok_limits=ok_limits, ok=ok)


def run_information(ev: Evaluation, prior: Prior, st: DesignSettings) -> np.ndarray:
    """Fisher information of (m, c, k) of every run at every plant: (R, G, 3, 3)."""
    R, G = ev.s.shape
    out = np.zeros((R, G, 3, 3))
    good = np.isfinite(ev.s) & (ev.s.imag > 0) & (ev.s.real < 0)
    if not np.any(good):
        return out
    ri, gi = np.nonzero(good)
    s = ev.s[ri, gi]
    info = mode_information(s, ev.w[ri, gi], fs=st.fs, duration=st.duration, noise=st.noise)
    pl = prior.plants[gi]
    Gm = _jacobian(s, pl, ev.P[ri], ev.D[ri], st.model_delay)
    out[ri, gi] = np.einsum("nai,nab,nbj->nij", Gm, info, Gm)
    return out


def _jacobian(s, plants, P, D, delay):
    """mode_jacobian for per-entry plants: (n, 2, 3)."""
    m, c, k = plants[:, 0], plants[:, 1], plants[:, 2]
    _, df = characteristic(s, m, c, k, P, D, delay)
    ds = -np.stack([s * s, s, np.ones_like(s)], axis=1) / df[:, None]
    return np.stack([-ds.real, ds.imag], axis=1)


def log_var(info: np.ndarray) -> np.ndarray:
    """Σ log Var(θⱼ) of the Cramér–Rao covariance, batched over leading axes (inf if singular)."""
    d = np.sqrt(np.clip(np.einsum("...ii->...i", info), 1e-300, None))
    Z = info / (d[..., :, None] * d[..., None, :])
    det = np.linalg.det(Z)
    with np.errstate(all="ignore"):
        # diagonal of the inverse by cofactors of the 3×3 correlation-scaled matrix
        c0 = Z[..., 1, 1] * Z[..., 2, 2] - Z[..., 1, 2] * Z[..., 2, 1]
        c1 = Z[..., 0, 0] * Z[..., 2, 2] - Z[..., 0, 2] * Z[..., 2, 0]
        c2 = Z[..., 0, 0] * Z[..., 1, 1] - Z[..., 0, 1] * Z[..., 1, 0]
        val = (np.log(c0) + np.log(c1) + np.log(c2) - 3.0 * np.log(det)
               - 2.0 * np.sum(np.log(d), axis=-1))
    return np.where((det > 1e-12) & np.isfinite(val), val, np.inf)

