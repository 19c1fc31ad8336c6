"""The rig controller's cost per microcontroller target (issue 29): the table of
src/phoid/rig/c/README.md "Cost per target".

For each target of tests/mcu_tools.py (Cortex-M0, M3, M4F float and double, M7, AVR
atmega2560; and the float build of M0, M3 and M7), built at -O2 with the strict flags: the
instructions (Cortex-M, counted in a QEMU trace) or cycles (AVR, simavr's Timer1) of the
dearest RUN step and of the dearest transition of tests/mcu/cost_main.c, with the transition
named; the flash and RAM of that firmware (the controller, the tests' start-up and the libgcc
routines it pulls in); and the controller's own code (text + data of phoid_ctrl.o, without
the libgcc routines).

    python bench/bench_mcu.py            # a Markdown table on stdout (about 10 s)
    python bench/bench_mcu.py --measured # tests/test_mcu_cost.py's MEASURED and MEASURED_WITH

``--measured`` prints, per target of the tests, the dearest count of each kind of call of
tests/mcu/cost_main.c and the compilers' versions, as the Python to paste into
tests/test_mcu_cost.py when a change to the controller is meant to change its cost (say the
commit and the compiler in the comment above it).

Needs Debian's gcc-arm-none-eabi, qemu-system-arm, gcc-avr, avr-libc and simavr; a target
whose tools are missing is listed as skipped, with the reason.
"""

from __future__ import annotations

import dataclasses
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import pytest  # noqa: E402  (mcu_tools skips through pytest's exceptions)
from mcu_tools import (  # noqa: E402
    TARGETS,
    build_cost_firmware,
    compiler_version,
    elf_sizes,
    measure_cost,
)


def measured() -> int:
    """Print tests/test_mcu_cost.py's MEASURED_WITH and MEASURED; 0, or 1 when a target's
    tools are missing or it failed (nothing printed then: a partial table is no table)."""
    counts: dict[str, dict[str, int]] = {}
    versions: dict[str, str] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, target in TARGETS.items():
            try:
                versions[target.arch] = compiler_version(target)
                costs = measure_cost(target, Path(tmp) / name)
            except (pytest.skip.Exception, pytest.fail.Exception) as exc:
                print(f"{name}: {str(exc).splitlines()[0]}", file=sys.stderr)
                return 1
            kinds: dict[str, int] = {}
            for kind, n in costs:
                kinds[kind] = max(kinds.get(kind, 0), n)
            counts[name] = kinds
    print(f"MEASURED_WITH = {versions!r}")
    print("MEASURED = {")
    for name, kinds in counts.items():
        print(f"    {name!r}: {kinds!r},")
    print("}")
    return 0


def main() -> int:
    """Print the table (or, with --measured, the tests' counts); 0, or 1 when a target failed
    to build or run."""
    if sys.argv[1:] == ["--measured"]:
        return measured()
    if sys.argv[1:]:
        print("usage: python bench/bench_mcu.py [--measured]", file=sys.stderr)
        return 2
    status = 0
    print("| target | RUN step | dearest transition | flash (B) | RAM (B) | phoid_ctrl.o (B) |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        # the tests' targets, then (for the table only) the float build of the other Cortex-M
        extra = {
            f"{n}-float": dataclasses.replace(TARGETS[n], name=f"{n}-float", real="float")
            for n in ("m0", "m3", "m7")
        }
        for name, target in {**TARGETS, **extra}.items():
            unit = "cycles" if target.arch == "avr" else "instructions"
            try:
                costs = measure_cost(target, Path(tmp) / name)
                flash, ram = elf_sizes(target, build_cost_firmware(target, Path(tmp) / name))
            except pytest.skip.Exception as exc:
                print(f"| {name} | skipped: {exc} | | | | |")
                continue
            except pytest.fail.Exception as exc:
                print(f"| {name} | failed: {str(exc).splitlines()[0]} | | | | |")
                status = 1
                continue
            run = max(n for kind, n in costs if kind == "run")
            kind, worst = max(
                ((k, n) for k, n in costs if k not in ("idle", "hold", "run")),
                key=lambda kn: kn[1],
            )
            own, _ = elf_sizes(target, Path(tmp) / name / "phoid_ctrl.o")
            print(f"| {name} | {run} {unit} | {worst} ({kind}) | {flash} | {ram} | {own} |")
    return status


if __name__ == "__main__":
    sys.exit(main())
