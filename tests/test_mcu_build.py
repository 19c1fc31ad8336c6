"""The build gate of the rig controller on microcontrollers (issue 29).

phoid's rig controller (src/phoid/rig/c/phoid_ctrl.c) and, where it exists, the firmware's
link core (src/phoid/rig/c/firmware/phoid_fw.c) must build for Cortex-M0, M3, M4F (a float
and a double build), M7 and AVR atmega2560 with the strict flags (tests/mcu_tools.py
STRICT_FLAGS: -std=c99 -Wall -Wextra -Werror -pedantic -Wfloat-equal -ffp-contract=off) at
-O2 and at -Os, use nothing but the compiler runtime (libgcc; on AVR avr-libc's
floating-point routines, where avr-gcc keeps them) and memcpy/memset, link into a firmware
(-nostdlib -nostartfiles, the tests' own start-up) and stay under stated flash and RAM
ceilings. The step path (phoid_step, phoid_step_force and what they call in phoid_ctrl.o)
has no divide instruction and calls no division routine, on every target at -O2 and -Os
(a structural check, whatever the compiler's version; tests/test_mcu_cost.py counts the
instructions). Each test is skipped, naming the Debian package, where its toolchain is
missing.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from mcu_tools import (
    ALLOWED_LIBC,
    CONTROLLER_DIR,
    FIRMWARE_DIR,
    MCU_DIR,
    TARGETS,
    Target,
    compile_sources,
    elf_sizes,
    link,
    need_real,
    need_toolchain,
    run_tool,
    runtime_symbols,
    start_file,
    step_path_divisions,
    tool,
    undefined_symbols,
)

# Flash and RAM ceilings (bytes) of the gate firmware: tests/mcu/cost_main.c (it drives every
# state transition) + the controller + the tests' start-up + the libgcc routines they pull in,
# built at -O2. Flash = text + data, RAM = data + bss (one phoid_ctrl and one phoid_config
# with the default sizes, the stack not counted). Measured at commit 9e5610f (the controller
# with PHOID_REAL, the 128-entry ring) on arm-none-eabi-gcc 12.2 and avr-gcc 5.4, then 25 %
# added and rounded up to 100 bytes, so that a change that grows the firmware by a quarter
# fails here and has to restate its numbers (src/phoid/rig/c/README.md "Cost per target").
#   target: (flash measured, RAM measured)
#   m0 (13492, 2376); m3 (7992, 2376); m4f-float (4396, 1368); m4f-double (7984, 2376);
#   m7 (4812, 2376); avr (9700, 1794: avr-gcc keeps string constants in RAM)
# (bench/bench_mcu.py prints these numbers.)
SIZE_CEILINGS = {
    "m0": (16900, 3000),
    "m3": (10000, 3000),
    "m4f-float": (5500, 1800),
    "m4f-double": (10000, 3000),
    "m7": (6100, 3000),
    "avr": (12200, 2300),
}

GATE_TARGETS = sorted(TARGETS)

# libgcc's software floating point on ARM: __aeabi_d* / __aeabi_f* (arithmetic, comparisons,
# conversions from d and f), __aeabi_i2d, __aeabi_ul2f, ... (from integers), and the GNU names
# (__adddf3, __mulsf3, ...); not the integer helpers (__aeabi_idiv, __aeabi_uldivmod)
SOFT_FLOAT = re.compile(r"^__aeabi_(d|f|[iul]+2[df])|^__\w+[sd]f\d$")

# The same for the firmware of src/phoid/rig/c/firmware (its Makefile, BOARD=mps2_hil: the
# controller, the link core, the MPS2 board's UART code, start-up, memcpy/memset; linked with
# --gc-sections), which runs on the MPS2 boards only (M3, M4F, M7). Measured at commit
# a0e6a97, flash / RAM: m3 10472 / 4416, m4f-float 10464 / 2960, m4f-double 10484 / 4416,
# m7 7944 / 4416; plus 25 %, rounded up to 100.
FIRMWARE_CEILINGS = {
    "m3": (13100, 5600),
    "m4f-float": (13100, 3700),
    "m4f-double": (13200, 5600),
    "m7": (10000, 5600),
}


@pytest.fixture(scope="module")
def runtime() -> dict[str, frozenset[str]]:
    """Per target name, the symbols of its compiler runtime (listed once per module)."""
    return {}


@pytest.fixture(scope="module")
def build_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One folder for every object and firmware of this module."""
    return tmp_path_factory.mktemp("mcu_build")


