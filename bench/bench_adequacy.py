"""Coverage of phoid's free-decay stderr on decays that break its model (issue 27).

An independent simulator (exact formulas, or ``scipy.integrate.solve_ivp`` at rtol 1e−12 where
there is none; never phoid's own) makes free decays of a 1 Hz oscillator released from rest at
x₀ = 10 mm — 20 s at 100 Hz, noise sd 10 µm (0.1 % of x₀) — that carry the defects of real
records, one at a time:

1. linear viscous decay, white noise (the control);
2. linear decay, coloured noise: AR(1) with ρ = 0.9 and 0.98, and 1/f (pink) noise;
3. Coulomb + viscous friction, with the stop (exact per half cycle), fitted with the viscous
   model and, where it exists, with the friction model (``--friction``);
4. amplitude-dependent damping (quadratic drag c₂|v|v) and stiffness (Duffing k₃x³).

Every replica is the same clean decay with fresh noise, so the spread of the estimates over the
replicas is the estimator's sampling spread, and its mean minus the truth is its bias. For each
case and parameter: the share of replicas with |error| < 3 stderr with the white-noise stderr
(``Estimate.white_stderr`` when set, else ``stderr``) and with the reported one (``stderr``: the
misfit- and autocorrelation-robust one once phoid reports it), the median ratio of the two, the
bias and the spread in stderr units, and, for the linear cases, the least-squares estimate's
exact sd under the noise's own covariance and the Cramér–Rao bound (both computed here from the
model's Jacobian, independently of phoid).

    python bench/bench_adequacy.py            # 500 replicas per case (~5–8 min, 2 workers)
    python bench/bench_adequacy.py --quick    # 40 replicas per case (a smoke run, ~20 s)
    python bench/bench_adequacy.py --write    # also splice its section into BENCHMARKS.md
                                              # and its results into bench/results.json
    python bench/bench_adequacy.py --json r.json      # keep the results ...
    python bench/bench_adequacy.py --from r.json --write   # ... and report them later
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import datetime  # noqa: E402
import functools  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402
from scipy.linalg import cho_factor, cho_solve  # noqa: E402
from sections import splice_section  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

FS = 100.0  # Hz
DURATION = 20.0  # s
N = round(FS * DURATION)
OMEGA0 = 2.0 * math.pi  # rad/s (1 Hz)
X0 = 0.01  # m, released from rest
NOISE = 1e-5  # m, marginal sd of every noise
FULL_REPLICAS = 500  # a 99 % coverage read to ±0.45 % (binomial sd)
QUICK_REPLICAS = 40
COVER = 3.0  # |error| < 3 stderr
TARGET = 0.99
ENFORCE_MIN = 300  # fewer replicas (a smoke run): coverage reported, not judged

# (name, description, plant, noise, fit, target); plant: dict of sigma (1/s, the viscous part
# c/2m), a (m/s², Coulomb f_c/m), q (1/m, quadratic drag c₂/m), d (1/(m² s²), Duffing k₃/m);
# target: issue 27's acceptance (coloured noise, Coulomb friction, amplitude-dependent damping)
# asks ≥ 99 % coverage of every parameter with a truth. The Duffing cases are reported only: a
# stiffness that changes with amplitude biases the viscous model's ω₀ away from its
# small-amplitude value by a fixed amount that no stderr of a noise spread can cover (the
# adequacy check's warning is the answer there), and the tiny one is kept as the detection
# limit's witness.
CASES: list[dict[str, Any]] = [
    {"name": "white", "label": "linear, white noise (control)",
     "plant": {"sigma": 0.05}, "noise": ("white",), "fit": "viscous", "target": True},
    {"name": "ar1-0.9", "label": "linear, AR(1) noise ρ = 0.9",
     "plant": {"sigma": 0.05}, "noise": ("ar1", 0.9), "fit": "viscous", "target": True},
    {"name": "ar1-0.98", "label": "linear, AR(1) noise ρ = 0.98",
     "plant": {"sigma": 0.05}, "noise": ("ar1", 0.98), "fit": "viscous", "target": True},
    {"name": "pink", "label": "linear, 1/f noise (flat below 0.05 Hz)",
     "plant": {"sigma": 0.05}, "noise": ("pink",), "fit": "viscous", "target": True},
    {"name": "coulomb", "label": "Coulomb + viscous friction, stops at 12.5 s; viscous fit",
     "plant": {"sigma": 0.02, "a": 0.007}, "noise": ("white",), "fit": "viscous", "target": True},
    {"name": "coulomb-friction", "label": "the same decays; friction fit (`--friction`)",
     "plant": {"sigma": 0.02, "a": 0.007}, "noise": ("white",), "fit": "friction", "target": True},
    {"name": "coulomb-mild", "label": "Coulomb + viscous, mild (no stop); viscous fit",
     "plant": {"sigma": 0.04, "a": 2e-4}, "noise": ("white",), "fit": "viscous", "target": True},
    {"name": "coulomb-mild-friction", "label": "the same mild decays; friction fit",
     "plant": {"sigma": 0.04, "a": 2e-4}, "noise": ("white",), "fit": "friction",
     "target": True},
    {"name": "quadratic", "label": "viscous + quadratic drag (σ_eq 0.02 + 0.05 at x₀)",
     "plant": {"sigma": 0.02, "q": 1.875}, "noise": ("white",), "fit": "viscous", "target": True},
    {"name": "duffing-tiny", "label": "Duffing, ω shift 3e−6 at x₀ (~2 stderr)",
     "plant": {"sigma": 0.05, "d": 8.0 * 3e-6 * OMEGA0**2 / (3.0 * X0**2)},
     "noise": ("white",), "fit": "viscous", "target": False},
    {"name": "duffing-small", "label": "Duffing, ω shift 1e−4 at x₀",
     "plant": {"sigma": 0.05, "d": 8.0 * 1e-4 * OMEGA0**2 / (3.0 * X0**2)},
     "noise": ("white",), "fit": "viscous", "target": False},
]


# --------------------------------------------------------------------------------------------
# the independent simulator


def time_grid() -> np.ndarray:
    return np.arange(N) / FS


def linear_decay(t: np.ndarray, sigma: complex, omega0: complex, x0: float = X0,
                 v0: float = 0.0) -> np.ndarray:
    """Exact x(t) of x'' + 2σx' + ω₀²x = 0 from (x0, v0) at t = 0 (complex-step safe)."""
    wd = np.sqrt(omega0**2 - sigma**2)
    return np.exp(-sigma * t) * (x0 * np.cos(wd * t) + (v0 + sigma * x0) / wd * np.sin(wd * t))


