"""Identify m, c, k from a PHO experiment set: runs → decay fits → loop → m, c, k.

The pipeline (ARCHITECTURE.md): each run's free decay is fitted for its dominant mode
(:func:`phoid.fits.fit_decay`), the modes are mapped through the delayed loop (eqs. 28–32) and
m, c, k follow from all runs together (:mod:`phoid.methods.pho`).

Right after the release the delayed loop also rings in its fast non-dominant modes, which would
bias a single-mode fit. A first pass skips 3Δt and gives a rough plant; its exact loop roots give
each run's next two modes, which the second pass fits alongside the dominant one (free amplitudes,
rates fixed) right from the release. The fit starts as soon as the first mode left out — whose
amplitude follows from its residue x₀N(s)/f′(s), N(s) = ms + c + De^{−sΔt} − P(1 − e^{−sΔt})/s —
is below 0.3 noise sd (or 1e−12 of the amplitude for noise-free data). This keeps the information
of the first instants: m, c, k come within a few per cent of the Cramér–Rao bound, where skipping
the transient instead costs 13–35 %. Because the second pass fits from the release on, the
release time is refitted there with the rough loop's own response from rest
(:func:`_model_releases`), not taken from the data-only detection alone.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.special import chdtri  # chi2 quantile: chdtri(dof, 1 - p) = chi2.ppf(p, dof)

from phoid._threads import single_blas_thread
from phoid.dynamics.loop import characteristic, rightmost_roots_many
from phoid.errors import IdentificationError
from phoid.fits import (
    DecayFit,
    FitJob,
    detect_release,
    fit_checked,
    fit_decays,
    start_decay,
    start_decays,
    uniform_step,
)
from phoid.methods.pho import (
    Estimate,
    MCKFit,
    delay_profile,
    fit_lines,
    fit_modes,
    open_loop_omega0,
    open_loop_zeta,
)

if TYPE_CHECKING:
    from phoid.methods.forced import ForcedIdentification
    from phoid.methods.free import FreeIdentification

__all__ = ["Identification", "RunMode", "identify", "measure_modes"]

_N_FAST = 2  # non-dominant loop modes fitted alongside the dominant one
_OMIT_NOISE_FRACTION = 0.3  # the fit starts once the first omitted mode is below 0.3 noise sd
_OMIT_FLOOR = 1e-12  # … or below 1e-12 of the release amplitude (noise-free records)
# a loop mode that decays by more than e² from one sample to the next is no column a fit can
# hold (it lives in the first sample or two: a tiny delay's fast modes, |Re s| ~ 1/Δt); it is
# left out and skipped instead, like the modes beyond the fitted ones
_FAST_MAX_DECAY_PER_SAMPLE = 2.0


@dataclass(frozen=True)
class RunMode:
    """One run's measured dominant mode and its place in eq. (35).

    Attributes
    ----------
    file : str
        Data file of the run (as named in the manifest).
    P, D : float
        Gains, N/m and N·s/m.
    sigma, omega_d : float
        Decay rate (1/s) and damped frequency (rad/s) of the dominant mode.
    sigma_stderr, omega_d_stderr : float
        Their standard errors.
    c_prime, k_prime : float
        Equivalent feedback damping (N·s/m) and stiffness (N/m), eq. (32); for a run with an
        added mass Δm the known part is taken off (c′ − 2Δmσ, k′ − Δmω₀²), so that every run's
        point lies on the lines of the mass without additions.
    cycles : float
        Oscillation cycles used (above the noise floor).
    residual_rms : float
        RMS of the decay fit's residual, m.
    used : bool
        False when the run was set aside (see ``warnings``).
    warnings : tuple of str
    fit : DecayFit or None
        The full decay fit (None when the run could not be fitted at all).
    added_mass : float
        Known mass added for this run, kg (0: none).
    u_fit : phoid.methods.udelay.URun or None
        The joint fit of x and the recorded u (an estimated delay with u; None otherwise).
    """

    file: str
    P: float
    D: float
    sigma: float
    omega_d: float
    sigma_stderr: float
    omega_d_stderr: float
    c_prime: float
    k_prime: float
    cycles: float
    residual_rms: float
    used: bool
    warnings: tuple[str, ...] = ()
    fit: DecayFit | None = None
    added_mass: float = 0.0
    u_fit: Any = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with the spec's keys (file, P, D, sigma, omega_d, c_prime, k_prime,
        cycles) and extra diagnostics."""

        def num(x):
            return None if x is None or not math.isfinite(x) else float(x)

        return {
            "file": self.file,
            "P": float(self.P),
            "D": float(self.D),
            "sigma": num(self.sigma),
            "omega_d": num(self.omega_d),
            "c_prime": num(self.c_prime),
            "k_prime": num(self.k_prime),
            "cycles": num(self.cycles),
            "sigma_stderr": num(self.sigma_stderr),
            "omega_d_stderr": num(self.omega_d_stderr),
            "residual_rms": num(self.residual_rms),
            "used": self.used,
            "warnings": list(self.warnings),
        } | ({"added_mass": float(self.added_mass)} if self.added_mass else {}) | (
            {"u": self.u_fit.to_dict()} if self.u_fit is not None else {})


