"""The result of a design or a check: :class:`Design` and its :class:`PlannedRun` s.

A :class:`Design` holds per-run predicted modes, cycles, stability margins and the
**Cramér–Rao standard errors** of m, c, k (:mod:`phoid.planning.fisher`) for the planned noise
level and record length; :func:`assemble` evaluates given gains exactly on the prior grid and
builds it. Model assumptions of the prediction: white Gaussian sensor noise, feedback on the
true position, a release from a held position x₀ = ``amplitude``, the record starting at the
release, the delay known.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from phoid.dynamics import rightmost_roots
from phoid.dynamics.digital import digital_roots
from phoid.methods.estimate import Estimate
from phoid.planning.evaluation import Evaluation, evaluate, run_information
from phoid.planning.fisher import mode_information, safe_inverse
from phoid.planning.render import design_report, plot_design
from phoid.planning.sampled import evaluate_sampled, predicted_covariance, sampled_information
from phoid.planning.schedule import schedule_target
from phoid.planning.settings import DesignError, DesignSettings, Prior
from phoid.reports.display import NotebookDisplay

__all__ = ["Design", "PlannedRun", "assemble", "roots_in_range"]


@dataclass(frozen=True)
class PlannedRun:
    """One run of a schedule with its predicted behaviour.

    Mode values (``sigma``, ``omega_d``, ``zeta``, ``omega0``, ``cycles``, ``amplitude`` and the
    stderr of σ and ω_d) are at the nominal plant; ``zeta_min``/``zeta_max`` and the margins are
    the extremes over the prior grid.

    Attributes
    ----------
    P, D : float
        Gains, N/m and N·s/m.
    sigma, omega_d : float
        Dominant mode's decay rate (1/s) and damped frequency (rad/s).
    zeta, omega0 : float
        Its damping ratio and natural frequency √(σ² + ω_d²) (rad/s).
    cycles : float
        Cycles above the noise floor within the record.
    amplitude : float
        Release amplitude |w| of the dominant mode, m.
    sigma_stderr, omega_d_stderr : float
        Cramér–Rao standard deviations of σ (1/s) and ω_d (rad/s) from this run.
    margin : float
        Decay margin, 1/s: the smallest distance of the rightmost root from the imaginary axis
        over the prior (negative: unstable somewhere).
    delay_margin : float
        Smallest extra delay the loop tolerates over the prior, s (0 where unstable).
    zeta_min, zeta_max : float
        Range of the dominant mode's ζ over the prior grid.
    share : float
        The run's share of the set's information, tr(I⁻¹Iᵢ)/3 (the shares sum to 1).
    safe : bool
        Stable and ringing with the required margins on the whole prior grid.
    informative : bool
        Rings with at least ``min_cycles`` cycles on the whole prior grid and ζ in the band at
        the nominal plant.
    warnings : tuple of str
    delay_margin_samples : float or None
        A sampled loop's delay margin, whole samples: the smallest over the prior of d′ − d,
        d′ the largest command delay for which the loop stays stable (``inf``: no delay
        destabilises it; 0 where unstable). None for a continuous loop.
    max_delay_samples : float or None
        d + ``delay_margin_samples``: the longest command delay, whole samples, the run stays
        stable with on the whole prior.
    roots : tuple of complex
        A sampled loop's d + 3 exact roots s = ln(z)/T (1/s) at the nominal plant, rightmost
        first (:func:`phoid.dynamics.digital.digital_roots`); empty for a continuous loop.
    """

    P: float
    D: float
    sigma: float
    omega_d: float
    zeta: float
    omega0: float
    cycles: float
    amplitude: float
    sigma_stderr: float
    omega_d_stderr: float
    margin: float
    delay_margin: float
    zeta_min: float
    zeta_max: float
    share: float
    safe: bool
    informative: bool
    warnings: tuple[str, ...] = ()
    delay_margin_samples: float | None = None
    max_delay_samples: float | None = None
    roots: tuple[complex, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict; non-finite numbers become null (a null ``delay_margin`` means that
        no extra delay destabilises the loop, a null mode that the run does not ring); a
        sampled loop's run adds ``delay_margin_samples``, ``max_delay_samples`` and ``roots``
        (``[re, im]`` of each s, 1/s; a root at z = 0 has re null)."""

        def num(x):
            return float(x) if x is not None and math.isfinite(x) else None

        out: dict[str, Any] = {"P": float(self.P), "D": float(self.D)}
        for key in ("sigma", "omega_d", "zeta", "omega0", "cycles", "amplitude",
                    "sigma_stderr", "omega_d_stderr", "margin", "delay_margin", "zeta_min",
                    "zeta_max", "share"):
            out[key] = num(getattr(self, key))
        out.update(safe=self.safe, informative=self.informative, warnings=list(self.warnings))
        if self.delay_margin_samples is not None:  # a sampled loop's
            out["delay_margin_samples"] = num(self.delay_margin_samples)
            out["max_delay_samples"] = num(self.max_delay_samples)
            out["roots"] = [[num(r.real), num(r.imag)] for r in self.roots]
        return out