def coulomb_decay(t: np.ndarray, sigma: float, omega0: float, a: float,
                  x0: float = X0) -> tuple[np.ndarray, float]:
    """Exact x(t) of x'' + 2σx' + ω₀²x = −a·sign(v) released from rest at x0, and the stop
    time (inf if it does not stop within t).

    Between two velocity zeros the motion is the viscous one about the shifted equilibrium
    −a·s/ω₀² (s the sign of v), half a damped period long; at a velocity zero it sticks for good
    where the spring cannot beat the friction, |ω₀²x| ≤ a."""
    wd = math.sqrt(omega0**2 - sigma**2)
    half = math.pi / wd
    x = np.empty_like(t)
    t_n, x_n = 0.0, x0
    while True:
        sel = t >= t_n
        if abs(omega0**2 * x_n) <= a:
            x[sel] = x_n
            return x, t_n
        s = -math.copysign(1.0, x_n)
        xe = -a * s / omega0**2
        tau = t[sel] - t_n
        x[sel] = xe + (x_n - xe) * np.exp(-sigma * tau) * (np.cos(wd * tau)
                                                            + sigma / wd * np.sin(wd * tau))
        t_n += half
        x_n = xe - (x_n - xe) * math.exp(-sigma * half)
        if t_n > t[-1]:
            return x, math.inf


def ivp_decay(t: np.ndarray, sigma: float, omega0: float, q: float = 0.0,
              d: float = 0.0, x0: float = X0) -> np.ndarray:
    """x'' + 2σx' + ω₀²x + q|v|v + d·x³ = 0 from rest at x0: solve_ivp (DOP853, rtol 1e−12)."""
    def rhs(_t, y):
        x, v = y
        return (v, -2.0 * sigma * v - omega0**2 * x - q * abs(v) * v - d * x**3)

    sol = solve_ivp(rhs, (0.0, float(t[-1])), (x0, 0.0), method="DOP853", t_eval=t,
                    rtol=1e-12, atol=1e-12 * x0)
    if not sol.success:  # pragma: no cover - a failure of scipy, not of phoid
        raise RuntimeError(sol.message)
    return sol.y[0]