@dataclass(frozen=True)
class Identification:
    """Result of :func:`identify`: m, c, k with uncertainties, per-run modes, warnings.

    Attributes
    ----------
    m, c, k : Estimate
        Mass (kg), viscous damping (N s/m), stiffness (N/m).
    delay : float
        Loop delay used (given) or estimated, s.
    delay_source : str
        ``"given"`` (from the manifest or the caller) or ``"estimated"``.
    delay_stderr : float or None
        Standard error of an estimated delay, s.
    digital : phoid.dynamics.digital.DigitalPD or None
        The sampled loop the modes were modelled with (None: a continuous loop with a delay).
    delay_from : str or None
        What an estimated delay came from: ``"x"`` (the runs' modes only) or ``"x+u"`` (also
        the recorded feedback force, :mod:`phoid.methods.udelay`); None for a given delay.
    runs : tuple of RunMode
    fit : MCKFit
        The underlying fit (covariance, eq. 35 lines, χ²).
    warnings : tuple of str
    source : str
        Where the data came from (a path or a description).
    """

    m: Estimate
    c: Estimate
    k: Estimate
    delay: float
    delay_source: str
    runs: tuple[RunMode, ...]
    fit: MCKFit
    warnings: tuple[str, ...] = ()
    source: str = ""
    delay_stderr: float | None = None
    digital: Any = None
    data: tuple[tuple[np.ndarray, np.ndarray], ...] = field(default=(), repr=False)
    delay_from: str | None = None

    @property
    def cov(self) -> np.ndarray:
        """(3, 3) covariance of (m, c, k)."""
        return self.fit.cov

    @property
    def omega0(self) -> Estimate:
        """Open-loop natural frequency ω₀ = √(k/m), rad/s (eq. 5), delta-method stderr."""
        return open_loop_omega0(self.m.value, self.k.value, self.cov)

    @property
    def zeta(self) -> Estimate:
        """Open-loop damping ratio ζ = c/(2√(mk)) (eq. 10), delta-method stderr."""
        return open_loop_zeta(self.m.value, self.c.value, self.k.value, self.cov)

    def summary(self) -> dict[str, Any]:
        """The JSON object of ``phoid identify --json`` (docs/format.md).

        Top-level keys are the spec's (method, m, c, k, delay, runs, warnings) plus the optional
        ``omega0`` and ``zeta`` in the same {value, stderr, unit} shape; each run carries the
        spec's keys plus sigma_stderr, omega_d_stderr, residual_rms, used and its warnings. The
        full covariance of (m, c, k) is :attr:`cov` (not in the JSON).
        """
        out: dict[str, Any] = {
            "method": "pho",
            "m": self.m.to_dict(),
            "c": self.c.to_dict(),
            "k": self.k.to_dict(),
            "delay": {"value": float(self.delay),
                      "stderr": None if self.delay_stderr is None else float(self.delay_stderr),
                      "unit": "s", "source": self.delay_source}
            | ({"from": self.delay_from} if self.delay_from else {}),
            "runs": [r.to_dict() for r in self.runs],
            "warnings": list(self.warnings),
        }
        if self.digital is not None:
            # a format extension, only for sampled loops: which model the modes went through
            g = self.digital
            out["loop"] = {"model": "digital", "sample_time": g.sample_time,
                           "delay_samples": g.delay_samples, "velocity": g.velocity,
                           "cutoff": g.cutoff}
        w0 = self.omega0
        if math.isfinite(w0.value):
            out["omega0"] = w0.to_dict()
        z = self.zeta
        if math.isfinite(z.value):
            out["zeta"] = z.to_dict()
        return out

    def report(self) -> str:
        """A plain-text report: estimates with ± one stderr, per-run table, warnings."""
        from phoid.reports.text import identification_text

        return identification_text(self)

    def plot(self, out_dir: str | Any, *, overwrite: bool = False) -> list:
        """Write per-run decay fits with residuals and the two eq. (35) lines as PNG files.

        Existing files are replaced only with ``overwrite``; links in ``out_dir`` are refused
        (:func:`phoid.reports.text.plot_identification`). Returns the list of paths written.
        """
        from phoid.reports.text import plot_identification

        return plot_identification(self, out_dir, overwrite=overwrite)


# ------------------------------------------------------------------------------------------


def _misfit(mck: MCKFit) -> bool:
    """True when the weighted fit's χ² exceeds its 99.9 % quantile (runs disagree)."""
    return mck.dof > 0 and mck.chi2 > chdtri(mck.dof, 0.001)


def _residue(s, m, c, k, P, D, delay) -> complex:
    """Amplitude per metre of release of the mode e^{st} after a release from a held position.

    With the history x = x₀ on [−Δt, 0], X(s) = x₀N(s)/f(s) with
    N(s) = m s + c + D e^{−sΔt} − P (1 − e^{−sΔt})/s (from eq. 23), so the mode's residue is
    N(s)/f′(s).
    """
    e = np.exp(-s * delay)
    p_term = P * (1 - e) / s if s != 0 else P * delay
    _, df = characteristic(s, m, c, k, P, D, delay)
    return complex((m * s + c + D * e - p_term) / df)


def _modes(roots: np.ndarray) -> list[complex]:
    """Distinct modes (one root of each conjugate pair, Im ≥ 0), rightmost first."""
    out: list[complex] = []
    tol: list[float] = []  # 1e−9 max(1, |o|) of each kept mode o
    for z in np.asarray(roots, dtype=complex).tolist():
        r = complex(z.real, abs(z.imag))
        if not any(abs(r - o) <= e for o, e in zip(out, tol, strict=True)):
            out.append(r)
            tol.append(1e-9 * max(1.0, abs(r)))
    return out


def _fit_run(t, x, skip, release, fast_roots=None, guess=None):
    try:
        # the record passed start_decay's checks in the first pass (identify_data made it a
        # float array), and identify_data already runs with one BLAS thread
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


_REL_HALF = 32  # model-fitted release: samples searched either side of the detected one