def _controller_objects(target: Target, build_dir: Path, opt: str) -> list[Path]:
    """The strictly compiled controller and firmware link core (firmware/phoid_fw.c) objects
    of a target, compiled once per module and optimisation level."""
    out = build_dir / f"{target.name}{opt}"
    objects = [out / "phoid_ctrl.o"]
    sources = [CONTROLLER_DIR / "phoid_ctrl.c"]
    if (FIRMWARE_DIR / "phoid_fw.c").exists():
        sources.append(FIRMWARE_DIR / "phoid_fw.c")
        objects.append(out / "phoid_fw.o")
    if all(o.exists() for o in objects):
        return objects
    return compile_sources(target, sources, out, opt=opt, extra=(f"-I{FIRMWARE_DIR}",))


def _board_functions() -> set[str]:
    """The functions firmware/board.h declares: the user's board code, which the firmware's
    link core may call (empty where there is no board.h yet)."""
    header = FIRMWARE_DIR / "board.h"
    if not header.exists():
        return set()
    return set(re.findall(r"\b(board_\w+)\s*\(", header.read_text(encoding="utf-8")))


@pytest.mark.parametrize("opt", ["-O2", "-Os"])
@pytest.mark.parametrize("name", GATE_TARGETS)
def test_strict_build(name: str, opt: str, build_dir: Path) -> None:
    """The controller (and the firmware core) compile with the strict flags, warnings as
    errors, at both optimisation levels (some warnings depend on the optimiser)."""
    target = TARGETS[name]
    need_real(target)
    objects = _controller_objects(target, build_dir, opt)
    assert all(o.stat().st_size > 0 for o in objects)


@pytest.mark.parametrize("name", GATE_TARGETS)
def test_only_the_compiler_runtime(
    name: str, build_dir: Path, runtime: dict[str, frozenset[str]]
) -> None:
    """Every symbol the objects need and do not define is the compiler runtime's, memcpy or
    memset (or a board function of firmware/board.h, the user's to write)."""
    target = TARGETS[name]
    need_real(target)
    objects = _controller_objects(target, build_dir, "-O2")
    if name not in runtime:
        runtime[name] = runtime_symbols(target)
    # an empty runtime list would let nothing through and fail below: guard the listing itself
    assert "__aeabi_dmul" in runtime[name] or "__mulsf3" in runtime[name]
    needed = undefined_symbols(target, objects)
    foreign = needed - runtime[name] - ALLOWED_LIBC - _board_functions()
    assert not foreign, f"{name}: symbols from outside the compiler runtime: {sorted(foreign)}"


@pytest.mark.parametrize("name", GATE_TARGETS)
def test_links_bare_and_fits(name: str, build_dir: Path) -> None:
    """The controller links into a firmware with -nostdlib -nostartfiles and the runtime only,
    within the target's flash and RAM ceilings (SIZE_CEILINGS, with where they come from)."""
    target = TARGETS[name]
    need_toolchain(target)
    need_real(target)
    ctrl = _controller_objects(target, build_dir, "-O2")[0]
    out = build_dir / f"{name}-gate"
    own = compile_sources(target, [start_file(target)], out, strict=False)
    main = compile_sources(target, [MCU_DIR / "cost_main.c"], out)
    elf = link(target, [*own, *main, ctrl], out / "gate.elf")
    flash, ram = elf_sizes(target, elf)
    flash_max, ram_max = SIZE_CEILINGS[name]
    assert flash <= flash_max, f"{name}: flash {flash} B above its ceiling {flash_max} B"
    assert ram <= ram_max, f"{name}: RAM {ram} B above its ceiling {ram_max} B"


def test_float_m4f_controller_runs_on_the_fpu(build_dir: Path) -> None:
    """The float build on the M4F (a single-precision FPU) calls no software floating-point
    routine: its step is the FPU's (the double build calls libgcc's __aeabi_d* for every
    operation, issue 29's 80 calls per step)."""
    target = TARGETS["m4f-float"]
    need_real(target)
    ctrl = _controller_objects(target, build_dir, "-O2")[0]
    soft = {s for s in undefined_symbols(target, [ctrl]) if SOFT_FLOAT.match(s)}
    # the double build of the same object is the counter-example this test must tell apart
    double = _controller_objects(TARGETS["m4f-double"], build_dir, "-O2")[0]
    assert "__aeabi_dmul" in undefined_symbols(TARGETS["m4f-double"], [double])
    assert not soft, f"the float M4F controller calls software floating point: {sorted(soft)}"