def coulomb_events(t: np.ndarray, sigma: float, omega0: float, a: float,
                   x0: float = X0) -> tuple[np.ndarray, float]:
    """The same as :func:`coulomb_decay` by solve_ivp, one slip direction at a time with a
    terminal event where v crosses 0 (the check of the exact formula; the stick rule alike)."""
    x = np.full_like(t, np.nan)
    t0, y = 0.0, (x0, 0.0)
    while t0 < t[-1] and abs(omega0**2 * y[0]) > a:
        s = -math.copysign(1.0, y[0])

        def turn(_t, yy):
            return yy[1]

        turn.terminal, turn.direction = True, -s
        sol = solve_ivp(lambda _t, yy, s=s: (yy[1], -2 * sigma * yy[1] - omega0**2 * yy[0]
                                             - a * s), (t0, float(t[-1])), y, method="DOP853",
                        events=turn, rtol=1e-12, atol=1e-12 * x0, dense_output=True)
        end = float(sol.t_events[0][0]) if sol.t_events[0].size else float(t[-1])
        sel = (t >= t0) & (t <= end)
        x[sel] = sol.sol(t[sel])[0]
        t0, y = end, (float(sol.sol(end)[0]), 0.0)
    x[t >= t0] = y[0] if t0 < t[-1] else x[t >= t0]
    return x, (t0 if t0 < t[-1] else math.inf)


@functools.cache
def clean(name: str) -> np.ndarray:
    """The noise-free decay of case ``name`` (the same for every replica)."""
    p = _case(name)["plant"]
    t = time_grid()
    if "a" in p:
        return coulomb_decay(t, p["sigma"], OMEGA0, p["a"])[0]
    if "q" in p or "d" in p:
        return ivp_decay(t, p["sigma"], OMEGA0, p.get("q", 0.0), p.get("d", 0.0))
    return linear_decay(t, p["sigma"], OMEGA0)


def _case(name: str) -> dict[str, Any]:
    return next(c for c in CASES if c["name"] == name)


# --------------------------------------------------------------------------------------------
# noise, and its covariance


def _pink_amplitude() -> np.ndarray:
    f = np.fft.rfftfreq(N, 1.0 / FS)
    amp = np.zeros_like(f)
    amp[1:] = 1.0 / np.sqrt(f[1:])
    amp[0] = amp[1]  # flat below the lowest frequency of the record (a finite variance)
    return amp


@functools.cache
def autocov(kind: tuple) -> np.ndarray:
    """The noise's autocovariance at lags 0 … N−1 (m²): exact for each generator below."""
    lag = np.arange(N)
    if kind[0] == "white":
        c = np.zeros(N)
        c[0] = 1.0
    elif kind[0] == "ar1":
        c = kind[1] ** lag
    else:  # circulant: the covariance of irfft(A·(g₁ + i g₂)/√2) is irfft(A²)/N
        c = np.fft.irfft(_pink_amplitude() ** 2, N) / N
        c = c / c[0]
    return NOISE**2 * c


def noise(kind: tuple, rng: np.random.Generator) -> np.ndarray:
    """One draw of stationary Gaussian noise of marginal sd NOISE."""
    if kind[0] == "white":
        return NOISE * rng.standard_normal(N)
    if kind[0] == "ar1":
        rho = kind[1]
        e = NOISE * math.sqrt(1.0 - rho**2) * rng.standard_normal(N)
        e[0] = NOISE * rng.standard_normal()
        out = np.empty(N)
        acc = 0.0
        for i in range(N):  # the stationary AR(1) recursion (N = 2000: cheap)
            acc = rho * acc + e[i] if i else e[0]
            out[i] = acc
        return out
    amp = _pink_amplitude()
    z = (rng.standard_normal(amp.size) + 1j * rng.standard_normal(amp.size)) / math.sqrt(2.0)
    z[0] = rng.standard_normal()
    if N % 2 == 0:
        z[-1] = rng.standard_normal()
    raw = np.fft.irfft(amp * z, N)
    c0 = np.fft.irfft(amp**2, N)[0] / N
    return NOISE * raw / math.sqrt(c0)


# --------------------------------------------------------------------------------------------
# the linear model's Jacobian: exact sd of the least-squares estimate and the Cramér–Rao bound