def _model_releases(data, fits, rough, P, D, delay, dm=None, digital=None
                    ) -> list[float | None]:
    """Release times fitted with each loop's own response from rest (None where not done).

    The data-only detection (:func:`phoid.fits.detect_release`: a quadratic, then an even
    quartic departure from the held level) is off by a few samples — and, for stiff loops on
    heavily damped plants, whose departure from rest is not of that shape (strong damping; the
    delayed feedback changes it after Δt), sometimes by 15–20 samples, early. The second pass
    fits from the release on, so an early release puts held samples into the window, which the
    decay model cannot fit: σ comes out several stderr off and the weighted fit reports runs
    that disagree (in about one set in ten of tests/test_identify_cases.py's overdamped design).

    Here the record near the release is fitted by x = a + b·g(t − τ), with g the exact response
    of the rough plant's loop released from rest at 1 (g = 1 before the release; one batched
    simulation per sample rate, :func:`phoid.simulation.core.release_response`). Where the span is
    sampled uniformly (to the rounding of its times), t − τ is a whole number of sample
    intervals, so g is simulated at the data's own rate (the same g, to simulate's rounding of
    ~1e−12, as on a finer grid) and is one vector per run for all its candidates; otherwise
    (or where the data's rate is below simulate's rule for the loop) on a grid 4 times finer,
    linearly interpolated (error ~1e−5 of the release displacement at most), each candidate
    with its own t − τ. a and b are free, τ on the sample times within ±32 samples of the
    detected release (every 4th, then around the best), refined by a parabola through the
    three best. The span runs from 64 samples before the
    detected release to a quarter period of the dominant mode (at most 512 samples) after the
    latest candidate: there the response is the sharpest function of τ, and the rough plant's
    error is far below the noise. Only which samples fall after τ matters downstream, so
    sub-sample accuracy is enough. None for a run without a held segment, a rough plant that is
    not physical, or a τ on the edge of the search (the detected release is used then).

    Over noisy replicas the release error drops from an sd of 1–3 ms (tails to −18 ms) to
    0.05–0.6 ms. On the paper's Table 1 set (100 replicas) m, c, k do not change (RMSE and
    stderr within 0.3 %); on the overdamped design the false "runs disagree" warnings (10 sets
    in 100, every stderr inflated 2–3× there) are gone. Cost: ~3.5 ms on the 19-run sample
    set (0.4 of the former per-run np.interp version's, timed paired in CPU time; 0.5–0.7 on
    the bench's overdamped and mass–damper sets, whose short delays mean many blocks).

    A digital loop (``digital``, a :class:`phoid.dynamics.digital.DigitalPD`) gets the response of
    its
    sampled controller instead, on a grid of a whole number of steps per controller sample (at
    least 4 per data sample), its clock started at the release. There the data-only detection
    is worse still — early by 1–6 ms (sd 5–10 ms) on tests/test_digital_identify.py's design at
    T_s = 2 ms — and the held samples it lets in bias σ by up to one stderr and make a third of
    the sets' runs disagree.
    """
    from phoid.dynamics.plant import Plant
    from phoid.simulation.core import release_response, simulate

    out: list[float | None] = [None] * len(data)
    m, c, k = rough
    if not m > 0:
        return out
    half = _REL_HALF
    jobs: dict[float, list[tuple[int, int, int, int]]] = {}
    uniform = True
    for i, f in enumerate(fits):
        if f is None or not 0 < f.omega_d < math.inf:
            continue
        t = data[i][0]
        j0 = int(np.searchsorted(t, f.release, side="left"))
        if j0 < half or j0 + half >= t.size:
            continue
        dt = float(t[j0 + 1] - t[j0])
        # every candidate τ has ≥ 32 held samples before it and a quarter period after it
        t_end = t[j0 + half] + min(0.5 * math.pi / f.omega_d, 512 * dt)
        hi = int(np.searchsorted(t, t_end, side="right"))
        if hi < j0 + half + 4:
            continue
        key = (float(f"{dt:.12g}"), 0.0 if dm is None else float(dm[i]))
        lo = max(j0 - 2 * half, 0)
        jobs.setdefault(key, []).append((i, lo, hi, j0))
        # uniform sampling over the span (the decay fit's test: every time within 1e−9 of a
        # step of the grid, or the rounding of the times; g then errs by ≲ 1e−9 of its jump)
        tr = np.asarray(t[lo:hi], dtype=float)
        uniform &= uniform_step(tr - tr[0], float(tr[0])) is not None
    # each simulated run: (run, span start, span end, detected release), grid rate, response
    runs: list[tuple[tuple[int, int, int, int], float, np.ndarray]] = []
    for (dt, added), items in jobs.items():
        plant = Plant(m + added, max(c, 0.0), max(k, 0.0))
        idx = [it[0] for it in items]
        span = max(float(data[i][0][hi - 1] - data[i][0][j0 - half]) for i, _, hi, j0 in items)
        if digital is None:
            # uniform sampling needs g at whole sample intervals only: simulated at the data's
            # rate (the same g to 1e−11 as on a finer grid), else (or where that rate is below
            # simulate's rule for the loop) on a grid 4 times finer, interpolated
            rates = (1.0 / dt, 4.0 / dt) if uniform else (4.0 / dt,)
        else:
            ts = digital.sample_time
            opts = {"sample_time": ts, "delay_samples": digital.delay_samples,
                    "velocity": digital.velocity, "cutoff": digital.cutoff}
            rates = (max(1, math.ceil(4.0 * ts / dt - 1e-9)) / ts,)  # whole steps per sample
        x = None
        for fs in rates:
            try:
                if digital is None:
                    x = release_response(plant, P[idx], D[idx], delay=delay,
                                          duration=span + 2 * dt, fs=fs)
                else:
                    x = simulate(plant, P[idx], D[idx], duration=span + 2 * dt, fs=fs, x0=1.0,
                                 **opts).x_true
                break
            except ValueError:
                continue
        if x is None:
            continue
        for row, it in enumerate(items):
            runs.append((it, fs, x[row]))
    if not runs:
        return out
    n, nc = len(runs), 2 * half + 1
    # the responses, padded to the longest by their last value (what np.interp holds beyond)
    ng = max(g.size for _, _, g in runs)
    resp = np.empty((n, ng))
    rate = np.array([fs for _, fs, _ in runs])
    size = np.array([hi - lo for (_, lo, hi, _), _, _ in runs])
    first = np.array([j0 - half - lo for (_, lo, _, j0), _, _ in runs])  # candidate 0's sample
    after = int(np.max(size - 1 - first))  # samples after candidate 0, at most
    # every span's record minus its mean over the span, zero-padded so that any candidate's
    # `after` following samples can be taken
    xc = np.zeros((n, int(np.max(first)) + nc + after))
    tt = np.empty_like(xc)  # the sample times, padded by repeating the last
    xx2 = np.empty(n)
    cand = np.empty((n, nc))
    for row, ((i, lo, hi, j0), _, g) in enumerate(runs):
        t, x = data[i]
        tr = np.asarray(t[lo:hi], dtype=float)
        xr = np.asarray(x[lo:hi], dtype=float)
        xr = xr - xr.mean()
        resp[row, : g.size], resp[row, g.size :] = g, g[-1]
        tt[row, : tr.size], tt[row, tr.size :] = tr, tr[-1]
        xc[row, : tr.size] = xr
        xx2[row] = float(xr @ xr)
        cand[row] = np.asarray(t[j0 - half : j0 + half + 1], dtype=float)
    lag = np.arange(after + 1)
    if uniform:  # t − τ is a whole number of sample intervals: one g per run
        dts = (tt[np.arange(n), size - 1] - tt[:, 0]) / (size - 1)  # sample intervals, s
        h = _interp_uniform(dts[:, None] * lag, rate, resp) - 1.0
    else:  # every candidate's own t − τ
        pos = np.minimum(first[:, None, None] + np.arange(nc)[:, None] + lag, xc.shape[1] - 1)
        off = np.take_along_axis(tt, pos.reshape(n, -1), axis=1).reshape(pos.shape)
        h = _interp_uniform(off - cand[:, :, None], rate, resp) - 1.0
    taus = _release_fit(xc, xx2, size, first, cand, h)
    for ((i, _lo, _hi, _j0), _, _), tau in zip(runs, taus, strict=True):
        out[i] = tau
    return out


