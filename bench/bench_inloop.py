"""Noise inside the loop (issue 28): RMSE and stderr against the in-loop Cramér–Rao bound.

On a digital rig the controller reads the recorded, noisy and quantised encoder, so the sensor
noise enters the loop. This study simulates such sets with phoid's sampled-loop simulator
(``phoid.simulate(..., sample_time=T, delay_samples=d, noise_in_loop=True, quantum=q)``: at its
instants the controller reads exactly the recorded value), identifies every replica by both
routes of ``phoid.identify`` on the same records —

* **in-loop**: ``noise_placement="in-loop"``, the output error of the plant driven by the
  applied command reconstructed from the recorded positions;
* **modal**: ``noise_placement="outside"``, today's route (per-run decay fits, then the
  weighted fit of the modes through the exact loop roots);
* **auto** (the first ``--auto-replicas`` replicas only): no option, phoid chooses by the data;
  only which placement it chose is reported —

and judges them against the in-loop bound ``phoid.planning.inloop_cramer_rao`` evaluated for
the same plant, gains, loop, rate, record, noise, quantum, release and hold as the simulation.

Cases (one replica = one whole set, fresh noise; offset 0, released from rest after a 0.2 s
hold, backward-difference velocity, recorder at the controller's rate):

* **overdamped** — the README's plant m 0.5 kg, c 40 N s/m, k 20 N/m on a 1 kHz loop with
  d = 1, its gains from ``phoid.design`` (for the sampled loop where the design takes
  ``sample_time``; before that, the continuous design at the loop's equivalent delay
  (d + ½)T, checked to ring on the sampled loop), 10 s records, x₀ 10 mm, a 1 µm encoder with
  0.2 µm noise;
* **paper** — the seed paper's sweep (m 2 kg, c 1 N s/m, k 64 N/m, Pᵢ = 0.25 + 1.375 i N/m,
  Dᵢ = 0.6 + 0.3 i N s/m, i = 0 … 18) on a 1 kHz loop with a 100-sample delay, 15 s records,
  x₀ 10 mm, 10 µm noise and a 1 µm quantum;
* the same two with the noise **outside** the loop (``noise_in_loop=False``), identified by
  the modal route and judged against the outside bound (``inloop_cramer_rao(...,
  noise_in_loop=False)``): today's outside-loop figures on the same loops. The outside-loop
  sets of the "Accuracy at the physical limit" section are not recomputed here; the section
  quotes them from the same run (``make bench``) or from bench/results.json.

Per case, route and parameter: RMSE, the bound, RMSE / bound (95 % Monte Carlo interval), the
z-scores' (est − truth)/stderr mean and sd, coverage at 3 stderr, median stderr / bound; the
time per set is the median wall (and CPU) time of one identification, in the Monte Carlo (two
workers share the machine) and timed alone. Issue 28's acceptance is printed beside them for
the in-loop route: z sd in [0.75, 1.25], |z mean| ≤ 0.6, stderr ≤ 1.2 × the in-loop bound.

    python bench/bench_inloop.py --replicas 200   # the full study (writes its section)
    python bench/bench_inloop.py --replicas 20    # quick check (prints, writes nothing)
    python bench/bench_inloop.py --replicas 20 --write        # force the write
    python bench/bench_inloop.py --json r.json ...  /  --from r.json --write   # keep, report

A full run (≥ 200 replicas) splices the section "Noise inside the loop (issue 28)" into
BENCHMARKS.md and the results into bench/results.json (key "inloop"), as ``make bench`` does.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import datetime  # noqa: E402
import inspect  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from dataclasses import asdict, dataclass  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from sections import splice_section  # noqa: E402

import phoid  # noqa: E402
from phoid.dynamics.digital import DigitalPD, digital_roots  # noqa: E402
from phoid.io.records import ExperimentSet, run_from_arrays  # noqa: E402
from phoid.planning import inloop_cramer_rao  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

FULL_REPLICAS = 200  # issue 28: ≥ 200 replicas per case
QUICK_REPLICAS = 20
ENFORCE_MIN = 200  # fewer (a quick run): the targets are printed, not enforced
AUTO_REPLICAS = 30  # replicas also identified with the automatic choice (which route it takes)
SEED = 20270128
COVER = 3.0
# issue 28's acceptance for sets with the noise inside the loop
Z_SD_RANGE = (0.75, 1.25)
Z_MEAN_MAX = 0.6
SE_OVER_BOUND_MAX = 1.2
RMSE_TARGET = 1.1  # outside-loop reference: RMSE ≈ CRB (the project's ≤ 1.1 × CRB, issue 7)
ROUTES = {"in-loop": "in-loop", "modal": "outside", "auto": None}  # label: noise_placement
UNIT = {"m": "kg", "c": "N s/m", "k": "N/m"}
TITLE = "## Noise inside the loop (issue 28)"
CASE_NAMES = ("overdamped", "paper", "overdamped-outside", "paper-outside")  # cases()


@dataclass(frozen=True)
class Case:
    """One digital PHO set of the study (SI units)."""

    name: str
    label: str
    m: float
    c: float
    k: float
    P: tuple[float, ...]
    D: tuple[float, ...]
    sample_time: float
    delay_samples: int
    fs: float
    duration: float
    hold: float
    x0: float
    noise: float
    quantum: float
    noise_in_loop: bool
    gains_source: str
    velocity: str = "backward-difference"
    offset: float = 0.0

    @property
    def theta(self) -> np.ndarray:
        return np.array([self.m, self.c, self.k])

    @property
    def loop(self) -> DigitalPD:
        return DigitalPD(0.0, 0.0, self.sample_time, self.delay_samples, self.velocity)

    @property
    def sigma_eff(self) -> float:
        return math.sqrt(self.noise**2 + self.quantum**2 / 12.0)

    def routes(self) -> tuple[str, ...]:
        """The routes every replica is identified by (auto: only the first few)."""
        return ("in-loop", "modal") if self.noise_in_loop else ("modal",)

    def describe(self) -> str:
        P, D = np.asarray(self.P), np.asarray(self.D)
        return (f"m {self.m:g} kg, c {self.c:g} N s/m, k {self.k:g} N/m; {len(self.P)} runs, "
                f"P {P.min():.4g}…{P.max():.4g} N/m, D {D.min():.4g}…{D.max():.4g} N s/m "
                f"({self.gains_source}); T {self.sample_time * 1e3:g} ms, d {self.delay_samples}"
                f", {self.velocity}; {self.duration:g} s at {self.fs:g} Hz after a "
                f"{self.hold:g} s hold, x₀ {self.x0 * 1e3:g} mm; noise "
                f"{self.noise * 1e6:g} µm, quantum {self.quantum * 1e6:g} µm "
                f"(σ {self.sigma_eff * 1e6:.3g} µm), "
                + ("inside the loop" if self.noise_in_loop else "outside the loop"))


def design_takes_sample_time() -> bool:
    """Whether ``phoid.design`` designs for a sampled loop (issue 28's design helper)."""
    return "sample_time" in inspect.signature(phoid.design).parameters


def overdamped_gains(noise: float) -> tuple[np.ndarray, np.ndarray, str]:
    """The README plant's designed gains for a 1 kHz loop with d = 1, and where they came from.

    With a sampled-loop design: ``phoid.design(0.5, 40, 20, sample_time=0.001,
    delay_samples=1, noise=σ)``. Before it: the continuous design at the sampled loop's
    equivalent delay (d + ½)T = 1.5 ms. Either way every run must be stable and ring on the
    sampled loop (checked here with ``digital_roots``), or the study stops.
    """
    if design_takes_sample_time():
        d = phoid.design(0.5, 40, 20, sample_time=0.001, delay_samples=1, noise=noise,
                         fs=1000.0, duration=10.0)
        src = "phoid.design(0.5, 40, 20, sample_time=0.001, delay_samples=1, noise=σ)"
    else:
        d = phoid.design(0.5, 40, 20, delay=0.0015, noise=noise, fs=1000.0, duration=10.0)
        src = ("phoid.design(0.5, 40, 20, delay=0.0015, noise=σ): the continuous design at "
               "(d + ½)T; the sampled-loop design had not landed")
    P, D = np.asarray(d.P, dtype=float), np.asarray(d.D, dtype=float)
    roots = digital_roots(0.5, 40, 20, P, D, DigitalPD(0.0, 0.0, 0.001, 1))
    dom = np.asarray(roots.dominant)
    if not (np.all(roots.stable) and np.all(dom.imag > 0)):
        raise SystemExit("bench_inloop: the overdamped design does not ring stably on the "
                         "sampled loop")
    return P, D, src


def cases() -> dict[str, Case]:
    """The study's four cases (two in the loop, their outside-loop twins)."""
    noise_a, quantum_a = 2e-7, 1e-6
    P, D, src = overdamped_gains(math.sqrt(noise_a**2 + quantum_a**2 / 12.0))
    i = np.arange(19)
    Pp, Dp = 0.25 + 1.375 * i, 0.6 + 0.3 * i
    a = {"m": 0.5, "c": 40.0, "k": 20.0, "P": tuple(P.tolist()), "D": tuple(D.tolist()),
         "sample_time": 1e-3, "delay_samples": 1, "fs": 1000.0, "duration": 10.0,
         "hold": 0.2, "x0": 0.01, "noise": noise_a, "quantum": quantum_a, "gains_source": src}
    b = {"m": 2.0, "c": 1.0, "k": 64.0, "P": tuple(Pp.tolist()), "D": tuple(Dp.tolist()),
         "sample_time": 1e-3, "delay_samples": 100, "fs": 1000.0, "duration": 15.0,
         "hold": 0.2, "x0": 0.01, "noise": 1e-5, "quantum": 1e-6,
         "gains_source": "the seed paper's 19 gains"}
    return {
        "overdamped": Case("overdamped", "overdamped, noise in the loop", noise_in_loop=True,
                           **a),
        "paper": Case("paper", "paper sweep, noise in the loop", noise_in_loop=True, **b),
        "overdamped-outside": Case("overdamped-outside", "overdamped, noise outside",
                                   noise_in_loop=False, **a),
        "paper-outside": Case("paper-outside", "paper sweep, noise outside",
                              noise_in_loop=False, **b),
    }


# --------------------------------------------------------------------------------------------
# one replica


def simulate_set(case: Case, rng: np.random.Generator, error: dict | None = None
                 ) -> ExperimentSet:
    """One noisy replica of the case as a pho experiment set with a digital [loop]; ``error``
    (a dict) receives the recorded error x̃ − x after the release: its sd over the bound's σ
    and its lag-1 autocorrelation (white quantisation: 1 and 0)."""
    P, D = np.asarray(case.P), np.asarray(case.D)
    sim = phoid.simulate(phoid.Plant(case.m, case.c, case.k), P, D, duration=case.duration,
                         fs=case.fs, x0=case.x0, hold=case.hold, noise=case.noise,
                         quantum=case.quantum, offset=case.offset, rng=rng,
                         sample_time=case.sample_time, delay_samples=case.delay_samples,
                         velocity=case.velocity, noise_in_loop=case.noise_in_loop)
    if error is not None:
        e = (sim.x - sim.x_true)[:, round(case.hold * case.fs):]
        e = e - e.mean(axis=1, keepdims=True)
        error["sd_over_sigma"] = float(np.sqrt(np.mean(e**2))) / case.sigma_eff
        error["acf1"] = float(np.sum(e[:, 1:] * e[:, :-1]) / np.sum(e * e))
    runs = tuple(run_from_arrays(sim.t, sim.x[i], P=float(P[i]), D=float(D[i]), index=i + 1,
                                 file=f"run{i + 1:02d}.csv") for i in range(P.size))
    loop = {"sample_time": case.sample_time, "delay_samples": case.delay_samples,
            "velocity": case.velocity}
    return ExperimentSet(Path(f"{case.name}/experiment.toml"), runs, method="pho", loop=loop)


def identify_once(exp: ExperimentSet, placement: str | None) -> dict[str, Any]:
    """One identification: estimates, stderr, warnings, the placement used, wall and CPU s."""
    w0, c0 = time.perf_counter(), time.process_time()
    try:
        r = phoid.identify(exp) if placement is None else \
            phoid.identify(exp, noise_placement=placement)
    except Exception as exc:  # a failure is counted, not fatal
        return {"error": f"{type(exc).__name__}: {exc}"[:300],
                "wall_s": time.perf_counter() - w0, "cpu_s": time.process_time() - c0}
    out = {"wall_s": time.perf_counter() - w0, "cpu_s": time.process_time() - c0,
           "est": [float(r.m.value), float(r.c.value), float(r.k.value)],
           "se": [float(r.m.stderr), float(r.c.stderr), float(r.k.stderr)],
           "wse": [float(e.stderr if getattr(e, "white_stderr", None) is None
                         else e.white_stderr) for e in (r.m, r.c, r.k)],
           "warnings": list(r.warnings),
           "placement": str(getattr(r, "noise_placement", "outside"))}
    return out


def replicas(job: tuple[Case, list[tuple[int, np.random.SeedSequence]], int]
             ) -> list[dict[str, Any]]:
    """Simulate and identify some replicas of one case (runs in a worker process)."""
    case, seeds, auto_n = job
    out = []
    for i, ss in seeds:
        err: dict[str, float] = {}
        exp = simulate_set(case, np.random.default_rng(ss), err)
        rec: dict[str, Any] = {"i": i, "error": err}
        for route in case.routes():
            rec[route] = identify_once(exp, ROUTES[route])
        if i < auto_n:
            rec["auto"] = identify_once(exp, None)
        out.append(rec)
    return out


# --------------------------------------------------------------------------------------------
# statistics


def warning_kind(text: str) -> str:
    """A warning's kind: its words before the first number, parenthesis or colon, without a
    leading run name (``run 3 (run03.csv): ``)."""
    text = re.sub(r"^run \d+ \([^)]*\): ", "", text)
    return re.split(r"[(:]|\s[-+]?\d|\d", text, maxsplit=1)[0].strip(" ,;.") or text[:60]


def _vec(a: Any) -> dict[str, float]:
    return dict(zip("mck", (float(v) for v in a), strict=True))


def summarise(case: Case, recs: list[dict[str, Any]], route: str, bound: np.ndarray
              ) -> dict[str, Any]:
    """Per parameter: RMSE (95 % interval), RMSE / bound, bias, z mean and sd, ±3 stderr
    coverage, median stderr / bound; per route: fails, warned, placements, times."""
    rows = [r[route] for r in recs if route in r]
    ok = [r for r in rows if "est" in r]
    out: dict[str, Any] = {
        "replicas": len(rows), "n": len(ok), "failed": len(rows) - len(ok),
        "errors": sorted({r["error"] for r in rows if "error" in r})[:3],
        "warned": sum(bool(r["warnings"]) for r in ok),
        "placements": {p: sum(r["placement"] == p for r in ok)
                       for p in sorted({r["placement"] for r in ok})},
        "wall_s_median": float(np.median([r["wall_s"] for r in rows])) if rows else math.nan,
        "cpu_s_median": float(np.median([r["cpu_s"] for r in rows])) if rows else math.nan,
    }
    counts: dict[str, int] = {}
    for r in ok:
        for k in {warning_kind(w) for w in r["warnings"]}:
            counts[k] = counts.get(k, 0) + 1
    out["warnings_seen"] = sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))[:4]
    n = len(ok)
    if n < 3:
        return out
    est = np.array([r["est"] for r in ok])
    se = np.array([r["se"] for r in ok])
    err = est - case.theta
    ms = np.mean(err**2, axis=0)
    ms_se = np.std(err**2, axis=0, ddof=1) / math.sqrt(n)
    z = err / np.where(se > 0, se, np.nan)
    wse = np.array([r["wse"] for r in ok])
    zw = err / np.where(wse > 0, wse, np.nan)
    out.update({
        "bias": _vec(err.mean(axis=0)),
        "rmse": _vec(np.sqrt(ms)),
        "rmse_over_bound": _vec(np.sqrt(ms) / bound),
        "rmse_over_bound_95ci": {
            q: [float(math.sqrt(max(ms[j] - 1.96 * ms_se[j], 0.0)) / bound[j]),
                float(math.sqrt(ms[j] + 1.96 * ms_se[j]) / bound[j])]
            for j, q in enumerate("mck")},
        "z_mean": _vec(np.nanmean(z, axis=0)),
        "z_sd": _vec(np.nanstd(z, axis=0, ddof=1)),
        "z_max_abs": _vec(np.nanmax(np.abs(z), axis=0)),
        "coverage_3se": _vec(np.mean(np.abs(err) < COVER * np.where(np.isfinite(se), se, 0.0),
                                     axis=0)),
        "se_median_over_bound": _vec(np.median(se, axis=0) / bound),
        "white_se_median_over_bound": _vec(np.median(wse, axis=0) / bound),
        "z_white_mean": _vec(np.nanmean(zw, axis=0)),
        "z_white_sd": _vec(np.nanstd(zw, axis=0, ddof=1)),
        "coverage_3se_white": _vec(np.mean(
            np.abs(err) < COVER * np.where(np.isfinite(wse), wse, 0.0), axis=0)),
        "sd_over_bound": _vec(est.std(axis=0, ddof=1) / bound),
    })
    return out