def jacobian(sigma: float, omega0: float) -> np.ndarray:
    """∂x/∂(σ, ω₀, offset, x₀, v₀) of the linear decay at the truth (complex step for the
    rates, exact for the linear coefficients)."""
    t = time_grid()
    h = 1e-30
    return np.column_stack([
        linear_decay(t, sigma + 1j * h, omega0).imag / h,
        linear_decay(t, sigma, omega0 + 1j * h).imag / h,
        np.ones(N),
        linear_decay(t, sigma, omega0, 1.0, 0.0),
        linear_decay(t, sigma, omega0, 0.0, 1.0),
    ])


def linear_bounds(sigma: float, kind: tuple) -> dict[str, dict[str, float]]:
    """Per parameter (σ, ω₀, ζ): ``ls_sd``, the exact sd of the (linearised) least-squares
    estimate under the noise's covariance Σ, (JᵀJ)⁻¹JᵀΣJ(JᵀJ)⁻¹; ``crb``, the Cramér–Rao bound
    (JᵀΣ⁻¹J)⁻¹ (for white noise the two are the same)."""
    J = jacobian(sigma, OMEGA0)
    c = autocov(kind)
    idx = np.abs(np.subtract.outer(np.arange(N), np.arange(N)))
    S = c[idx]
    A = np.linalg.inv(J.T @ J)
    ls = A @ (J.T @ S @ J) @ A
    crb = np.linalg.inv(J.T @ cho_solve(cho_factor(S), J))
    g = np.array([[1.0, 0.0], [0.0, 1.0], [1.0 / OMEGA0, -sigma / OMEGA0**2]])
    out: dict[str, dict[str, float]] = {}
    for name, row in zip(("sigma", "omega0", "zeta"), g, strict=True):
        out[name] = {"ls_sd": float(math.sqrt(row @ ls[:2, :2] @ row)),
                     "crb": float(math.sqrt(row @ crb[:2, :2] @ row))}
    return out


# --------------------------------------------------------------------------------------------
# truths: what each estimate is compared with


def truths(case: dict[str, Any]) -> dict[str, float | None]:
    """The true value of each reported parameter, None where the fitted model has none.

    ω₀ is always √(k/m): Coulomb friction and quadratic drag leave the stiffness alone, and for
    the Duffing spring it is the small-amplitude frequency (the fit's ω₀ is an amplitude
    average, so its bias there measures the nonlinearity, not the stderr). The viscous model's
    σ and ζ have a truth only where the damping is viscous (linear and Duffing cases); with
    Coulomb friction or quadratic drag the decay rate depends on the amplitude and no single σ
    is right. The friction fit's truths are σ = c/2m, ω₀, ζ = σ/ω₀ and f_c/m = a."""
    p = case["plant"]
    viscous_only = not ("a" in p or "q" in p)
    if case["fit"] == "friction":
        return {"sigma": p["sigma"], "omega0": OMEGA0, "zeta": p["sigma"] / OMEGA0,
                "fc_over_m": p["a"]}
    s = p["sigma"] if viscous_only else None
    return {"sigma": s, "omega0": OMEGA0, "zeta": None if s is None else s / OMEGA0}


# --------------------------------------------------------------------------------------------
# one replica


def _friction_fitter():
    try:
        from phoid.methods.free_friction import identify_free_friction_data
    except ImportError:
        return None
    return identify_free_friction_data


def _estimates(fit: Any, names: tuple[str, ...]) -> dict[str, tuple[float, float, float]]:
    out = {}
    for n in names:
        e = getattr(fit, n)
        se = float(e.stderr) if e.stderr is not None else math.nan
        white = float(e.white_stderr) if getattr(e, "white_stderr", None) is not None else se
        out[n] = (float(e.value), white, se)
    return out