def _interp_uniform(x, rate, fp):
    """Linear interpolation on uniform grids from 0, as ``np.interp`` (held beyond either end).

    Parameters
    ----------
    x : ndarray, shape (n, ...)
        Finite points, s; row r on grid r.
    rate : ndarray, shape (n,)
        Each grid's rate, Hz: its nodes are at i/rate, i = 0 … ng − 1.
    fp : ndarray, shape (n, ng)
        The values at the nodes (ng ≥ 2).

    Returns
    -------
    ndarray, shape of ``x``
        fp interpolated at x: fp[:, 0] before 0, fp[:, −1] beyond the last node.
    """
    n, ng = fp.shape
    u = np.clip(x * rate.reshape((n,) + (1,) * (x.ndim - 1)), 0.0, ng - 1.0)
    i = np.minimum(u.astype(np.intp), ng - 2)  # u ≥ 0: the cast is the floor
    u -= i
    i = i.reshape(n, -1)
    lo = np.take_along_axis(fp, i, axis=1).reshape(x.shape)
    hi = np.take_along_axis(fp, i + 1, axis=1).reshape(x.shape)
    return lo + u * (hi - lo)


def _release_fit(xc, xx2, size, first, cand, h) -> list[float | None]:
    """Release time of each run: the τ minimising Σ(x − a − b·g(t − τ))² over its candidate
    times (every 4th, then the neighbours of the best), parabola-refined.

    With H = g(t − τ) − 1, zero up to τ, the centred sums need only the samples after τ:
    Σ(G − Ḡ)² = ΣH² − (ΣH)²/N and Σ(G − Ḡ)x_c = ΣH·x_c − ΣH·Σx_c/N over the span's N samples.
    The candidates of all the runs are evaluated at once, on arrays padded to the longest span
    (the padding kept out of every sum). When the sampling is uniform, H of the m-th sample
    after τ is the same function of m for every candidate (``h`` of shape (n, l)), and ΣH, ΣH²
    are cumulative sums of it.

    Parameters
    ----------
    xc : ndarray, shape (n, w)
        The record over each run's span minus its mean over the span, m, zero beyond the span
        (w ≥ max(first) + c + l − 1).
    xx2 : ndarray, shape (n,)
        Σ xc² of each run, m².
    size : ndarray of int, shape (n,)
        The number of samples in each span.
    first : ndarray of int, shape (n,)
        The sample of the span at candidate 0 (candidate j at sample first + j).
    cand : ndarray, shape (n, c)
        Each run's candidate release times, s (sample times around the detected release).
    h : ndarray, shape (n, l) or (n, c, l)
        g − 1 at the m-th sample after the candidate, m = 0 … l − 1, of each run (uniform
        sampling) or of each run's every candidate; g is the loop response from rest at 1.

    Returns
    -------
    list of float or None
        Each run's release time, s; None where a coarse candidate's fit is undefined or the
        best candidate is on the edge of the search.
    """
    n, c = cand.shape
    rows = np.arange(n)[:, None]
    lag = np.arange(1, h.shape[-1])
    sse = np.full((n, c), np.inf)
    xs = xc.sum(axis=1)[:, None]  # Σx_c: zero to rounding
    win = np.lib.stride_tricks.sliding_window_view(xc, lag.size, axis=1)
    if h.ndim == 2:
        cum = np.zeros((n, h.shape[1], 2))
        np.cumsum(np.stack([h, h * h], axis=2)[:, 1:], axis=1, out=cum[:, 1:])

    def evaluate(idx):
        # sse of the candidates idx (n, k) of every run
        pos = first[:, None] + idx  # (n, k)
        count = size[:, None] - 1 - pos  # samples after each candidate
        X = win[rows, pos + 1]  # (n, k, l − 1): the samples after each, zero beyond the span
        if h.ndim == 2:
            sh = np.take_along_axis(cum[:, :, 0], count, axis=1)
            shh = np.take_along_axis(cum[:, :, 1], count, axis=1)
            shx = np.matmul(X, h[:, 1:, None])[:, :, 0]
        else:
            H = np.where(lag <= count[:, :, None], h[rows, idx, 1:], 0.0)
            sh = H.sum(axis=2)
            shh = np.einsum("rkm,rkm->rk", H, H)
            shx = np.einsum("rkm,rkm->rk", H, X)
        gg = shh - sh * sh / size[:, None]
        gx = shx - sh * xs / size[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            sse[rows, idx] = np.where(gg > 0, xx2[:, None] - gx * gx / gg, np.nan)

    evaluate(np.broadcast_to(np.arange(0, c, 4), (n, len(range(0, c, 4)))))
    coarse_ok = np.all(np.isfinite(sse[:, ::4]), axis=1)
    best = 4 * np.argmin(np.where(coarse_ok[:, None], sse[:, ::4], 0.0), axis=1)
    evaluate(np.clip(best[:, None] + np.arange(-3, 4), 0, c - 1))  # (repeats at the edges)
    i = np.argmin(sse, axis=1)
    j = np.clip(i, 1, c - 2)[:, None] + np.arange(-1, 2)
    y0, y1, y2 = np.take_along_axis(sse, j, axis=1).T
    ok = coarse_ok & (i > 0) & (i < c - 1) & np.isfinite(y0) & np.isfinite(y1) & np.isfinite(y2)
    den = y0 - 2 * y1 + y2
    with np.errstate(divide="ignore", invalid="ignore"):
        shift = np.where(den > 0, np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5), 0.0)
    t0, t1, t2 = np.take_along_axis(cand, j, axis=1).T
    tau = t1 + shift * np.where(shift > 0, t2 - t1, t1 - t0)
    return [float(x) if good else None for x, good in zip(tau.tolist(), ok.tolist(), strict=True)]


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
    _first, fits, reasons, skips, _rough = _measure(data, P, D, delay)
    return fits, reasons, skips


def _start_run(t, x, skip, coarse_release=False):
    try:
        return start_decay(t, x, skip=skip, coarse_release=coarse_release,
                           refine="auto" if coarse_release else True), None
    except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
        return None, str(exc)


def _digital_modes_of(rough, P, D, digital, dm):
    """Per run: the sampled loop's finite roots (decreasing real part) and their amplitudes
    for a unit release (phoid.dynamics.digital.digital_residues), from the rough plant with each
    run's
    added mass ``dm`` (one call per distinct added mass)."""
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