@dataclass(frozen=True, repr=False)
class Design(NotebookDisplay):
    """A gain schedule with its predicted modes, margins and Cramér–Rao uncertainties.

    Attributes
    ----------
    runs : tuple of PlannedRun
    m, c, k : Estimate
        The nominal plant with the predicted (Cramér–Rao) standard error at it.
    stderr_worst : ndarray, shape (3,)
        Worst predicted standard error of m, c, k over the prior grid (kg, N·s/m, N/m).
    cov : ndarray, shape (3, 3)
        Predicted covariance of (m, c, k) at the nominal plant.
    settings : DesignSettings
    prior : dict
        ``{"m": (lo, hi), ...}`` as given, and ``checked`` (the widened box of the safety
        checks) under ``"checked_ranges"``.
    kind : {"design", "check"}
        Proposed by :func:`design` or evaluated by :func:`check`.
    warnings : tuple of str
    notes : tuple of str
        Information that is not a problem (e.g. where a checked set's plant came from).
    plants : ndarray, shape (G, 3)
        The prior grid (row 0 the nominal plant).
    roots : ndarray, shape (n, G)
        Dominant root of every run at every plant of the grid.
    bound : {"modal", "in-loop"}
        What the predicted stderrs are: ``"modal"`` the Cramér–Rao bound of the runs'
        dominant modes (:mod:`phoid.planning.fisher`; noise outside the loop), ``"in-loop"``
        the bound of the plant driven by the applied command with the noise read by the
        controller (:func:`phoid.planning.inloop_bound.inloop_cramer_rao`).
    modal_stderr : ndarray, shape (3,)
        The modal bound's standard errors at the nominal plant (= ``stderr`` when ``bound``
        is ``"modal"``), kept for comparison.
    """

    runs: tuple[PlannedRun, ...]
    m: Estimate
    c: Estimate
    k: Estimate
    stderr_worst: np.ndarray
    cov: np.ndarray
    settings: DesignSettings
    prior: dict[str, Any]
    kind: str
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    plants: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False)
    roots: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), complex), repr=False)
    bound: str = "modal"
    modal_stderr: np.ndarray = field(default_factory=lambda: np.full(3, np.nan), repr=False)

    @property
    def P(self) -> np.ndarray:
        """Proportional gains of the runs, N/m."""
        return np.array([r.P for r in self.runs])

    @property
    def D(self) -> np.ndarray:
        """Derivative gains of the runs, N·s/m."""
        return np.array([r.D for r in self.runs])

    @property
    def stderr(self) -> np.ndarray:
        """Predicted standard errors of (m, c, k) at the nominal plant."""
        return np.array([self.m.stderr, self.c.stderr, self.k.stderr], dtype=float)

    @property
    def safe(self) -> bool:
        """Every run is safe on the whole prior grid."""
        return all(r.safe for r in self.runs)

    def summary(self) -> dict[str, Any]:
        """Plain JSON-ready dict: ``runs``, ``predicted``, ``warnings`` and the inputs."""

        def num(x):
            return float(x) if x is not None and math.isfinite(x) else None

        predicted = {}
        for j, name in enumerate(("m", "c", "k")):
            e = getattr(self, name)
            predicted[name] = {"value": float(e.value), "stderr": num(e.stderr),
                               "stderr_worst": num(self.stderr_worst[j]), "unit": e.unit,
                               "modal_stderr": num(self.modal_stderr[j])}
        return {
            "kind": self.kind,
            "runs": [r.to_dict() for r in self.runs],
            "predicted": predicted,
            "warnings": list(self.warnings),
            "notes": list(self.notes),
            "delay": self.settings.delay,
            "prior": {n: list(self.prior[n]) for n in ("m", "c", "k")},
            "checked_ranges": {n: list(r) for n, r in self.prior["checked_ranges"].items()},
            "settings": self.settings.to_dict(),
            "safe": self.safe,
            "loop": self.loop_summary(),
            "noise_placement": self.settings.noise_placement,
            "bound": self.bound,
        }

    def loop_summary(self) -> dict[str, Any]:
        """The loop designed for: ``{"kind": "continuous", "delay"}`` or ``{"kind":
        "sampled", "sample_time", "delay_samples", "velocity", "cutoff", "samples_per_period",
        "equivalent_delay"}`` (the continuous surrogate's delay the search used, s)."""
        st = self.settings
        if st.digital is None:
            return {"kind": "continuous", "delay": st.delay}
        return {"kind": "sampled", "sample_time": st.sample_time,
                "delay_samples": st.delay_samples, "velocity": st.velocity,
                "cutoff": st.cutoff, "samples_per_period": round(st.fs * st.sample_time),
                "equivalent_delay": st.model_delay}

    def report(self) -> str:
        """Human-readable schedule, margins and predicted uncertainties."""
        return design_report(self)

    def plot(self, path: str | Path | None = None, *, ax=None, overwrite: bool = False):
        """Root locus of the planned runs and their predicted uncertainties.

        Left: each run's dominant root at every plant of the prior grid (the nominal plant
        marked), coloured by run number (a colour bar says which), with the ζ band's rays and
        a legend of the markers; right: the predicted relative standard errors of m, c,
        k (nominal and worst over the prior).

        Parameters
        ----------
        path : str or Path, optional
            Write the figure there as PNG (atomically; its folder is created if needed; an
            existing file is replaced only with ``overwrite``, a symbolic link never).
        ax : sequence of two matplotlib Axes, optional
            Draw into these instead of a new figure.
        overwrite : bool
            Replace an existing file at ``path``.

        Returns
        -------
        matplotlib.figure.Figure
        """
        return plot_design(self, path, ax=ax, overwrite=overwrite)

    def to_toml(self, *, gzip: bool = False) -> str:
        """The schedule as a ``phoid/1`` manifest skeleton (``experiment.toml``).

        Runs name the files the rig operator will record (``run01.csv`` …); the prediction is
        kept in extra keys (``[design]`` at the top level, ``predicted_*`` in each run), which
        :func:`phoid.read_experiment` keeps and ignores. A sampled loop is written as
        ``[loop] sample_time``, ``delay_samples``, ``velocity`` (``cutoff``) and ``noise``
        (the placement the prediction assumed), with ``[design] fs`` the record's rate:
        ``phoid run`` runs its controller at 1/fs with ``delay_samples`` samples of delay.
        """
        import tomli_w

        width = max(2, len(str(len(self.runs))))
        suffix = ".csv.gz" if gzip else ".csv"
        st = self.settings
        doc: dict[str, Any] = {
            "title": f"phoid design: {len(self.runs)} runs",
            "format": "phoid/1",
            "method": "pho",
            "design": {
                "tool": "phoid design",
                "prior": {n: (self.prior[n][0] if self.prior[n][0] == self.prior[n][1]
                              else list(self.prior[n])) for n in ("m", "c", "k")},
                "fs": st.fs, "duration": st.duration, "noise": st.noise,
                "amplitude": st.amplitude,
                "predicted_stderr": {n: float(getattr(self, n).stderr)
                                     for n in ("m", "c", "k")
                                     if math.isfinite(getattr(self, n).stderr)},
            },
            "loop": {"delay": st.delay},
        }
        if st.digital is not None:
            doc["design"]["bound"] = self.bound
            doc["loop"] = {"sample_time": st.sample_time, "delay_samples": st.delay_samples,
                           "velocity": st.velocity,
                           **({"cutoff": st.cutoff} if st.cutoff is not None else {}),
                           "noise": st.noise_placement}
        parts = [tomli_w.dumps(doc)]
        for i, r in enumerate(self.runs, start=1):
            table = {"file": f"run{i:0{width}d}{suffix}", "P": float(r.P), "D": float(r.D)}
            for key in ("sigma", "omega_d", "zeta"):
                val = getattr(r, key)
                if math.isfinite(val):
                    table[f"predicted_{key}"] = float(val)
            parts.append("\n[[run]]\n")
            parts.extend(tomli_w.dumps({k: v}) for k, v in table.items())
        return "".join(parts)

    def write(self, path: str | Path, *, overwrite: bool = False) -> Path:
        """Write :meth:`to_toml` to ``path`` (a folder gets ``experiment.toml``); returns it.

        The file is written atomically (a temporary file beside it, then renamed); its folder
        is created if needed. An existing file is replaced only with ``overwrite``; a symbolic
        link as the file, or a dangling one as the folder, is refused either way
        (:mod:`phoid._output`).

        Raises
        ------
        DesignError
            A file in the way or a failed write, naming the path.
        """
        out, name = schedule_target(path, overwrite=overwrite)
        return out.write(name, self.to_toml().encode("utf-8"))



