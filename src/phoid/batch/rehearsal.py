"""A design rehearsed: simulated replicas of its sweep identified, set against its prediction.

Each replica simulates every run of the design's schedule — the designed gains (P, D) on the
design's nominal plant (m, c, k), with its loop, sample rate, record length, release
amplitude and white sensor noise (:func:`phoid.simulation.simulate`, in memory) — and
identifies it with the PHO pipeline (:func:`phoid.methods.identification.identify_pho_data`,
the loop known, as the design assumes). A design for a sampled loop is rehearsed on that loop
(its ``sample_time``, ``delay_samples``, ``velocity``, ``cutoff``) with the noise where the
design put it (``noise_in_loop``: the controller reads the noisy record, as on a rig, or the
true position), held for (d + taps)·T before the release (the hold the in-loop bound assumes:
the first command after the release is computable from the record); its records are
identified with that placement stated, as a set whose ``[loop] noise`` states it. Replica i
draws its noise from the i-th child of ``numpy.random.SeedSequence(seed).spawn(n)``: the
replicas are independent, and the same seed gives the same numbers wherever and in whatever
order they run.

Over the replicas that identify, for each of m, c, k with true value θ, estimates θ̂ᵢ and
reported stderrs sᵢ, and the design's Cramér–Rao prediction σ_CR:

* observed spread SD = √(Σ(θ̂ᵢ − mean)²/(n − 1)), its ratio to σ_CR, and the 95 % range
  of that ratio under a correct prediction, √(χ²_{n−1; 0.975}/(n − 1)) … √(χ²_{n−1; 0.025}/(n − 1))
  (normal estimates);
* bias = mean(θ̂ᵢ) − θ with its Monte Carlo error SD/√n;
* RMSE = √(mean((θ̂ᵢ − θ)²)), and its ratio to σ_CR (1 for an efficient, unbiased estimator);
* the mean reported stderr, and the coverage: the share of replicas with |θ̂ᵢ − θ| ≤ 3 sᵢ
  (0.9973 for normal estimates with correct stderrs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from phoid._notation import unit_text
from phoid.errors import PhoidError

__all__ = ["MAX_REPLICAS", "NOMINAL_COVERAGE", "ParameterRehearsal", "Rehearsal", "rehearse",
           "rehearse_replica"]

NOMINAL_COVERAGE = math.erf(3.0 / math.sqrt(2.0))
"""Pr(|N(0, 1)| ≤ 3) = 0.99730: the coverage of ±3 correct standard errors."""

MAX_REPLICAS = 100_000
"""The most replicas one rehearsal runs (its results are held in memory)."""

_NAMES = ("m", "c", "k")


@dataclass(frozen=True)
class ParameterRehearsal:
    """One parameter's predicted and observed uncertainty over the replicas.

    Attributes
    ----------
    name, unit : str
    true : float
        The value simulated (the design's nominal plant).
    predicted : float
        The design's Cramér–Rao standard error σ_CR.
    observed_sd : float
        SD of the estimates over the replicas.
    sd_ratio : float
        observed_sd / predicted.
    sd_ratio_range : (float, float)
        The 95 % range of sd_ratio when the prediction is right (χ² on n − 1 dof).
    mean_stderr : float
        Mean of the stderrs the identification reported.
    bias, bias_mc : float
        Mean error and its Monte Carlo standard error.
    rmse : float
        Root mean square error.
    rmse_ratio : float
        rmse / predicted.
    coverage : float
        Share of replicas whose error is within ±3 reported stderr.
    """

    name: str
    unit: str
    true: float
    predicted: float
    observed_sd: float
    sd_ratio: float
    sd_ratio_range: tuple[float, float]
    mean_stderr: float
    bias: float
    bias_mc: float
    rmse: float
    rmse_ratio: float
    coverage: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (non-finite numbers as null)."""

        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        out: dict[str, Any] = {key: num(getattr(self, key)) for key in (
            "true", "predicted", "observed_sd", "sd_ratio", "mean_stderr", "bias", "bias_mc",
            "rmse", "rmse_ratio", "coverage")}
        out["sd_ratio_range"] = [num(x) for x in self.sd_ratio_range]
        out["unit"] = self.unit
        return out


@dataclass(frozen=True)
class Rehearsal:
    """The result of :func:`rehearse`.

    Attributes
    ----------
    replicas : int
        Replicas simulated.
    identified : int
        Replicas that identified (the statistics are over these).
    seed : int
        The root seed: ``rehearse(design, replicas, seed=seed)`` repeats the numbers.
    parameters : tuple of ParameterRehearsal
        m, c, k.
    estimates, stderrs : ndarray, shape (identified, 3)
        Every identified replica's m, c, k and their reported stderrs, in replica order.
    errors : tuple of str
        The messages of the replicas that failed (``replica i: …``).
    warnings : tuple of str
    """

    replicas: int
    identified: int
    seed: int
    parameters: tuple[ParameterRehearsal, ...]
    estimates: np.ndarray
    stderrs: np.ndarray
    errors: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()

    def summary(self) -> dict[str, Any]:
        """JSON-ready dict: the counts, the seed, each parameter's statistics, the errors."""
        return {"replicas": self.replicas, "identified": self.identified, "seed": self.seed,
                "nominal_coverage": NOMINAL_COVERAGE,
                "parameters": {p.name: p.to_dict() for p in self.parameters},
                "errors": list(self.errors), "warnings": list(self.warnings)}

    def report(self) -> str:
        """The predicted stderr against the replicas' spread, bias and coverage, as text."""
        from phoid._notation import fit_width
        from phoid.reports.text import format_number, text_table

        lines = [f"rehearsal: {self.replicas} simulated replicas of the schedule "
                 f"(seed {self.seed}), {self.identified} identified", ""]
        def span(r: tuple[float, float]) -> str:
            return f"[{format_number(r[0], 3)}, {format_number(r[1], 3)}]"

        # SD/pred's 95 % range once below the table when it is the same for every parameter
        # (the same number of replicas identified), else a column of its own
        ranges = {span(p.sd_ratio_range) for p in self.parameters}
        own = len(ranges) > 1
        rows = [[f"{p.name} ({unit_text(p.unit)})", f"{p.true:.4g}", f"{p.predicted:.3g}",
                 f"{p.observed_sd:.3g}", format_number(p.sd_ratio, 3),
                 *([span(p.sd_ratio_range)] if own else []), f"{p.mean_stderr:.3g}",
                 f"{p.bias:.2g} ± {p.bias_mc:.2g}", format_number(p.rmse_ratio, 3),
                 f"{100 * p.coverage:.1f}"] for p in self.parameters]
        # a header of two rows: each column's name and what it is of (a row's unit is in its
        # label; SD/pred, RMSE/pred and the coverage have none)
        lines += text_table([("", ""), ("true", ""), ("predicted", "stderr"),
                             ("observed", "SD"), ("SD/", "pred"),
                             *([("95% if", "right")] if own else []), ("mean", "stderr"),
                             ("bias", "± MC error"), ("RMSE/", "pred"), ("cover", "±3 (%)")],
                            rows, indent=0)
        if ranges and not own:
            lines.append(f"(SD/pred: within {ranges.pop()} in 95 % of rehearsals where the "
                         "predicted stderrs are right)")
        lines.append(f"(cover ±3: the share of replicas within 3 reported stderr, "
                     f"{100 * NOMINAL_COVERAGE:.2f} % if the stderrs are right)")
        lines += [f"warning: {w}" for w in self.warnings]
        return fit_width("\n".join(lines))


def _spec(design: Any) -> dict[str, Any]:
    """What a replica needs of a design (small, picklable): plant, gains, settings, and a
    sampled loop's keys with the noise placement."""
    s = design.settings
    spec = {"m": float(design.m.value), "c": float(design.c.value), "k": float(design.k.value),
            "P": np.asarray(design.P, float), "D": np.asarray(design.D, float),
            "delay": float(s.delay), "duration": float(s.duration), "fs": float(s.fs),
            "amplitude": float(s.amplitude), "noise": float(s.noise)}
    if getattr(s, "sample_time", None) is not None:
        spec.update(sample_time=float(s.sample_time), delay_samples=int(s.delay_samples),
                    velocity=s.velocity, cutoff=s.cutoff, noise_in_loop=bool(s.noise_in_loop))
    return spec


def rehearse_replica(spec: dict[str, Any], seed: np.random.SeedSequence
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Simulate one replica of a schedule and identify it.

    Parameters
    ----------
    spec : dict
        ``m``, ``c``, ``k`` (the plant: kg, N·s/m, N/m), ``P``, ``D`` (the runs' gains, N/m
        and N·s/m), ``delay`` (s), ``duration`` (s), ``fs`` (Hz), ``amplitude`` (release
        position, m) and ``noise`` (sensor noise SD, m); for a sampled loop also
        ``sample_time`` (s), ``delay_samples``, ``velocity``, ``cutoff`` (rad/s or None) and
        ``noise_in_loop``.
    seed : numpy.random.SeedSequence
        The replica's seed.

    Returns
    -------
    (ndarray, ndarray)
        The estimates of (m, c, k) and their reported stderrs.

    Raises
    ------
    IdentificationError
        When the replica's records do not determine m, c, k.
    """
    from phoid.dynamics import Plant
    from phoid.dynamics.digital import DigitalPD
    from phoid.methods.identification import identify_pho_data
    from phoid.simulation import simulate

    rng = np.random.default_rng(seed)
    plant = Plant(spec["m"], spec["c"], spec["k"])
    if spec.get("sample_time") is not None:
        loop = DigitalPD(0.0, 0.0, spec["sample_time"], spec["delay_samples"],
                         spec["velocity"], spec["cutoff"])
        hold = (loop.delay_samples + loop.estimator.taps) * loop.sample_time
        sim = simulate(plant, spec["P"], spec["D"], duration=spec["duration"], fs=spec["fs"],
                       x0=spec["amplitude"], noise=spec["noise"], rng=rng, hold=hold,
                       sample_time=loop.sample_time, delay_samples=loop.delay_samples,
                       velocity=loop.velocity, cutoff=loop.cutoff,
                       noise_in_loop=spec["noise_in_loop"])
        placement = "in-loop" if spec["noise_in_loop"] else "outside"
        result = identify_pho_data([(sim.t, sim.x[i]) for i in range(len(spec["P"]))],
                                   spec["P"], spec["D"], None, digital=loop, stated=placement)
    else:
        sim = simulate(plant, spec["P"], spec["D"], delay=spec["delay"],
                       duration=spec["duration"], fs=spec["fs"], x0=spec["amplitude"],
                       noise=spec["noise"], rng=rng)
        result = identify_pho_data([(sim.t, sim.x[i]) for i in range(len(spec["P"]))],
                                   spec["P"], spec["D"], spec["delay"])
    est = [getattr(result, n) for n in _NAMES]
    return (np.array([e.value for e in est], float),
            np.array([np.nan if e.stderr is None else e.stderr for e in est], float))


def _replica_task(item: tuple[dict[str, Any], np.random.SeedSequence]
                  ) -> tuple[np.ndarray, np.ndarray]:
    return rehearse_replica(*item)


def _statistics(name: str, unit: str, true: float, predicted: float, est: np.ndarray,
                se: np.ndarray) -> ParameterRehearsal:
    """One parameter's statistics over the identified replicas (the module's equations)."""
    from phoid.methods.chi2 import chi2_isf

    n = len(est)
    err = est - true
    sd = float(np.std(est, ddof=1)) if n > 1 else math.nan
    if n > 1:
        dof = n - 1
        rng = (math.sqrt(chi2_isf(0.975, dof) / dof), math.sqrt(chi2_isf(0.025, dof) / dof))
    else:
        rng = (math.nan, math.nan)
    rmse = float(np.sqrt(np.mean(err ** 2)))
    pred = predicted if predicted is not None and math.isfinite(predicted) else math.nan
    return ParameterRehearsal(
        name=name, unit=unit, true=true, predicted=pred, observed_sd=sd,
        sd_ratio=sd / pred, sd_ratio_range=rng, mean_stderr=float(np.nanmean(se)),
        bias=float(np.mean(err)), bias_mc=sd / math.sqrt(n), rmse=rmse, rmse_ratio=rmse / pred,
        coverage=float(np.mean(np.abs(err) <= 3 * se)))


def rehearse(design: Any, n: int, *, client: Any = None, seed: int | None = None) -> Rehearsal:
    """Rehearse a design: n simulated replicas of its schedule identified, against its prediction.

    Parameters
    ----------
    design : phoid.Design
        A design or a check (:func:`phoid.design`, :func:`phoid.planning.check_experiment`);
        read: the nominal plant ``m``, ``c``, ``k`` with their Cramér–Rao stderrs, the gains
        ``P``, ``D`` and ``settings`` (delay, fs, duration, amplitude, noise; a sampled loop's
        sample_time, delay_samples, velocity, cutoff and noise_in_loop).
    n : int
        Number of replicas, 2 to 100 000.
    client : distributed.Client, optional
        Run the replicas on this Dask cluster (:func:`phoid.batch.cluster.cluster_client`);
        None runs them one after another in this process.
    seed : int, optional
        The root of the replicas' seeds; None draws one (reported as ``Rehearsal.seed``).

    Returns
    -------
    Rehearsal

    Raises
    ------
    ValueError
        A bad ``n`` or ``seed``.
    PhoidError
        Fewer than two replicas identify.

    Examples
    --------
    >>> import phoid
    >>> plan = phoid.design(2, 1, 64, delay=0.1, noise=1e-4, runs=4)
    >>> r = phoid.rehearse(plan, 20, seed=1)
    >>> r.identified, r.parameters[2].name
    (20, 'k')
    """
    if isinstance(n, bool) or int(n) != n or not 2 <= n <= MAX_REPLICAS:
        raise ValueError(f"`n` (replicas) must be a whole number from 2 to {MAX_REPLICAS}; "
                         f"got {n!r}")
    n = int(n)
    if seed is not None and (isinstance(seed, bool) or int(seed) != seed or seed < 0):
        raise ValueError(f"`seed` must be a whole number ≥ 0; got {seed!r}")
    root = np.random.SeedSequence(seed)
    spec = _spec(design)
    items = [(spec, child) for child in root.spawn(n)]
    results: list[Any] = [None] * n
    if client is None:
        from phoid._progress import task

        with task("rehearsal", total=n) as advance:
            for i, item in enumerate(items):
                try:
                    results[i] = _replica_task(item)
                except ValueError as exc:  # phoid's errors: the replica did not identify
                    results[i] = exc
                advance()
    else:
        from phoid.batch.cluster import map_unordered

        for i, result in map_unordered(client, _replica_task, items, description="rehearsal"):
            results[i] = result
    for r in results:  # a fault of phoid's, not of a replica's data: not hidden in a count
        if isinstance(r, BaseException) and not isinstance(r, ValueError):
            raise r
    errors = tuple(f"replica {i + 1}: {' '.join(str(r).split())}"
                   for i, r in enumerate(results) if isinstance(r, BaseException))
    good = [r for r in results if not isinstance(r, BaseException)]
    if len(good) < 2:
        raise PhoidError(f"rehearsal: {len(good)} of {n} replicas identified; "
                         + (errors[0] if errors else ""))
    est = np.array([g[0] for g in good])
    se = np.array([g[1] for g in good])
    params = tuple(
        _statistics(name, getattr(design, name).unit, spec[name],
                    getattr(design, name).stderr or math.nan, est[:, j], se[:, j])
        for j, name in enumerate(_NAMES))
    warnings = []
    if errors:
        warnings.append(f"{len(errors)} of {n} replicas did not identify (first: {errors[0]}); "
                        "the statistics are over the others")
    return Rehearsal(replicas=n, identified=len(good), seed=int(root.entropy), parameters=params,
                     estimates=est, stderrs=se, errors=errors, warnings=tuple(warnings))
