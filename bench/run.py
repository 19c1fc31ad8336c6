"""`make bench`: run the benchmark suite, write BENCHMARKS.md and bench/results.json.

Every figure is a median over repeats with min–max, next to a named alternative measured in the
same run. Exits with status 1 only when an accuracy target is missed (never on wall-clock times).

    python bench/run.py              # the full suite (a few minutes on 2 cores)
    python bench/run.py --quick      # a smoke run (~1 minute): few replicas, smaller sizes

Only a full run (no --quick, --only, --replicas or --repeats) writes BENCHMARKS.md and
bench/results.json; other runs print the report and write nothing unless --write is given.

BLAS runs single-threaded (OPENBLAS_NUM_THREADS=1 etc., unless already set), so that the two
Monte Carlo workers do not oversubscribe a 2-core machine; every pipeline is timed under the
same setting.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import datetime as _dt  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

import bench_adequacy  # noqa: E402
import bench_batch  # noqa: E402
import bench_emps  # noqa: E402
import bench_figures  # noqa: E402
import bench_identify  # noqa: E402
import bench_inloop  # noqa: E402
import bench_scaling  # noqa: E402
import bench_simulate  # noqa: E402
import bench_startup  # noqa: E402
import numpy as np  # noqa: E402
import scipy  # noqa: E402
from crb import crb_sd  # noqa: E402
from sets import SETS, check_rings  # noqa: E402

from phoid._progress import progress as phoid_progress  # noqa: E402
from phoid._progress import task as progress_task  # noqa: E402

RMSE_TARGET = 1.1  # phoid RMSE ≤ 1.1 × CRB (issue 7)
COVERAGE_TARGET = 0.99  # |err| < 3 stderr in ≥ 99 % of replicas (the project's promise)
FEW_TIMES = 4.0  # "a few times its own size": peak ≤ 4 × the record (t, x)
CRB_CHECK_TOL = 0.05  # bench/crb.py reproduces truth.json's crb_sd within 5 %
FULL_REPLICAS = 200  # fewer (--quick): a smoke run, whose Monte Carlo cannot resolve the targets
# phoid's own replicas: its reported stderr is ~1.01–1.04 × the dominant-mode CRB (it fits the
# loop's fast-mode amplitudes too), so its true RMSE / CRB is ~1.04, 6 % under the target. The
# Monte Carlo estimate of RMSE / CRB has a relative sd of 1/√(2n): 2.9 % at n = 600 (one set in
# ~20 would read > 1.1 by chance), 2.2 % at n = 1000 (< 1 % chance per quantity).
PHOID_REPLICAS = 1000
SMOKE_COVERAGE = 0.95  # a smoke run fails only on gross under-coverage
LABEL = {"table1": "Table 1", "overdamped": "overdamped", "mass_damper": "mass–damper"}
UNIT = {"m": "kg", "c": "N s/m", "k": "N/m"}


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _ncpu() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


def _g(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}g}"


def _ms(s: dict) -> str:
    return f"{s['median_s'] * 1e3:.1f} ms ({s['min_s'] * 1e3:.1f}–{s['max_s'] * 1e3:.1f})"


def _rate(r: dict) -> str:
    return (f"{r['samples_per_s_median']:.3g} ({r['samples_per_s_min']:.3g}–"
            f"{r['samples_per_s_max']:.3g})")


def _truth() -> dict | None:
    """../shared/data/truth.json's ``crb_sd`` (an independent bound), or None where it is absent:
    examples/paper-sample/truth.json's bound is bench/crb.py's own, so checking against it would
    prove nothing, and the check is left out of the report."""
    p = bench_identify.SHARED / "data" / "truth.json"
    if not p.is_file():
        return None
    return json.loads(p.read_text())["paper-sample"]["crb_sd"]


# --------------------------------------------------------------------------------------------
# sections of BENCHMARKS.md


def _vs(chk: dict, key: str) -> str:
    """Table cells: bench/crb.py's value and its difference from truth.json's."""
    return " | ".join(f"{_g(chk[key][q], 4)} ({chk[key][q] / chk['truth'][q] - 1:+.1%})"
                      for q in "mck")


def _sets_section(res: dict) -> list[str]:
    lines = [
        "## The three sets",
        "",
        "Defined in `bench/sets.py`; every run checked stable and ringing by phoid's certified "
        "root finder (`phoid.characteristic_roots`), its next root at least 5× faster than the "
        "dominant pair. Noise and quantisation scale with the release amplitude x₀ as in the "
        "Table 1 set (noise 1 % of x₀, quantum 1e−4 x₀, offset −3 % of x₀, 0.2 s hold).",
        "",
        "| set | plant, loop, gains, record | σ (1/s) | ω_d (rad/s) | next root rate (1/s) "
        "| Cramér–Rao sd of m, c, k |",
        "|---|---|---|---|---|---|",
    ]
    for name, s in res["sets"].items():
        crb = s["crb_sd"]
        lines.append(
            f"| {LABEL[name]} | {s['description']} | {min(s['sigma']):.2f}–{max(s['sigma']):.2f}"
            f" | {min(s['omega_d']):.1f}–{max(s['omega_d']):.1f} | ≥ {min(s['next_rate']):.0f}"
            f" | {_g(crb['m'])} kg, {_g(crb['c'])} N s/m, {_g(crb['k'])} N/m |"
        )
    chk = res.get("crb_check")
    lines += [
        "",
        "Cramér–Rao sd: `bench/crb.py`, the model of the sample sets' truth.json `crb_sd` notes "
        "(single dominant mode per run; amplitude, phase and offset unknown per run; delay "
        "known): per-run Fisher information of (σ, ω_d) summed over the sample grid with the "
        "nuisance parameters profiled out, chained to (m, c, k) through the exact loop roots "
        "(∂s/∂θ = −(s², s, 1)/f′(s)). The dominant mode's amplitude and phase are its residue in "
        "the exact response to a release from rest.",
    ]
    if chk:
        lines += [
            "",
            "Check against truth.json (Table 1 set, noise 0.1 mm):",
            "",
            "| | m (kg) | c (N s/m) | k (N/m) |",
            "|---|---|---|---|",
            "| truth.json `crb_sd` | " + " | ".join(_g(chk["truth"][q], 4) for q in "mck") + " |",
            "| bench/crb.py, residue amplitude (used here) | " + _vs(chk, "residue") + " |",
            "| bench/crb.py, release initial conditions x(0) = x₀, ẋ(0) = 0 | "
            + _vs(chk, "release") + " |",
            "",
            "The second variant gives the dominant mode the release's own initial conditions "
            "(ignoring the share of the release the loop's fast modes take) and matches "
            "truth.json to < 0.5 %, which tells how those numbers were made; the residue "
            "amplitude is the one actually in the records, 1–2 % smaller, so its bound is 1–2 % "
            "wider. Both are within the 5 % this benchmark requires of itself.",
        ]
    return lines


def _mc_section(res: dict) -> list[str]:
    mc = res["monte_carlo"]
    if not mc:
        return []
    first = next(iter(mc.values()))
    n, nph = first["replicas"], first["phoid_replicas"]
    lines = [
        f"## Accuracy at the physical limit: Monte Carlo, {n} noisy replicas per set "
        f"({nph} for phoid)",
        "",
        "Replicas made by phoid's simulator (checked against jitcdde below), each with fresh "
        f"noise; every pipeline sees the same {n} records, and phoid {nph - n} more (it is "
        "cheap, and 200 replicas resolve RMSE / CRB only to about ±10 % at 95 %, more than "
        "the target's margin; the n column says how many each figure rests on). RMSE / CRB "
        "with its 95 % Monte Carlo interval; \"stderr / sd\": the mean reported standard "
        "error over the observed spread of the estimates; coverage: share of replicas with "
        "|error| < 3 reported stderr. The two alternatives are given the true release time "
        "(phoid finds it itself). \"fails\": replicas where the pipeline raised or did not "
        "converge (left out of its figures); \"warned\": replicas where phoid attached a "
        "warning.",
    ]
    for name, m in mc.items():
        crb = m["crb_sd"]
        lines += [
            "",
            f"### {LABEL[name]} set (CRB: m {_g(crb['m'])} kg, c {_g(crb['c'])} N s/m, "
            f"k {_g(crb['k'])} N/m)",
            "",
            "| pipeline | n | | bias / CRB | RMSE / CRB (95 % interval) | stderr / sd "
            "| ±3 stderr coverage | fails / warned |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for p in bench_identify.PIPELINES:
            row = m[p]
            for j, q in enumerate("mck"):
                nn = str(row["n"]) if j == 0 else ""
                if "rmse_over_crb" not in row:
                    lines.append(f"| {p} | {nn} | {q} | – | – | – | – | {row['failed']} |")
                    continue
                lo, hi = row["rmse_over_crb_95ci"][q]
                tail = f"{row['failed']} / {row['warned']}" if j == 0 else ""
                lines.append(
                    f"| {p} | {nn} | {q} | {row['bias_over_crb'][q]:+.2f} | "
                    f"**{row['rmse_over_crb'][q]:.2f}** ({lo:.2f}–{hi:.2f}) | "
                    f"{row['stderr_over_sd'][q]:.2f} | {row['coverage_3se'][q]:.1%} | {tail} |"
                )
    return lines


def _ratio(s: dict, p: str) -> float:
    """Pipeline p's time over phoid's: the median of the per-round ratios (older results: the
    ratio of the medians)."""
    return s[p].get("ratio_to_phoid", s[p]["median_s"] / s["phoid"]["median_s"])


def _speed_section(res: dict) -> list[str]:
    sp = res["identification_speed"]
    if not sp:
        return []
    lines = [
        "## Identification speed",
        "",
        "Compute time (CPU time) to identify a whole set (data already in memory), median "
        f"(min–max) over {res['args']['repeats']} rounds after one untimed call; each round "
        "times every pipeline once in turn, and \"phoid N× faster\" is the median over the "
        "rounds of the pipeline's time over phoid's in the same round. The alternatives skip the "
        "release detection (they are given the release time), phoid does not.",
        "",
        "| set (records) | samples | phoid | curve_fit+OLS | curve_fit+OLS, numerical "
        "Jacobian | logdec+OLS |",
        "|---|---|---|---|---|---|",
    ]
    for name, s in sp.items():
        cells = [_ms(s["phoid"])]
        for p in ("curve_fit+OLS", bench_identify.NUMJAC, "logdec+OLS"):
            cells.append(f"{_ms(s[p])}: phoid {_ratio(s, p):.1f}× faster")
        lines.append(f"| {LABEL[name]} ({s['data']}) | {s['samples']:,} | " + " | ".join(cells)
                     + " |")
    return lines


def _sim_section(res: dict) -> list[str]:
    sim = res["simulation"]
    if not sim:
        return []
    lines = [
        "## Simulation speed and accuracy",
        "",
        f"{sim['workload']}. Max deviation: the largest |x − x_ref| / x₀ over every sample of the "
        f"runs compared, x_ref = jitcdde at rtol {sim['tight_rtol']:g} (itself good to "
        "~1e−11 x₀, which bounds what phoid's figure can show). jitcdde and solve_ivp take one "
        "run at a time; on the large batch they are timed on an evenly spread subset of its "
        "runs (\"timed on\"), and phoid's deviation there is taken on the same subset. "
        f"jitcdde's compile time (once, excluded): {sim['jitcdde_compile_s']:.2f} s.",
        "",
        "| workload | simulator | timed on | samples/s, median (min–max) | max deviation / x₀ "
        "| phoid's speed-up |",
        "|---|---|---|---|---|---|",
    ]
    for r in sim["rows"]:
        up = "" if r["phoid"] else f"{sim['speedup'][r['workload']][r['simulator']]:.0f}×"
        name = f"**{r['simulator']}**" if r["phoid"] else r["simulator"]
        lines.append(f"| {r['workload']} | {name} | {r['runs_timed']} runs | {_rate(r)} | "
                     f"{r['max_deviation_rel_x0']:.1e} | {up} |")
    lines += [
        "",
        "jitcdde lands a step on every output time and on every multiple of Δt, so its accuracy "
        "hardly changes below rtol 1e−5 while its speed does; rtol 1e−6 is the fastest setting "
        "tried that stays within 1e−6 x₀, and the one the target compares with.",
    ]
    return lines


def _scaling_section(res: dict) -> list[str]:
    sc = res["scaling"]
    if not sc:
        return []
    lines = [
        "## Scaling: time and peak memory",
        "",
        "Each point in a fresh subprocess (`bench/bench_scaling.py`). Record length: 10 s "
        "records at f_s = samples/10 s (100 Hz … 1 MHz); `simulate` one run, `identify` three "
        "runs (Table 1 runs 1, 10, 19). Number of runs: 10 s at 1 kHz per run. Time: median "
        "(min–max) of up to 3 calls; peak: tracemalloc's peak during one call above what was "
        "allocated before it (the outputs count, the input records do not); × record: peak over "
        "the records' own size (t and x in float64, 16 bytes per sample). `simulate` returns "
        "t, x, x_true, v and u (40 bytes per sample of the peak are its result).",
        "",
        "| function | axis | runs × samples | time, median (min–max) | peak memory "
        "| bytes / sample | × record |",
        "|---|---|---|---|---|---|---|",
    ]
    for p in sc["points"]:
        head = f"| {p['func']} | {p['axis']} | "
        if "error" in p:
            lines.append(head + f"{p['size']:,} | failed: {p['error']} | | | |")
            continue
        bps = bench_scaling.bytes_per_sample(p)
        t = (f"{p['median_s']:.3g} s ({p['min_s']:.3g}–{p['max_s']:.3g})" if p["calls"] > 1
             else f"{p['median_s']:.3g} s (1 call)")
        lines.append(head + f"{p['runs']:,} × {p['samples_per_run']:,} | {t} | "
                     f"{p['peak_bytes'] / 2**20:.1f} MiB | {bps:.1f} | "
                     f"{bench_scaling.times_record(p):.1f} |")
    lines += [
        "",
        "Growth exponents (least-squares slope of log time and log peak memory against log "
        "samples; 1 = linear), over the upper three sizes (where the fixed per-call cost is "
        "small) and over the whole range:",
        "",
        "| function / axis | upper sizes | time (upper) | time (all) | memory (upper) "
        "| memory (all) |",
        "|---|---|---|---|---|---|",
    ]
    for k, s in sc["slopes"].items():
        if "error" in s:
            lines.append(f"| {k} | {s['error']} | | | | |")
            continue
        lines.append(f"| {k} | {', '.join(f'{u:g}' for u in s['upper_sizes'])} | "
                     f"{s['time_upper']:.2f} | {s['time_all']:.2f} | {s['memory_upper']:.2f} | "
                     f"{s['memory_all']:.2f} |")
    return lines


# --------------------------------------------------------------------------------------------
# targets


def _startup_section(res: dict) -> list[str]:
    st = res.get("startup")
    if not st:
        return []
    n = next(iter(st["wall"].values()))["n"]
    lines = [
        "## Start-up",
        "",
        f"Wall time of a fresh process (`{st['phoid_command']}`), median (min–max) over {n} "
        "rounds after one untimed round; each round runs every command in turn, so the "
        "machine's busy spells fall on all alike; the CPU column (the child's user + system "
        "time) is less sensitive to a busy machine. Byte code is cached (a temporary "
        "`PYTHONPYCACHEPREFIX`, filled by the untimed round), as in an installed phoid. "
        "`python -c pass` and `import numpy` are the scale: what any Python tool, and any "
        "numpy tool, pays before it starts. The import rows are the time of the import "
        "statement inside the process (no interpreter start): `import phoid` is lazy "
        "(PEP 562), the public names load their subpackages on first use.",
        "",
        "| command | wall, median (min–max) | CPU (user + system) | target (wall) |",
        "|---|---|---|---|",
    ]
    for label, s in st["wall"].items():
        target = st["targets"].get(label)
        cpu = _ms(st["cpu"][label]) if "cpu" in st else ""
        lines.append(f"| `{label}` | {_ms(s)} | {cpu} | {f'≤ {target:g} s' if target else ''} |")
    for label, s in st["import"].items():
        lines.append(f"| `{label}` (in-process) | {_ms(s)} | | |")
    if st.get("load_average"):
        lines += ["", "Load average at the end (1, 5, 15 min): "
                  + ", ".join(f"{v:.2f}" for v in st["load_average"]) + "."]
    return lines


def _sps(t: dict, n: int) -> str:
    return f"{n / t['median_s']:.3g}"


def _emps_section(res: dict) -> list[str]:
    em = res.get("emps")
    if not em:
        return []
    head = ["## The EMPS record (issue 17): IDIM-LS, exact loop simulation, output error", ""]
    if "skipped" in em:
        return [*head, f"Skipped: {em['skipped']}."]
    n = em["record"]["samples"]
    k = em["repeats"]
    lines = [
        *head,
        f"`bench/bench_emps.py` on ../shared/data/emps/DATA_EMPS.mat ({n:,} samples at 1 kHz; "
        "loop u = kv·(kp·(qg − qm) − (qm[n] − qm[n−2])/(2T)), force gtau·sat(u), ±10 V, k = 0). "
        f"Times: wall, median (min–max) over {k} calls after one untimed call, and the CPU "
        "time's median.",
        "",
        "### IDIM-LS",
        "",
        "`idim_ls(t, qm, vir, gain=gtau, trim=(49, 0), sigma=\"sample-std\")` against the "
        "benchmark's published estimates (printed to the published digits):",
        "",
        "| | M (kg) | Fv (N s/m) | Fc (N) | OF (N) | time | CPU |",
        "|---|---|---|---|---|---|---|",
    ]
    idim = em["idim"]
    est = idim["estimates"]
    lines.append("| published | " + " | ".join(f"{est[q]['published'][0]} ± "
                                               f"{est[q]['published'][1]}" for q in est)
                 + " | | |")
    lines.append("| phoid `idim_ls` | " + " | ".join(f"{est[q]['printed'][0]} ± "
                                                     f"{est[q]['printed'][1]}" for q in est)
                 + f" | {_ms(idim['time'])} | {idim['time']['cpu_median_s'] * 1e3:.1f} ms |")
    lines += [
        "",
        f"Relative error of the fitted force {idim['relative_error']:.4f} % (published "
        f"4.0834 %), condition number {idim['condition_number']:.2f} (published 25.99).",
        "",
        "### Simulation of the whole record",
        "",
        "The published IDIM-LS plant (M 95.1089 kg, Fv 203.5034 N s/m, Fc 20.3935 N, OF "
        "−3.1648 N) in the loop, driven by qg from the recorded state at sample 2 "
        "(`phoid.methods.tracking.replay`: history qm[0:3], v₀ = (qm[3] − qm[1])/(2T), the "
        "commands before it from vir). Named alternative: the independent pure-Python "
        "reference `tests/_tracking_reference.py::reference_tracking` (Taylor series of each "
        "constant-force piece, Newton-located reversals) in plain floats, started alike. "
        "Relative errors: `validate_tracking` over the benchmark's window 50:end, "
        "100·‖y − ŷ‖/‖y‖ of the tracking error qm − qg and of the force gtau·sat(vir).",
        "",
        "| τ | simulator | time, median (min–max) | samples/s | max \\|x − x_ref\\| "
        "| tracking error | force |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, row in em["simulation"]["delays"].items():
        ns, rel = row["samples"], row["relative_error_percent"]
        lines.append(f"| {label} | **phoid `replay`** | {_ms(row['phoid'])} | "
                     f"{_sps(row['phoid'], ns)} | {row['max_abs_dx_m']:.1e} m | "
                     f"{rel['tracking error']:.4f} % | {rel['force']:.3f} % |")
        lines.append(f"| {label} | reference, floats | {_ms(row['reference'])} | "
                     f"{_sps(row['reference'], ns)} | 0 (itself) | | |")
    ivp = em["simulation"]["solve_ivp"]
    rows = ivp["rows"]
    ph = rows["phoid replay"]
    lines += [
        "",
        f"A notebook user's route on the first {ivp['samples']:,} samples only (τ = 0; "
        "nothing extrapolated): `scipy.integrate.solve_ivp` one controller period at a time "
        "with the force held, rtol 1e−10, atol 1e−13. \"v = 0 events\": the slip direction "
        "fixed per piece, a terminal event where v crosses 0, then stick (|F − OF| ≤ Fc) or "
        "slip the other way — the stick–slip logic written by hand. \"sign(v) in the rhs\": "
        "the friction written as Fc·sign(v) in the right-hand side, run until its wall-clock "
        "budget was spent. Max deviation against the reference above on the samples "
        "simulated.",
        "",
        "| simulator | samples simulated | time, median (min–max) | samples/s "
        "| max \\|x − x_ref\\| | phoid's speed-up |",
        "|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        sps = r["samples"] / r["time"]["median_s"] if r["samples"] else 0.0
        if name == "phoid replay":
            cells = (f"**{name}**", f"{r['samples']:,}", _ms(r["time"]), f"{sps:.3g}",
                     f"{r['max_abs_dx_m']:.1e} m", "")
        elif "budget_s" in r:
            state = ("finished" if r["finished"] else
                     f"then no further sample in the rest of its {r['budget_s']:g} s budget")
            cells = (name, f"{r['samples']:,} ({state})",
                     f"{r['seconds_to_last_sample'] * 1e3:.1f} ms to its last sample (1 call)",
                     "", f"{r['max_abs_dx_m']:.1e} m",
                     "" if r["finished"] else "stalls at the first stop of the axis")
        else:
            up = (r["time"]["median_s"] / r["samples"]) / (ph["time"]["median_s"]
                                                          / ph["samples"])
            cells = (name, f"{r['samples']:,}", _ms(r["time"]), f"{sps:.3g}",
                     f"{r['max_abs_dx_m']:.1e} m", f"{up:.0f}×")
        lines.append("| " + " | ".join(cells) + " |")
    oe = em["output_error"]
    lines += [
        "",
        "### Output error",
        "",
        "`fit_tracking(qm, qg, ctrl, fixed={\"k\": 0.0})` (the loop simulated exactly and fitted "
        "to qm; ± the Newey–West stderrs), with the delay given or estimated. Issue 17's "
        "acceptance at τ = 0: M 95.11 ± 0.5, Fv 203.5 ± 10, Fc 20.39 ± 1.0, OF −3.165 ± 0.3; "
        "HAC stderr M 0.1–0.5, Fv 2–8, Fc 0.2–0.8; at τ = 1 ms M ≈ 94.87, Fv ≈ 217.3, "
        "Fc ≈ 19.37; the estimated delay ≤ 0.15 ms.",
        "",
        "| τ | M (kg) | Fv (N s/m) | Fc (N) | OF (N) | τ (ms) | evaluations | time, median "
        "(min–max) | CPU |",
        "|---|---|---|---|---|---|---|---|---|",
    ]

    def pm(e: dict, digits: int) -> str:
        se = e["stderr"]
        return f"{e['value']:.{digits}f}" + (f" ± {se:.{digits}f}" if se else "")

    for label in ("τ = 0", "τ = 1 ms", "τ estimated"):
        r = oe[label]
        e = r["estimates"]
        tau = e["delay"]
        tau_s = f"{tau['value'] * 1e3:.3g}" + (f" ± {tau['stderr'] * 1e3:.2g}"
                                               if tau["stderr"] else "")
        if label == "τ estimated":
            tau_s += f" ({r['delay_status']})"
        lines.append(f"| {label} | {pm(e['m'], 2)} | {pm(e['c'], 1)} | {pm(e['fc'], 2)} | "
                     f"{pm(e['offset'], 3)} | {tau_s} | {r['nfev']} | "
                     f"{r['time']['median_s']:.2f} s ({r['time']['min_s']:.2f}–"
                     f"{r['time']['max_s']:.2f}) | {r['time']['cpu_median_s']:.2f} s |")
    wh = em["whole_identification"]
    val = oe["validation"]
    lines += [
        "",
        "Whole identification (issue 17: ≤ 10 s on the 2-core machine), the sum of the "
        "medians: " + " + ".join(f"{k} {v:.3g} s" for k, v in wh["parts_s"].items())
        + f" = **{wh['total_s']:.2f} s**; with the delay estimated instead of given "
        f"{wh['total_delay_estimated_s']:.2f} s. The validation (replay with the output-error "
        "estimates and `validate_tracking`): tracking error "
        f"{val['relative_error_percent']['tracking error']:.4f} %, force "
        f"{val['relative_error_percent']['force']:.3f} %.",
    ]
    it = em.get("identify_tracking", {})
    if "skipped" in it:
        lines += ["", f"`identify_tracking` on a tracking set: not timed — {it['skipped']}."]
    elif it:
        cells = [f"estimator {k!r} {_ms(v['time'])}" for k, v in it.items() if k != "read"]
        lines += ["", "`identify_tracking` on a tracking set (the record in a temporary "
                  "folder with its manifest; read once, "
                  f"`read_experiment` {_ms(it['read']['time'])}): " + ", ".join(cells) + "."]
    return lines


def _targets(res: dict) -> tuple[list[str], list[str]]:
    """(lines of the Targets section, accuracy failures)."""
    acc: list[tuple[str, bool, str]] = []
    rep: list[tuple[str, bool, str]] = []
    chk = res.get("crb_check")
    if chk:
        worst = max(abs(chk["residue"][q] / chk["truth"][q] - 1) for q in "mck")
        acc.append(("bench/crb.py reproduces truth.json's crb_sd within 5 %",
                    worst <= CRB_CHECK_TOL, f"worst {worst:.1%}"))
    for name, m in res["monte_carlo"].items():
        ph = m["phoid"]
        if "rmse_over_crb" not in ph:
            acc.append((f"{LABEL[name]}: phoid identifies the replicas", False,
                        f"{ph['failed']} failed"))
            continue
        r = ph["rmse_over_crb"]
        cov = ph["coverage_3se"]
        if m["replicas"] >= FULL_REPLICAS:
            acc.append((f"{LABEL[name]}: phoid RMSE ≤ {RMSE_TARGET} × CRB",
                        max(r.values()) <= RMSE_TARGET,
                        ", ".join(f"{q} {r[q]:.2f}" for q in "mck")))
            acc.append((f"{LABEL[name]}: phoid ±3 stderr coverage ≥ 99 %",
                        min(cov.values()) >= COVERAGE_TARGET,
                        ", ".join(f"{q} {cov[q]:.1%}" for q in "mck")))
        else:  # smoke run: too few replicas to judge the targets, only gross misses fail
            lo = {q: ph["rmse_over_crb_95ci"][q][0] for q in "mck"}
            acc.append((f"{LABEL[name]} (smoke run, {ph['n']} replicas): phoid RMSE not "
                        f"significantly above {RMSE_TARGET} × CRB (95 % lower bound)",
                        max(lo.values()) <= RMSE_TARGET,
                        ", ".join(f"{q} {r[q]:.2f} (≥ {lo[q]:.2f})" for q in "mck")))
            acc.append((f"{LABEL[name]} (smoke run): phoid ±3 stderr coverage ≥ 95 %",
                        min(cov.values()) >= SMOKE_COVERAGE,
                        ", ".join(f"{q} {cov[q]:.1%}" for q in "mck")))
        if ph["failed"]:
            acc.append((f"{LABEL[name]}: phoid never fails", False, f"{ph['failed']} failed"))
    sim = res["simulation"]
    if sim:
        dev = sim["target"]["phoid_max_deviation_all_workloads"]
        acc.append(("simulator within 1e−6 x₀ of jitcdde (tight)", dev <= 1e-6, f"{dev:.1e}"))
        jit = sim["target"]["jitcdde_setting"]
        for w, ups in sim["speedup"].items():
            r = ups[jit]
            rep.append((f"simulation ≥ 20× {jit} ({w})", r >= 20, f"{r:.0f}×"))
    for name, s in res["identification_speed"].items():
        for p in ("curve_fit+OLS", bench_identify.NUMJAC):
            r = _ratio(s, p)
            rep.append((f"{LABEL[name]}: identification ≥ 10× faster than {p}", r >= 10,
                        f"{r:.1f}×"))
        if name == "table1":
            t = s["phoid"]["median_s"]
            rep.append(("Table 1 sample set identified in ≤ 100 ms", t <= 0.1,
                        f"{t * 1e3:.0f} ms"))
    sc = res["scaling"]
    if sc:
        for k, s in sc["slopes"].items():
            name = f"{k}: time and memory grow linearly (exponents ≤ 1.1, upper sizes)"
            if "error" in s:
                rep.append((name, False, s["error"]))
                continue
            rep.append((name, max(s["time_upper"], s["memory_upper"]) <= 1.1,
                        f"time {s['time_upper']:.2f}, memory {s['memory_upper']:.2f}"))
        for p in sc["points"]:
            if p["axis"] == "length" and p["size"] == bench_scaling.LENGTHS[-1]:
                name = (f"{p['func']}: 1e7-sample runs need ≤ {FEW_TIMES:g} × their record "
                        "(t, x) in memory")
                if "peak_bytes" not in p:
                    rep.append((name, False, p.get("error", "not measured")))
                    continue
                x = bench_scaling.times_record(p)
                rep.append((name, x <= FEW_TIMES, f"{x:.1f}×"))
    for t in (*res.get("emps", {}).get("targets", []),
              *res.get("adequacy", {}).get("targets", []),
              *res.get("inloop", {}).get("targets", [])):
        (acc if t["enforced"] else rep).append((t["name"], t["ok"], t["got"]))
    st = res.get("startup")
    if st:
        for label, limit in st["targets"].items():
            t = st["wall"][label]["median_s"]
            rep.append((f"`{label}` in ≤ {limit:g} s wall", t <= limit, f"{t:.2f} s"))
    fg = res.get("figures")
    if fg:
        for label in ("identify --plots DIR", "identify --html FILE"):
            t = fg["wall"][label]["median_s"]
            rep.append((f"`phoid {label}` on the example set in ≤ {fg['target']:g} s wall "
                        "(median)", t <= fg["target"], f"{t:.2f} s"))
    failures = [f"{n}: {got}" for n, ok, got in acc if not ok]
    lines = ["## Targets", "",
             "Accuracy targets (`make bench` exits non-zero when one is missed):", ""]
    lines += [f"- {'met' if ok else '**MISSED**'}: {n} ({got})" for n, ok, got in acc]
    lines += ["", "Speed and scaling targets (reported, never enforced: wall-clock times depend "
              "on the machine):", ""]
    lines += [f"- {'met' if ok else '**NOT MET**'}: {n} ({got})" for n, ok, got in rep]
    return lines, failures


PROFILING = [
    "## What changed after profiling",
    "",
    "- **Identification (Table 1 sample set).** cProfile: per run a first look (release, "
    "noise, ESPRIT start and Gauss–Newton after 3Δt, for a rough plant), one full decay fit "
    "(the dominant mode plus the loop's next two modes, from the release), the loop roots "
    "(certified by the argument principle), the model-fitted release time; then the weighted "
    "fit. Changes made after profiling, 137 → 84 → ~70 ms on a quiet machine: root "
    "continuation across runs; the full fit started from the first look; the first pass cut "
    "to the start and Gauss–Newton (no exact residual, covariance or warnings: the estimates "
    "are unchanged to 8 digits on 60 noisy sets); half-contour argument-principle counts "
    "(f(s̄) = conj f(s)); scalar Newton for the few roots of a continuation step; the "
    "data-only release detection stopped at its first stage where the loop's own response "
    "refines it anyway; and one BLAS thread in the hot paths (`phoid._threads`, "
    "threadpoolctl): with OpenBLAS's default pool an identification took 10× longer (950 ms "
    "of CPU) whenever the other core was busy.",
    "- **2026-12-01: 5–17 % less compute** (paired timings of the old and new "
    "code in one process, interleaved, median of the per-call ratios: Table 1 0.85, "
    "overdamped 0.87, mass–damper 0.95; /tmp scripts, not in the bench): the first look "
    "confirms its ESPRIT start by "
    "Gauss–Newton only where the start is in doubt (its frequency off the record's spectral "
    "peak, or a heavily damped pair — the signature of the records where ESPRIT alone is "
    "lost); the argument-principle certificates of the root continuation and of the weighted "
    "fit's final dominance check are counted for all runs in one array evaluation, in rounds "
    "(a run whose continuation loses roots is computed in full at once); each record is "
    "validated once; the χ² quantile by `scipy.special.chdtri`. Estimates move by ≤ 0.01 "
    "stderr on the three sets, and z-scores agree to two digits on 40 random designs. The "
    "machine of the 2026-12-01 runs was slower than that of 2026-11-22 (the old code, timed "
    "in the same process as the new one that day: 85 ms least, 93 ms median CPU time on "
    "Table 1, against 68 ms wall time in the 11-22 run), so this file's absolute times are "
    "not comparable with that run's; the ratios to the alternatives, measured in the same run, "
    "are.",
    "- **2026-12-01 (second session): a further ~22 % less compute on Table 1** (paired as "
    "above against that morning's code: Table 1 0.78, overdamped 0.79, mass–damper 0.90; "
    "estimates unchanged to ~1e−12 stderr): every run's full decay fit is made in one batch "
    "(`phoid.fits.modal`: the tabulated sums, linear solves, Kaufman normal matrices and the "
    "step-halving Gauss–Newton stacked over the runs, the per-sample products and exact "
    "residuals record by record — stacked, those streamed 2–5 MB temporaries from memory and "
    "were slower than the one-by-one fits; fit stage 0.71); the first look's ESPRIT "
    "eigenproblems, solves and eigenvalues stacked (bit-for-bit the same starts); the root "
    "continuation's Newton steps batched over the runs of a round, with one batched "
    "certificate; the model-fitted release candidates of all runs evaluated together; the "
    "weighted fit's whitening matrices in one stacked call. This bench now times the "
    "pipelines interleaved, round by round, in CPU time, and gives each ratio as the median "
    "of the per-round ratios: timed in blocks of wall-clock repeats, the same code read "
    "71 ms (9.9× the default curve_fit) in one run and 91 ms (7.1×) in the next on this "
    "shared 2-core VM.",
    "- **2026-12-01 (third session): a further ~19 % less compute on Table 1** (paired as "
    "above against that session's starting code: Table 1 0.81, overdamped 0.72, mass–damper "
    "0.62; estimates unchanged to ~1e−12 stderr). The first look's release change points in "
    "one batch (`decay._change_points`, exact per record) and its spectral periods in one FFT; "
    "the full fits' fast-mode columns and cross sums stacked (`decay_batch._fast_columns_many`, "
    "fit stage 0.78); the model-fitted release simulating each run's response once, at the "
    "data's rate where the span is uniformly sampled, with block products for short delays "
    "(`simulation.release_response`), and its sums over the samples after τ only (stage 0.4); "
    "the roots' certificate turning the contour's right and top edges exactly from a bound "
    "(|f − ms²| < m|s|² there) instead of sampling them, and a continuation that loses roots "
    "where the gains cross D = 0 retried from the delay chain's asymptotic roots (roots stage "
    "0.66 on Table 1, 0.33 on the mass–damper set, which needed three full computations and "
    "now needs one). A further exact batching of the first look's per-run checks and noise "
    "estimates was tried and left out: 0.9 of that stage, 0.99 of an identification, for 270 "
    "more lines.",
    "- **Where the rest of the time goes.** Per identification of the Table 1 set (60–70 ms "
    "of CPU in this session's runs; stage timer, /tmp script): the batched full fits ~40 % "
    "(each window's preparation, the batch's data products, two evaluations and the exact "
    "residual, the result objects), the first look ~25 % (each record's checks, release "
    "detection, window, uniform-sampling test, block means and median), the roots ~10 %, the "
    "model-fitted release ~10 %, the weighted fit and the result ~15 %. What is left is mostly "
    "passes over the records (one over a 15 200-sample run costs 5–7 µs here, a median "
    "45–60 µs) and per-call overhead (~1.5–5 µs a numpy call); 10× the analytic-Jacobian "
    "curve_fit (itself ~1.7× faster than the default one) would need "
    "about a third less again, i.e. compiled code or fewer passes than the checks and the two "
    "looks at each record need — phoid does not get there by doing less (its RMSE stays at the "
    "Cramér–Rao bound, the pipelines compared here are 1.7–21× it).",
    "- **Overdamped and mass–damper sets.** Their records are 3× shorter than Table 1's "
    "(5 200 vs 15 200 samples per run), and phoid's time per run is mostly a fixed cost, not a "
    "per-sample one, so its ratio to curve_fit+OLS, whose cost is per sample, is smaller than "
    "on Table 1 (and logdec+OLS, a single cheap pass, is about as fast).",
    "- **Simulation of a single run.** Not ≥ 20× jitcdde (7×): cProfile of one 15 s run "
    "shows all of its ~6 ms in the Python loop over the 150 delay intervals "
    "(`simulation._linear_blocks`: one `scipy.signal.lfilter`, `_ch_input` and `_emit` per "
    "interval, ~40 µs each), none in per-sample work; a batch shares that loop among its runs, "
    "hence ≥ 20× there (the table above). Closing the gap for one run needs fewer Python "
    "iterations per delay interval (or a compiled loop), not faster arithmetic.",
    "- **Monte Carlo size.** The first full run (600 phoid replicas per set) read phoid's "
    "RMSE / CRB for c on Table 1 as 1.10 (95 % interval 1.04–1.16). Inspection: the errors "
    "are Gaussian (excess kurtosis 0.07, largest |z| 3.5, no outliers, no link to the "
    "release-time error or the fit's χ²), an independent 1000-replica run (another seed) gave "
    "0.995, the two pooled 1.04 ± 0.02 — the same as phoid's reported stderr / CRB for c "
    "(1.04: phoid also fits the loop's fast-mode amplitudes, which the dominant-mode bound "
    "does not carry). So the miss was Monte Carlo noise around a true ratio 6 % under the "
    "target; phoid now gets 1000 replicas per set (±2.2 % sd), the alternatives 200.",
    "- **Record length 1e7 samples per run (identify).** Profiling the 1e7-sample point "
    "showed the time growing ~50× from 1e6 to 1e7 samples (not 10×): "
    "`phoid.fits.start.uniform_step` accepted a record as uniformly sampled only when every time "
    "stamp was within 1e−9 of a step of the ideal grid, but float64 time stamps near t = 10 s "
    "carry rounding of ~2e−15 s, 2e−9 of a 1 µs step; such records fell to interpolation and "
    "the per-sample `_Direct` evaluator. Fixed: the test now also allows 64 ulp of the "
    "largest time stamp (a regression test covers 1 MHz stamps near 10 s).",
]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: 20 (phoid 100) replicas, 2 repeats, 100-run batch, "
                         "sizes to 1e6")
    ap.add_argument("--replicas", type=int, default=None,
                    help="Monte Carlo replicas for every pipeline (200)")
    ap.add_argument("--phoid-replicas", type=int, default=None,
                    help="Monte Carlo replicas for phoid (1000; --quick: 100)")
    ap.add_argument("--repeats", type=int, default=None, help="timing repeats (9)")
    ap.add_argument("--workers", type=int, default=2, help="Monte Carlo worker processes (2)")
    ap.add_argument("--only",
                    default="sets,mc,speed,sim,scaling,startup,figures,emps,batch,adequacy,"
                            "inloop",
                    help="comma-separated sections to run (for development; the default runs "
                         "all and is what BENCHMARKS.md must come from)")
    ap.add_argument("--write", action="store_true",
                    help="write BENCHMARKS.md and bench/results.json even for a partial run")
    ap.add_argument("--no-progress", action="store_true",
                    help="no progress bar (drawn on stderr only when stdout is a terminal)")
    args = ap.parse_args()
    replicas = args.replicas or (20 if args.quick else 200)
    phoid_replicas = args.phoid_replicas or (100 if args.quick else max(PHOID_REPLICAS,
                                                                       replicas))
    repeats = args.repeats or (2 if args.quick else 9)
    only = set(args.only.split(","))
    t_start = time.perf_counter()

    command = "make bench" if not args.quick else "python bench/run.py --quick"
    opts = []
    if args.replicas:
        opts.append(f"--replicas {args.replicas}")
    if args.phoid_replicas:
        opts.append(f"--phoid-replicas {args.phoid_replicas}")
    if args.repeats:
        opts.append(f"--repeats {args.repeats}")
    if args.workers != 2:
        opts.append(f"--workers {args.workers}")
    if args.only != ap.get_default("only"):
        opts.append(f"--only {args.only}")
    if opts:
        command = f"python bench/run.py {' '.join(opts)}" + (" --quick" if args.quick else "")

    res: dict = {
        "date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "command": command,
        "args": {"replicas": replicas, "phoid_replicas": phoid_replicas, "repeats": repeats,
                 "workers": args.workers,
                 "quick": args.quick},
        "machine": {"cpu": _cpu(), "cores": _ncpu(), "python": platform.python_version(),
                    "numpy": np.__version__, "scipy": scipy.__version__,
                    "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS")},
        "sets": {}, "monte_carlo": {}, "identification_speed": {}, "simulation": {},
        "scaling": {}, "startup": {}, "figures": {}, "emps": {}, "batch": {},
        "adequacy": {},
        "inloop": {},
    }

    # one step of the progress bar per log line: the sets, then each section (per set)
    steps = 1 + sum(len(SETS) if sec in ("speed", "mc") else 1
                    for sec in ("speed", "sim", "mc", "scaling", "startup", "figures", "emps",
                                "batch")
                    if sec in only)
    steps += len(bench_adequacy.CASES) if "adequacy" in only else 0
    steps += len(bench_inloop.CASE_NAMES) if "inloop" in only else 0
    if sys.stdout.isatty() and not args.no_progress:
        phoid_progress(True)
    with progress_task("benchmark", total=steps) as advance:  # erased before the report
        _run_sections(args, res, only, replicas, phoid_replicas, repeats, t_start, advance)
    return _report(args, res, opts, command)


def _run_sections(args, res, only, replicas, phoid_replicas, repeats, t_start, advance
                  ) -> None:
    """Run the sections asked for into ``res`` (one log line and one bar step each)."""
    def log(msg: str) -> None:
        print(f"[{time.perf_counter() - t_start:6.1f} s] {msg}", file=sys.stderr, flush=True)
        advance(description=f"benchmark: {msg}")

    crbs = {}
    for name, spec in SETS.items():
        rings = check_rings(spec)
        crbs[name] = crb_sd(spec)
        res["sets"][name] = {"description": spec.describe(), **rings,
                             "P": list(spec.P), "D": list(spec.D),
                             "crb_sd": dict(zip("mck", crbs[name].tolist(), strict=True))}
    truth = _truth()
    if truth is not None:
        rel = crb_sd(SETS["table1"], "release")
        res["crb_check"] = {"truth": {q: truth[q] for q in "mck"},
                            "residue": res["sets"]["table1"]["crb_sd"],
                            "release": dict(zip("mck", rel.tolist(), strict=True))}
    log("sets checked")
    if "speed" in only:
        for name, spec in SETS.items():
            res["identification_speed"][name] = bench_identify.speed(spec, repeats)
            log(f"identification speed: {name}")
    if "sim" in only:
        res["simulation"] = bench_simulate.run(repeats, batch=100 if args.quick else 1000)
        log("simulation")
    if "mc" in only:
        for name, spec in SETS.items():
            res["monte_carlo"][name] = bench_identify.monte_carlo(
                spec, crbs[name], replicas, phoid_replicas=phoid_replicas,
                workers=args.workers)
            log(f"Monte Carlo: {name}")
    if "scaling" in only:
        res["scaling"] = bench_scaling.run(
            max_length=1_000_000 if args.quick else 10_000_000,
            max_runs=100 if args.quick else 1000)
        log("scaling")
    if "startup" in only:
        res["startup"] = bench_startup.run(5 if args.quick else max(repeats, 20))
        log("start-up")
    if "figures" in only:  # issue 30: --plots and --html on the example set in ≤ 3 s
        res["figures"] = bench_figures.run(2 if args.quick else max(min(repeats, 9), 5))
        log("figures")
    if "emps" in only:
        # ≥ 3 timed calls (issue 17: medians of at least 3); the fits take seconds each
        res["emps"] = bench_emps.run(3 if args.quick else max(3, min(repeats, 5)),
                                     ivp_samples=2000 if args.quick else 5000,
                                     naive_budget=2.0 if args.quick else 5.0)
        if "skipped" in res["emps"]:
            log(f"EMPS skipped: {res['emps']['skipped']}")
        else:
            log("EMPS")
    if "batch" in only:
        res["batch"] = bench_batch.run_all(quick=args.quick)
        log("batch")
    if "adequacy" in only:  # issue 27: stderr coverage on decays the model does not fit
        res["adequacy"] = bench_adequacy.run(
            bench_adequacy.QUICK_REPLICAS if args.quick else bench_adequacy.FULL_REPLICAS,
            workers=args.workers, log=log)
    if "inloop" in only:  # issue 28: noise inside a digital loop, against the in-loop bound
        res["inloop"] = bench_inloop.run(replicas, workers=args.workers,
                                         repeats=min(repeats, 5), log=log)
    res["wall_s"] = time.perf_counter() - t_start


def _report(args, res, opts, command) -> int:
    """Write (for a full run) and print the report; 1 when an accuracy target is missed."""
    write = args.write or (not opts and not args.quick)
    if write:
        (HERE / "results.json").write_text(json.dumps(res, indent=1, default=float))

    target_lines, failures = _targets(res)
    mach = res["machine"]
    lines = [
        "# phoid benchmarks",
        "",
        f"Made by `{command}` on {res['date']} in {res['wall_s'] / 60:.1f} min; CPU: "
        f"{mach['cpu']} ({mach['cores']} cores), Python {mach['python']}, numpy "
        f"{mach['numpy']}, scipy {mach['scipy']}, BLAS threads {mach['blas_threads']}.",
        "Times are medians over repeats with (min–max); every phoid figure stands next to an "
        "alternative measured in the same run. Machine-readable: `bench/results.json`. "
        "`python bench/run.py --quick` is a smoke run of the same code.",
        "",
    ]
    lines += [*target_lines, ""]
    for sec in (_sets_section, _mc_section, _speed_section, _sim_section, _scaling_section,
                _startup_section,
                lambda r: bench_figures.section(r["figures"]) if r.get("figures") else [],
                _emps_section, lambda r: bench_batch.section(r.get("batch")),
                lambda r: bench_adequacy.section(r.get("adequacy")),
                lambda r: bench_inloop.section(r.get("inloop"), r.get("monte_carlo"))):
        part = sec(res)
        if part:
            lines += [*part, ""]
    lines += PROFILING
    text = "\n".join(lines) + "\n"
    if write:
        (ROOT / "BENCHMARKS.md").write_text(text)
    print(text)
    if failures:
        print("accuracy target(s) missed:\n  " + "\n  ".join(failures), file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())