def replicas(name: str, seeds: list[np.random.SeedSequence]) -> list[dict[str, Any]]:
    """Fit ``len(seeds)`` noisy replicas of case ``name``: per replica the estimates
    {parameter: (value, white stderr, reported stderr)}, warnings, seconds; or an error."""
    from phoid.methods.free import identify_free_data

    case = _case(name)
    t = time_grid()
    x = clean(name)
    names = tuple(truths(case))
    fitter = identify_free_data if case["fit"] == "viscous" else _friction_fitter()
    out: list[dict[str, Any]] = []
    for ss in seeds:
        y = x + noise(case["noise"], np.random.default_rng(ss))
        t0 = time.perf_counter()
        try:
            fit = fitter([(t, y)])
            est = _estimates(fit, names)
        except Exception as exc:  # a failure is counted, not fatal
            out.append({"error": f"{type(exc).__name__}: {exc}"[:200]})
            continue
        sec = time.perf_counter() - t0
        out.append({"est": est, "warnings": list(getattr(fit, "warnings", ())),
                    "seconds": sec, **_residual(fit, t, y)})
    return out


def _residual(fit: Any, t: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """What the residual looks like: its rms over the noise sd, its autocorrelation at lags 1
    and 10 (white: ~0), and the correlation of its two halves' rms (first-half rms over
    second-half rms: ~1 when it is stationary)."""
    model = getattr(fit, "model", None)
    if model is None:
        return {}
    try:
        r = y - np.asarray(model(0, t), dtype=float)
    except Exception:  # a result without a usable model: no residual figures
        return {}
    r = r - r.mean()
    v = float(r @ r)
    h = r.size // 2
    return {"resid_rms_over_noise": math.sqrt(v / r.size) / NOISE,
            "resid_acf1": float(r[1:] @ r[:-1]) / v, "resid_acf10": float(r[10:] @ r[:-10]) / v,
            "resid_halves_rms_ratio": math.sqrt(float(r[:h] @ r[:h]) / float(r[h:] @ r[h:]))}


# --------------------------------------------------------------------------------------------
# statistics


def summarise(case: dict[str, Any], reps: list[dict[str, Any]]) -> dict[str, Any]:
    tr = truths(case)
    ok = [r for r in reps if "est" in r]
    res: dict[str, Any] = {"label": case["label"], "plant": case["plant"],
                           "noise": list(case["noise"]), "fit": case["fit"],
                           "replicas": len(reps), "failed": len(reps) - len(ok),
                           "errors": sorted({r["error"] for r in reps if "error" in r})[:3],
                           "warned": sum(bool(r["warnings"]) for r in ok),
                           "warnings_seen": _common_warnings(ok),
                           "seconds_median": float(np.median([r["seconds"] for r in ok]))
                           if ok else math.nan,
                           "params": {}}
    for k in ("resid_rms_over_noise", "resid_acf1", "resid_acf10", "resid_halves_rms_ratio"):
        vals = [r[k] for r in ok if k in r]
        if vals:
            res[k] = float(np.median(vals))
    for p, truth in tr.items():
        v = np.array([r["est"][p][0] for r in ok])
        w = np.array([r["est"][p][1] for r in ok])
        s = np.array([r["est"][p][2] for r in ok])
        if not v.size:
            continue
        row: dict[str, Any] = {
            "truth": truth, "n": int(v.size), "mean": float(v.mean()),
            "sd": float(v.std(ddof=1)) if v.size > 1 else math.nan,
            "se_white_median": float(np.median(w)), "se_median": float(np.median(s)),
            "ratio_median": float(np.median(s / w)),
        }
        row["spread_over_se"] = row["sd"] / row["se_median"]
        row["spread_over_se_white"] = row["sd"] / row["se_white_median"]
        if truth is not None:
            err = v - truth
            row["cover_white"] = float(np.mean(np.abs(err) < COVER * w))
            row["cover"] = float(np.mean(np.abs(err) < COVER * s))
            row["bias_over_se"] = float(err.mean()) / row["se_median"]
            row["bias_over_se_white"] = float(err.mean()) / row["se_white_median"]
            row["rmse"] = float(math.sqrt(np.mean(err**2)))
            z = np.abs(err) / s
            row["worst_z"] = float(z.max())
        res["params"][p] = row
    return res


def warning_kind(text: str) -> str:
    """A warning's kind: its words before the first number, parenthesis or colon (the numbers
    differ from replica to replica, the kind does not), without a leading run name."""
    text = re.sub(r"^run\d+: ", "", text)
    return re.split(r"[(:]|\s[-+]?\d|\d", text, maxsplit=1)[0].strip(" ,;.") or text[:60]


def _common_warnings(ok: list[dict[str, Any]]) -> list[tuple[str, int]]:
    """The kinds of warning seen, most frequent first, with the number of replicas that carried
    each (at most six)."""
    counts: dict[str, int] = {}
    for r in ok:
        for k in {warning_kind(w) for w in r["warnings"]}:
            counts[k] = counts.get(k, 0) + 1
    return sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))[:6]


