"""`make bench`: run the benchmark suite, write BENCHMARKS.md and bench/results.json.

Every figure is a median over repeats with min–max, next to a named alternative measured in the
same run. Exits non-zero only when an accuracy target is missed (never on wall-clock times).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import platform
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT / "tests"))

import bench_identify  # noqa: E402
import bench_simulate  # noqa: E402


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _ncpu() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


def _f(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}g}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--replicas", type=int, default=200, help="Monte Carlo replicas")
    ap.add_argument("--repeats", type=int, default=5, help="timing repeats")
    args = ap.parse_args()

    sim = bench_simulate.run(repeats=args.repeats)
    ident_speed = bench_identify.speed(repeats=max(args.repeats, 5))
    mc = bench_identify.monte_carlo(replicas=args.replicas)

    results = {
        "date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "command": f"make bench (python bench/run.py --replicas {args.replicas} "
                   f"--repeats {args.repeats})",
        "machine": {"cpu": _cpu(), "cores": _ncpu(), "python": platform.python_version()},
        "simulation": sim,
        "identification_speed": ident_speed,
        "monte_carlo_table1": mc,
    }
    (HERE / "results.json").write_text(json.dumps(results, indent=1, default=float))

    failures: list[str] = []
    lines = [
        "# phoid benchmarks",
        "",
        f"Made by `{results['command']}` on {results['date']}; CPU: {results['machine']['cpu']}"
        f" ({results['machine']['cores']} cores), Python {results['machine']['python']}.",
        "Times are medians over repeats with (min–max); every phoid figure stands next to an",
        "alternative measured in the same run. Machine-readable: `bench/results.json`.",
        "",
        "## Simulation: the 19-run Table 1 set (15 s at 1 kHz)",
        "",
        "| simulator | samples/s (median, min–max) | max deviation from jitcdde (tight), × x0 |",
        "|---|---|---|",
    ]
    for row in sim.get("table", []):
        lines.append(f"| {row['name']} | {row['rate']} | {row['deviation']} |")
    for note in sim.get("notes", []):
        lines.append(f"\n{note}")
    ratio = sim.get("speedup_vs_jitcdde")
    if ratio is not None:
        lines.append(f"\nphoid vs jitcdde: **{ratio:.0f}×** the sample rate (target ≥ 20×).")
    dev = sim.get("phoid_max_deviation")
    if dev is not None and dev > 1e-6:
        failures.append(f"simulator deviation {dev:.2g} x0 > 1e-6")

    lines += [
        "",
        "## Identification speed: ../shared/data/paper-sample (19 runs, 15 s, 1 kHz)",
        "",
        "Compute time only (the data are read once beforehand; reading the 19 gzip files takes "
        f"{ident_speed['read_experiment_s'] * 1e3:.0f} ms).",
        "",
        "| pipeline | time per set (median, min–max) | vs phoid |",
        "|---|---|---|",
    ]
    base = ident_speed["phoid"]["median_s"]
    for name in ("phoid", "curve_fit+OLS", "logdec+OLS"):
        s = ident_speed[name]
        lines.append(
            f"| {name} | {s['median_s'] * 1e3:.1f} ms ({s['min_s'] * 1e3:.1f}–"
            f"{s['max_s'] * 1e3:.1f}) | {s['median_s'] / base:.1f}× |"
        )

    crb = mc["crb_sd"]
    lines += [
        "",
        f"## Accuracy at the physical limit: Monte Carlo, {mc['replicas']} noisy replicas of "
        "the Table 1 set",
        "",
        "0.1 mm white noise, 1 µm quantisation, −0.3 mm offset, 0.2 s hold, made by phoid's "
        "simulator; Cramér–Rao sd from ../shared/data/truth.json "
        f"(m {_f(crb['m'])} kg, c {_f(crb['c'])} N s/m, k {_f(crb['k'])} N/m).",
        "",
        "| pipeline | quantity | bias / CRB | RMSE / CRB | mean stderr / sd | ±3 stderr coverage |",
        "|---|---|---|---|---|---|",
    ]
    for name in ("phoid", "curve_fit+OLS", "logdec+OLS"):
        row = mc[name]
        for q in "mck":
            se = row.get("stderr_over_sd", {}).get(q)
            cov = row.get("coverage_3se", {}).get(q)
            lines.append(
                f"| {name} | {q} | {row['bias_over_crb'][q]:+.2f} | {row['rmse_over_crb'][q]:.2f}"
                f" | {'' if se is None else f'{se:.2f}'} | "
                f"{'' if cov is None else f'{cov:.1%}'} |"
            )
    ph = mc["phoid"]
    for q in "mck":
        if ph["rmse_over_crb"][q] > 1.1:
            failures.append(f"phoid RMSE/CRB for {q} = {ph['rmse_over_crb'][q]:.2f} > 1.1")
        if ph["coverage_3se"][q] < 0.99:
            failures.append(f"phoid 3-stderr coverage for {q} = {ph['coverage_3se'][q]:.1%}")
    lines += ["", "## Targets", ""]
    if failures:
        lines += [f"- MISSED (accuracy): {f}" for f in failures]
    else:
        lines.append("- accuracy: all targets met (phoid RMSE ≤ 1.1 × CRB, ±3 stderr coverage "
                     "≥ 99 %, simulator within 1e-6 x0 of jitcdde)")
    # speed targets are reported, never enforced (wall-clock times depend on the machine)
    t_ph = ident_speed["phoid"]["median_s"]
    ratio_cf = ident_speed["curve_fit+OLS"]["median_s"] / t_ph
    speed = [
        ("identification ≤ 100 ms", t_ph <= 0.1, f"{t_ph * 1e3:.0f} ms"),
        ("identification ≥ 10× the curve_fit pipeline", ratio_cf >= 10, f"{ratio_cf:.1f}×"),
    ]
    if ratio is not None:
        speed.append(("simulation ≥ 20× jitcdde", ratio >= 20, f"{ratio:.0f}×"))
    for name, ok, got in speed:
        lines.append(f"- speed: {name}: {'met' if ok else 'NOT MET'} ({got})")
    lines += [
        "",
        "Where the identification time goes (cProfile, sample set): two decay fits per run "
        "(~1.4 ms for the first pass, ~1.0 ms for the second, mostly fixed per-call cost: "
        "release detection, starting guess, Gauss-Newton on 15 000 samples), the loop roots of "
        "every run (certified by the argument principle, continued from run to run), the "
        "model-fitted release times and the weighted fit. Changes made after profiling: root "
        "continuation across runs, the second pass started from the first pass's mode, and "
        "leaner per-call work in the decay fit (137 → ~80 ms). Reaching 10× the curve_fit "
        "pipeline (~50 ms) needs a cheaper decay fit still (closed-form sums, a leaner release "
        "detector) or a single pass.",
    ]
    (ROOT / "BENCHMARKS.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