def assemble(P: np.ndarray, D: np.ndarray, prior: Prior, st: DesignSettings, kind: str,
             extra_warnings: Sequence[str] = (), *, evaluation: Evaluation | None = None
             ) -> Design:
    """Evaluate gains exactly on the prior grid and assemble the :class:`Design`.

    Parameters
    ----------
    P, D : array_like
        Gains of the runs, N/m and N·s/m.
    prior : Prior
        The prior grid.
    st : DesignSettings
        The requirements.
    kind : {"design", "check"}
        Who asks, kept in :attr:`Design.kind`.
    extra_warnings : sequence of str
        Warnings put before those of the evaluation.
    evaluation : Evaluation, optional
        A sampled loop's runs already evaluated exactly on ``prior``
        (:func:`phoid.planning.sampled.evaluate_sampled` of these gains).

    Returns
    -------
    Design
    """
    P = np.asarray(P, dtype=float)
    D = np.asarray(D, dtype=float)
    m0, c0, k0 = prior.nominal
    sampled = st.digital is not None
    if sampled:
        ev = evaluate_sampled(P, D, prior, st) if evaluation is None else evaluation
        info = sampled_information(ev, prior, st)
    else:
        ev = _evaluate_continuous(P, D, prior, st)
        info = run_information(ev, prior, st)
    total = info.sum(axis=0)  # (G, 3, 3)
    modal0 = safe_inverse(total[0])
    cov0, run_info, bound = modal0, info[:, 0], "modal"
    worst = np.array([max(safe_inverse(t)[j, j] for t in total) for j in range(3)])
    if sampled:
        cov0, run_info, bound, worst = _sampled_prediction(P, D, prior, st, ev, info)
    # per-run information share at the nominal plant
    with np.errstate(all="ignore"):
        share = np.einsum("ij,nji->n", cov0, run_info) / 3.0 if np.all(
            np.isfinite(cov0)) else np.full(P.size, np.nan)
    nominal_roots = (digital_roots(m0, c0, k0, P, D, st.digital).s if sampled
                     else np.zeros((P.size, 0), complex))
    runs: list[PlannedRun] = []
    warnings: list[str] = list(extra_warnings)
    found: dict[str, list[tuple[int, float]]] = {}  # warning kind -> [(run, value)]
    zlo, zhi = st.zeta
    G = prior.plants.shape[0]
    for i in range(P.size):
        si = ev.s[i, 0]
        rw: list[tuple[str, float, str]] = []
        sig_i, wd_i = -si.real, si.imag
        rings = bool(np.isfinite(si) and wd_i > 0)
        sse = wse = math.inf
        if rings:  # a growing mode's sums overflow: no stderr for it
            with np.errstate(all="ignore"):
                Ii = mode_information(si, ev.w[i, 0], fs=st.fs, duration=st.duration,
                                      noise=st.noise)[0]
            if np.all(np.isfinite(Ii)):
                try:
                    mc = np.linalg.inv(Ii)
                except np.linalg.LinAlgError:
                    mc = None
                if mc is not None and mc[0, 0] >= 0 and mc[1, 1] >= 0:
                    sse, wse = math.sqrt(mc[0, 0]), math.sqrt(mc[1, 1])
        margin_all = -np.where(np.isfinite(ev.s[i]), ev.s[i].real, np.nan)
        margin_all = np.where(ev.stable[i], margin_all, np.minimum(margin_all, 0.0))
        ringing = ev.dominant[i] & np.isfinite(ev.s[i]) & (ev.s[i].imag > 0)
        if not np.all(ev.stable[i]):
            bad = int(np.sum(~ev.stable[i]))
            rw.append(("unstable", bad,
                       f"UNSTABLE for {bad} of {G} plants of the prior grid"
                       + (" (including the nominal plant)" if not ev.stable[i, 0] else "")))
        elif not np.all(ringing):
            rw.append(("noring", 0.0, "does not ring (its slowest mode is not oscillatory) "
                                      "for some plants of the prior"))
        else:
            zmin = float(np.nanmin(ev.zeta[i]))
            if zmin < 0.5 * zlo:
                rw.append(("damping", zmin, f"barely damped for some plants (ζ down to "
                                            f"{zmin:.3g} < {0.5 * zlo:g})"))
            if sampled:
                dm = float(np.min(ev.dsamples[i]))
                if dm < st.delay_margin_samples:
                    rw.append(("dmargin", dm, f"delay margin only {dm:g} samples "
                                              f"(< {st.delay_margin_samples} samples)"))
            else:
                dm = float(np.min(ev.dmargin[i]))
                if dm < st.delay_margin:
                    rw.append(("dmargin", dm, f"delay margin only {dm:.3g} s "
                                              f"(< {st.delay_margin:.3g} s)"))
            if not np.all(ev.separated[i]):
                rw.append(("separation", 0.0, f"another mode decays less than "
                                              f"{st.separation:g}× faster than the ringing one "
                                              "for some plants"))
        cyc = ev.cycles[i][np.isfinite(ev.cycles[i])]
        cyc_min = float(cyc.min()) if cyc.size else 0.0
        if rings and cyc_min < st.min_cycles:
            rw.append(("cycles", cyc_min, f"only {cyc_min:.1f} cycles above the noise floor "
                                          f"for some plants (< {st.min_cycles:g})"))
        if rings and not ev.in_band[i]:
            rw.append(("band", float(ev.zeta[i, 0]), f"ζ {ev.zeta[i, 0]:.3g} outside the "
                                                     f"band {zlo:g}–{zhi:g}"))
        if not np.all(ev.ok_freq[i] | ~np.isfinite(ev.s[i])):
            rw.append(("bandwidth", 0.0, f"ω_d above the bandwidth limit "
                                         f"{st.omega_max:.4g} rad/s"))
        if not ev.ok_limits[i]:
            rw.append(("limits", 0.0, f"gains beyond the limits (|P| ≤ {st.pmax:g} N/m, "
                                      f"|D| ≤ {st.dmax:g} N s/m)"))
        margin_ok = (np.all(ev.dsamples[i] >= st.delay_margin_samples) if sampled
                     else np.all(ev.dmargin[i] >= st.delay_margin))
        safe = bool(np.all(ev.stable[i]) and np.all(ringing)
                    and np.all(ev.zeta[i] >= 0.5 * zlo) and margin_ok and ev.ok_limits[i])
        informative = bool(rings and ev.cycles[i, 0] >= st.min_cycles and ev.in_band[i]
                           and np.all(ev.ok_freq[i]))
        if math.isfinite(share[i]) and share[i] < 0.1 / P.size and safe and informative:
            rw.append(("share", float(share[i]),
                       f"adds little information (share {share[i]:.2g})"))
        for kind_, val, _msg in rw:
            found.setdefault(kind_, []).append((i + 1, val))
        finite_z = ev.zeta[i][np.isfinite(ev.zeta[i])]
        extra: dict[str, Any] = {}
        if sampled:
            least = float(np.min(ev.dsamples[i]))
            extra = {"delay_margin_samples": least,
                     "max_delay_samples": st.delay_samples + least,
                     "roots": tuple(complex(r) for r in nominal_roots[i])}
        runs.append(PlannedRun(
            P=float(P[i]), D=float(D[i]), sigma=float(sig_i) if rings else math.nan,
            omega_d=float(wd_i) if rings else math.nan,
            zeta=float(ev.zeta[i, 0]) if rings else math.nan,
            omega0=float(abs(si)) if rings else math.nan,
            cycles=float(ev.cycles[i, 0]) if rings else 0.0,
            amplitude=float(abs(ev.w[i, 0])) if rings else math.nan,
            sigma_stderr=sse, omega_d_stderr=wse,
            margin=float(np.nanmin(margin_all)) if np.any(np.isfinite(margin_all))
            else math.nan,
            delay_margin=float(np.min(ev.dmargin[i])),
            zeta_min=float(finite_z.min()) if finite_z.size else math.nan,
            zeta_max=float(finite_z.max()) if finite_z.size else math.nan,
            share=float(share[i]), safe=safe, informative=informative,
            warnings=tuple(msg for _k, _v, msg in rw), **extra,
        ))
    warnings.extend(_grouped(found, st, P.size))
    if not np.all(np.isfinite(np.diag(cov0))):
        warnings.append("the runs cannot determine m, c and k (fewer than two distinct ringing "
                        "runs): predicted stderr undetermined")
    se = np.sqrt(np.clip(np.diag(cov0), 0.0, None))
    worst_se = np.sqrt(np.clip(worst, 0.0, None))
    prior_info = dict(prior.given)
    prior_info["checked_ranges"] = dict(prior.ranges)
    return Design(
        runs=tuple(runs),
        m=Estimate(m0, float(se[0]), "kg"), c=Estimate(c0, float(se[1]), "N s/m"),
        k=Estimate(k0, float(se[2]), "N/m"), stderr_worst=worst_se, cov=cov0, settings=st,
        prior=prior_info, kind=kind, warnings=tuple(warnings), plants=prior.plants.copy(),
        roots=ev.s.copy(), bound=bound,
        modal_stderr=np.sqrt(np.clip(np.diag(modal0), 0.0, None)),
    )