def timing(case: Case, repeats: int, seed: int = 7) -> dict[str, Any]:
    """Time per set, alone in this process: one replica identified by each route once untimed,
    then ``repeats`` interleaved rounds; medians (min–max) of wall and CPU time, and each
    route's time over the modal route's (median of the per-round ratios)."""
    exp = simulate_set(case, np.random.default_rng(seed))
    routes = case.routes()
    for r in routes:
        identify_once(exp, ROUTES[r])
    wall: dict[str, list[float]] = {r: [] for r in routes}
    cpu: dict[str, list[float]] = {r: [] for r in routes}
    for _ in range(repeats):
        for r in routes:
            o = identify_once(exp, ROUTES[r])
            wall[r].append(o["wall_s"])
            cpu[r].append(o["cpu_s"])
    base = np.array(cpu["modal"])
    return {r: {"wall_median_s": float(np.median(wall[r])), "wall_min_s": float(min(wall[r])),
                "wall_max_s": float(max(wall[r])), "cpu_median_s": float(np.median(cpu[r])),
                "cpu_over_modal": float(np.median(np.array(cpu[r]) / base)),
                "samples": int(sum(run.n for run in exp.runs))}
            for r in routes}


def _revision() -> dict[str, Any]:
    """The commit the study ran on and the files of phoid that differed from it."""
    import subprocess

    def git(*a: str) -> str:
        try:
            return subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True,
                                  timeout=30, check=True).stdout.rstrip("\n")
        except (OSError, subprocess.SubprocessError):
            return ""

    src = Path(phoid.__file__).resolve().parent
    if not src.is_relative_to(ROOT / "src"):
        return {"commit": None, "source": str(src), "modified": []}
    mod = git("status", "--porcelain", "--", "src/phoid")
    return {"commit": git("rev-parse", "--short", "HEAD"),
            "modified": mod.split("\n") if mod else []}