@pytest.mark.parametrize("opt", ["-O2", "-Os"])
@pytest.mark.parametrize("name", GATE_TARGETS)
def test_no_division_on_the_step_path(name: str, opt: str, build_dir: Path) -> None:
    """No divide instruction and no division or remainder routine on the step path:
    phoid_step, phoid_step_force and every function of phoid_ctrl.o they call (issue 29: the
    ring's ``% 65`` cost two __aeabi_uidivmod calls per step on the M0, the 0/0 NaN a
    __aeabi_ddiv, or a vdiv on an FPU). Structural, so it holds whatever the compiler version;
    at -Os GCC divides where -O2 multiplies by a reciprocal (``% 65u`` on the M3: udiv)."""
    target = TARGETS[name]
    need_real(target)
    ctrl = _controller_objects(target, build_dir, opt)[0]
    path, divisions = step_path_divisions(target, ctrl)
    # the guard: the step reaches the controller's fault() at least (a disassembly misread
    # would find nothing and pass)
    assert {"phoid_step", "phoid_step_force", "fault"} <= path, path
    assert not divisions, f"{name} {opt}: division on the step path: {'; '.join(divisions)}"


# A step path with a division of each kind, for the counter-example below: a remainder in a
# static function the step calls (a ring index by a size that is not a power of two) and a
# real 0/0 in phoid_step.
_DIVIDING_STEP = """
#ifndef REAL
#define REAL double
#endif
volatile unsigned ring_size = 65u;
volatile REAL zero = 0;
static unsigned __attribute__((noinline)) ring_next(unsigned head, unsigned size)
{
    return (head + 1u) % size;
}
REAL phoid_step_force(REAL x, REAL r)
{
    return x + r + (REAL)ring_next((unsigned)x, ring_size);
}
REAL phoid_step(REAL x)
{
    REAL z = zero;
    return phoid_step_force(x, z / z);
}
"""


@pytest.mark.parametrize("name", GATE_TARGETS)
def test_the_division_check_finds_divisions(name: str, tmp_path: Path) -> None:
    """The step-path check finds a remainder in a called static function and a real division
    in phoid_step on every target (the counter-example of test_no_division_on_the_step_path:
    instruction or runtime routine as the target has them)."""
    target = TARGETS[name]
    src = tmp_path / "dividing_step.c"
    src.write_text(_DIVIDING_STEP, encoding="utf-8")
    real = ("-DREAL=float",) if target.real == "float" else ()
    obj = compile_sources(target, [src], tmp_path, strict=False, extra=real)[0]
    path, divisions = step_path_divisions(target, obj)
    assert path == {"phoid_step", "phoid_step_force", "ring_next"}, path
    assert any(d.startswith("ring_next: ") for d in divisions), divisions
    assert any(d.startswith("phoid_step: ") for d in divisions), divisions


@pytest.mark.parametrize("name", sorted(FIRMWARE_CEILINGS))
def test_firmware_template_builds_and_fits(name: str, build_dir: Path) -> None:
    """The firmware's own Makefile (its strict flags, -nostdlib, libgcc) builds the MPS2 HIL
    firmware for the target, within its flash and RAM ceilings (FIRMWARE_CEILINGS)."""
    target = TARGETS[name]
    need_toolchain(target)
    need_real(target)
    if not (FIRMWARE_DIR / "Makefile").exists():
        pytest.skip("no firmware template (src/phoid/rig/c/firmware/Makefile) yet")
    make = tool("make")
    out = build_dir / f"{name}-firmware"
    out.mkdir(parents=True, exist_ok=True)
    run_tool(
        [make, "-s", "-C", str(FIRMWARE_DIR), f"TARGET={name.split('-')[0]}",
         f"REAL={target.real}", "BOARD=mps2_hil", f"OUT={out}"],
        f"building the firmware template for {name}",
    )
    flash, ram = elf_sizes(target, out / "phoid_fw.elf")
    flash_max, ram_max = FIRMWARE_CEILINGS[name]
    assert flash <= flash_max, f"{name}: firmware flash {flash} B above its ceiling {flash_max} B"
    assert ram <= ram_max, f"{name}: firmware RAM {ram} B above its ceiling {ram_max} B"