def _measure(data, P, D, delay, *, rough=None, first=None, noise=None, digital=None,
             added_mass=None):
    """Both passes of :func:`measure_modes`; with ``rough`` (m, c, k) given, the loop modes come
    from it, and with ``first`` (the first pass's starts) that pass is not redone. ``noise``
    (m, per run) replaces the first pass's noise level.

    The first pass is only the starting stage of the decay fit
    (:func:`phoid.fits.start_decay`:
    release, noise, window, and (σ, ω_d) from ESPRIT on the record after 3Δt): it is within
    about one standard error of a full fit, which is all the rough plant needs, at a third of
    the cost. Each run is then fitted once, in full: from the release with the loop's fast
    modes where the rough plant gives them, else a single mode after 3Δt.

    Returns (first, fits, reasons, skips, rough).
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
                else _model_releases(data, starts, rough, P, D, delay, dm, digital))
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
                                                           delay, count=2 * _N_FAST + 4),
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
            len(modes := _modes(all_roots[i])) >= _N_FAST + 2
            or (digital is not None and len(modes) >= 1)
        ):
            rest = modes[1:]
            if digital is not None:
                # a root on the negative real z axis rings at the controller's Nyquist rate,
                # (−1)ⁿ: not a column the decay fit can hold; it can only be skipped
                nyq = 0.99 * math.pi / digital.sample_time
                fitted = [q for q in rest if abs(q.imag) < nyq][:_N_FAST]
            else:
                step = float(np.median(np.diff(t[: min(t.size, 64)])))
                fitted = [q for q in rest if -q.real * step <= _FAST_MAX_DECAY_PER_SAMPLE]
                fitted = fitted[:_N_FAST]
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
                a_omit = 2.0 * abs(_residue(omitted, rough[0] + dm[i], rough[1], rough[2],
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


def identify(
    experiment: Any,
    *,
    delay: float | None = None,
    estimator: str = "gls",
    compensate: bool = True,
) -> Identification | ForcedIdentification | FreeIdentification:
    """Identify m, c, k from a PHO experiment set.

    Parameters
    ----------
    experiment : phoid.io.experiment.ExperimentSet
        The runs (t, x, P, D) and the loop delay (``[loop] delay``), as read by
        :func:`phoid.io.experiment.read_experiment`.
    delay : float, optional
        Loop delay Δt (s), overriding the manifest's.
    estimator : {"gls", "ols"}
        ``"gls"``: the efficient weighted fit through the exact loop roots (default).
        ``"ols"``: the paper's eq. (35) lines by ordinary least squares.
    compensate : bool, default True
        Correct for the delay (eqs. 28–32). False reproduces the paper's uncompensated column
        (only with ``estimator="ols"``).

    Returns
    -------
    Identification
        For ``method = "forced"`` or ``"free"`` sets the result of
        :func:`phoid.methods.forced.identify_forced` or :func:`phoid.methods.free.identify_free` (a
        known mass
        for a free set: :func:`phoid.methods.free.identify_free` with ``mass=``).

    Raises
    ------
    IdentificationError
        When the data cannot determine m, c, k (no usable runs, all gains equal, …).
    """
    if estimator not in ("gls", "ols"):
        raise ValueError(f"`estimator` must be 'gls' or 'ols'; got {estimator!r}")
    if estimator == "gls" and not compensate:
        raise ValueError("`compensate=False` is only available with estimator='ols'")
    method = getattr(experiment, "method", "pho")
    refuse_bias(experiment, method)
    if method in ("forced", "free"):
        # the other methods of the format, with their own estimators; PHO-only options refused
        if delay is not None or estimator != "gls" or not compensate:
            raise IdentificationError(
                f"{experiment.path}: method = {method!r}: `delay`, `estimator` and "
                "`compensate` apply to PHO sets only"
            )
        if method == "forced":
            from phoid.methods.forced import identify_forced

            return identify_forced(experiment)
        from phoid.methods.free import identify_free

        return identify_free(experiment)
    if method != "pho":
        raise IdentificationError(f"{experiment.path}: method = {method!r} is not known")
    runs = list(experiment.runs)
    if not runs:
        raise IdentificationError(f"{experiment.path}: no runs")
    added_mass = np.array([getattr(r, "added_mass", 0.0) for r in runs], dtype=float)
    digital = read_digital_loop(experiment)
    if digital is not None:
        _check_sample_time(experiment, digital, runs)
        if delay is not None or experiment.delay is not None:
            raise IdentificationError(
                f"{experiment.path}: [loop] delay: a digital loop (sample_time) takes its delay "
                "as delay_samples, in whole samples; give one or the other"
            )
        return identify_data(
            [(r.t, r.x) for r in runs],
            np.array([r.P for r in runs], dtype=float),
            np.array([r.D for r in runs], dtype=float),
            None, files=[r.file for r in runs], names=[getattr(r, "name", r.file) for r in runs],
            estimator=estimator, source=str(experiment.path), digital=digital,
            added_mass=added_mass,
        )
    if delay is None:
        delay = experiment.delay
    if delay is None and estimator != "gls":
        raise IdentificationError(
            f"{experiment.path}: [loop] delay is not given: estimating it needs the weighted "
            "fit (estimator 'gls'), or give the delay (phoid identify --delay)"
        )
    return identify_data(
        [(r.t, r.x) for r in runs],
        np.array([r.P for r in runs], dtype=float),
        np.array([r.D for r in runs], dtype=float),
        None if delay is None else float(delay),
        added_mass=added_mass if np.any(added_mass) else None,
        files=[r.file for r in runs],
        names=[getattr(r, "name", r.file) for r in runs],
        estimator=estimator,
        compensate=compensate,
        source=str(experiment.path),
        u=[getattr(r, "u", None) for r in runs],
    )


def refuse_bias(experiment: Any, method: str) -> None:
    """Refuse runs whose command carries a DC-offset bias (``[[run]] bias``): their decay is not
    a sum of the loop's modes, so the mode fit would return a wrong m, c, k without noticing;
    the friction fit models it (``phoid identify --friction``, :mod:`phoid.methods.friction`)."""
    for r in getattr(experiment, "runs", ()):
        if getattr(r, "bias", 0.0):
            hint = ("; fit it with the stick-slip model: phoid identify --friction "
                    "(phoid.methods.friction.identify_friction_set)" if method == "pho" else
                    f"; a {method} set has no PD loop to carry it")
            raise IdentificationError(
                f"{experiment.path}: {r.name}: bias = {r.bias:g} N: a biased PD command is not "
                f"a linear loop, so the mode fit does not apply{hint}")


def _as_record(run) -> tuple[Any, Any]:
    """(t, x) as float64 arrays where they convert (the first pass reports those that do
    not, or that are not 1-d, finite and increasing)."""
    try:
        t, x = run
        return np.asarray(t, dtype=float), np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        return run


@single_blas_thread
def identify_data(
    data: Sequence[tuple[np.ndarray, np.ndarray]],
    P: np.ndarray,
    D: np.ndarray,
    delay: float | None,
    *,
    files: Sequence[str] | None = None,
    names: Sequence[str] | None = None,
    estimator: str = "gls",
    compensate: bool = True,
    source: str = "",
    digital: Any = None,
    added_mass: np.ndarray | None = None,
    u: Sequence[np.ndarray | None] | None = None,
) -> Identification:
    """:func:`identify` on plain arrays: ``data`` is a sequence of (t, x) per run.

    Parameters are as in :func:`identify`; ``files``/``names`` label the runs. ``delay=None``
    estimates the loop delay with m, c, k (see :func:`_estimate_delay`). ``digital``
    (a :class:`phoid.dynamics.digital.DigitalPD`; its gains are ignored) models a sampled loop
    exactly;
    ``delay`` is then ignored (the loop's own d·T_s is used for the starting lines).
    ``added_mass`` (kg, per run) is a known mass added in each run (the paper's added-mass
    trick): run i's loop has mass m + Δmᵢ and the estimate is the mass without additions.
    ``u`` (N, per run, None where not recorded; same samples as x) is the feedback force
    applied: with ``delay=None`` the delay is then estimated from x and u together
    (:func:`phoid.methods.udelay.with_u`).
    """
    n = len(data)
    if n == 0:
        raise IdentificationError("no runs")
    # float arrays once: every run is checked by its first pass and fitted unchecked after it
    data = [_as_record(run) for run in data]
    files = list(files) if files is not None else [f"run{i + 1}" for i in range(n)]
    names = list(names) if names is not None else files
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    if added_mass is not None:
        added_mass = np.broadcast_to(np.asarray(added_mass, dtype=float), (n,)).copy()
        if not np.all(np.isfinite(added_mass) & (added_mass >= 0)):
            raise ValueError(f"`added_mass` must be finite and ≥ 0 kg; got {added_mass}")
    if digital is not None:
        if estimator != "gls":
            raise IdentificationError("a digital loop needs the weighted fit (estimator='gls')")
        # starting lines: the continuous loop with the delay of the samples, plus half a sample
        # (the hold) and, for a backward difference, half a sample more on the velocity
        res = _identify_core(data, P, D, digital.delay + 0.5 * digital.sample_time,
                             files=files, names=names, source=source, digital=digital,
                             added_mass=added_mass)
        return replace(res, delay=digital.delay)
    if delay is None:
        if estimator != "gls":
            raise IdentificationError("estimating the loop delay needs estimator='gls'")
        from phoid.methods.udelay import check_u, with_u

        u = None if u is None else check_u(u, data)
        res = _estimate_delay(data, P, D, files=files, names=names, source=source,
                              added_mass=added_mass)
        if u is None or all(ui is None for ui in u):
            return replace(res, delay_from="x")

        dm = np.zeros(n) if added_mass is None else added_mass
        return with_u(res, u, P, D, names=names, added_mass=dm, n_fast=_N_FAST,
                      rerun=lambda tau: _identify_core(data, P, D, tau, files=files,
                                                       names=names, source=source,
                                                       estimate_delay=True, added_mass=dm))
    _check_delay(float(delay), data, source)
    res = _identify_core(data, P, D, float(delay), files=files, names=names,
                         estimator=estimator, compensate=compensate, source=source,
                         added_mass=added_mass)
    if u is not None and any(ui is not None for ui in u):
        from phoid.methods.udelay import check_u

        wd = [r.omega_d for r in res.runs]
        note = _u_contradicts_gains(data, check_u(u, data), P, D, float(delay), names, wd)
        if note is not None:
            res = replace(res, warnings=(*res.warnings, note))
    return res


# a given delay shorter than this fraction of the records' sample step is no delay the data can
# tell from 0 (and the release model would step through it in 1e300 steps): a unit mistake
_MIN_DELAY_PER_STEP = 1e-6


def _check_delay(delay: float, data, source: str) -> None:
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
            f"{where}{what} = {delay:.3g} s is {h / delay:.3g} times shorter than the records' "
            f"sample step ({h:.3g} s): is it in seconds? Give 0 for a loop without delay")
    if 3.0 * delay >= max(spans):
        raise IdentificationError(
            f"{where}{what} = {delay:.4g} s is too long for the records: the fit starts 3 "
            f"delays ({3 * delay:.4g} s) after the release, beyond the longest record "
            f"({max(spans):.4g} s); is it in seconds?")


# the recorded force and the gains agree when u's least-squares scale on −(P x + D ẋ)(t − Δt)
# is 1; a smoothed derivative of noisy x biases it low by a few per cent and a force sensor's
# calibration is rarely better than a few per cent, so only a scale outside 0.8 … 1.25 (a gain
# or unit mistake, e.g. gains off by 2×: scale 0.5) is reported
_U_SCALE_OK = (0.8, 1.25)


def _u_contradicts_gains(data, u, P, D, delay, names, omega_d) -> str | None:
    """A warning naming the runs whose recorded u contradicts the given gains and delay
    (u ≠ −[P x(t − Δt) + D ẋ(t − Δt)] by more than a calibration could explain), or None."""
    from scipy.signal import savgol_filter

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
    return (f"the recorded u contradicts the given gains and delay in {len(bad)} run(s): u is "
            f"not -(P x + D x') at t - delay but that times {listed}: check P, D, the units "
            "of x (m) and u (N), or the delay; m, c, k assume the gains are right")


_DELAY_GRID = 400  # candidate delays of the starting profile


def _estimate_delay(data, P, D, *, files, names, source, added_mass=None) -> Identification:
    """m, c, k and the loop delay Δt together (the manifest gives no delay).

    Only the right delay maps all runs' modes onto one plant (eq. 35's points collinear, with
    one slope), so with three or more distinct gain pairs Δt is identifiable. Start: each run's
    mode from the release on (:func:`phoid.fits.start_decay`, no transient skipped: a slightly
    biased but robust first look), then the profile of :func:`phoid.methods.pho.delay_profile` over
    0 … π/max ω_d (a delay of half the fastest run's period; the loop's phase lag at that delay
    is already beyond what a PD loop rings with). Then the full pipeline at that delay with
    Δt fitted alongside m, c, k through the exact roots (:func:`phoid.methods.pho.fit_modes`),
    twice:
    the second time with the transient skip and fast modes of the first estimate.
    """
    n = len(data)
    where = f"{source}: " if source else ""
    starts = [_start_run(t, x, 0.0)[0] for t, x in data]
    ok = [i for i in range(n) if starts[i] is not None and starts[i].oscillating]
    if len({(P[i], D[i]) for i in ok}) < 3:
        raise IdentificationError(
            f"{where}[loop] delay is not given and cannot be estimated: that needs at least three "
            f"runs with distinct gains (P, D) that oscillate; {len(ok)} such runs found. Give "
            "the delay ([loop] delay in the manifest, or phoid identify --delay)"
        )
    sig = np.array([starts[i].sigma for i in ok])
    wd = np.array([starts[i].omega_d for i in ok])
    hi = math.pi / float(np.max(wd))
    grid = np.linspace(0.0, hi, _DELAY_GRID + 1)
    dm = np.zeros(n) if added_mass is None else np.asarray(added_mass, dtype=float)
    prof = delay_profile(sig, wd, P[ok], D[ok], grid, added_mass=dm[ok])
    j = int(np.argmin(prof))
    cause = None
    if j == grid.size - 1:
        cause = _probable_cause([(st, None) for st in starts], data, P, D, None, names, dm, True)
    if cause is not None:
        raise IdentificationError(f"{where}{cause}")
    if j == grid.size - 1:
        raise IdentificationError(
            f"{where}the loop delay estimate hits its upper bound ({hi:.4g} s, half the period "
            "of the fastest run): the runs do not look like one plant under a delayed PD loop; "
            "give the delay, or check the gains"
        )
    tau = float(grid[j])
    notes: list[str] = []
    result = None
    for _ in range(3):
        try:
            result = _identify_core(data, P, D, tau, files=files, names=names, source=source,
                                    estimate_delay=True, added_mass=dm)
        except IdentificationError as exc:
            cause = _probable_cause([(st, None) for st in starts], data, P, D, None, names, dm,
                                    True)
            if cause is not None:
                msg = str(exc) if cause in str(exc) else (
                    f"{where}{cause} (estimating the loop delay: {exc})")
                raise IdentificationError(msg) from None
            raise IdentificationError(
                f"{where}estimating the loop delay: {exc} (the delay is searched in 0–{hi:.4g} "
                "s, half the period of the fastest run: a longer delay must be given, [loop] "
                "delay or phoid identify --delay)") from None
        moved = abs(result.delay - tau)
        tau = result.delay
        if moved <= 0.1 * (result.delay_stderr or 0.0) + 1e-12 * max(tau, 1.0):
            break
    assert result is not None
    if not tau > 0.0:
        notes.append("the loop delay estimate is 0 (its lower bound): the loop behaves as if "
                     "it had no delay")
    elif result.delay_stderr is not None and result.delay_stderr > 0.2 * tau:
        notes.append(f"the loop delay is poorly determined ({tau:.4g} ± "
                     f"{result.delay_stderr:.2g} s): spread the gains more, or give the delay")
    if notes:
        result = replace(result, warnings=tuple(notes) + result.warnings)
    return result


# a controller sampling more than this many times per recorded sample is no sampled loop phoid
# can model (its z-domain model degenerates as T_s |s| -> 0: JᵀJ singular at 1e-300 s), and no
# rig records that much slower than it controls; such a loop is a continuous one
_MAX_CONTROL_PER_RECORD = 1e4


def _check_sample_time(experiment: Any, digital: Any, runs: Sequence[Any]) -> None:
    """Refuse a ``[loop] sample_time`` far below the records' own sample step (a unit mistake,
    or a controller so fast it is a continuous loop)."""
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
        return
    h = float(np.median(steps))
    if digital.sample_time * _MAX_CONTROL_PER_RECORD < h:
        raise IdentificationError(
            f"{experiment.path}: [loop] sample_time = {digital.sample_time:.3g} s is "
            f"{h / digital.sample_time:.3g} times shorter than the records' sample step "
            f"({h:.3g} s): is it in seconds? A controller that fast is a continuous loop: give "
            "[loop] delay instead of sample_time")


DIGITAL_KEYS = ("sample_time", "delay_samples", "velocity", "cutoff")


def read_digital_loop(experiment: Any):
    """The manifest's digital loop ([loop] sample_time, …) as a DigitalPD, or None."""
    from phoid.dynamics.digital import DigitalPD

    loop = dict(getattr(experiment, "loop", {}) or {})
    unknown = sorted(set(loop) - {"delay", *DIGITAL_KEYS})
    if unknown:
        raise IdentificationError(
            f"{experiment.path}: [loop] {unknown[0]}: unknown key (known: delay, "
            + ", ".join(DIGITAL_KEYS) + ")"
        )
    if "sample_time" not in loop:
        extra = [key for key in DIGITAL_KEYS if key in loop]
        if extra:
            raise IdentificationError(
                f"{experiment.path}: [loop] {extra[0]}: needs [loop] sample_time (s), the "
                "controller's sampling period"
            )
        return None
    try:
        return DigitalPD(
            P=0.0, D=0.0, sample_time=loop["sample_time"],
            delay_samples=loop.get("delay_samples", 0),
            velocity=loop.get("velocity", "backward-difference"), cutoff=loop.get("cutoff"),
        )
    except (ValueError, TypeError) as exc:
        raise IdentificationError(f"{experiment.path}: [loop]: {exc}") from None