def targets(res: dict[str, Any]) -> list[dict[str, Any]]:
    """run.py's targets (``name``, ``ok``, ``got``, ``enforced``): issue 28's acceptance for the
    in-loop route on the in-loop cases (enforced from ENFORCE_MIN replicas), and RMSE ≤ 1.1 ×
    the outside bound for the modal route on the outside cases (reported)."""
    out = []
    full = res["setup"]["replicas"] >= ENFORCE_MIN
    for name, c in res["cases"].items():
        if c["noise_in_loop"]:
            s = c["routes"].get("in-loop", {})
            if "z_sd" not in s:
                out.append({"name": f"in-loop study, `{name}`: the in-loop route identifies "
                                    "the replicas", "ok": False,
                            "got": f"{s.get('failed', '?')} failed: "
                                   + "; ".join(s.get("errors", [])[:1]),
                            "enforced": full})
                continue
            zs, zm, sb = s["z_sd"], s["z_mean"], s["se_median_over_bound"]
            out.append({"name": f"in-loop study, `{name}`: z sd in [{Z_SD_RANGE[0]}, "
                                f"{Z_SD_RANGE[1]}]",
                        "ok": all(Z_SD_RANGE[0] <= zs[q] <= Z_SD_RANGE[1] for q in "mck"),
                        "got": ", ".join(f"{q} {zs[q]:.2f}" for q in "mck"), "enforced": full})
            out.append({"name": f"in-loop study, `{name}`: |z mean| ≤ {Z_MEAN_MAX}",
                        "ok": all(abs(zm[q]) <= Z_MEAN_MAX for q in "mck"),
                        "got": ", ".join(f"{q} {zm[q]:+.2f}" for q in "mck"), "enforced": full})
            out.append({"name": f"in-loop study, `{name}`: median stderr ≤ {SE_OVER_BOUND_MAX}"
                                " × the in-loop bound",
                        "ok": all(sb[q] <= SE_OVER_BOUND_MAX for q in "mck"),
                        "got": ", ".join(f"{q} {sb[q]:.2f}" for q in "mck"), "enforced": full})
        else:
            s = c["routes"].get("modal", {})
            if "rmse_over_bound" not in s:
                continue
            r = s["rmse_over_bound"]
            out.append({"name": f"in-loop study, `{name}` (noise outside): modal RMSE ≤ "
                                f"{RMSE_TARGET} × the outside bound",
                        "ok": max(r.values()) <= RMSE_TARGET,
                        "got": ", ".join(f"{q} {r[q]:.2f}" for q in "mck"), "enforced": False})
    return out