def _evaluate_continuous(P: np.ndarray, D: np.ndarray, prior: Prior, st: DesignSettings):
    """The continuous loop's evaluation from the certified nominal roots (tracked over the
    prior grid; where tracking failed or another root is further right, the certified
    rightmost)."""
    m0, c0, k0 = prior.nominal
    s0 = np.array([_nominal_root(m0, c0, k0, float(p), float(d), st.delay)
                   for p, d in zip(P, D, strict=True)])
    ev = evaluate(P, D, s0, prior, st)
    s = ev.s.copy()
    redo = ~(ev.dominant)
    if np.any(redo):
        for i, g in zip(*np.nonzero(redo), strict=True):
            m, c, k = prior.plants[g]
            try:
                r = rightmost_roots(float(m), float(c), float(k), float(P[i]), float(D[i]),
                                     st.delay, count=2)[0]
            except RuntimeError:  # pathological loop: leave the root unknown (unsafe)
                continue
            s[i, g] = complex(r.real, abs(r.imag))
        ev = evaluate(P, D, s0, prior, st, s_grid=s)
    return ev


def _sampled_prediction(P, D, prior: Prior, st: DesignSettings, ev, info):
    """A sampled loop's prediction for its noise placement (:func:`predicted_covariance`) at
    every plant of the prior grid (over the runs stable there): the covariance and each run's
    information at the nominal plant, the bound's name, and the worst variances."""
    worst = np.zeros(3)
    cov0 = run0 = None
    bound = "modal"
    for g in range(prior.plants.shape[0]):
        keep = ev.stable[:, g]
        plant = tuple(float(x) for x in prior.plants[g])
        cov, run_info, bound = predicted_covariance(plant, P[keep], D[keep], st,
                                                    info[keep, g])
        if g == 0:
            cov0 = cov
            run0 = np.zeros((P.size, 3, 3))
            run0[keep] = run_info
        worst = np.maximum(worst, np.diag(cov))
    return cov0, run0, bound, worst