# an added mass more than this many times the mass the runs without one give is no mass a rig
# adds (a unit or typing mistake); beyond it the loop's numbers overflow
_MAX_ADDED_RATIO = 1e6


def _check_added_mass(first, P, D, delay, dm, names, source) -> None:
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


def _coarse_sampling(data, fits) -> str | None:
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


def _cli_words(message: str) -> str:
    """A decay fit's message in the identification's words: its ``skip`` is not a setting
    here but three loop delays after the release (set through the delay, --delay)."""
    return (message.replace("(increase `skip`?)", "(is the loop delay, --delay, right?)")
            .replace("[release + skip, t_end]", "[release + 3 delay, end]"))


def _probable_cause(first, data, P, D, delay, names, dm, estimate_delay) -> str | None:
    """`diagnose.probable_cause` from the first pass's rough modes (``first``: each
    run's (start, error)); ``delay`` None (a digital loop, or a delay being estimated) skips
    the delay check."""
    from phoid.methods.diagnose import probable_cause

    sig = np.full(len(data), np.nan)
    wd = np.full(len(data), np.nan)
    steps = np.full(len(data), np.nan)
    for i, (st, _err) in enumerate(first):
        if st is not None and st.oscillating:
            sig[i], wd[i] = st.sigma, st.omega_d
        try:
            t = np.asarray(data[i][0], dtype=float)
            steps[i] = float(np.median(np.diff(t[: min(t.size, 64)])))
        except (TypeError, ValueError, IndexError):
            pass
    return probable_cause(sig, wd, P, D, None if estimate_delay else delay, steps=steps,
                          names=names, added_mass=dm)