def run(replicas_per_case: int = FULL_REPLICAS, workers: int = 2, seed: int = SEED,
        auto_replicas: int = AUTO_REPLICAS, repeats: int = 5, only: list[str] | None = None,
        log=None) -> dict[str, Any]:
    """The whole study; ``log(msg)`` is called after each case."""
    t_start = time.perf_counter()
    all_cases = cases()
    chosen = {k: c for k, c in all_cases.items() if only is None or k in only}
    auto_n = min(auto_replicas, replicas_per_case)
    res: dict[str, Any] = {
        "setup": {"replicas": replicas_per_case, "auto_replicas": auto_n, "seed": seed,
                  "workers": workers, "timing_repeats": repeats,
                  "design_for_sampled_loop": design_takes_sample_time(),
                  "identify_has_noise_placement":
                      "noise_placement" in inspect.signature(phoid.identify).parameters},
        "cases": {}, "phoid": _revision(),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }
    for ci, (name, case) in enumerate(all_cases.items()):
        if name not in chosen:
            continue
        t0 = time.perf_counter()
        P, D = np.asarray(case.P), np.asarray(case.D)
        kw = {"fs": case.fs, "duration": case.duration, "noise": case.noise,
              "quantum": case.quantum, "x0": case.x0, "hold": case.hold}
        inside = inloop_cramer_rao(case.m, case.c, case.k, P, D, case.loop, noise_in_loop=True,
                                   **kw).stderr
        outside = inloop_cramer_rao(case.m, case.c, case.k, P, D, case.loop,
                                    noise_in_loop=False, **kw).stderr
        bound = inside if case.noise_in_loop else outside
        seeds = list(enumerate(np.random.SeedSequence([seed, ci]).spawn(replicas_per_case)))
        nchunk = max(workers, 1) * 4
        jobs = [(case, seeds[j::nchunk], auto_n) for j in range(nchunk) if seeds[j::nchunk]]
        if workers > 1:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                parts = list(pool.map(replicas, jobs))
        else:
            parts = [replicas(j) for j in jobs]
        recs = sorted((r for part in parts for r in part), key=lambda r: r["i"])
        routes = {r: summarise(case, recs, r, bound) for r in (*case.routes(), "auto")}
        errs = [r["error"] for r in recs]
        mc_wall = time.perf_counter() - t0
        res["cases"][name] = {
            "label": case.label, "description": case.describe(), "spec": asdict(case),
            "noise_in_loop": case.noise_in_loop, "truth": _vec(case.theta),
            "bound": _vec(bound), "bound_inloop": _vec(inside), "bound_outside": _vec(outside),
            "routes": routes, "timing": timing(case, repeats), "wall_s": mc_wall,
            "record_error": {k: float(np.median([e[k] for e in errs]))
                             for k in ("sd_over_sigma", "acf1")},
        }
        if log:
            log(f"in-loop study: {name} ({mc_wall:.0f} s)")
    res["targets"] = targets(res)
    res["wall_s"] = time.perf_counter() - t_start
    res["load_average"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    return res


# --------------------------------------------------------------------------------------------
# BENCHMARKS.md


def _f(x: float | None, fmt: str = ".2f") -> str:
    return "–" if x is None or not math.isfinite(x) else format(x, fmt)


def _outside_today(mc: dict | None) -> list[str]:
    """One line per set of the "Accuracy at the physical limit" section (phoid's RMSE / CRB
    and coverage), quoted, not recomputed."""
    if not mc:
        return []
    parts = []
    for name, m in mc.items():
        ph = m.get("phoid", {})
        if "rmse_over_crb" not in ph:
            continue
        r, cov = ph["rmse_over_crb"], ph["coverage_3se"]
        parts.append(f"{name} ({ph['n']} replicas): RMSE / CRB "
                     + ", ".join(f"{q} {r[q]:.2f}" for q in "mck")
                     + "; ±3 stderr coverage "
                     + ", ".join(f"{q} {cov[q]:.1%}" for q in "mck"))
    return parts


def _record_error(c: dict[str, Any]) -> str:
    """The records' sensor error against the bound's white-noise model (median over the
    replicas), or nothing for older results."""
    e = c.get("record_error")
    if not e:
        return ""
    return (f" Recorded error x̃ − x after the release (median over the replicas): sd "
            f"{e['sd_over_sigma']:.2f} × the bound's σ, lag-1 autocorrelation {e['acf1']:.3f}"
            " (1 and 0 if the quantiser's error were white, of variance q²/12).")


def section(res: dict[str, Any] | None, monte_carlo: dict | None = None) -> list[str]:
    """BENCHMARKS.md's section for :func:`run`'s results; ``monte_carlo``: the "Accuracy at the
    physical limit" results (``results.json``'s ``monte_carlo``) to quote beside them."""
    if not res or not res.get("cases"):
        return []
    su = res["setup"]
    lines = [
        TITLE,
        "",
        "`bench/bench_inloop.py` (`make bench`, or `python bench/bench_inloop.py --replicas "
        f"{su['replicas']}`). Digital PD loops whose controller reads the recorded, noisy and "
        "quantised position (`phoid.simulate(..., sample_time, delay_samples, "
        "noise_in_loop=True, quantum)`), "
        f"{su['replicas']} replicas per case (a whole set each, fresh noise), every replica "
        "identified by `phoid.identify` twice on the same records: **in-loop** "
        "(`noise_placement=\"in-loop\"`: output error of the plant driven by the applied "
        "command) and **modal** (`noise_placement=\"outside\"`: today's route, the runs' modes "
        "through the exact loop roots). Bound: `phoid.planning.inloop_cramer_rao` for the "
        "same plant, gains, loop, rate, record, noise, quantum, release and hold (in-loop for "
        "the in-loop cases; `noise_in_loop=False`, the sampled loop's dominant-mode bound, for "
        "the outside ones). z = (estimate − truth)/stderr; coverage: share with |z| < 3; "
        "se / bound: the median reported stderr over the bound (white se: the "
        "white-noise stderr `Estimate.white_stderr`, before the misfit and agreement "
        "inflations; white z sd: the z-scores' sd with it); sd / bound: the estimates' "
        "spread over the bound. Time per set: median wall (CPU) time of one identification "
        "in the Monte Carlo, two workers sharing the machine.",
        "",
    ]
    for name, c in res["cases"].items():
        bi, bo = c["bound_inloop"], c["bound_outside"]
        lines += [f"### {c['label']} (`{name}`)", "", c["description"] + ".", "",
                  "Bounds (sd): in-loop " + ", ".join(f"{q} {bi[q]:.3g} {UNIT[q]}" for q in "mck")
                  + "; outside " + ", ".join(f"{q} {bo[q]:.3g}" for q in "mck")
                  + "; in-loop / outside " + ", ".join(f"{q} {bi[q] / bo[q]:.2f}" for q in "mck")
                  + ". Judged against the " + ("in-loop" if c["noise_in_loop"] else "outside")
                  + " bound." + _record_error(c), "",
                  "| route | n | | RMSE | RMSE / bound (95 %) | sd / bound | z mean | z sd "
                  "| ±3 se coverage | se / bound | white se / bound | white z sd "
                  "| fails / warned | time per set |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for route, s in c["routes"].items():
            if route == "auto":
                continue
            if "rmse" not in s:
                err = "; ".join(s.get("errors", [])[:1]) or "no replicas"
                lines.append(f"| {route} | {s.get('n', 0)} | | failed ({s.get('failed', 0)}):"
                             f" {err} | | | | | | | | | | |")
                continue
            for j, q in enumerate("mck"):
                lo, hi = s["rmse_over_bound_95ci"][q]
                head = (route, str(s["n"])) if j == 0 else ("", "")
                tail = (f"{s['failed']} / {s['warned']}",
                        f"{s['wall_s_median']:.2f} s ({s['cpu_s_median']:.2f})") \
                    if j == 0 else ("", "")
                zs, zm, sb = s["z_sd"][q], s["z_mean"][q], s["se_median_over_bound"][q]
                mark = c["noise_in_loop"] and route == "in-loop"
                zs_t = f"**{zs:.2f}**" if mark and not Z_SD_RANGE[0] <= zs <= Z_SD_RANGE[1] \
                    else f"{zs:.2f}"
                zm_t = f"**{zm:+.2f}**" if mark and abs(zm) > Z_MEAN_MAX else f"{zm:+.2f}"
                sb_t = f"**{sb:.2f}**" if mark and sb > SE_OVER_BOUND_MAX else f"{sb:.2f}"
                lines.append(
                    f"| {head[0]} | {head[1]} | {q} | {s['rmse'][q]:.3g} {UNIT[q]} | "
                    f"{s['rmse_over_bound'][q]:.2f} ({lo:.2f}–{hi:.2f}) | "
                    f"{s['sd_over_bound'][q]:.2f} | {zm_t} | {zs_t} | "
                    f"{s['coverage_3se'][q]:.1%} | {sb_t} | "
                    f"{_f(s.get('white_se_median_over_bound', {}).get(q))} | "
                    f"{_f(s.get('z_white_sd', {}).get(q))} | {tail[0]} | {tail[1]} |")
        au = c["routes"].get("auto", {})
        if au.get("replicas"):
            pl = ", ".join(f"{p} {n}" for p, n in au.get("placements", {}).items()) or "none"
            lines += ["", f"Automatic choice (no option, no manifest key) on the first "
                          f"{au['replicas']} replicas: {pl}"
                      + (f"; {au['failed']} failed" if au.get("failed") else "")
                      + f"; median {au['wall_s_median']:.2f} s per set."]
        tm = c["timing"]
        lines += ["", "Timed alone (one replica, "
                  f"{su['timing_repeats']} rounds after an untimed call): "
                  + "; ".join(f"{r} {t['wall_median_s']:.2f} s wall ({t['wall_min_s']:.2f}–"
                              f"{t['wall_max_s']:.2f}), {t['cpu_median_s']:.2f} s CPU, "
                              f"{t['cpu_over_modal']:.2f}× the modal route's CPU"
                              for r, t in tm.items())
                  + f" ({next(iter(tm.values()))['samples']} samples)."]
        warn = []
        for route, s in c["routes"].items():
            if s.get("warnings_seen"):
                warn.append(f"{route}: " + "; ".join(f"“{k}” ({n})"
                                                       for k, n in s["warnings_seen"]))
        if warn:
            lines += ["", "Warnings (replicas carrying each kind): " + " — ".join(warn) + "."]
        lines.append("")
    today = _outside_today(monte_carlo)
    if today:
        lines += ["Today's outside-loop figures (the section \"Accuracy at the physical "
                  "limit\", continuous-delay sets with the noise outside the loop, phoid's "
                  "modal route; quoted, not recomputed): " + "; ".join(today) + ".", ""]
    tg = res.get("targets") or targets(res)
    lines += [f"Issue 28's acceptance (judged from {ENFORCE_MIN} replicas per case; the "
              "in-loop route on the in-loop cases; the outside cases against RMSE ≤ "
              f"{RMSE_TARGET} × their bound, reported):", ""]
    lines += [f"- {'met' if t['ok'] else '**NOT MET**'}: {t['name']} ({t['got']})"
              + ("" if t["enforced"] else " [not enforced]") for t in tg]
    rev = res.get("phoid", {})
    mod = rev.get("modified") or []
    where = (f"commit {rev['commit']}" if rev.get("commit")
             else f"the copy in {rev['source']}" if rev.get("source") else "unknown")
    lines += ["", f"Whole study on {res['date']}: {res['wall_s']:.0f} s on {su['workers']} "
              f"workers; phoid at {where}"
              + (f" with {len(mod)} modified file(s) under src/phoid" if mod else "") + "."]
    return lines



def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--replicas", type=int, default=FULL_REPLICAS,
                    help=f"replicas per case ({FULL_REPLICAS}; {QUICK_REPLICAS} for a check)")
    ap.add_argument("--auto-replicas", type=int, default=AUTO_REPLICAS,
                    help=f"replicas also identified with the automatic choice ({AUTO_REPLICAS})")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=5, help="timing rounds per case (5)")
    ap.add_argument("--cases", default=None,
                    help="comma-separated case names (all: overdamped, paper, "
                         "overdamped-outside, paper-outside)")
    ap.add_argument("--json", type=Path, default=None, help="also write the results here")
    ap.add_argument("--from", dest="source", type=Path, default=None,
                    help="report the results a previous run wrote with --json (no new run)")
    ap.add_argument("--write", action="store_true",
                    help="splice the section into BENCHMARKS.md and the results into "
                         "bench/results.json (key \"inloop\") even for fewer than "
                         f"{FULL_REPLICAS} replicas or some cases")
    ap.add_argument("--no-write", action="store_true", help="never write")
    args = ap.parse_args()
    if args.replicas < 3 or args.workers < 1 or args.repeats < 1 or args.auto_replicas < 0:
        ap.error("--replicas must be ≥ 3, --workers and --repeats ≥ 1, --auto-replicas ≥ 0")
    names = CASE_NAMES
    only = args.cases.split(",") if args.cases else None
    if only and sorted(set(only) - set(names)):
        ap.error(f"--cases: unknown {', '.join(sorted(set(only) - set(names)))}")
    t0 = time.perf_counter()

    def log(msg: str) -> None:
        print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    if args.source:
        try:
            res = json.loads(args.source.read_text())
        except (OSError, ValueError) as exc:
            ap.error(f"--from {args.source}: cannot be read ({exc})")
        if not isinstance(res, dict) or not {"cases", "setup"} <= set(res):
            ap.error(f"--from {args.source}: not a results file of this bench")
    else:
        res = run(args.replicas, args.workers, auto_replicas=args.auto_replicas,
                  repeats=args.repeats, only=only, log=log)
    rj = HERE / "results.json"
    allres = json.loads(rj.read_text()) if rj.is_file() else {}
    part = section(res, allres.get("monte_carlo"))
    print("\n".join(part))
    if args.json:
        args.json.write_text(json.dumps(res, indent=1, default=float))
    full = res["setup"]["replicas"] >= FULL_REPLICAS and len(res["cases"]) == len(names)
    if (args.write or full) and not args.no_write:
        md = ROOT / "BENCHMARKS.md"
        md.write_text(splice_section(md.read_text() if md.is_file() else "", TITLE, part))
        allres["inloop"] = res
        rj.write_text(json.dumps(allres, indent=1, default=float))
        print(f"wrote {md.name} (section \"{TITLE[3:]}\") and bench/results.json (\"inloop\")",
              file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