def _runs_text(items: list[tuple[int, float]]) -> str:
    """'run 3' or 'runs 1–4, 7' for the run numbers in ``items``."""
    nums = sorted(i for i, _ in items)
    parts, start = [], nums[0]
    for a, b in zip(nums, [*nums[1:], None], strict=True):
        if b != a + 1:
            parts.append(str(start) if start == a else f"{start}–{a}")
            start = b
    return ("run " if len(nums) == 1 else "runs ") + ", ".join(parts)


def _grouped(found: dict[str, list[tuple[int, float]]], st: DesignSettings, n: int) -> list[str]:
    """One warning per kind of problem, naming the runs and the worst value."""
    out = []
    for kind, items in found.items():
        runs = _runs_text(items)
        vals = [v for _, v in items]
        if kind == "unstable":
            out.append(f"{runs}: UNSTABLE for some plants of the prior (do not use them)")
        elif kind == "noring":
            out.append(f"{runs}: do not ring for some plants of the prior")
        elif kind == "damping":
            out.append(f"{runs}: barely damped for some plants of the prior (ζ down to "
                       f"{min(vals):.3g})")
        elif kind == "dmargin" and st.digital is not None:
            out.append(f"{runs}: delay margin down to {min(vals):g} samples "
                       f"(< {st.delay_margin_samples} samples)")
        elif kind == "dmargin":
            out.append(f"{runs}: delay margin down to {min(vals):.3g} s "
                       f"(< {st.delay_margin:.3g} s)")
        elif kind == "separation":
            out.append(f"{runs}: another loop mode decays less than {st.separation:g}× faster "
                       "than the ringing one for some plants")
        elif kind == "cycles":
            out.append(f"{runs}: as few as {min(vals):.1f} cycles above the noise floor for "
                       f"some plants of the prior (< {st.min_cycles:g})")
        elif kind == "band":
            out.append(f"{runs}: ζ at the nominal plant outside the band "
                       f"{st.zeta[0]:g}–{st.zeta[1]:g} ({min(vals):.3g} to {max(vals):.3g})")
        elif kind == "bandwidth":
            out.append(f"{runs}: ω_d above the bandwidth limit {st.omega_max:.4g} rad/s")
        elif kind == "limits":
            out.append(f"{runs}: gains beyond the limits |P| ≤ {st.pmax:g} N/m, "
                       f"|D| ≤ {st.dmax:g} N s/m")
        elif kind == "share":
            out.append(f"{runs}: add little information (share below {0.1 / n:.2g} each)")
    return out


def _nominal_root(m, c, k, P, D, delay) -> complex:
    """Certified rightmost root (Im ≥ 0) of one run at the nominal plant."""
    r = rightmost_roots(m, c, k, P, D, delay, count=2)[0]
    return complex(r.real, abs(r.imag))


def roots_in_range(func: Callable[..., Design]) -> Callable[..., Design]:
    """:func:`design` and :func:`check` with the loop-root computation's failure (a prior so far
    from the gains' scale that the roots cannot be certified: a unit mistake) as a DesignError
    that says so, instead of a RuntimeError."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except RuntimeError as exc:
            raise DesignError(
                f"the loop's roots cannot be computed for this prior plant and these gains "
                f"({exc}): a plant this far from the gains' scale is usually in other units "
                "(m in kg, c in N s/m, k in N/m; P in N/m, D in N s/m)") from None

    return wrapper