def _identify_core(data, P, D, delay, *, files, names, estimator="gls", compensate=True,
                   source="", estimate_delay=False, notes=(), digital=None,
                   added_mass=None) -> Identification:
    """The pipeline at one delay: measure modes, combine (estimating the delay too if asked,
    ``delay`` then being its start), refine on misfit, and assemble the result."""
    n = len(data)
    dm = np.zeros(n) if added_mass is None else np.asarray(added_mass, dtype=float)
    first = None
    if np.any(dm):
        first = [(st, None) if not isinstance(st, str) else (None, st) for st in
                 start_decays(data, skip=3.0 * delay, refine="auto", coarse_release=True)]
        _check_added_mass(first, P, D, delay, dm, names, source)
    first, fits, reasons, _skips, rough = _measure(data, P, D, delay, digital=digital,
                                                   added_mass=dm, first=first)
    used = [i for i in range(n) if reasons[i] is None]
    if not used:
        raise IdentificationError(
            "no usable runs: " + "; ".join(f"{names[i]}: {reasons[i]}" for i in range(n))
        )

    def combine(fits, used):
        sig = np.array([fits[i].sigma for i in used])
        wd = np.array([fits[i].omega_d for i in used])
        cov = np.array([fits[i].cov for i in used])
        if estimator == "gls":
            return fit_modes.__wrapped__(sig, wd, cov, P[used], D[used], delay,
                                         estimate_delay=estimate_delay, digital=digital,
                                         added_mass=dm[used])
        return fit_lines(sig, wd, P[used], D[used], delay, compensate=compensate,
                         added_mass=dm[used])

    try:
        mck = combine(fits, used)
    except IdentificationError as exc:
        cause = _probable_cause(first, data, P, D, None if digital is not None else delay,
                                names, dm, estimate_delay)
        if cause is None:
            raise
        where = f"{source}: " if source else ""
        raise IdentificationError(f"{where}{cause} ({exc})") from None
    # The second pass took the loop's fast modes from a rough plant (first pass). Where that
    # plant was poor — a run whose next root is slow biases the first pass — the runs then
    # disagree beyond their noise: refit the modes with the weighted estimate (at most twice)
    # and keep whichever combination fits best.
    for _ in range(2):
        if estimator != "gls" or rough is None or not _misfit(mck):
            break
        _first, fits2, reasons2, _s, _r = _measure(
            data, P, D, delay, rough=(mck.m, mck.c, mck.k), first=first, digital=digital,
            added_mass=dm,
            noise=[f.noise_sd if f is not None else None for f in fits],
        )
        used2 = [i for i in range(n) if reasons2[i] is None]
        if len(used2) < len(used):
            break
        try:
            mck2 = combine(fits2, used2)
        except (IdentificationError, ValueError, np.linalg.LinAlgError):
            break
        if not mck2.chi2 / max(mck2.dof, 1) < mck.chi2 / max(mck.dof, 1):
            break
        fits, reasons, used, mck, rough = fits2, reasons2, used2, mck2, (mck2.m, mck2.c, mck2.k)
    warnings: list[str] = list(notes)
    reasons = [None if r is None else _cli_words(r) for r in reasons]
    for i, f in enumerate(fits):
        if reasons[i] is not None:
            warnings.append(f"{names[i]}: set aside: {reasons[i]}")
        elif f is not None:
            warnings.extend(f"{names[i]}: {_cli_words(w)}" for w in f.warnings)
    warnings.extend(mck.warnings)
    if _misfit(mck):
        cause = _probable_cause(first, data, P, D, None if digital is not None else delay,
                                names, dm, estimate_delay)
        if cause is not None:
            warnings.append(f"probably: {cause}")
    misfits = [i for i in used if any(w.startswith("misfit") for w in fits[i].warnings)]
    if digital is None and len(misfits) >= max(2, len(used) // 2):
        warnings.append(
            f"{len(misfits)} of {len(used)} runs do not decay like a linear loop (residuals well "
            "above the noise): if the rig has Coulomb friction, identify with friction "
            "(phoid identify --friction, phoid.identify_friction), which fits f_c too"
        )
    if len(used) >= 3 and np.ptp(D[used]) == 0.0:
        # P-only loops (the seed's Discussion): damping varies between runs only through the
        # delay, so the damping line's points crowd together; say how much that costs
        sd = np.sqrt(np.diag(mck.cov))
        corr = mck.cov / np.outer(sd, sd)
        rho = float(np.max(np.abs(corr[np.triu_indices(3, 1)])))
        warnings.append(
            f"all runs have the same D ({D[used][0]:g} N s/m, a P-only sweep): the runs' "
            "damping differs only through the delay, so c rests on the delay being right; "
            f"conditioning: largest correlation of m, c, k {rho:.3f}, condition number of "
            f"their correlation matrix {float(np.linalg.cond(corr)):.3g}, c known to "
            f"{100 * sd[1] / max(abs(mck.c), 1e-300):.2g} %"
        )
    coarse = _coarse_sampling(data, [fits[i] for i in used])
    if coarse is not None:
        warnings.append(coarse)
    if len(used) < 3:
        warnings.append(f"only {len(used)} usable runs: m, c, k are barely determined")
    se = mck.stderr
    runs: list[RunMode] = []
    j = 0
    for i in range(n):
        f = fits[i]
        if i in used:
            cp, kp = float(mck.c_prime[j]), float(mck.k_prime[j])
            j += 1
        else:
            cp = kp = math.nan
        runs.append(RunMode(
            file=files[i], P=float(P[i]), D=float(D[i]),
            sigma=f.sigma if f else math.nan, omega_d=f.omega_d if f else math.nan,
            sigma_stderr=f.sigma_stderr if f else math.nan,
            omega_d_stderr=f.omega_d_stderr if f else math.nan,
            c_prime=cp, k_prime=kp, cycles=f.cycles if f else math.nan,
            residual_rms=f.residual_rms if f else math.nan, used=i in used,
            warnings=tuple(([reasons[i]] if reasons[i] else [])
                           + ([_cli_words(w) for w in f.warnings] if f else [])),
            fit=f, added_mass=float(dm[i]),
        ))
    return Identification(
        m=Estimate(mck.m, float(se[0]), "kg"),
        c=Estimate(mck.c, float(se[1]), "N s/m"),
        k=Estimate(mck.k, float(se[2]), "N/m"),
        delay=delay if mck.delay is None else mck.delay,
        delay_source="estimated" if mck.delay_stderr is not None else "given",
        delay_stderr=mck.delay_stderr, runs=tuple(runs), fit=mck, digital=digital,
        warnings=tuple(warnings), source=source, data=tuple(data),
    )