def _revision() -> dict[str, Any]:
    """The commit the study ran on, and the files of the methods it measures that differed
    from it (a run on work in progress says so)."""
    import subprocess

    def git(*a: str) -> str:
        try:
            return subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True,
                                  timeout=30, check=True).stdout.rstrip("\n")
        except (OSError, subprocess.SubprocessError):
            return ""

    import phoid

    src = Path(phoid.__file__).resolve().parent
    if not src.is_relative_to(ROOT / "src"):  # another copy (an export, an installed phoid)
        return {"commit": None, "source": str(src), "modified": []}
    return {"commit": git("rev-parse", "--short", "HEAD"),
            "modified": git("status", "--porcelain", "--", "src/phoid/methods").split("\n")
            if git("status", "--porcelain", "--", "src/phoid/methods") else []}


def run(replicas_per_case: int = FULL_REPLICAS, workers: int = 2, seed: int = 20270127,
        cases: list[str] | None = None, log=None) -> dict[str, Any]:
    """The whole study; ``log(msg)`` is called after each case."""
    t_start = time.perf_counter()
    chosen = [c for c in CASES if cases is None or c["name"] in cases]
    res: dict[str, Any] = {
        "setup": {"fs_hz": FS, "duration_s": DURATION, "omega0": OMEGA0, "x0_m": X0,
                  "noise_sd_m": NOISE, "replicas": replicas_per_case, "seed": seed,
                  "workers": workers},
        "cases": {}, "checks": {}, "phoid": _revision(),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }
    # the simulator's own check: solve_ivp with q = d = 0 against the exact linear decay
    t = time_grid()
    dev = float(np.max(np.abs(ivp_decay(t, 0.05, OMEGA0) - linear_decay(t, 0.05, OMEGA0))))
    res["checks"]["ivp_vs_exact_rel_x0"] = dev / X0
    cp = _case("coulomb")["plant"]
    xc, t_stop = coulomb_decay(t, cp["sigma"], OMEGA0, cp["a"])
    xe, t_ev = coulomb_events(t, cp["sigma"], OMEGA0, cp["a"])
    res["checks"]["coulomb_stop_s"] = t_stop
    res["checks"]["coulomb_events_stop_s"] = t_ev
    res["checks"]["coulomb_vs_events_rel_x0"] = float(np.nanmax(np.abs(xc - xe))) / X0
    friction = _friction_fitter() is not None
    res["setup"]["friction_fit_available"] = friction
    with ProcessPoolExecutor(max_workers=workers) as pool:
        for ci, case in enumerate(chosen):
            name = case["name"]
            if case["fit"] == "friction" and not friction:
                res["cases"][name] = {"label": case["label"], "skipped":
                                      "phoid.methods.free_friction not available"}
                if log:
                    log(f"adequacy coverage: {name} skipped")
                continue
            t0 = time.perf_counter()
            seeds = np.random.SeedSequence([seed, ci]).spawn(replicas_per_case)
            chunks = [seeds[i::max(workers, 1) * 4] for i in range(max(workers, 1) * 4)]
            reps = [r for part in pool.map(replicas, [name] * len(chunks), chunks)
                    for r in part]
            out = summarise(case, reps)
            if case["fit"] == "viscous" and set(case["plant"]) == {"sigma"}:
                b = linear_bounds(case["plant"]["sigma"], case["noise"])
                for p, row in out["params"].items():
                    row.update(b[p])
            out["wall_s"] = time.perf_counter() - t0
            res["cases"][name] = out
            if log:
                log(f"adequacy coverage: {name} ({out['wall_s']:.1f} s)")
    res["targets"] = targets(res)
    res["wall_s"] = time.perf_counter() - t_start
    res["load_average"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    return res


# --------------------------------------------------------------------------------------------
# BENCHMARKS.md


TITLE = "## Model adequacy: stderr coverage on decays phoid's model does not fit (issue 27)"
SYMBOL = {"sigma": "σ", "omega0": "ω₀", "zeta": "ζ", "fc_over_m": "f_c/m"}


def _pct(x: float | None) -> str:
    return "–" if x is None or not math.isfinite(x) else f"{x:.1%}"


def _f(x: float | None, fmt: str = ".2f") -> str:
    return "–" if x is None or not math.isfinite(x) else format(x, fmt)


def targets(res: dict[str, Any]) -> list[dict[str, Any]]:
    """run.py's targets (``name``, ``ok``, ``got``, ``enforced``): ±3 reported-stderr coverage
    ≥ 99 % of every parameter with a truth, per case; enforced for the cases of issue 27's
    acceptance in a run of at least ENFORCE_MIN replicas (fewer cannot resolve 99 %)."""
    out = []
    for name, c in res.get("cases", {}).items():
        if "params" not in c:
            continue
        cov = {p: r["cover"] for p, r in c["params"].items() if "cover" in r}
        if not cov:
            continue
        enforced = bool(_case(name)["target"]) and c["replicas"] >= ENFORCE_MIN
        out.append({"name": f"adequacy study, `{name}`: ±3 reported-stderr coverage ≥ 99 %"
                            + ("" if _case(name)["target"] else " (reported only)"),
                    "ok": min(cov.values()) >= TARGET,
                    "got": ", ".join(f"{SYMBOL[p]} {v:.1%}" for p, v in cov.items()),
                    "enforced": enforced})
    return out


def section(res: dict[str, Any]) -> list[str]:
    """BENCHMARKS.md's section for :func:`run`'s results."""
    if not res or not res.get("cases"):
        return []
    su = res["setup"]
    lines = [
        TITLE,
        "",
        f"`bench/bench_adequacy.py` (design: docs/adequacy-coverage.md). A 1 Hz oscillator "
        f"released from rest at x₀ = {su['x0_m'] * 1e3:g} mm, {su['duration_s']:g} s at "
        f"{su['fs_hz']:g} Hz, noise of marginal sd {su['noise_sd_m'] * 1e6:g} µm, simulated "
        "independently of phoid (exact formulas; Coulomb friction exactly per half cycle with "
        f"the stop, within {res['checks'].get('coulomb_vs_events_rel_x0', math.nan):.0e} x₀ of "
        "solve_ivp with v = 0 events; quadratic drag and Duffing by solve_ivp DOP853 at rtol "
        "1e−12, within "
        f"{res['checks']['ivp_vs_exact_rel_x0']:.0e} x₀ of the exact linear decay); "
        f"{su['replicas']} replicas per case, the same decay with fresh noise, fitted by "
        "`identify_free_data` (friction: `identify_free_friction_data`). Coverage: share of "
        "replicas with |error| < 3 stderr, with the white-noise stderr (`white_stderr` where "
        "set, else `stderr`) and with the reported `stderr`; robust / white: their median "
        "ratio; bias and spread (sd over the replicas) in units of the median reported "
        "stderr. LS sd: the least-squares estimate's exact sd under the noise's covariance, "
        "(JᵀJ)⁻¹JᵀΣJ(JᵀJ)⁻¹; CRB: (JᵀΣ⁻¹J)⁻¹ (linear cases; J, Σ computed in the bench). "
        "\"–\": no truth (the fitted model's parameter has none on these decays).",
        "",
        "| case | | truth | mean estimate | coverage, white | coverage, reported | robust / "
        "white | bias / se | spread / se | spread / LS sd | reported se / CRB | fails / "
        "warned |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, c in res["cases"].items():
        if "skipped" in c:
            lines.append(f"| {c['label']} | skipped: {c['skipped']} | | | | | | | | | | |")
            continue
        for j, (p, r) in enumerate(c["params"].items()):
            head = f"{c['label']} (`{name}`)" if j == 0 else ""
            truth = "–" if r["truth"] is None else f"{r['truth']:.6g}"
            ls = r["sd"] / r["ls_sd"] if "ls_sd" in r else None
            crb = r["se_median"] / r["crb"] if "crb" in r else None
            tail = f"{c['failed']} / {c['warned']}" if j == 0 else ""
            cov = _pct(r.get("cover"))
            if "cover" in r and r["cover"] < TARGET:
                cov = f"**{cov}**"
            lines.append(
                f"| {head} | {SYMBOL[p]} | {truth} | {r['mean']:.6g} | "
                f"{_pct(r.get('cover_white'))} | {cov} | {r['ratio_median']:.2f} | "
                f"{_f(r.get('bias_over_se'), '+.2f')} | {_f(r['spread_over_se'])} | "
                f"{_f(ls)} | {_f(crb)} | {tail} |")
    lines += ["", "The residual (medians over the replicas): rms over the noise sd, "
              "autocorrelation at lags 1 and 10, first-half rms over second-half rms; the time "
              "per fit; the replicas warned, and each kind of warning with the number of "
              "replicas that carried it.", "",
              "| case | rms / noise | acf(1) | acf(10) | halves | time per fit | warned "
              "| warnings (replicas) |", "|---|---|---|---|---|---|---|---|"]
    for name, c in res["cases"].items():
        if "skipped" in c:
            continue
        w = c["warnings_seen"]
        warn = "; ".join(f"{k}… ({n})" for k, n in w) if w else "none"
        lines.append(f"| `{name}` | {_f(c.get('resid_rms_over_noise'))} | "
                     f"{_f(c.get('resid_acf1'))} | {_f(c.get('resid_acf10'))} | "
                     f"{_f(c.get('resid_halves_rms_ratio'))} | "
                     f"{c['seconds_median'] * 1e3:.0f} ms | {c['warned']} / "
                     f"{c['replicas'] - c['failed']} | {warn} |")
    tg = res.get("targets") or targets(res)
    lines += ["", "Targets (≥ 99 % needs at least "
              f"{ENFORCE_MIN} replicas to be judged):", ""]
    lines += [f"- {'met' if t['ok'] else '**NOT MET**'}: {t['name']} ({t['got']})"
              for t in tg]
    rev = res.get("phoid", {})
    mod = rev.get("modified") or []
    where = (f"commit {rev['commit']}" if rev.get("commit")
             else f"the copy in {rev['source']}" if rev.get("source") else "unknown")
    when = f" on {res['date']}" if res.get("date") else ""
    lines += ["", f"Whole study{when}: {res['wall_s']:.0f} s on {su['workers']} workers; "
              f"phoid at {where}"
              + (f" with {len(mod)} modified file(s) under src/phoid/methods" if mod else "")
              + "."]
    return lines



def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help=f"{QUICK_REPLICAS} replicas per case (a smoke run)")
    ap.add_argument("--replicas", type=int, default=None,
                    help=f"replicas per case ({FULL_REPLICAS})")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cases", default=None, help="comma-separated case names (all)")
    ap.add_argument("--json", type=Path, default=None, help="also write the results here")
    ap.add_argument("--from", dest="source", type=Path, default=None,
                    help="report the results a previous run wrote with --json (no new run)")
    ap.add_argument("--write", action="store_true",
                    help="splice the section into BENCHMARKS.md and the results into "
                         "bench/results.json (key \"adequacy\")")
    args = ap.parse_args()
    n = args.replicas or (QUICK_REPLICAS if args.quick else FULL_REPLICAS)
    if n < 2 or args.workers < 1:
        ap.error("--replicas must be ≥ 2 and --workers ≥ 1")
    cases = args.cases.split(",") if args.cases else None
    if cases:
        unknown = sorted(set(cases) - {c["name"] for c in CASES})
        if unknown:
            ap.error(f"--cases: unknown {', '.join(unknown)}")
    t0 = time.perf_counter()

    def log(msg: str) -> None:
        print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    if args.source:
        try:
            res = json.loads(args.source.read_text())
        except (OSError, ValueError) as exc:
            ap.error(f"--from {args.source}: cannot be read ({exc})")
        if not isinstance(res, dict) or not {"cases", "setup", "checks"} <= set(res):
            ap.error(f"--from {args.source}: not a results file of this bench")
    else:
        res = run(n, args.workers, cases=cases, log=log)
    part = section(res)
    print("\n".join(part))
    for t in res["targets"]:
        print(f"{'met' if t['ok'] else 'NOT MET'}: {t['name']} ({t['got']})"
              + ("" if t["enforced"] else " [not enforced]"))
    if args.json:
        args.json.write_text(json.dumps(res, indent=1, default=float))
    if args.write:
        md = ROOT / "BENCHMARKS.md"
        md.write_text(splice_section(md.read_text(), TITLE, part))
        rj = HERE / "results.json"
        allres = json.loads(rj.read_text()) if rj.is_file() else {}
        allres["adequacy"] = res
        rj.write_text(json.dumps(allres, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
